"""Curved (steerable) needle planning: problem, planners, verification, direction sweep."""
