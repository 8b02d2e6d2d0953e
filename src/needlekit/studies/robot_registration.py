"""Where the patient lies for the robot when it inserts a straight multi-needle plan
(:mod:`needlekit.studies.execute_multi`): the registration from the patient's frame (RAS)
into the robot's world, and each needle's start point.

Tang et al. simulate guide lines that come from above (the four octants over the
horizontal plane), a patient cylinder along the world's y axis, and a start point 300 mm
out along the line. A plan's lines are turned into that workspace: their mean outward
direction to the vertical, the patient's superior axis onto y (then further about the
vertical while the robot cannot reach a needle), the targets' centroid at the study's
target centre. A needle whose start point 300 mm out lies inside the patient cylinder or
out of the arm's comfortable reach (the puncture study's filter) starts further out.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from needlekit.errors import InvalidInputError
from needlekit.studies.guide_filter import ACCEPTABLE, GuideFilter
from needlekit.studies.puncture_study import PunctureScenario

__all__ = [
    "START_MAX_MM",
    "START_STEP_MM",
    "YAWS_DEG",
    "Registration",
    "place_patient",
    "register_plan",
    "start_distances",
]

#: The start point's distance out along the line: Tang et al.'s 300 mm, then further out in
#: these steps until the puncture study's filter accepts it.
START_STEP_MM = 10.0
START_MAX_MM = 600.0


@dataclass(frozen=True)
class Registration:
    """The patient (RAS) in the robot's world (the EM transmitter's frame), rigid.

    Attributes
    ----------
    world_T_ras : ndarray, shape (4, 4)
    patient_axis : ndarray, shape (3,)
        The patient's superior axis in the world: the patient cylinder's axis.
    """

    world_T_ras: np.ndarray
    patient_axis: np.ndarray
    yaw_deg: float = 0.0

    def point(self, p) -> np.ndarray:
        """A RAS point in the world (mm).

        Parameters
        ----------
        p : array_like, shape (..., 3)

        Returns
        -------
        ndarray, shape (..., 3)
        """
        return np.asarray(p, float) @ self.world_T_ras[:3, :3].T + self.world_T_ras[:3, 3]

    def direction(self, v) -> np.ndarray:
        """A RAS direction in the world.

        Parameters
        ----------
        v : array_like, shape (..., 3)

        Returns
        -------
        ndarray, shape (..., 3)
        """
        return np.asarray(v, float) @ self.world_T_ras[:3, :3].T

    def to_ras(self, p) -> np.ndarray:
        """A world point back in RAS.

        Parameters
        ----------
        p : array_like, shape (..., 3)

        Returns
        -------
        ndarray, shape (..., 3)
        """
        return (np.asarray(p, float) - self.world_T_ras[:3, 3]) @ self.world_T_ras[:3, :3]

    def to_dict(self) -> dict:
        """JSON-ready.

        Returns
        -------
        dict
        """
        return {
            "world_T_ras": np.round(self.world_T_ras, 9).tolist(),
            "patient_axis": np.round(self.patient_axis, 9).tolist(),
            "yaw_deg": self.yaw_deg,
        }


def _rotation_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The smallest rotation taking unit ``a`` onto unit ``b`` (Rodrigues)."""
    v, c = np.cross(a, b), float(a @ b)
    if c < -1.0 + 1e-12:  # opposite: half a turn about any axis normal to a
        n = np.cross(a, [1.0, 0.0, 0.0] if abs(a[0]) < 0.9 else [0.0, 1.0, 0.0])
        n /= np.linalg.norm(n)
        return 2.0 * np.outer(n, n) - np.eye(3)
    k = np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])
    return np.eye(3) + k + k @ k / (1.0 + c)


def register_plan(
    targets_ras, out_directions_ras, scenario: PunctureScenario, yaw_deg: float = 0.0
) -> Registration:
    """Where the patient lies for the robot: the needles' mean outward direction turned to
    the world's vertical (up, the side Tang et al.'s guide lines come from), the patient's
    superior axis then turned about the vertical onto the world's y axis (the patient
    cylinder's axis in Tang et al.) and ``yaw_deg`` further, and the targets' centroid at
    the scenario's target centre.

    Parameters
    ----------
    targets_ras : array_like, shape (k, 3)
    out_directions_ras : array_like, shape (k, 3)
        Unit directions from each target out through its entry.
    scenario : PunctureScenario
    yaw_deg : float
        A further turn about the vertical (deg).

    Returns
    -------
    Registration
    """
    t = np.atleast_2d(np.asarray(targets_ras, float))
    m = np.atleast_2d(np.asarray(out_directions_ras, float)).sum(axis=0)
    if not np.linalg.norm(m) > 1e-9:
        raise InvalidInputError("plan", "the needles' directions cancel out: no side to work from")
    up = np.array([0.0, 0.0, 1.0])
    r1 = _rotation_between(m / np.linalg.norm(m), up)
    s = r1 @ np.array([0.0, 0.0, 1.0])  # the superior axis after the first turn
    sp = s - up * (s @ up)
    psi = math.atan2(sp[0], sp[1]) if np.linalg.norm(sp) > 1e-9 else 0.0  # from y to sp
    psi += math.radians(yaw_deg)
    c, si = math.cos(psi), math.sin(psi)
    rz = np.array([[c, -si, 0.0], [si, c, 0.0], [0.0, 0.0, 1.0]])  # turns sp onto y
    r = rz @ r1
    pose = np.eye(4)
    pose[:3, :3] = r
    pose[:3, 3] = np.asarray(scenario.target_center_mm, float) - r @ t.mean(axis=0)
    return Registration(pose, r @ np.array([0.0, 0.0, 1.0]), float(yaw_deg))


#: The turns about the vertical :func:`place_patient` tries, nearest the patient along y
#: first (deg).
YAWS_DEG = tuple(sorted(range(-180, 180, 5), key=lambda a: (abs(a), a)))


def place_patient(lines: dict, scenario: PunctureScenario, radius_mm: float):
    """The registration and start distances of a plan: :func:`register_plan` at the first
    turn of :data:`YAWS_DEG` for which every needle has a start point
    (:func:`start_distances`).

    Parameters
    ----------
    lines : dict
        :func:`plan_lines`.
    scenario : PunctureScenario
    radius_mm : float
        The needles' radius.

    Returns
    -------
    registration : Registration
    starts : list of float
    controller : ControllerSettings
        Tang et al.'s, with this patient axis and needle radius.

    Raises
    ------
    InvalidInputError
        No turn suits every needle.
    """
    from needlekit.control.controller import ControllerSettings

    out = lines["entry_mm"] - lines["aimed_mm"]
    out = out / np.linalg.norm(out, axis=1, keepdims=True)
    first = None
    for yaw in YAWS_DEG:
        reg = register_plan(lines["aimed_mm"], out, scenario, yaw)
        cs = ControllerSettings(patient_axis=reg.patient_axis, needle_radius_mm=radius_mm)
        try:
            starts = start_distances(
                reg.point(lines["aimed_mm"]), reg.direction(out), reg, scenario, cs
            )
        except InvalidInputError as exc:
            first = first or exc
            continue
        return reg, starts, cs
    raise InvalidInputError(
        "plan",
        f"the robot cannot reach every needle, however the patient is turned ({first.reason})",
    )


def start_distances(targets_w, lg_w, registration: Registration, scenario, controller) -> list:
    """Each needle's start distance: the first of 300, 310, ... mm (at most
    :data:`START_MAX_MM`) that the puncture study's guide filter accepts (start point out
    of the patient cylinder, wrist within reach).

    Parameters
    ----------
    targets_w, lg_w : ndarray, shape (k, 3)
        The guide lines in the world (targets and outward directions).
    registration : Registration
    scenario : PunctureScenario
    controller : ControllerSettings

    Returns
    -------
    list of float

    Raises
    ------
    InvalidInputError
        A needle with no acceptable start point.
    """
    base = replace(
        GuideFilter.from_scenario(scenario, controller), patient_axis=registration.patient_axis
    )
    out = []
    for k, (t, lg) in enumerate(zip(targets_w, lg_w, strict=True)):
        d, verdict = scenario.start_distance_mm, ""
        while d <= START_MAX_MM + 1e-9:
            verdict = replace(base, start_distance_mm=d).verdict(t, lg)
            if verdict == ACCEPTABLE:
                break
            d += START_STEP_MM
        else:
            raise InvalidInputError(
                "plan",
                f"needle {k + 1}: no start point from {scenario.start_distance_mm:g} to "
                f"{START_MAX_MM:g} mm out along its line suits the robot ({verdict})",
            )
        out.append(float(d))
    return out
