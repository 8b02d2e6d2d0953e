"""A quasi-static insertion of a bevel-tip needle: the needle that bends by mechanics.

The tissue holds the shaft toward the channel the tip has cut (virtual springs anchored
on the cut path, as in Roesthuis et al. 2012, here a continuous Winkler foundation); a
guide at the base holds position and direction; between the guide and the tissue the rod
is free. Each step inserts ``ds``, in sub-steps of at most ``max_substep_mm`` (a tenth of
that over the first ``4 max(L_u, L_k, 1 mm)``, where the tissue takes hold): the tip
cuts the sub-step along its current (deflected) tangent, extending the channel; then the
rod is solved against the channel with the bevel's load at the tip
(:func:`needlekit.mechanics.shaft.solve_shaft`), which gives the tip's new position and
tangent. Curvature is nowhere a parameter: the path bends because the tip load turns the
tip against the shaft's stiffness and the tissue's hold, and how much follows from the
needle's ``EI`` and bevel and the tissue's modulus and toughness.

**Bevel duty-cycling.** A command ``kappa_per_mm`` maps to a duty fraction
``f = kappa / kappa_max``: for a fraction ``f`` of the step the bevel is held, for the
rest it spins, which averages its lateral load out, so the step carries the mean lateral
load ``f Q`` toward the tip's -y axis. The model is linear, so the path's curvature
after the transient is ``f kappa_max`` exactly. A negative command bends toward +y (as
spinning by pi would); ``|f|`` is clipped at 1: the needle cannot bend more than its
held bevel makes it.

**The load follows the depth cut.** The bevel face, ``L_b = d / tan(alpha)`` long, carries
the load of the tissue it has wedged: tissue enters contact at the point and leaves at the
heel as the needle advances ``L_b``. So the rod is solved with the mean of the commanded
loads over the last ``L_b`` of depth (each recorded in the channel's transported frame),
and a pre-bent tip's curvature with the mean over its own length. Depths before the entry
count as the first command for the bevel's load, so a constant command acts in full from
the start; a pre-bent tip leaves a straight introducer at the surface, so before the entry
its curvature counts as zero and its bend grows over its own length as it cuts (the tip
enters along its aim instead of turning at once by the bend a first command asks for). A spin in
place turns the tip frame but loads nothing until the tip cuts, and a step of ``ds``
changes the load by at most ``2 Q min(1, ds / L_b)``. Applied at once, a change of the
duty or the bevel's direction moved the tip by the shaft's whole static compliance times
the change (up to ``2 lambda / k`` per newton: 9.7 mm per 0.05 mm step for nitinol in
lung; docs/mechanics.md, "Commands that change every step").

**Pre-bent tips** (:meth:`NeedleSpec.with_prebend
<needlekit.mechanics.materials.NeedleSpec.with_prebend>`): the tip segment's stress-free
curvature points to the bevel's side and is duty-cycled like the bevel's load. Its radii
are indicative: the shaft's slope off the channel reaches 0.1-0.4 rad, past the
small-offset premise of the solve.

**Torsion** is left out: the shaft is torsionally rigid, so a spin of the base turns the
bevel by the same angle, and the tip frame is the channel's transported frame turned by
the accumulated spin about the tangent.

**Anchors.** :meth:`MechanicalNeedle.channel_points_mm` are the tissue's anchors;
:meth:`MechanicalNeedle.displace_channel` moves them (a tissue model deforming under
:meth:`MechanicalNeedle.shaft_loads` feeds back this way) and re-solves the rod.

**Noise** (tissue inhomogeneity), zero by default: with ``inhomogeneity > 0`` and an
``rng``, each millimetre of depth scales the tissue's modulus by ``1 + sigma N(0, 1)``
(clipped at 0): the foundation that holds the shaft there, and the bevel's load (the
wedged tissue's reaction) while the tip cuts it; and a lateral load ``sigma Q N(0, I_2)``
is added in the tip's normal plane.

Frames and units: RAS mm, N; the tip frame's z axis is the tangent, the bevel bends the
needle toward the tip's -y axis (:mod:`needlekit.conventions`), as the planner's arcs
(:mod:`needlekit.geometry.arcs`) do.
"""

from __future__ import annotations

import bisect
import math

import numpy as np

from needlekit.errors import InvalidInputError
from needlekit.geometry.so3 import cross3
from needlekit.mechanics.channel import Channel, transport
from needlekit.mechanics.materials import NeedleSpec, TissueSpec
from needlekit.mechanics.shaft import ShaftSolution, solve_shaft
from needlekit.mechanics.tip_load import bevel_tip_load

__all__ = ["MechanicalNeedle", "steady_curvature"]

_KAPPA_CACHE: dict[tuple, float] = {}


def _number(name: str, value, *, low: float = 0.0, strict: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.floating, np.integer)):
        raise InvalidInputError(name, f"expected a number, got {value!r}")
    v = float(value)
    bad = not math.isfinite(v) or (v <= low if strict else v < low)
    if bad:
        op = ">" if strict else ">="
        raise InvalidInputError(name, f"expected a finite number {op} {low:g}, got {value!r}")
    return v


class _ContactHistory:
    """What the tip has been commanded per millimetre of depth, and its mean over a window.

    Each sub-step records its command (the lateral load and the pre-bend's curvature,
    in the channel's transported frame) over the depths it cut. :meth:`mean` is the
    average of the commands over the last ``window`` of depth: the load the bevel face
    carries is that of the tissue it wedged, which entered at the point and leaves at the
    heel as the needle advances one bevel length. Depths before the entry count as the
    first command with its pre-bend taken out: a constant load acts in full from depth 0,
    and a pre-bent tip is straight in its introducer until it cuts.
    """

    def __init__(self) -> None:
        self.depth = [0.0]  # segment ends, increasing
        self.cum = [np.zeros(4)]  # integral of the command up to each end
        self.value: list[np.ndarray] = []  # the command over each segment

    def record(self, depth_end: float, value: np.ndarray) -> None:
        start = self.depth[-1]
        self.depth.append(depth_end)
        self.cum.append(self.cum[-1] + (depth_end - start) * value)
        self.value.append(value)

    def _integral(self, z: float) -> np.ndarray:
        if z <= 0.0:
            before = self.value[0].copy()
            before[2:] = 0.0  # the pre-bend: straight in the introducer
            return z * before
        i = min(bisect.bisect_left(self.depth, z), len(self.depth) - 1)
        return self.cum[i] - (self.depth[i] - z) * self.value[i - 1]

    def mean(self, window: float) -> np.ndarray:
        end = self.depth[-1]
        if window <= 0.0:
            return self.value[-1].copy()
        return (self.cum[-1] - self._integral(end - window)) / window


class MechanicalNeedle:
    """The true tip of one insertion, from the needle's and tissue's mechanics.

    Parameters
    ----------
    start_pose : ndarray, shape (4, 4)
        The tip where the insertion starts, on the tissue's surface (RAS mm).
    needle_spec : NeedleSpec or str
        The needle, or a preset name (``"nitinol"``, ``"steel"``).
    tissue_spec : TissueSpec or str
        The tissue, or a preset name.
    rng : numpy.random.Generator, optional
        Draws the tissue inhomogeneity (only when ``inhomogeneity > 0``).
    guide_gap_mm : float
        Free length between the guide and the tissue's surface (mm), >= 0.
    element_mm : float
        Element length of the rod's mesh (mm), > 0.
    max_substep_mm : float
        Longest sub-step the tip cuts before the rod is solved again (mm), > 0.
    inhomogeneity : float
        Relative SD of the tip load per millimetre of depth, >= 0 (see module notes).

    Attributes
    ----------
    pose : ndarray, shape (4, 4)
        The tip now.
    inserted_mm : float
        Depth inserted so far (mm).
    """

    def __init__(
        self,
        start_pose,
        needle_spec: NeedleSpec | str = "nitinol",
        tissue_spec: TissueSpec | str = "plastisol",
        rng=None,
        *,
        guide_gap_mm: float = 10.0,
        element_mm: float = 1.0,
        max_substep_mm: float = 1.0,
        inhomogeneity: float = 0.0,
    ) -> None:
        pose = np.array(start_pose, dtype=np.float64)
        if pose.shape != (4, 4) or not np.all(np.isfinite(pose)):
            raise InvalidInputError("start_pose", "expected a 4x4 matrix of finite numbers")
        rot = pose[:3, :3]
        if not np.allclose(rot.T @ rot, np.eye(3), atol=1e-6) or np.linalg.det(rot) <= 0:
            raise InvalidInputError("start_pose", "expected a rotation in the upper-left 3x3")
        needle = NeedleSpec.preset(needle_spec) if isinstance(needle_spec, str) else needle_spec
        tissue = TissueSpec.preset(tissue_spec) if isinstance(tissue_spec, str) else tissue_spec
        if not isinstance(needle, NeedleSpec):
            raise InvalidInputError("needle_spec", f"expected a NeedleSpec, got {needle!r}")
        if not isinstance(tissue, TissueSpec):
            raise InvalidInputError("tissue_spec", f"expected a TissueSpec, got {tissue!r}")
        self.gap_mm = _number("guide_gap_mm", guide_gap_mm)
        self.element_mm = _number("element_mm", element_mm, strict=True)
        self.max_substep_mm = _number("max_substep_mm", max_substep_mm, strict=True)
        self.inhomogeneity = _number("inhomogeneity", inhomogeneity)
        if self.inhomogeneity > 0 and rng is None:
            raise InvalidInputError("rng", "inhomogeneity > 0 needs a numpy Generator")
        self.needle = needle
        self.tissue = tissue
        self.rng = rng
        self.ei = needle.bending_stiffness_nmm2
        self.k = tissue.foundation_modulus(needle)
        self.unsupported_mm = tissue.unsupported_length(needle)
        self.tip_load = bevel_tip_load(needle, tissue)
        # the start, where the tissue takes hold of the shaft: sub-steps a tenth as long
        self._onset_mm = 4.0 * max(self.unsupported_mm, needle.prebend_length_mm, 1.0)

        z, x = rot[:, 2].copy(), rot[:, 0].copy()
        self.channel = Channel(pose[:3, 3].copy(), z, x)
        self.guide = (pose[:3, 3] - self.gap_mm * z, z, x)
        self._spin = 0.0  # bevel's turn about the tangent from the transported frame
        self._tip_pos = pose[:3, 3].copy()
        self._tip_tan = z
        self._tip_ex = x
        self._noise = np.zeros((0, 3))
        self._k_by_mm = np.zeros(0)  # the tissue's modulus per millimetre (the noise's first column)
        self._last_force_xy = (0.0, 0.0)
        self._rest_xy = (0.0, 0.0)
        self._history = _ContactHistory()
        self.solution: ShaftSolution | None = None
        self.inserted_mm = 0.0
        self.pose = self._compose_pose()

    # ------------------------------------------------------------------------------------
    @property
    def kappa_max_per_mm(self) -> float:
        """The path's curvature with the bevel held in this tissue (1/mm), from the model.

        The steady state of a long insertion (:func:`steady_curvature`), cached per needle,
        tissue and discretisation.
        """
        return steady_curvature(
            self.needle, self.tissue, self.gap_mm, self.element_mm, self.max_substep_mm
        )

    def _compose_pose(self) -> np.ndarray:
        t, ex = self._tip_tan, self._tip_ex
        ey = cross3(t, ex)
        c, s = math.cos(self._spin), math.sin(self._spin)
        g = np.eye(4)
        g[:3, 0] = c * ex + s * ey
        g[:3, 1] = -s * ex + c * ey
        g[:3, 2] = t
        g[:3, 3] = self._tip_pos
        return g

    def _noise_at(self, depth_mm: float) -> np.ndarray:
        """(load factor, lateral x, lateral y) for the millimetre of depth holding the tip."""
        if self.inhomogeneity == 0.0:
            return np.array([1.0, 0.0, 0.0])
        i = int(depth_mm)
        while self._noise.shape[0] <= i:
            draw = self.rng.normal(0.0, self.inhomogeneity, (16, 3))
            draw[:, 0] = np.maximum(0.0, 1.0 + draw[:, 0])
            self._noise = np.vstack([self._noise, draw])
            self._k_by_mm = np.ascontiguousarray(self._noise[:, 0])
        return self._noise[i]

    def _solve(self) -> None:
        fx, fy = self._last_force_xy
        sol = solve_shaft(
            self.channel,
            self.guide,
            self.gap_mm,
            self.inserted_mm,
            self.ei,
            self.k,
            self.unsupported_mm,
            (fx, fy),
            self.element_mm,
            self._rest_xy,
            self.needle.prebend_length_mm,
            k_by_mm=self._k_by_mm if self.inhomogeneity > 0.0 else None,
        )
        self.solution = sol
        u, th = sol.offsets_mm[-1], sol.slopes[-1]
        t_ref, ex_ref, ey_ref = sol.tangents[-1], sol.e_x[-1], sol.e_y[-1]
        self._tip_pos = sol.ref_mm[-1] + u[0] * ex_ref + u[1] * ey_ref
        tan = t_ref + th[0] * ex_ref + th[1] * ey_ref
        tan /= np.linalg.norm(tan)
        ex = transport(ex_ref, t_ref, tan)
        self._tip_ex = ex / np.linalg.norm(ex)
        self._tip_tan = tan

    def _substep(self, length: float, duty: float) -> None:
        """Cut ``length`` and re-solve: a predictor-corrector (Heun) step.

        The predictor cuts along the tip's tangent now and solves; the corrector cuts
        again, ending with the predicted tangent (the chord along the mean of the two),
        and solves: the path is second order in the sub-step.
        """
        noise = self._noise_at(self.inserted_mm + length)
        q = duty * self.tip_load.lateral_n * noise[0]
        c, s = math.cos(self._spin), math.sin(self._spin)
        q0 = self.tip_load.lateral_n
        rest = duty * self.needle.rest_curvature_per_mm
        # toward the tip's -y axis, -(-s e_x + c e_y), plus the inhomogeneity's push; the
        # pre-bend's curvature the same way
        command = np.array([q * s + q0 * noise[1], -q * c + q0 * noise[2], rest * s, -rest * c])
        self._history.record(self.inserted_mm + length, command)
        # the face carries the load of the tissue it wedged over the last bevel length;
        # the pre-bent segment lies in the tissue it cut over its own length
        fx, fy = self._history.mean(self.needle.bevel_length_mm)[:2]
        self._last_force_xy = (float(fx), float(fy))
        rx, ry = self._history.mean(self.needle.prebend_length_mm)[2:]
        self._rest_xy = (float(rx), float(ry))
        self.inserted_mm += length
        self.channel.extend(length, self._tip_tan.copy())
        self._solve()
        self.channel.retract()
        self.channel.extend(length, self._tip_tan.copy())
        self._solve()

    def step(self, spin_rad: float, kappa_per_mm: float, ds_mm: float, dt_s: float) -> np.ndarray:
        """Spin the base (and so the bevel) about the tip's axis, then insert ``ds_mm``.

        Parameters
        ----------
        spin_rad : float
            Rotation about the tip's axis before inserting (rad).
        kappa_per_mm : float
            Commanded curvature (1/mm): the duty fraction ``kappa / kappa_max``, clipped
            to [-1, 1] (module notes).
        ds_mm : float
            Inserted length (mm), >= 0; 0 moves nothing (the spin still turns the frame).
        dt_s : float
            How long the step takes (s), >= 0; the quasi-static model does not use it.

        Returns
        -------
        ndarray, shape (4, 4)
            The tip's pose after the step.
        """
        spin = _number("spin_rad", spin_rad, low=-math.inf)
        kappa = _number("kappa_per_mm", kappa_per_mm, low=-math.inf)
        ds = _number("ds_mm", ds_mm)
        _number("dt_s", dt_s)
        self._spin = math.remainder(self._spin + spin, 2.0 * math.pi)
        if ds > 0.0:
            kmax = self.kappa_max_per_mm if kappa != 0.0 else 0.0
            duty = 0.0 if kmax <= 0.0 else max(-1.0, min(1.0, kappa / kmax))
            remaining = ds
            while remaining > 0.0:
                limit = self.max_substep_mm
                if self.inserted_mm < self._onset_mm:
                    # the tissue takes hold: finer sub-steps keep the start step-size free
                    limit = min(0.1 * limit, max(self._onset_mm - self.inserted_mm, 1e-3))
                sub = remaining / max(1, math.ceil(remaining / limit - 1e-9))
                self._substep(sub, duty)
                remaining = remaining - sub if remaining - sub > 1e-12 * ds else 0.0
        self.pose = self._compose_pose()
        return self.pose.copy()

    # ------------------------------------------------------------------------------------
    def shaft_points_mm(self) -> np.ndarray:
        """The rod's nodes from the guide to the tip (RAS mm), shape (n, 3).

        Returns
        -------
        ndarray, shape (n, 3)
        """
        if self.solution is None:
            return np.stack([self.guide[0], self._tip_pos])
        return self.solution.points_mm

    def shaft_loads(self) -> tuple[np.ndarray, np.ndarray]:
        """The tissue's forces on the needle: along the shaft and at the tip.

        Shaft rows: the foundation's consistent nodal forces at the rod's nodes (zero on
        the free gap and the unsupported bevel length). The last row, at the tip, is the
        tissue's load on the bevel from the last sub-step: the lateral ``f Q`` toward -y
        plus the axial resistance ``P`` against the tangent. The tissue feels the
        opposite forces.

        Returns
        -------
        points_mm : ndarray, shape (n, 3)
            The rod's nodes, the tip last (RAS mm).
        forces_n : ndarray, shape (n, 3)
            The tissue's force on the needle at each (N).
        """
        if self.solution is None:
            return np.zeros((0, 3)), np.zeros((0, 3))
        sol = self.solution
        pts = sol.points_mm
        forces = sol.tissue_forces_n.copy()
        fx, fy = self._last_force_xy
        forces[-1] += fx * sol.e_x[-1] + fy * sol.e_y[-1] - self.tip_load.axial_n * self._tip_tan
        return pts, forces

    def channel_points_mm(self) -> np.ndarray:
        """The tissue's anchors: the channel's points from the entry to the tip (RAS mm).

        Returns
        -------
        ndarray, shape (m, 3)
        """
        return self.channel.points_mm.copy()

    def displace_channel(self, fn) -> np.ndarray:
        """Move the tissue's anchors and re-solve the rod against them.

        Parameters
        ----------
        fn : callable
            ``fn(points_mm (m, 3)) -> displacements_mm (m, 3)``: how the tissue moved at
            each anchor (e.g. interpolated from a tissue model's nodes).

        Returns
        -------
        ndarray, shape (4, 4)
            The tip's pose after the rod has followed.
        """
        disp = np.asarray(fn(self.channel.points_mm.copy()), dtype=np.float64)
        self.channel.displace(disp)
        if self.inserted_mm > 0.0:
            self._solve()
        self.pose = self._compose_pose()
        return self.pose.copy()


def steady_curvature(
    needle: NeedleSpec,
    tissue: TissueSpec,
    guide_gap_mm: float = 10.0,
    element_mm: float = 1.0,
    max_substep_mm: float = 1.0,
) -> float:
    """The path's curvature with the bevel held, after the start's transient (1/mm).

    A straight start inserted with the bevel held until the curvature of the tip's path
    settles: the insertion runs ``12`` of the foundation's lengths ``(4 EI / k)^(1/4)``
    (at least 60 mm), and the curvature is the tip tangent's turn over its last third
    divided by that length. Cached per argument.

    Parameters
    ----------
    needle : NeedleSpec
    tissue : TissueSpec
    guide_gap_mm, element_mm, max_substep_mm : float
        As for :class:`MechanicalNeedle`.

    Returns
    -------
    float
    """
    key = (needle, tissue, guide_gap_mm, element_mm, max_substep_mm)
    if key in _KAPPA_CACHE:
        return _KAPPA_CACHE[key]
    probe = MechanicalNeedle(
        np.eye(4),
        needle,
        tissue,
        guide_gap_mm=guide_gap_mm,
        element_mm=element_mm,
        max_substep_mm=max_substep_mm,
    )
    ei = needle.bending_stiffness_nmm2
    length = max(60.0, 12.0 * (4.0 * ei / probe.k) ** 0.25)
    n = math.ceil(length / max_substep_mm)
    marks = {}
    for i in range(1, n + 1):
        probe._substep(length / n, 1.0)
        if i in (math.ceil(2 * n / 3), n):
            marks[i] = probe._tip_tan.copy()
    a, b = marks[math.ceil(2 * n / 3)], marks[n]
    turn = math.atan2(np.linalg.norm(np.cross(a, b)), float(a @ b))
    kappa = turn / (length * (n - math.ceil(2 * n / 3)) / n)
    _KAPPA_CACHE[key] = kappa
    return kappa
