"""Straight multi-needle planning: problem, CFRW, entries, sequence, ablation coverage."""
