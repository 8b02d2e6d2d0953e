"""Tissue that deforms: an organ meshed in tetrahedra from its segmentation, linear
elasticity on it, and the condensed compliance that moves the target, the vessels and the
airways under a needle's loads and under breathing inside a 40 Hz loop (docs/tissue.md).

- :mod:`needlekit.tissue.meshing`: mask -> tetrahedral mesh.
- :mod:`needlekit.tissue.fem`: material, stiffness, boundary conditions, solves.
- :mod:`needlekit.tissue.compliance`: the precomputation (and its cache).
- :mod:`needlekit.tissue.runtime`: :class:`~needlekit.tissue.runtime.DeformingTissue`.
"""
