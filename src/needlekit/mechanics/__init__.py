"""The needle as an elastic rod in tissue: a bevel-tip needle that bends by mechanics.

- :mod:`~needlekit.mechanics.materials`: needle and tissue specifications, checked, with
  presets (units mm, N, MPa = N/mm^2, rad);
- :mod:`~needlekit.mechanics.rod`: Euler-Bernoulli beam finite elements (Hermite cubics)
  on an elastic foundation, assembled banded and solved by a banded Cholesky;
- :mod:`~needlekit.mechanics.tip_load`: the bevel's load on the tip, from its geometry and
  the tissue's stiffness and rupture toughness;
- :mod:`~needlekit.mechanics.insertion`: a quasi-static insertion along the channel the
  tip cuts, :class:`~needlekit.mechanics.insertion.MechanicalNeedle`, with the execution's
  truth protocol (``pose``, ``inserted_mm``, ``step``).

See docs/mechanics.md for the model, its parameters and its measured errors.
"""
