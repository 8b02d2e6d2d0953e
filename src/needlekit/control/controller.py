"""The constrained velocity controller of Tang et al. (their Eq. 1) for the three puncture
steps.

At every control step the joint velocities solve

    min ||J q_dot + eta e - x_d_dot||^2 + lambda^2 ||q_dot||^2   s.t.   B q_dot <= b

with the task of the current step (the task vector is the needle tip position and the
needle's insertion axis, world frame):

- ``Step.ALIGN``: axis onto the insertion direction ``u = -l_g`` of the guide line (roll
  about the needle free); VFIs: robot points outside the patient cylinder (Eq. 4);
- ``Step.APPROACH``: tip to the start point ``p_s = p_p + d_s l_g`` with the axis kept on
  ``u``; VFIs as in ALIGN;
- ``Step.PUNCTURE``: tip along the desired trajectory (with its velocity fed forward); VFIs:
  tip inside the guide cylinder (Eq. 5), needle within the cone about ``u`` (Eq. 6), tip not
  past the plane through the target (Eq. 7).

Joint position and velocity limits hold in every step. The guide line's ``l_g`` points out
of the patient (the start point lies along it), as in the paper; the needle's axis points
into the patient (``needlekit.conventions``: tip z = insertion direction).
"""

from __future__ import annotations

import enum
import threading
from dataclasses import dataclass, field

import numpy as np

from needlekit.control import _tick
from needlekit.control.panda import ArmState, PandaModel
from needlekit.control.qp import CROSSED_BOUNDS, QPSolver, QPStatus
from needlekit.control.qp_registry import get_qp_solver
from needlekit.control.vfi import (
    Line,
    Plane,
    Zone,
    vfi_row,
)
from needlekit.errors import InvalidInputError

__all__ = [
    "ControlOutput",
    "ControllerSettings",
    "GuideLine",
    "Step",
    "StepVFI",
    "control_step",
    "step_vfi_rows",
    "step_vfis",
    "task_parameter_jacobian",
]


class Step(enum.Enum):
    """The procedure step a control law serves."""

    ALIGN = "align"
    APPROACH = "approach"
    PUNCTURE = "puncture"


@dataclass(frozen=True)
class GuideLine:
    """The puncture guide line: the target ``p_p`` and the unit direction ``l_g`` pointing out
    of the patient (the needle goes in along ``-l_g``).

    Attributes
    ----------
    target_mm : ndarray, shape (3,)
    direction : ndarray, shape (3,)
    """

    target_mm: np.ndarray
    direction: np.ndarray

    def __post_init__(self) -> None:
        line = Line(self.target_mm, self.direction)  # validates both
        object.__setattr__(self, "target_mm", line.point_mm)
        object.__setattr__(self, "direction", line.direction)
        object.__setattr__(self, "_line", line)
        object.__setattr__(self, "_plane", Plane(line.point_mm, line.direction))
        object.__setattr__(self, "_cylinders", {})
        object.__setattr__(self, "_packed", {})

    @property
    def line(self) -> Line:
        """The guide line (axis of the guide cylinder)."""
        return self._line

    @property
    def plane(self) -> Plane:
        """The plane through the target, normal ``l_g`` (the tip stays on its positive side)."""
        return self._plane

    def patient_line(self, axis) -> Line:
        """The patient cylinder's axis: through the target along ``axis`` (cached).

        Parameters
        ----------
        axis : array_like, shape (3,)

        Returns
        -------
        Line
        """
        key = tuple(np.asarray(axis, dtype=float).tolist())
        if key not in self._cylinders:
            self._cylinders[key] = Line(self.target_mm, axis)
        return self._cylinders[key]

    @property
    def insertion_direction(self) -> np.ndarray:
        """``u = -l_g``, the direction the needle must point."""
        return -self.direction

    def start_point(self, distance_mm: float) -> np.ndarray:
        """``p_s = p_p + distance l_g``.

        Parameters
        ----------
        distance_mm : float

        Returns
        -------
        ndarray, shape (3,)
        """
        return self.target_mm + float(distance_mm) * self.direction

    def _kernel_data(self, settings: ControllerSettings) -> tuple:
        """``(geo, par, robot_points)`` of :func:`needlekit.control._tick.pack_geometry`,
        cached per settings object (settings are frozen)."""
        hit = self._packed.get(id(settings))
        if hit is None or hit[0] is not settings:
            hit = (settings, *_tick.pack_geometry(self, settings))
            self._packed[id(settings)] = hit
        return hit[1:]


@dataclass(frozen=True)
class ControllerSettings:
    """Gains, radii and angles of the controller (mm, rad, 1/s).

    Attributes
    ----------
    eta : float
        Task gain (the paper uses 0.2 to 0.5 in different steps).
    damping : float
        lambda: joint-velocity damping (the paper does not give it).
    axis_scale_mm : float
        Weight of the axis rows in the APPROACH task (turns a unit-vector error into mm).
    patient_axis : ndarray, shape (3,)
        Direction of the patient cylinder's axis (through the target; head to foot).
    patient_radius_mm : float
        R_p (200 mm in the paper).
    guide_radius_mm : float
        R_g (1.5 mm).
    cone_angle_rad : float
        theta_o (0.5 deg).
    robot_points : tuple of int
        Joint-frame origins (indices into ``ArmState.origins``) kept outside the patient
        cylinder: the elbow, the wrist and the flange-side frame.
    eta_patient, eta_guide, eta_cone, eta_plane, eta_joints : float
        VFI gains (not given in the paper).
    puncture_keeps_axis : bool
        PUNCTURE's task also holds the needle on the guide direction (weighted like
        APPROACH); without it (the paper's translation-only task) the redundant arm lets
        the needle drift to the cone's edge, where the cone VFI stops it.
    needle_radius_mm : float
        Radius of the held needle and of the needles already placed (the placed-needle
        VFIs; 1 mm, a 2 mm microwave antenna).
    needle_gap_mm : float
        Smallest surface-to-surface gap the placed-needle VFIs keep between the held
        needle's shaft and a placed needle (the safe distance between the axes is
        ``2 needle_radius_mm + needle_gap_mm``).
    eta_needle : float
        Gain of the placed-needle VFIs. The adaptation does not share their decay rate (its
        rows are the step's own VFIs), so the joints take all of it.
    """

    eta: float = 0.5
    damping: float = 1e-3
    axis_scale_mm: float = 100.0
    patient_axis: np.ndarray = field(default_factory=lambda: np.array([0.0, 1.0, 0.0]))
    patient_radius_mm: float = 200.0
    guide_radius_mm: float = 1.5
    cone_angle_rad: float = float(np.radians(0.5))
    robot_points: tuple = (3, 4, 5, 6, 7)
    eta_patient: float = 1.0
    eta_guide: float = 5.0
    eta_cone: float = 5.0
    eta_plane: float = 5.0
    eta_joints: float = 1.0
    puncture_keeps_axis: bool = True
    needle_radius_mm: float = 1.0
    needle_gap_mm: float = 0.5
    eta_needle: float = 5.0


@dataclass(frozen=True)
class ControlOutput:
    """One control step's result.

    Attributes
    ----------
    q_dot : ndarray, shape (7,)
        Joint velocities (zero when the QP failed).
    status : QPStatus
    task_error : ndarray
    distances : dict
        The VFI distances of the step (``patient_sq_mm2`` (smallest), ``guide_sq_mm2``,
        ``cone_f``, ``plane_mm``, and with placed needles ``needle_sq_mm2``, the smallest
        squared distance between the axes).
    """

    q_dot: np.ndarray
    status: QPStatus
    task_error: np.ndarray
    distances: dict


@dataclass(frozen=True)
class StepVFI:
    """One VFI of a step at the current state.

    Attributes
    ----------
    name : str
        ``patient`` (robot point ``k`` outside the patient cylinder), ``guide``, ``cone``
        or ``plane``.
    distance, safe : float
        The distance (mm^2 for the cylinders, ``2 - 2 cos`` for the cone, mm for the plane)
        and its safe value.
    zone : Zone
    gain : float
    jac_q : ndarray, shape (7,)
        Derivative with respect to the joint angles.
    jac_a : ndarray, shape (12,) or None
        Derivative with respect to the model parameters (when they were given).
    """

    name: str
    distance: float
    safe: float
    zone: Zone
    gain: float
    jac_q: np.ndarray
    jac_a: np.ndarray | None = None


def step_vfis(
    state: ArmState, step: Step, guide: GuideLine, settings: ControllerSettings, pj=None, a=None
) -> list[StepVFI]:
    """The VFIs active in a step, with their Jacobians in q (and in the parameters).

    Parameters
    ----------
    state : ArmState
    step : Step
    guide : GuideLine
    settings : ControllerSettings
    pj : ParameterJacobians, optional
        With ``a``: also give each VFI's derivative with respect to the parameters.
    a : ndarray, shape (12,), optional

    Returns
    -------
    list of StepVFI
    """
    d, jq, jp, kinds = _step_vfi_data(state, step, guide, settings, pj, a)
    with_a = pj is not None
    return [
        StepVFI(name, float(d[r]), safe, zone, gain, jq[r], jp[r] if with_a else None)
        for r, (name, safe, zone, gain) in enumerate(kinds)
    ]


def step_vfi_rows(
    state: ArmState, step: Step, guide: GuideLine, settings: ControllerSettings, pj, a, share
) -> tuple[np.ndarray, np.ndarray]:
    """The step's VFIs as the adaptation's rows: :func:`step_vfis` without the objects.

    Parameters
    ----------
    state : ArmState
    step : Step
    guide : GuideLine
    settings : ControllerSettings
    pj : ParameterJacobians
    a : ndarray, shape (12,)
    share : float
        The joints' share of each VFI's decay rate (the adaptation's is ``1 - share``).

    Returns
    -------
    vfi : ndarray, shape (m, 4)
        Per VFI: distance, safe value, the adaptation's gain ``(1 - share) gain``, and 1 for
        a forbidden (outside) zone, 0 for a safe one.
    jac_a : ndarray, shape (m, 12)
        Each VFI's derivative in the parameters.
    """
    d, _, jp, kinds = _step_vfi_data(state, step, guide, settings, pj, a)
    vfi = np.empty((len(kinds), 4))
    for r, (_, safe, zone, gain) in enumerate(kinds):
        vfi[r] = d[r], safe, (1.0 - share) * gain, zone is Zone.OUTSIDE
    return vfi, jp


def _step_vfi_data(state, step, guide, cfg, pj, a) -> tuple:
    """``d``, ``jq``, ``jp`` of :func:`needlekit.control._tick.vfi_data` and the VFIs'
    ``(name, safe, zone, gain)``."""
    geo, par, ks = guide._kernel_data(cfg)
    puncture = step is Step.PUNCTURE
    with_a = pj is not None
    z = _NO_PARAMETERS
    d, jq, jp = _tick.vfi_data(
        _tick.VFI_PUNCTURE if puncture else _tick.VFI_PATIENT, state.tip_mm, state.needle_axis,
        state.tip_jacobian, state.axis_jacobian, state.axes, state.origins, ks, geo, with_a,
        pj.tip if with_a else z, pj.axis if with_a else z, pj.base_rate if with_a else z,
        np.asarray(a, dtype=float) if with_a else geo,
    )  # fmt: skip
    if puncture:
        kinds = (
            ("guide", par[3], Zone.INSIDE, cfg.eta_guide),
            ("cone", 2.0 - 2.0 * np.cos(cfg.cone_angle_rad), Zone.INSIDE, cfg.eta_cone),
            ("plane", 0.0, Zone.OUTSIDE, cfg.eta_plane),
        )
    else:
        kinds = (("patient", cfg.patient_radius_mm**2, Zone.OUTSIDE, cfg.eta_patient),) * len(ks)
    return d, jq, jp, kinds


_NO_PARAMETERS = np.zeros((1, 1))


def control_step(
    model: PandaModel,
    q,
    step: Step,
    guide: GuideLine,
    settings: ControllerSettings | None = None,
    *,
    desired_mm=None,
    desired_velocity_mm_s=None,
    state: ArmState | None = None,
    vfis: list[StepVFI] | None = None,
    vfi_share: float = 1.0,
    solver: QPSolver | str | None = None,
    placed: np.ndarray | None = None,
) -> ControlOutput:
    """Joint velocities for one control step (Tang et al.'s Eq. 1 with the step's VFIs).

    Parameters
    ----------
    model : PandaModel
        The (estimated) arm and needle.
    q : array_like, shape (7,)
    step : Step
    guide : GuideLine
    settings : ControllerSettings, optional
    desired_mm : array_like, shape (3,), optional
        Desired tip position (APPROACH: the start point; PUNCTURE: the trajectory's).
    desired_velocity_mm_s : array_like, shape (3,), optional
        Its velocity (fed forward; default zero).
    state : ArmState, optional
        ``model.state(q)`` when the caller has it already.
    vfis : list of StepVFI, optional
        :func:`step_vfis` of this state when the caller has them already.
    vfi_share : float
        Share of each VFI's decay rate given to the joints (the rest goes to the
        parameters' adaptation, which moves the estimated distances too).
    solver : QPSolver or str, optional
        The QP solver (an object or a registered name,
        :func:`~needlekit.control.qp_registry.get_qp_solver`; default DAQP).
    placed : ndarray, shape (k, 2, 3), optional
        Needles already placed, each as its segment (tip, then the hub end; mm, world),
        where the controller believes them: one more VFI row each keeps the held needle's
        shaft (tip to flange, the model's needle length) ``2 needle_radius_mm +
        needle_gap_mm`` from its axis (:func:`needlekit.control._tick.shaft_rows`).

    Returns
    -------
    ControlOutput

    Raises
    ------
    InvalidInputError
        A step that needs a desired position without one, or ``placed`` not segments.
    """
    cfg = settings or _DEFAULT_SETTINGS
    s = model.state(q) if state is None else state
    if step is not Step.ALIGN and desired_mm is None:
        raise InvalidInputError("desired_mm", f"step {step.value} needs a desired tip position")
    p_d = _ZERO3 if desired_mm is None else np.asarray(desired_mm, dtype=float)
    v_d = _ZERO3 if desired_velocity_mm_s is None else np.asarray(desired_velocity_mm_s, float)
    if step is Step.ALIGN:
        task = _tick.TASK_AXIS
    elif step is Step.APPROACH or cfg.puncture_keeps_axis:
        task = _tick.TASK_TIP_AXIS
    else:
        task = _tick.TASK_TIP
    geo, par, ks = guide._kernel_data(cfg)
    n = len(s.q)
    if vfis is None:
        kind = _tick.VFI_PUNCTURE if step is Step.PUNCTURE else _tick.VFI_PATIENT
        m = 3 if kind == _tick.VFI_PUNCTURE else len(ks)
    else:
        kind, m = _tick.VFI_NONE, len(vfis)
    k = 0
    if placed is not None:
        placed = np.asarray(placed, dtype=float)
        if placed.ndim != 3 or placed.shape[1:] != (2, 3):
            raise InvalidInputError("placed", f"expected (k, 2, 3) segments, got {placed.shape}")
        k = len(placed)
    H, f, A, bu, bl, dist = _buffers(n, m + k)
    err, infeasible = _tick.control_qp(
        task, kind, s.q, s.tip_mm, s.needle_axis, s.tip_jacobian, s.axis_jacobian, s.axes,
        s.origins, ks, geo, par, p_d, v_d, model.q_min, model.q_max, model.q_dot_max,
        float(vfi_share), H, f, A, bu, bl, dist,
    )  # fmt: skip
    if kind == _tick.VFI_PUNCTURE:
        d0, d1, d2 = dist.tolist()
        distances = {"guide_sq_mm2": d0, "cone_f": d1, "plane_mm": d2}
    elif kind == _tick.VFI_PATIENT:
        distances = {"patient_sq_mm2": float(dist[0])} if m else {}
    else:
        distances = {}
        for i, v in enumerate(vfis):
            A[i], bu[n + i] = vfi_row(v.distance, v.jac_q, v.safe, v.zone, vfi_share * v.gain)
            key = _DIST_KEYS[v.name]
            distances[key] = min(distances.get(key, np.inf), v.distance)
    if k:
        gap = 2.0 * cfg.needle_radius_mm + cfg.needle_gap_mm
        distances["needle_sq_mm2"] = _tick.shaft_rows(
            s.tip_mm, s.needle_axis, s.tip_jacobian, s.axis_jacobian,
            model.needle_length_mm, placed, gap * gap,
            cfg.eta_needle, A, bu, m, True,
        )  # fmt: skip
    sol = CROSSED_BOUNDS if infeasible else get_qp_solver(solver).solve(H, f, A, bu, bl)
    q_dot = sol.x if sol.status is QPStatus.OPTIMAL else np.zeros(n)
    return ControlOutput(q_dot, sol.status, err, distances)


_DEFAULT_SETTINGS = ControllerSettings()
_ZERO3 = np.zeros(3)  # read only by the kernel (a read-only flag would compile it twice)
_local = threading.local()


def _buffers(n: int, m: int) -> tuple:
    """The QP buffers (:mod:`needlekit.control.qp`'s layout) of an ``n``-joint step with
    ``m`` VFI rows, kept per thread (a step overwrites them; a solver keeps no reference)."""
    cache = getattr(_local, "buffers", None)
    if cache is None:
        cache = _local.buffers = {}
    buf = cache.get((n, m))
    if buf is None:
        buf = cache[(n, m)] = (
            np.zeros((n, n)), np.zeros(n), np.zeros((m, n)), np.zeros(n + m),
            np.zeros(n + m), np.zeros(3),
        )  # fmt: skip
    return buf


_DIST_KEYS = {
    "patient": "patient_sq_mm2",
    "guide": "guide_sq_mm2",
    "cone": "cone_f",
    "plane": "plane_mm",
}


def task_parameter_jacobian(step: Step, pj, settings: ControllerSettings) -> np.ndarray:
    """Derivative of the step's task vector with respect to the model parameters.

    Parameters
    ----------
    step : Step
    pj : ParameterJacobians
    settings : ControllerSettings

    Returns
    -------
    ndarray, shape (m, 12)
        Rows as in the step's task error (ALIGN: axis; APPROACH: tip and weighted axis;
        PUNCTURE: tip).
    """
    if step is Step.ALIGN:
        return pj.axis
    if step is Step.APPROACH or settings.puncture_keeps_axis:
        out = np.empty((6, pj.tip.shape[1]))  # [tip; w axis] (np.vstack's values, faster)
        out[:3] = pj.tip
        np.multiply(settings.axis_scale_mm, pj.axis, out=out[3:])
        return out
    return pj.tip
