"""The statistics of a puncture study: summary figures of a quantity over trials, and the
constraint violations beyond the measurement noise (Tang et al.'s criterion)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from needlekit.records import trial_solved

__all__ = ["summary_stats"]


def summary_stats(values) -> dict:
    """``mean``, ``sd`` (sample), ``median``, ``min`` and ``max`` of finite values.

    Parameters
    ----------
    values : array_like, shape (n,)

    Returns
    -------
    dict
        Also ``n``; the statistics are None when there is no value.
    """
    v = np.asarray([x for x in values if x is not None and math.isfinite(x)], dtype=float)
    if not len(v):
        return dict.fromkeys(("n", "mean", "sd", "median", "min", "max")) | {"n": 0}
    return {
        "n": len(v),
        "mean": float(v.mean()),
        "sd": float(v.std(ddof=1)) if len(v) > 1 else 0.0,
        "median": float(np.median(v)),
        "min": float(v.min()),
        "max": float(v.max()),
    }


@dataclass(frozen=True)
class _Bounds:
    guide_mm: float
    cone_deg: float
    patient_mm: float
    noise_mm: float
    noise_deg: float


def _violations(trials: list[dict], b: _Bounds) -> dict:
    """Constraint violations beyond the measurement noise (the paper's criterion), on the
    real tip and needle over the whole puncture, from its first step, whether or not the
    tip ever entered the guide cylinder: the tip farther from the guide line, or the needle
    farther from its direction, than the bound or than where the puncture started
    (whichever is larger: starting outside, a VFI only lets it come closer)."""

    def start(t, key):
        v = t.get(key)
        return 0.0 if v is None else v

    checks = {
        "guide_cylinder": lambda t: (
            t["max_guide_distance_mm"]
            > max(b.guide_mm, start(t, "start_guide_distance_mm")) + b.noise_mm
        ),
        "cone": lambda t: (
            t["max_cone_angle_deg"]
            > max(b.cone_deg, start(t, "start_cone_angle_deg")) + b.noise_deg
        ),
        "plane": lambda t: (t["min_plane_distance_mm"] or 0.0) < -b.noise_mm,
        "patient_cylinder": lambda t: (
            (t["min_patient_distance_mm"] or math.inf) < b.patient_mm - b.noise_mm
        ),
    }
    out = {}
    for name, bad in checks.items():
        hit = [t["trial"] for t in trials if trial_solved(t["status"]) and bad(t)]
        out[name] = {"count": len(hit), "trials": hit}
    out["total"] = sum(v["count"] for v in out.values())
    out["tolerance"] = {"position_mm": b.noise_mm, "angle_deg": b.noise_deg}
    return out
