"""Sampled lung targets screened beside the UNC reference app.

``needlekit bench steerable --reference-app PATH --sample-targets N [--target-seed S]``
replaces each patient's own target by ``N`` targets drawn reproducibly
(``numpy.random.default_rng(S)``) by :func:`sample_targets`: for each, a start of the
patient chosen at random, then a voxel centre chosen uniformly among the voxels that are

- free: in the case's free space (the pleural region and the nodules, minus the airway,
  vessels and fissures: ``MedradCase.free_space``, the region needlekit plans in),
- :data:`SAMPLE_DISTANCE_MM` (35 to 90 mm) from that start,
- within the heading cone of the start (at most :data:`SAMPLE_CONE_DEG` from its
  insertion direction, the needle's largest heading change), and
- clear for the benchmark's 1 mm needle (``MedradCase.voxel_obstacles(...).collides``).

Every (start, target, r_min) is then one case of
:class:`~needlekit.benchmarks.reference_comparison.ReferenceComparison` (the same
interleaving and 1 s budget), and :func:`screening_summary` counts the cases the app
refuses with "Reachable workspace is not connected to the goal", how many of those
needlekit answers ``infeasible`` and how fast, and any case where needlekit answers
``infeasible`` while the app finds a plan (a soundness bug).
"""

from __future__ import annotations

import math
from collections import Counter
from typing import Any

import numpy as np

from needlekit.benchmarks.reference_comparison import _case_name
from needlekit.errors import InvalidInputError

__all__ = [
    "NOT_CONNECTED",
    "SAMPLE_CONE_DEG",
    "SAMPLE_DISTANCE_MM",
    "SCREEN_TIME_S",
    "format_screening",
    "sample_targets",
    "screening_summary",
]

#: Distance of a sampled target from its start (mm): at least, at most.
SAMPLE_DISTANCE_MM = (35.0, 90.0)
#: Largest angle between a start's insertion direction and the way to its target (deg).
SAMPLE_CONE_DEG = 90.0
#: The app's refusal that needlekit's connectivity proof must match.
NOT_CONNECTED = "Reachable workspace is not connected to the goal"
#: The bound on needlekit's time to answer those cases.
SCREEN_TIME_S = 0.1
#: Voxels drawn per batch, and batches tried per target before giving up.
_BATCH = 4096
_MAX_BATCHES = 2000


def _box(affine: np.ndarray, shape, centre: np.ndarray, radius_mm: float):
    """Voxel index bounds (``lo`` inclusive, ``hi`` exclusive) of a ball's bounding box."""
    corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)])
    world = centre + radius_mm * corners
    ijk = (world - affine[:3, 3]) @ np.linalg.inv(affine[:3, :3]).T
    lo = np.clip(np.floor(ijk.min(axis=0)).astype(int), 0, shape)
    hi = np.clip(np.ceil(ijk.max(axis=0)).astype(int) + 1, 0, shape)
    return lo, hi


def _draw(rng, free, affine, obstacles, world_T_tip, lo, hi, d_lo, d_hi, cos_cone):
    """One target for one start: the first voxel of a stream of uniform draws in the box
    that meets every condition (so uniform over those voxels), or None."""
    p, z = world_T_tip[:3, 3], world_T_tip[:3, 2] / np.linalg.norm(world_T_tip[:3, 2])
    if np.any(hi <= lo):
        return None
    for _ in range(_MAX_BATCHES):
        ijk = rng.integers(lo, hi, size=(_BATCH, 3))
        ijk = ijk[free[ijk[:, 0], ijk[:, 1], ijk[:, 2]]]
        world = ijk @ affine[:3, :3].T + affine[:3, 3]
        v = world - p
        d = np.linalg.norm(v, axis=1)
        ok = (d >= d_lo) & (d <= d_hi) & (v @ z >= cos_cone * d - 1e-9)
        cand = world[ok]
        if len(cand):
            clear = cand[~obstacles.collides(cand)]
            if len(clear):
                return clear[0]
    return None


def sample_targets(
    case,
    n: int,
    seed: int = 0,
    *,
    needle_diameter_mm: float = 1.0,
    distance_mm: tuple[float, float] = SAMPLE_DISTANCE_MM,
    cone_deg: float = SAMPLE_CONE_DEG,
) -> list[dict[str, Any]]:
    """Draw ``n`` targets in the free space of a lung, each ahead of one of its starts.

    Parameters
    ----------
    case : needlekit.io.medrad.MedradCase
        Its ``free_space`` (mask and affine), ``voxel_obstacles`` and ``starts`` are used.
    n : int
        Targets to draw (>= 1).
    seed : int
        Seed of ``numpy.random.default_rng``: the same seed and case give the same targets.
    needle_diameter_mm : float
        A target is clear of the obstacle voxels for this needle.
    distance_mm : (float, float)
        Least and greatest distance from the start (mm).
    cone_deg : float
        Largest angle from the start's insertion direction (z of ``world_T_tip``).

    Returns
    -------
    list of dict
        In drawing order: ``sample`` (0, 1, ...), ``start`` (its number), ``start_name``,
        ``start_mm`` (its position), ``target_mm`` (a voxel centre, RAS mm) and
        ``distance_mm``, ``angle_deg`` (from the insertion direction).

    Raises
    ------
    InvalidInputError
        Naming ``--sample-targets`` when some start has no such voxel.
    """
    if int(n) < 1:
        raise InvalidInputError("--sample-targets", f"expected a whole number >= 1, got {n}")
    rng = np.random.default_rng(int(seed))
    free = np.asarray(case.free_space.data, dtype=bool)
    affine = np.asarray(case.free_space.affine, dtype=float)
    obstacles = case.voxel_obstacles(needle_diameter_mm=needle_diameter_mm)
    d_lo, d_hi = (float(v) for v in distance_mm)
    cos_cone = math.cos(math.radians(cone_deg))
    starts = list(case.starts)
    boxes = [_box(affine, free.shape, s.world_T_tip[:3, 3], d_hi) for s in starts]
    out = []
    for k in range(int(n)):
        i = int(rng.integers(len(starts)))
        s = starts[i]
        pose = np.asarray(s.world_T_tip, dtype=float)
        t = _draw(rng, free, affine, obstacles, pose, *boxes[i], d_lo, d_hi, cos_cone)
        if t is None:
            raise InvalidInputError(
                "--sample-targets",
                f"{s.name}: no free voxel {d_lo:g}-{d_hi:g} mm ahead of it within "
                f"{cone_deg:g} deg (after {_MAX_BATCHES * _BATCH} draws)",
            )
        v = t - pose[:3, 3]
        dist = float(np.linalg.norm(v))
        z = pose[:3, 2] / np.linalg.norm(pose[:3, 2])
        angle = math.degrees(math.acos(max(-1.0, min(1.0, float(v @ z) / dist))))
        out.append(
            {
                "sample": k,
                "start": int(s.name.removeprefix("start")) if s.name.startswith("start") else i + 1,
                "start_name": s.name,
                "start_mm": pose[:3, 3].tolist(),
                "target_mm": t.tolist(),
                "distance_mm": dist,
                "angle_deg": angle,
            }
        )
    return out


def _case(row: dict[str, Any]) -> dict[str, Any]:
    a, n = row["app"], row["needlekit"]
    return {
        "case": _case_name(row),
        "start": row["start"],
        "target_mm": row.get("target_mm"),
        "app_status": a["status"],
        "app_reason": a["reason"],
        "needlekit_verdict": n["verdict"],
        "needlekit_reason": n.get("reason"),
        "needlekit_time_s": n["time_s"],
    }


def screening_summary(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """What the screening found.

    Parameters
    ----------
    rows : list of dict
        :attr:`ReferenceComparison.rows` (``app`` and ``needlekit`` figures per case).

    Returns
    -------
    dict
        ``cases``; ``app_statuses`` and ``needlekit_verdicts`` (counts); ``app_not_connected``
        (cases the app refuses with :data:`NOT_CONNECTED`), ``needlekit_infeasible_of_those``,
        ``needlekit_infeasible_within_0_1_s_of_those`` and ``max_needlekit_time_s_of_those``
        (over every such case, whatever needlekit answered); ``not_connected_cases`` (each:
        ``case``, ``start``, ``target_mm``, the app's status and reason, needlekit's
        verdict, reason and ``needlekit_time_s``); ``unsound`` (needlekit ``infeasible``
        where the app finds a plan) and ``disagreements`` (every other case whose verdicts
        differ), each in the same form.
    """
    nc = [r for r in rows if r["app"].get("reason") == NOT_CONNECTED]
    inf = [r for r in nc if r["needlekit"]["verdict"] == "infeasible"]
    unsound = [r for r in rows if r["needlekit"]["verdict"] == "infeasible"
               and r["app"]["verdict"] in ("certified", "solved")]  # fmt: skip
    other = [r for r in rows
             if r["app"]["verdict"] != r["needlekit"]["verdict"] and r not in unsound]  # fmt: skip
    return {
        "cases": len(rows),
        "app_statuses": dict(Counter(r["app"]["status"] for r in rows)),
        "needlekit_verdicts": dict(Counter(r["needlekit"]["verdict"] for r in rows)),
        "app_not_connected": len(nc),
        "needlekit_infeasible_of_those": len(inf),
        "needlekit_infeasible_within_0_1_s_of_those": sum(
            r["needlekit"]["time_s"] <= SCREEN_TIME_S for r in inf
        ),
        "max_needlekit_time_s_of_those": max((r["needlekit"]["time_s"] for r in nc), default=None),
        "not_connected_cases": [_case(r) for r in nc],
        "unsound": [_case(r) for r in unsound],
        "disagreements": [_case(r) for r in other],
    }


def _line(c: dict[str, Any]) -> str:
    t = "-" if c["target_mm"] is None else "(" + ", ".join(f"{v:.2f}" for v in c["target_mm"]) + ")"
    reason = f" ({c['needlekit_reason']})" if c["needlekit_reason"] else ""
    return (
        f"{c['case']} target {t}: app {c['app_status']}, needlekit {c['needlekit_verdict']}"
        f"{reason} in {1000 * c['needlekit_time_s']:.1f} ms"
    )


def format_screening(summary: dict[str, Any]) -> str:
    """The screening's counts and cases (for the terminal); unsound cases first, loudly.

    Parameters
    ----------
    summary : dict
        :func:`screening_summary`.

    Returns
    -------
    str
    """
    s = summary
    lines = [
        f"SOUNDNESS BUG: needlekit says infeasible, the app finds a plan: {_line(c)}"
        for c in s["unsound"]
    ]
    worst = s["max_needlekit_time_s_of_those"]
    lines += [
        f"screening: {s['cases']} cases; the app says not connected in {s['app_not_connected']}, "
        f"needlekit infeasible in {s['needlekit_infeasible_of_those']} of them "
        f"({s['needlekit_infeasible_within_0_1_s_of_those']} within {SCREEN_TIME_S:g} s), "
        f"largest needlekit time {'-' if worst is None else f'{1000 * worst:.1f} ms'}",
        *(f"  not connected: {_line(c)}" for c in s["not_connected_cases"]),
        f"unsound cases: {len(s['unsound'])}; other verdict disagreements: "
        f"{len(s['disagreements'])}",
        *(f"  disagreement: {_line(c)}" for c in s["disagreements"]),
    ]
    return "\n".join(lines)
