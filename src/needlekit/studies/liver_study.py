"""The Med-RAD liver study: every nodule of every Med-RAD liver ablated by straight needles.

For each patient, each start pose the patient's files pair with a nodule
(``start1`` with the only nodule, ``target2_start1`` with nodule 2, ...), and each safety
distance gamma, :func:`run_liver_study` plans the case as ``needlekit multi`` plans
``examples/medrad_liver4.yaml`` (:data:`LIVER_SETTINGS`, the example's settings; only the
patient, start, nodule and gamma change):

- the targets are chosen so that the ablation zones cover the nodule plus its margin
  (counted inside the liver), with at most ``max_needles`` needles;
- their trajectories are planned one after another by the ``liu_cfrw`` planner (CFRW at
  ``resolution_deg``, entries on the liver capsule within the approach cone around the
  start's direction, gamma from the hepatic artery, hepatic vein and portal vein, each
  placed needle an obstacle for the next);
- the coverage is re-checked along the planned needles (one more round of targets along
  them when it dropped, as ``needlekit multi`` does);
- every needle the plan reports is re-checked by
  :func:`~needlekit.planning.straight.verify.verify_multi` from the record alone.

Each row says whether the case is covered and, where it is not, what stops it: the
coverage with the reachable targets, the needle with no trajectory and what blocks the
directions of its CFRW within the angle limits (the anatomy, a needle placed before, too
long, too oblique, no entry), or the coverage lost along the planned directions.

:func:`run_liver_study` writes ``study.json`` (settings, machine, rows) atomically and
returns the rows; ``needlekit study livers`` prints them as a table.
"""

from __future__ import annotations

import copy
import os
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from needlekit.errors import INTERRUPT_FORMS, Interrupted, InvalidInputError, is_interrupt
from needlekit.io.files import write_json
from needlekit.io.medrad_paths import chosen_patients, patient_folder
from needlekit.io.partial import read_partial, write_partial
from needlekit.planning.interface import get_planner
from needlekit.provenance import machine_info
from needlekit.scenario.straight import coverage_region, multi_problem_from_scenario

__all__ = [
    "LIVER_SETTINGS",
    "liver_cases",
    "liver_scenario",
    "read_partial_livers",
    "run_liver_case",
    "run_liver_study",
]

#: The scenario of ``examples/medrad_liver4.yaml`` (the study's defaults); ``patient``,
#: the start, the nodule and gamma are filled in per case.
LIVER_SETTINGS: dict = {
    "version": 1,
    "needle": {"diameter_mm": 2.0, "max_length_mm": 200},
    "straight": {
        "entry_surface": "liver",
        "targets": "coverage",
        "coverage": {
            "zone": {"kind": "ellipsoid", "length_mm": 60, "diameter_mm": 50},
            "margin_mm": 5,
            "max_needles": 6,
            "coverage_goal": 1.0,
        },
        "gamma_mm": 1.5,
        "approach_cone_deg": 45,
    },
}
#: The safety distances (mm).
DEFAULT_GAMMAS_MM: tuple[float, ...] = (1.5, 3.0)


def liver_cases(medrad_dir=None, livers: Sequence[int] | None = None) -> list[dict]:
    """Every (patient, start, nodule) of the Med-RAD livers, in patient and start order.

    Parameters
    ----------
    medrad_dir : path-like, optional
        Med-RAD folder (default ``$NEEDLEKIT_MEDRAD`` or ``../shared/data/med-rad``).
    livers : sequence of int, optional
        Patients (default: every ``Patient*`` folder).

    Returns
    -------
    list of dict
        ``patient``, ``start`` (the pose file's stem) and ``nodule`` (the structure name).

    Raises
    ------
    InvalidInputError
        No Med-RAD liver folder, or a patient that is not there.
    """
    from needlekit.io.medrad import _files, _starts_and_targets

    root, chosen = chosen_patients("liver", medrad_dir, livers, patients_flag="--livers")
    out = []
    for p in chosen:
        folder = patient_folder("liver", p, root)
        starts, _ = _starts_and_targets(_files(folder), folder)
        for s in starts:
            nodule = "nodule" if s.target == "target" else f"nodule{s.target[len('target') :]}"
            out.append({"patient": int(p), "start": s.name, "nodule": nodule})
    return out


def liver_scenario(
    case: dict, gamma_mm: float, *, medrad_dir=None, resolution_deg: float | None = None
) -> dict:
    """The scenario document of one case (:data:`LIVER_SETTINGS` filled in).

    Parameters
    ----------
    case : dict
        From :func:`liver_cases`.
    gamma_mm : float
    medrad_dir : path-like, optional
    resolution_deg : float, optional
        CFRW grid step (default the planner's, 1 degree).

    Returns
    -------
    dict
    """
    doc = copy.deepcopy(LIVER_SETTINGS)
    medrad = {"organ": "liver", "patient": int(case["patient"])}
    if medrad_dir is not None:
        medrad["root"] = str(Path(medrad_dir).resolve())
    doc["name"] = f"Med-RAD liver {case['patient']}, {case['nodule']} from {case['start']}"
    doc["base"] = {"medrad": medrad}
    doc["start"] = {"case_start": case["start"]}
    doc["straight"]["gamma_mm"] = float(gamma_mm)
    doc["straight"]["coverage"]["structure"] = case["nodule"]
    if resolution_deg is not None:
        doc["straight"]["resolution_deg"] = float(resolution_deg)
    return doc


def run_liver_case(
    case: dict,
    gamma_mm: float,
    *,
    medrad_dir=None,
    resolution_deg: float | None = None,
    cache_dir=None,
    use_cache: bool = True,
) -> dict:
    """Plan one case as ``needlekit multi`` does and check it; one row of the study.

    Parameters
    ----------
    case : dict
        From :func:`liver_cases`.
    gamma_mm : float
    medrad_dir, cache_dir : path-like, optional
    resolution_deg : float, optional
    use_cache : bool

    Returns
    -------
    dict
        The case, ``gamma_mm``, ``status`` (``covered``, ``not_covered`` or ``blocked``:
        some needle has no trajectory), ``reason``, ``needles_chosen``,
        ``needles_planned``, ``coverage``, ``tumour_coverage``, ``healthy_ablated_ml``,
        ``tumour_volume_ml``, ``rounds``, ``min_clearance_mm``,
        ``min_needle_clearance_mm``, ``lengths_mm``, ``blocked`` (the failing needle's
        counts, or None), ``verified`` (every planned needle passes the independent
        check; None when none was planned), ``violations``, ``prepare_s`` and ``plan_s``.
    """
    from needlekit.planning.straight.ablation import plan_coverage
    from needlekit.planning.straight.verify import verify_multi
    from needlekit.scenario.loading import parse_scenario

    t0 = time.perf_counter()
    doc = liver_scenario(case, gamma_mm, medrad_dir=medrad_dir, resolution_deg=resolution_deg)
    sc = parse_scenario(doc, source=doc["name"], cache_dir=cache_dir, use_cache=use_cache)
    multi, options = multi_problem_from_scenario(sc)
    region, settings = coverage_region(sc, multi.problem)
    prepare_s = time.perf_counter() - t0
    planner = get_planner("liu_cfrw", options)
    steps: dict = {}
    t1 = time.perf_counter()
    plan, outcome = plan_coverage(
        multi, planner, region, settings, time_limit_s=3600.0, timings=steps
    )
    plan_s = time.perf_counter() - t1
    rep = outcome.planned or outcome.chosen.report
    placed = [] if plan is None else [n for n in plan.needles if n.entry is not None]
    failing = None if plan is None else next((n for n in plan.needles if n.entry is None), None)
    if outcome.ok:
        status = "covered"
    elif plan is not None and not plan.solved:
        status = "blocked"
    else:
        status = "not_covered"
    verified, violations = None, []
    if placed:
        record = plan.to_dict()
        record["needles"] = [n for n in record["needles"] if n.get("entry_mm") is not None]
        check = verify_multi(multi.problem, record)
        verified, violations = bool(check.ok), list(check.violations)
    needle_clear = [n.needle_clearance_mm for n in placed if np.isfinite(n.needle_clearance_mm)]
    return {
        **case,
        "gamma_mm": float(gamma_mm),
        "status": status,
        "reason": outcome.reason,
        "needles_chosen": int(outcome.chosen.needles),
        "needles_planned": len(placed),
        "coverage": float(rep.coverage),
        "tumour_coverage": float(rep.tumour_coverage),
        "healthy_ablated_ml": float(rep.healthy_ablated_ml),
        "tumour_volume_ml": float(rep.tumour_volume_ml),
        "rounds": int(steps.get("rounds", 1)),
        "min_clearance_mm": min((n.entry.clearance_mm for n in placed), default=None),
        "min_needle_clearance_mm": min(needle_clear, default=None),
        "lengths_mm": [float(n.entry.length_mm) for n in placed],
        "blocked": None if failing is None else dict(failing.blocked),
        "verified": verified,
        "violations": violations,
        "prepare_s": prepare_s,
        "plan_s": plan_s,
    }


def _summary(rows: list[dict]) -> dict:
    by = {s: sum(r["status"] == s for r in rows) for s in ("covered", "not_covered", "blocked")}
    return {
        "cases": len(rows),
        **by,
        "verified": sum(r["verified"] is True for r in rows),
        "violations": sum(len(r["violations"]) for r in rows),
    }


def run_liver_study(
    out,
    *,
    medrad_dir=None,
    livers: Sequence[int] | None = None,
    gammas_mm: Sequence[float] = DEFAULT_GAMMAS_MM,
    resolution_deg: float | None = None,
    cache_dir=None,
    use_cache: bool = True,
    progress: Callable[[dict], None] | None = None,
    resume: Sequence[dict] | None = None,
) -> dict:
    """Run every case at every gamma and write ``out`` (JSON, atomically).

    Parameters
    ----------
    out : path-like
        The study record to write.
    medrad_dir : path-like, optional
    livers : sequence of int, optional
        Patients (default all).
    gammas_mm : sequence of float
        Safety distances (default 1.5 and 3 mm).
    resolution_deg : float, optional
        CFRW grid step (default 1 degree).
    cache_dir : path-like, optional
    use_cache : bool
    progress : callable, optional
        Called with each row as it is done.
    resume : sequence of dict, optional
        Rows an interrupted run finished (:func:`read_partial_livers`): kept, and only the
        other cases planned.

    Returns
    -------
    dict
        The record written: ``settings``, ``machine``, ``summary`` and ``rows``.

    Raises
    ------
    Interrupted
        Ctrl-C during the cases: the rows done are written to ``out`` marked partial,
        which ``resume`` carries on from.
    """
    cases = liver_cases(medrad_dir, livers)
    head = _study_head(cases, gammas_mm, medrad_dir, resolution_deg)
    done = {_row_key(r, r["gamma_mm"]): r for r in resume or ()}
    rows = []
    t0 = time.perf_counter()
    try:
        for case in cases:
            for g in gammas_mm:
                row = done.get(_row_key(case, g)) or run_liver_case(
                    case,
                    g,
                    medrad_dir=medrad_dir,
                    resolution_deg=resolution_deg,
                    cache_dir=cache_dir,
                    use_cache=use_cache,
                )
                rows.append(row)
                if progress is not None:
                    progress(row)
    except INTERRUPT_FORMS as exc:  # keep what is done, and say so
        if not is_interrupt(exc):  # Ctrl-C, also inside a compiled kernel
            raise
        written = write_partial(out, {**head, "rows": rows})
        raise Interrupted(
            f"{len(rows)} of {len(cases) * len(gammas_mm)} cases done; written to {written} "
            "marked partial; the same command with --resume carries on"
        ) from None
    record = {
        **head,
        "machine": machine_info(),
        "wall_s": time.perf_counter() - t0,
        "summary": _summary(rows),
        "rows": rows,
    }
    write_json(out, record)
    return record


def _row_key(case: dict, gamma_mm) -> tuple:
    return (case["patient"], case["start"], case["nodule"], float(gamma_mm))


def _study_head(cases: list[dict], gammas_mm, medrad_dir, resolution_deg) -> dict:
    """The record's ``study`` and ``settings`` (what a resumed run must share)."""
    for g in gammas_mm:
        if not (np.isfinite(g) and g >= 0):
            raise InvalidInputError("--gamma", f"expected numbers >= 0 (mm), got {g}")
    settings = liver_scenario(cases[0], gammas_mm[0], resolution_deg=resolution_deg)
    for key in ("name", "base", "start"):
        settings.pop(key)
    settings["straight"].pop("gamma_mm")
    settings["straight"]["coverage"].pop("structure")
    return {
        "study": "medrad_livers",
        "settings": {
            **settings,
            "gammas_mm": [float(g) for g in gammas_mm],
            "resolution_deg": 1.0 if resolution_deg is None else float(resolution_deg),
            "livers": sorted({c["patient"] for c in cases}),
            "medrad_dir": None if medrad_dir is None else os.fspath(medrad_dir),
        },
    }


def read_partial_livers(
    out, cases: list[dict], *, medrad_dir=None, gammas_mm=DEFAULT_GAMMAS_MM, resolution_deg=None
) -> list[dict]:
    """The rows an interrupted study finished (``study livers --resume``), from its
    record marked partial (signed: :func:`needlekit.io.partial.read_partial`).

    Parameters
    ----------
    out : path-like
    cases : list of dict
        This run's cases (:func:`liver_cases`).
    medrad_dir, gammas_mm, resolution_deg
        This run's: the record's.

    Returns
    -------
    list of dict

    Raises
    ------
    InvalidInputError
        (named ``--resume``) No such file, not partial, changed since it was written, or
        other settings than this run's.
    """
    head = _study_head(cases, gammas_mm, medrad_dir, resolution_deg)
    return list(read_partial(out, "study", head).get("rows") or [])
