"""Independent check of a multi-needle plan, from its record alone (``multi.json``).

Every needle is rebuilt from its target and entry points and re-checked against the
problem, finely, without the planner's map:

- entry: on the entry surface (within :data:`ENTRY_ON_SURFACE_TOL_MM`), the target inside;
- length: at most the needle's;
- angles: Sigma's theta and phi within Eq. 2's limits, the approach cone, and the angle to
  the entry surface's inward normal within its limit;
- clearance to the anatomy and to the needles placed before it: at least gamma by the
  straight planners' clearance rule (:mod:`needlekit.constants`), with two certificates
  (:func:`~needlekit.planning.straight.certify.certify_needle`): the planner's own samples,
  re-derived from the record (its entry and target, the planner's sphere-tracing step and
  cap), and dense samples every :data:`CHECK_STEP_MM` (for the placed needles, the
  closed-form distance between the axes besides their heads traced densely). A needle
  passes when either proves it, and the better bound is reported. The planner certifies
  each needle from the same rounded numbers before accepting it, so every needle of a
  plan it calls solved passes here, with the same clearance.

A rule that cannot be checked (a missing field in the record) counts as broken.
"""

from __future__ import annotations

import numpy as np

from needlekit.anatomy.needle_body import LIU_HEAD, NeedleBody
from needlekit.constants import STRAIGHT_CHECK_STEP_MM
from needlekit.geometry.so3 import angle_between
from needlekit.planning.result import Verification
from needlekit.planning.straight.certify import certify_needle
from needlekit.planning.straight.problem import StraightProblem, angles_of

__all__ = ["CHECK_STEP_MM", "ENTRY_ON_SURFACE_TOL_MM", "verify_multi"]

#: Sample spacing (mm) of the check's dense certificate: its bound is at most half of it
#: low (:data:`~needlekit.constants.STRAIGHT_CHECK_STEP_MM`).
CHECK_STEP_MM: float = STRAIGHT_CHECK_STEP_MM
#: An entry point this close (mm) to the entry surface is on it (the planner locates it to
#: 1e-4 mm; the record rounds to 1e-6).
ENTRY_ON_SURFACE_TOL_MM: float = 1e-3
SLACK = 1e-9
#: Angles within this (rad) of a limit pass: the record rounds points to 1e-6 mm, which
#: moves a direction by up to ~1e-7 rad at 10 mm.
ANGLE_TOL_RAD: float = 1e-6


def verify_multi(problem: StraightProblem, record: dict, *, head=LIU_HEAD) -> Verification:
    """Re-check every needle of a multi-needle plan record.

    Parameters
    ----------
    problem : StraightProblem
        Anatomy, needle, gamma and limits (its target is ignored: each needle's own is).
    record : dict
        A ``multi.json`` document (``needles`` with ``order``, ``target_mm``,
        ``entry_mm``).
    head : NeedleHead or None
        The placed needles' heads (default the paper's Eq. 4, as the planner's).

    Returns
    -------
    Verification
        ``metrics["needles"]``: per needle, the re-measured length, clearances and angles.
    """
    bad: list[str] = []
    rows = []
    needles = record.get("needles")
    if not isinstance(needles, list) or not needles:
        return Verification(False, ("needles: the record holds no needles",), {"needles": []})
    body = problem.scene[problem.entry_surface].field
    r, gamma = problem.needle.radius_mm, problem.gamma_mm
    placed: list[tuple[np.ndarray, np.ndarray]] = []
    bodies: list = []
    t_lo, t_hi = np.radians(problem.theta_range_deg)
    p_lo, p_hi = np.radians(problem.phi_range_deg)
    for i, n in enumerate(sorted(needles, key=lambda n: n.get("order", 0))):
        name = f"needle {n.get('order', i + 1)}"
        try:
            tip = np.asarray(n["target_mm"], dtype=float).reshape(3)
            entry = np.asarray(n["entry_mm"], dtype=float).reshape(3)
        except (KeyError, TypeError, ValueError):
            bad.append(f"{name}: target_mm/entry_mm missing or malformed: cannot be checked")
            continue
        if not (np.all(np.isfinite(tip)) and np.all(np.isfinite(entry))):
            bad.append(f"{name}: target_mm/entry_mm not finite: cannot be checked")
            continue
        axis = entry - tip
        length = float(np.linalg.norm(axis))
        u = axis / length
        row = {"order": n.get("order", i + 1), "length_mm": length}
        if length > problem.needle.max_length_mm + SLACK:
            bad.append(
                f"{name}: length {length:.3f} mm exceeds {problem.needle.max_length_mm:g} mm"
            )
        on = float(body.signed_distance(entry))
        row["entry_surface_distance_mm"] = on
        if abs(on) > ENTRY_ON_SURFACE_TOL_MM + body.error_bound_mm:
            bad.append(f"{name}: entry {on:.4f} mm from the {problem.entry_surface} surface")
        if float(body.signed_distance(tip)) >= 0:
            bad.append(f"{name}: target outside the {problem.entry_surface} surface")
        sigma = problem.with_target(tip).world_T_sigma
        theta, phi = (float(a[0]) for a in angles_of(u[None], sigma))
        row["theta_deg"], row["phi_deg"] = np.degrees(theta), np.degrees(phi)
        if not (t_lo - ANGLE_TOL_RAD <= theta <= t_hi + ANGLE_TOL_RAD):
            bad.append(
                f"{name}: theta {np.degrees(theta):.3f} deg outside {problem.theta_range_deg}"
            )
        if p_hi - p_lo < 2 * np.pi - 1e-9 and not (
            p_lo - ANGLE_TOL_RAD <= phi <= p_hi + ANGLE_TOL_RAD
        ):
            bad.append(f"{name}: phi {np.degrees(phi):.3f} deg outside {problem.phi_range_deg}")
        if problem.approach_direction is not None and problem.approach_cone_deg < 180.0:
            off = float(np.degrees(angle_between(u, problem.approach_direction)))
            if off > problem.approach_cone_deg + np.degrees(ANGLE_TOL_RAD):
                bad.append(
                    f"{name}: {off:.2f} deg off the approach direction, limit {problem.approach_cone_deg:g}"
                )
        g = body.gradient(entry[None])[0]
        angle = float(np.degrees(angle_between(u, g)))
        row["normal_angle_deg"] = angle
        if angle > problem.max_normal_angle_deg + np.degrees(ANGLE_TOL_RAD):
            bad.append(
                f"{name}: {angle:.2f} deg to the surface normal, limit {problem.max_normal_angle_deg:g}"
            )
        cert = certify_needle(problem, tip, entry, tuple(placed), tuple(bodies))
        row["clearance_mm"] = cert.clearance_mm
        row["planner_samples_clearance_mm"] = cert.planner_clearance_mm
        row["dense_clearance_mm"] = cert.dense_clearance_mm
        if cert.clearance_mm < gamma:
            bad.append(
                f"{name}: certified clearance {cert.clearance_mm:.4f} mm below gamma {gamma:g} mm"
            )
        if placed:
            gap = cert.needle_clearance_mm
            row["needle_clearance_mm"] = gap
            row["planner_samples_needle_clearance_mm"] = cert.planner_needle_clearance_mm
            row["dense_needle_clearance_mm"] = cert.dense_needle_clearance_mm
            if gap < gamma:
                bad.append(
                    f"{name}: {gap:.4f} mm from a needle placed before it, below gamma {gamma:g} mm"
                )
        placed.append((tip, entry))
        bodies.append(NeedleBody(tip, entry, radius_mm=r, head=head))
        rows.append(row)
    return Verification(not bad, tuple(bad), {"needles": rows})
