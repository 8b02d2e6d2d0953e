"""Figures and reports built from needlekit results (matplotlib Agg; no plotting elsewhere)."""
