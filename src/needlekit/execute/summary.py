"""The figures of a study's trials (``execute.json``'s ``summary``): per loop the errors,
clearances, crossings, re-plans and their latency, the faults met and what the sensor guard
did; the trials that crashed; and the published errors the report sets beside them."""

from __future__ import annotations

import math

import numpy as np

from needlekit.execute.breathing import POLICIES

__all__ = [
    "ANSWER_WITHIN_S",
    "HOLDING_FAULTS",
    "LITERATURE",
    "loop_summary",
    "study_summary",
    "unanswered_faults",
]

#: Published closed-loop steerable-needle and robotic insertion errors, for the
#: report's table: (source, setting, mean mm, SD mm or None, note).
LITERATURE: tuple[tuple, ...] = (
    ("Vrooijink et al.", "phantom, RRT re-planned from 2D ultrasound, no obstacle", 0.86, 0.35, ""),
    ("Vrooijink et al.", "phantom, moving obstacle", 2.16, 0.88, ""),
    ("Rossa et al.", "phantom", 0.56, 0.62, ""),
    ("Rossa et al.", "ex vivo tissue", 0.48, 0.48, ""),
    ("Moreira et al.", "moving phantom", 1.05, 0.41, ""),
    ("Patil et al. (T-RO 2014)", "tissue, re-planned", None, None, "under 3 mm"),
    ("Hauser et al.", "simulation", None, None, "up to 88 % less error than open loop"),
    ("robotic CT-guided, in vivo", "lung", None, None, "1.2-1.4 mm"),
    ("robotic CT-guided, in vivo", "liver, targets moving 6.4 +- 3.9 mm", 2.9, None, ""),
)


def _stats(values) -> dict:
    v = np.asarray([x for x in values if x is not None], dtype=float)
    if not len(v):
        return {"n": 0}
    return {
        "n": int(len(v)),
        "mean": float(v.mean()),
        "sd": float(v.std(ddof=1)) if len(v) > 1 else 0.0,
        "min": float(v.min()),
        "median": float(np.median(v)),
        "p95": float(np.percentile(v, 95)),
        "max": float(v.max()),
    }


def loop_summary(runs: list[dict]) -> dict:
    """Statistics of the runs of one kind (open or closed loop).

    Parameters
    ----------
    runs : list of dict
        The ``open_loop`` (or ``closed_loop``) records of the trials.

    Returns
    -------
    dict
        ``final_error_mm`` and ``min_clearance_mm`` statistics, ``within_1mm`` (fraction),
        ``violated`` (count, and the trials), re-plans and their latency (p50, p95, max).
    """
    lat = [t for r in runs for t in r["replan_latency_s"]]
    err = [r["final_error_mm"] for r in runs]
    cross = [d for r in runs for d in r.get("cross_track_mm") or ()]
    return {
        "cross_track_rms_mm": math.sqrt(sum(d * d for d in cross) / len(cross)) if cross else None,
        "cross_track_max_mm": max(cross) if cross else None,
        "runs": len(runs),
        "final_error_mm": _stats(err),
        "within_1mm": (sum(e <= 1.0 for e in err) / len(err)) if err else None,
        "min_clearance_mm": _stats(r["min_clearance_mm"] for r in runs),
        "violated": sum(bool(r["violated"]) for r in runs),
        "replans": _stats(r["replans"] for r in runs),
        "replan_latency_ms": _stats(1e3 * t for t in lat),
        **_fault_summary(runs),
    }


def _fault_summary(runs: list[dict]) -> dict:
    """Closed loop: the faults met and what the guard did (counts over the runs)."""
    if not runs or "faults" not in runs[0]:
        return {}
    events = [e for r in runs for e in r["faults"]]
    rejected: dict = {}
    for r in runs:
        for k, n in r["rejected"].items():
            rejected[k] = rejected.get(k, 0) + n
    injected: dict = {}
    for r in runs:
        for f in r.get("faults_injected", ()):
            injected[f["kind"]] = injected.get(f["kind"], 0) + 1
    return {
        "holds": sum(r["holds"] for r in runs),
        "held_s": _stats(r["held_s"] for r in runs),
        "aborted": sum(bool(r["aborted"]) for r in runs),
        "stopped_near_obstacle": sum(bool(r.get("stopped_near_obstacle")) for r in runs),
        "fault_events": {
            f"{k}/{a}": sum(e["kind"] == k and e["action"] == a for e in events)
            for k, a in sorted({(e["kind"], e["action"]) for e in events})
        },
        "rejected": rejected,
        "faults_injected": injected,
        "faults_unanswered": sum(len(unanswered_faults(r)) for r in runs),
    }


#: The injected faults that must hold the needle (a late sample or a failed re-plan need
#: not), and how long after a fault's end its hold may begin (s): the guard's stale time
#: and a sample period, rounded up.
HOLDING_FAULTS: tuple[str, ...] = ("dropout", "freeze", "distortion", "nan")
ANSWER_WITHIN_S: float = 0.5


def unanswered_faults(run: dict) -> list[dict]:
    """The injected faults of one closed-loop run that no hold (or abort) answered: met
    while the insertion ran, and no hold overlapping them (or beginning within
    :data:`ANSWER_WITHIN_S` of their end).

    Parameters
    ----------
    run : dict
        A closed-loop record with ``faults``, ``faults_injected`` and ``procedure_s``.

    Returns
    -------
    list of dict
    """
    spans, start = [], None
    end_s = run.get("procedure_s", math.inf)
    for e in run["faults"]:
        if e["action"] in ("hold", "abort") and start is None:  # a hold's first event
            start = e["time_s"]
        if e["action"] in ("resume", "abort") and start is not None:
            spans.append((start, e["time_s"]))
            start = None
    if start is not None:
        spans.append((start, end_s))
    out = []
    for f in run.get("faults_injected", ()):
        if f["kind"] not in HOLDING_FAULTS or f["start_s"] >= end_s:
            continue
        if not any(a <= f["end_s"] + ANSWER_WITHIN_S and b >= f["start_s"] for a, b in spans):
            out.append(f)
    return out


def study_summary(records: list[dict], margin_mm: float) -> dict:
    """The summary of a study's trials: per loop (:func:`loop_summary`), the trials that
    crashed, and the margin.

    Parameters
    ----------
    records : list of dict
    margin_mm : float

    Returns
    -------
    dict
    """
    ok = [r for r in records if "error" not in r]
    statuses = [r["status"] for r in records if "status" in r]
    return {
        "trials": len(records),
        "status": {k: statuses.count(k) for k in sorted(set(statuses))},
        "crashed": [{"trial": r["trial"], "error": r["error"]} for r in records if "error" in r],
        "margin_mm": margin_mm,
        "open_loop": loop_summary([r["open_loop"] for r in ok]),
        "closed_loop": loop_summary([r["closed_loop"] for r in ok]),
        **_breathing_summary(ok),
        **_sensing_summary(ok),
        "literature": [
            dict(zip(("source", "setting", "mean_mm", "sd_mm", "note"), row, strict=True))
            for row in LITERATURE
        ],
    }


def _breathing_summary(records: list[dict]) -> dict:
    with_b = [r["breathing"] for r in records if "breathing" in r]
    if not with_b:
        return {}
    return {
        "breathing": {
            name: {
                **loop_summary([b[name] for b in with_b]),
                "procedure_s": _stats(b[name]["procedure_s"] for b in with_b),
            }
            for name in POLICIES
        }
    }


def _sensing_summary(records: list[dict]) -> dict:
    """Several sensing policies side by side: per policy the loop's figures, the procedure's
    time, the scans (the dose), how far the target moved and how far the belief ended from
    it."""
    with_s = [r["sensing"] for r in records if "sensing" in r]
    if not with_s:
        return {}
    out = {}
    for name in with_s[0]:
        runs = [b[name] for b in with_s]
        out[name] = {
            **loop_summary(runs),
            "procedure_s": _stats(r.get("procedure_s") for r in runs),
            "scans": _stats(r.get("scans") for r in runs),
            "target_displacement_max_mm": _stats(r.get("target_displacement_max_mm") for r in runs),
            "target_error_mm": _stats(r.get("target_error_mm") for r in runs),
            "target_samples_refused": _refused(runs),
        }
    return {"sensing": out}


def _refused(runs: list[dict]) -> dict:
    out: dict = {}
    for r in runs:
        for k, n in (r.get("target_samples_refused") or {}).items():
            out[k] = out.get(k, 0) + n
    return out
