"""Needle path planning: steerable (curved) needles and straight multi-needle plans."""
