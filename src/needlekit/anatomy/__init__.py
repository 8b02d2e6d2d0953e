"""Anatomy: distance fields, scenes of named structures, real segmentations and phantoms."""
