"""The shaft held by the tissue along its channel: one quasi-static solve.

The needle runs from a guide (clamped: position and direction held) over a free gap
``g`` to the tissue's surface, then along the channel its tip has cut. Arc length ``s``
(mm) is measured from the guide; the rod's length is ``g + depth``.

The solve is linearised about the *reference curve*: the guide's straight line over
``[0, g]``, then the channel. The rod's position is the reference plus small offsets
``u_x e_x + u_y e_y`` in the reference's transported normal frame, so paths that bend
far from the straight line (radii of 50-200 mm over 100-150 mm) stay exact to first
order in the offsets (tenths of a millimetre), not in the overall bend. The rod is
straight when unloaded, so following the reference costs bending energy: per element, in
the frame of its first node, the reference is the Hermite cubic with end offsets
``(0, 0, (p_1 - p_0) . e, t_1 . e)`` and the total deflection is that plus the offsets;
its bending stiffness times the reference gives the load that pulls the rod off a bent
channel. The tissue holds the shaft toward the channel (the anchors) by a Winkler
foundation ``k`` over ``[g, g + depth - L_u]``; the last ``L_u`` behind the tip (the
bevel) is not held. The tip carries the bevel's lateral load; a pre-bent tip adds its
stress-free curvature over its last ``L_k`` (the reference minus the rest shape). The two bending planes
share one banded Cholesky factorisation.

Left out (docs/mechanics.md): axial load in the bending equation (buckling; the tip's
axial resistance is small beside ``EI / L^2``), shaft friction, torsion (the shaft is
torsionally rigid: the bevel turns as the base does).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from needlekit.errors import InvalidInputError
from needlekit.mechanics._kernels import (
    foundation_kernel,
    node_positions_kernel,
    offsets_kernel,
    reference_kernel,
    rod_solve_kernel,
)
from needlekit.mechanics.channel import Channel
from needlekit.mechanics.rod import (
    assemble_upper_band,
    element_foundation,
    element_stiffness,
    solve_band,
)

__all__ = [
    "MIN_ELEMENT_FRACTION",
    "ShaftSolution",
    "node_positions",
    "node_positions_reference",
    "solve_linear_reference",
    "solve_shaft",
]

#: No foundation factors (a homogeneous tissue).
_NO_FACTORS = np.zeros(0)

#: Shortest element, as a fraction of the element length: nodes closer are merged (a
#: break such as the support's end then moves by at most this much).
MIN_ELEMENT_FRACTION = 0.05


@dataclass
class ShaftSolution:
    """One solve of the shaft in its channel.

    Attributes
    ----------
    s_mm : ndarray, shape (n,)
        Node arc lengths from the guide (mm).
    ref_mm, tangents, e_x, e_y : ndarray, shape (n, 3)
        The reference curve at the nodes and its frame.
    offsets_mm : ndarray, shape (n, 2)
        Deflection off the reference along ``e_x`` and ``e_y`` (mm).
    slopes : ndarray, shape (n, 2)
        Slope off the reference's tangent toward ``e_x`` and ``e_y`` (rad).
    tissue_forces_n : ndarray, shape (n, 3)
        The tissue's force on the shaft lumped at each node (consistent nodal forces of
        the foundation), world frame (N).
    """

    s_mm: np.ndarray
    ref_mm: np.ndarray
    tangents: np.ndarray
    e_x: np.ndarray
    e_y: np.ndarray
    offsets_mm: np.ndarray
    slopes: np.ndarray
    tissue_forces_n: np.ndarray

    @property
    def points_mm(self) -> np.ndarray:
        """The rod's node positions (world mm), shape (n, 3)."""
        u = self.offsets_mm
        return self.ref_mm + u[:, :1] * self.e_x + u[:, 1:] * self.e_y


def node_positions(gap_mm: float, depth_mm: float, breaks_mm, h_mm: float):
    """Node arc lengths: fixed to the tissue's entry, plus the given breaks and the tip.

    Parameters
    ----------
    gap_mm : float
        Free length between guide and tissue (mm).
    depth_mm : float
        Inserted depth (mm).
    breaks_mm : sequence of float
        Arc lengths that must be nodes (mm): where the tissue stops holding the shaft,
        where a pre-bent tip starts; those outside ``(gap_mm, tip)`` are ignored.
    h_mm : float
        Element length (mm).

    Returns
    -------
    ndarray, shape (n,)
        Increasing node positions from 0 to ``gap_mm + depth_mm``; elements lie wholly on
        one side of each break, no element is shorter than ``MIN_ELEMENT_FRACTION h_mm``
        (closer breaks are merged) unless the rod itself is.
    """
    b = np.asarray(breaks_mm, dtype=np.float64).reshape(-1)
    return node_positions_kernel(float(gap_mm), float(depth_mm), b, float(h_mm), MIN_ELEMENT_FRACTION)


def node_positions_reference(gap_mm: float, depth_mm: float, breaks_mm, h_mm: float):
    """:func:`node_positions` in numpy: the reference of the compiled kernel (the same
    parameters and result).

    Parameters
    ----------
    gap_mm, depth_mm : float
    breaks_mm : sequence of float
    h_mm : float

    Returns
    -------
    ndarray, shape (n,)
    """
    tip = gap_mm + depth_mm
    n_gap = max(1, math.ceil(gap_mm / h_mm - 1e-9)) if gap_mm > 0 else 0
    parts = [np.linspace(0.0, gap_mm, n_gap + 1)] if n_gap else [np.zeros(1)]
    inner = gap_mm + h_mm * np.arange(1, max(1, math.ceil(depth_mm / h_mm)))
    must = [tip] + [b for b in breaks_mm if gap_mm < b < tip - 1e-9]
    tol = 0.3 * h_mm
    keep = np.ones(inner.size, dtype=bool)
    for m in must:
        keep &= np.abs(inner - m) >= tol
    parts.append(inner[keep & (inner < tip)])
    parts.append(np.array(must))
    s = np.unique(np.concatenate(parts))
    s = s[s < tip]
    # no element shorter than MIN_ELEMENT_FRACTION h (its stiffness would swamp the rest)
    # (a node dropped for its predecessor leaves its successor at least min_len away)
    min_len = MIN_ELEMENT_FRACTION * h_mm
    keep = np.ones(s.size, dtype=bool)
    keep[1:] = (np.diff(s) >= min_len) & (tip - s[1:] >= min_len)
    return np.append(s[keep], tip)


def solve_linear_reference(lengths, ei, k_e, ref, fx: float, fy: float):
    """The rod's linear solve in numpy: the reference of the compiled kernel.

    Parameters
    ----------
    lengths : ndarray, shape (e,)
        Element lengths (mm).
    ei : float
        Flexural rigidity (N mm^2).
    k_e : ndarray, shape (e,)
        Foundation modulus per element (N/mm^2).
    ref : ndarray, shape (e, 4, 2)
        Each element's reference offsets (minus a rest shape), both planes.
    fx, fy : float
        Tip force in the two planes (N).

    Returns
    -------
    sol : ndarray, shape (2 (e + 1), 2)
        Deflections and slopes (zero at the clamped first node).
    nodal : ndarray, shape (e + 1, 2)
        The foundation's consistent nodal forces on the rod (N).
    """
    kb = element_stiffness(lengths, ei)
    kf = element_foundation(lengths, k_e)
    ab = assemble_upper_band(kb + kf)
    f_el = -(kb @ ref)
    n = lengths.size + 1
    rhs = np.zeros((2 * n, 2))
    for a in range(4):
        rhs[a : a + 2 * lengths.size : 2] += f_el[:, a]
    rhs[-2, 0] += fx
    rhs[-2, 1] += fy
    sol = solve_band(ab, rhs, 2)
    ue = np.stack([sol[0:-2:2], sol[1:-2:2], sol[2::2], sol[3::2]], axis=1)  # (e, 4, 2)
    fe = -(kf @ ue)
    nodal = np.zeros((n, 2))
    nodal[:-1] += fe[:, 0]
    nodal[1:] += fe[:, 2]
    return sol, nodal


def _reference(channel: Channel, guide, s: np.ndarray, gap: float):
    """Reference points, tangents and frames at the nodes (compiled once the channel has
    two points: :func:`~needlekit.mechanics._kernels.reference_kernel`, the same bits)."""
    if channel.n > 1:
        g = [np.ascontiguousarray(v, dtype=np.float64) for v in guide]
        return reference_kernel(s, float(gap), g[0], g[1], g[2], channel.depth_mm,
                                channel.points_mm, channel.tangents, channel.normals_x)  # fmt: skip
    return _reference_numpy(channel, guide, s, gap)


def _reference_numpy(channel: Channel, guide, s: np.ndarray, gap: float):
    """:func:`_reference` in numpy (its reference, and a channel of one point)."""
    g_pos, g_tan, g_ex = guide
    n = s.size
    pos = np.empty((n, 3))
    tan = np.empty((n, 3))
    ex = np.empty((n, 3))
    on_guide = s <= gap
    pos[on_guide] = g_pos + s[on_guide, None] * g_tan
    tan[on_guide] = g_tan
    ex[on_guide] = g_ex
    inside = ~on_guide
    if np.any(inside):
        pos[inside], tan[inside], ex[inside] = channel.sample(s[inside] - gap)
    ey = np.empty_like(ex)  # tan x ex, written out (np.cross is slow on small arrays)
    ey[:, 0] = tan[:, 1] * ex[:, 2] - tan[:, 2] * ex[:, 1]
    ey[:, 1] = tan[:, 2] * ex[:, 0] - tan[:, 0] * ex[:, 2]
    ey[:, 2] = tan[:, 0] * ex[:, 1] - tan[:, 1] * ex[:, 0]
    return pos, tan, ex, ey


def _offsets_numpy(s, pos, tan, ex, ey, rest_curvature_xy, rest_length_mm, bend_start):
    """Element lengths and the reference's end offsets in each element's first-node frame,
    both planes, less a pre-bent tip's stress-free shape (its Hermite offsets ``c l^2 / 2``
    and ``c l``): the numpy reference of
    :func:`~needlekit.mechanics._kernels.offsets_kernel`."""
    lengths = np.diff(s)
    mid = 0.5 * (s[1:] + s[:-1])
    chord = pos[1:] - pos[:-1]
    ref = np.zeros((lengths.size, 4, 2))
    ref[:, 2, 0] = np.sum(chord * ex[:-1], axis=1)
    ref[:, 3, 0] = np.sum(tan[1:] * ex[:-1], axis=1)
    ref[:, 2, 1] = np.sum(chord * ey[:-1], axis=1)
    ref[:, 3, 1] = np.sum(tan[1:] * ey[:-1], axis=1)
    if rest_length_mm > 0.0:
        bent = mid > max(bend_start, 0.0)
        for p, c in enumerate(rest_curvature_xy):
            ref[bent, 2, p] -= 0.5 * c * lengths[bent] ** 2
            ref[bent, 3, p] -= c * lengths[bent]
    return lengths, ref


def solve_shaft(
    channel: Channel,
    guide,
    gap_mm: float,
    depth_mm: float,
    ei: float,
    k: float,
    unsupported_mm: float,
    tip_force_xy: tuple[float, float],
    h_mm: float,
    rest_curvature_xy: tuple[float, float] = (0.0, 0.0),
    rest_length_mm: float = 0.0,
    *,
    k_by_mm=None,
    reference: bool = False,
) -> ShaftSolution:
    """Solve the shaft against its channel with a lateral tip force (module notes).

    Parameters
    ----------
    channel : Channel
        The channel cut so far; its end is at ``depth_mm``.
    guide : tuple of ndarray
        The guide's exit point, direction and normal ``e_x`` (world), each shape (3,).
    gap_mm : float
        Free length between guide and tissue (mm).
    depth_mm : float
        Inserted depth (mm).
    ei : float
        Flexural rigidity (N mm^2).
    k : float
        Foundation modulus (N/mm^2).
    unsupported_mm : float
        Length behind the tip the tissue does not hold (mm).
    tip_force_xy : tuple of float
        Lateral force on the tip along the channel end's ``e_x`` and ``e_y`` (N).
    h_mm : float
        Element length (mm).
    rest_curvature_xy : tuple of float
        Stress-free curvature of a pre-bent tip, toward ``e_x`` and ``e_y`` (1/mm).
    rest_length_mm : float
        Length of the pre-bent tip segment (mm); 0 for none.
    k_by_mm : ndarray, optional
        The foundation's factor for each whole millimetre of depth (the tissue's
        inhomogeneity): an element whose middle lies in millimetre ``i`` is held by
        ``k * k_by_mm[i]`` (the last factor beyond the array's end).
    reference : bool
        Solve with the numpy reference instead of the compiled kernel.

    Returns
    -------
    ShaftSolution
    """
    tip = gap_mm + depth_mm
    support_end = tip - unsupported_mm
    bend_start = tip - rest_length_mm
    s = node_positions(gap_mm, depth_mm, (support_end, bend_start), h_mm)
    pos, tan, ex, ey = _reference(channel, guide, s, gap_mm)
    factors = _NO_FACTORS if k_by_mm is None else np.ascontiguousarray(k_by_mm, dtype=np.float64)
    k_e = foundation_kernel(s, float(gap_mm), float(support_end), float(k), factors)
    if reference:
        lengths, ref = _offsets_numpy(s, pos, tan, ex, ey, rest_curvature_xy, rest_length_mm, bend_start)
        sol, nodal = solve_linear_reference(lengths, ei, k_e, ref, *tip_force_xy)
    else:
        cx, cy = (float(c) for c in rest_curvature_xy)
        lengths, ref = offsets_kernel(s, pos, tan, ex, ey, cx, cy, float(rest_length_mm), float(bend_start))
        sol, nodal, ok = rod_solve_kernel(
            lengths, float(ei), k_e, ref, float(tip_force_xy[0]), float(tip_force_xy[1])
        )
        if not ok:
            raise InvalidInputError("rod", "the shaft's stiffness is not positive definite")
    u = sol[0::2]
    th = sol[1::2]
    forces = nodal[:, :1] * ex + nodal[:, 1:] * ey
    return ShaftSolution(s, pos, tan, ex, ey, u, th, forces)
