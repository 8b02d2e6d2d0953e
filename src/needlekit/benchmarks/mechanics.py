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
from needlekit.mechanics.tip_load import bevel_tip_load
from needlekit.provenance import machine_info

__all__ = ["curvature_table", "run_mechanics_benchmark"]


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
        ``step_ms_p99``, ``step_ms_max`` (wall time), ``step_cpu_ms_p50``,
        ``step_cpu_ms_p99`` (the thread's CPU time: the same without the time other
        processes took the core), ``steps``, ``kappa_max_per_mm``,
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
    cpu = np.empty(steps)
    for i in range(steps):
        phase = int(i * ds // 10.0) % 3
        spin = math.pi if phase == 2 and int((i - 1) * ds // 10.0) % 3 != 2 else 0.0
        kappa = kappa_max if phase != 1 else 0.5 * kappa_max
        c0 = time.thread_time()
        t0 = time.perf_counter()
        sim.step(spin, kappa, ds, dt)
        times[i] = time.perf_counter() - t0
        cpu[i] = time.thread_time() - c0
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
            "step_cpu_ms_p50": float(np.percentile(cpu * 1e3, 50)),
            "step_cpu_ms_p99": float(np.percentile(cpu * 1e3, 99)),
            "kappa_max_per_mm": kappa_max,
            "kappa_max_s": probe_s,
            "tip_mm": sim.pose[:3, 3].tolist(),
            "rod_nodes_at_end": int(sim.shaft_points_mm().shape[0]),
        },
    }


def curvature_table(
    needles: tuple[str, ...] = ("nitinol", "steel"),
    tissues: tuple[str, ...] = ("gelatin", "plastisol", "chicken", "liver", "lung"),
    bevels_deg: tuple[float, ...] = (10.0, 20.0, 30.0, 45.0, 60.0),
    stiffness_factors: tuple[float, ...] = (0.5, 1.0, 2.0, 4.0),
    prebends_deg: tuple[float, ...] = (10.0, 20.0, 30.0),
) -> dict[str, list[dict[str, Any]]]:
    """The model's steady curvature with the bevel held, over presets and sweeps.

    Parameters
    ----------
    needles, tissues : tuple of str
        Preset names for the preset table.
    bevels_deg : tuple of float
        Bevel angles (degrees) swept on the nitinol needle in chicken.
    stiffness_factors : tuple of float
        Factors on the chicken preset's Young's modulus, swept with the nitinol needle.
    prebends_deg : tuple of float
        Pre-bent tips (degrees over 5 mm) on the nitinol needle, in chicken (ex vivo)
        and liver (in vivo).

    Returns
    -------
    dict
        ``presets``, ``bevel``, ``stiffness`` and ``prebend``: rows with the inputs, the tip load
        ``q_n`` (N), the foundation length ``one_over_lambda_mm``, ``kappa_per_mm`` and
        ``radius_mm``.
    """

    def row(n: NeedleSpec, t: TissueSpec, **extra: Any) -> dict[str, Any]:
        kappa = steady_curvature(n, t)
        k = t.foundation_modulus(n)
        return {
            **extra,
            "q_n": bevel_tip_load(n, t).lateral_n,
            "one_over_lambda_mm": (4.0 * n.bending_stiffness_nmm2 / k) ** 0.25,
            "kappa_per_mm": kappa,
            "radius_mm": 1.0 / kappa if kappa > 0 else math.inf,
        }

    presets = [
        row(NeedleSpec.preset(n), TissueSpec.preset(t), needle=n, tissue=t)
        for n in needles
        for t in tissues
    ]
    nit, chicken = NeedleSpec.preset("nitinol"), TissueSpec.preset("chicken")
    bevel = [row(nit.with_bevel_deg(b), chicken, bevel_deg=b) for b in bevels_deg]
    stiff = [
        row(nit, chicken.scaled(f), tissue_modulus_kpa=1e3 * chicken.youngs_modulus_mpa * f)
        for f in stiffness_factors
    ]
    prebend = [
        row(nit.with_prebend(b, 5.0), TissueSpec.preset(t), prebend_deg=b, tissue=t)
        for t in ("chicken", "liver")
        for b in prebends_deg
    ]
    return {"presets": presets, "bevel": bevel, "stiffness": stiff, "prebend": prebend}
