"""The mechanical needle's step time: a 150 mm insertion at the execution's 40 Hz.

Each step is one call of :meth:`needlekit.mechanics.insertion.MechanicalNeedle.step` as
the execution loop makes it (a spin, a commanded curvature, ``ds`` of insertion); its
wall time is taken with :func:`time.perf_counter` and the percentiles reported. The
model's ``kappa_max`` (one long probe insertion, cached per needle and tissue) is timed
apart: it is paid once per process, not per step.
"""

from __future__ import annotations

import math
import time
from typing import Any

import numpy as np

from needlekit.mechanics.insertion import MechanicalNeedle, steady_curvature
from needlekit.mechanics.materials import NeedleSpec, TissueSpec
from needlekit.provenance import machine_info

__all__ = ["run_mechanics_benchmark"]


def run_mechanics_benchmark(
    length_mm: float = 150.0,
    speed_mm_s: float = 4.0,
    rate_hz: float = 40.0,
    needle: str = "nitinol",
    tissue: str = "liver",
    seed: int = 0,
) -> dict[str, Any]:
    """Time every step of one insertion of ``length_mm`` under a duty-cycled command.

    The command alternates every 10 mm between the bevel held, half duty and a spin by
    pi (a realistic steering pattern); the tissue inhomogeneity is on (SD 0.1).

    Parameters
    ----------
    length_mm : float
        Depth inserted (mm).
    speed_mm_s : float
        Insertion speed (mm/s); ``ds = speed / rate`` per step.
    rate_hz : float
        Steps per second of the loop.
    needle, tissue : str
        Preset names.
    seed : int
        Seed of the inhomogeneity.

    Returns
    -------
    dict
        ``benchmark``, ``machine``, ``inputs`` and ``results``: ``step_ms_p50``,
        ``step_ms_p99``, ``step_ms_max``, ``steps``, ``kappa_max_per_mm``,
        ``kappa_max_s`` (the probe's time) and the tip's final position.
    """
    n_spec, t_spec = NeedleSpec.preset(needle), TissueSpec.preset(tissue)
    t0 = time.perf_counter()
    kappa_max = steady_curvature(n_spec, t_spec)
    probe_s = time.perf_counter() - t0
    rng = np.random.default_rng(seed)
    sim = MechanicalNeedle(np.eye(4), n_spec, t_spec, rng, inhomogeneity=0.1)
    ds = speed_mm_s / rate_hz
    dt = 1.0 / rate_hz
    steps = math.ceil(length_mm / ds)
    times = np.empty(steps)
    for i in range(steps):
        phase = int(i * ds // 10.0) % 3
        spin = math.pi if phase == 2 and int((i - 1) * ds // 10.0) % 3 != 2 else 0.0
        kappa = kappa_max if phase != 1 else 0.5 * kappa_max
        t0 = time.perf_counter()
        sim.step(spin, kappa, ds, dt)
        times[i] = time.perf_counter() - t0
    ms = times * 1e3
    return {
        "benchmark": "mechanics-step",
        "machine": machine_info(),
        "inputs": {
            "length_mm": length_mm,
            "speed_mm_s": speed_mm_s,
            "rate_hz": rate_hz,
            "needle": needle,
            "tissue": tissue,
            "seed": seed,
        },
        "results": {
            "steps": steps,
            "step_ms_p50": float(np.percentile(ms, 50)),
            "step_ms_p99": float(np.percentile(ms, 99)),
            "step_ms_max": float(ms.max()),
            "kappa_max_per_mm": kappa_max,
            "kappa_max_s": probe_s,
            "tip_mm": sim.pose[:3, 3].tolist(),
            "rod_nodes_at_end": int(sim.shaft_points_mm().shape[0]),
        },
    }
