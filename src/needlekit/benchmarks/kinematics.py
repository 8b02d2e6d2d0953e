"""``needlekit bench kinematics``: arcs propagated and sampled per second.

The numba kernels are timed against the numpy references in the same process on the same
seeded inputs, so the ratio is the figure to compare across machines; the first call
(compilation, or loading from numba's cache) is timed separately.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from needlekit.benchmarks.record import best_time, machine_info
from needlekit.geometry.arcs import (
    propagate_arcs,
    propagate_arcs_reference,
    sample_arcs,
    sample_arcs_reference,
)
from needlekit.geometry.se3 import se3_exp

__all__ = ["run_kinematics_benchmark"]


def _inputs(n: int, seed: int):
    rng = np.random.default_rng(seed)
    poses = se3_exp(np.column_stack([rng.normal(0, 50, (n, 3)), rng.normal(0, 1, (n, 3))]))
    spin = rng.uniform(-np.pi, np.pi, n)
    kappa = rng.uniform(0.0, 0.02, n)
    length = rng.uniform(0.5, 20.0, n)
    return poses, spin, kappa, length


def run_kinematics_benchmark(
    n_arcs: int = 200_000, n_samples: int = 32, repeat: int = 5, seed: int = 0
) -> dict[str, Any]:
    """Time arc propagation and dense sampling, numba kernels vs numpy references.

    Parameters
    ----------
    n_arcs : int
        Arcs per timed batch (each from its own start pose).
    n_samples : int
        Points per sampled arc.
    repeat : int
        Timed repetitions; the best is reported.
    seed : int
        Seed of the random inputs.

    Returns
    -------
    dict
        ``benchmark``, ``machine``, ``inputs`` and ``results`` (one row per kernel with
        ``arcs_per_s``, ``reference_arcs_per_s``, ``speedup_vs_reference``,
        ``first_call_s`` and ``max_abs_diff_mm`` against the reference).
    """
    poses, spin, kappa, length = _inputs(n_arcs, seed)
    ref_n = min(n_arcs, 20_000)  # the numpy reference is slow and memory-hungry on big batches
    small = (poses[:ref_n], spin[:ref_n], kappa[:ref_n], length[:ref_n])

    results = []
    for name, fast, ref, extra in (
        ("propagate_arcs", propagate_arcs, propagate_arcs_reference, ()),
        ("sample_arcs", sample_arcs, sample_arcs_reference, (n_samples,)),
    ):
        t0 = time.perf_counter()
        fast(*small, *extra)
        first_call = time.perf_counter() - t0
        diff = float(np.abs(fast(*small, *extra) - ref(*small, *extra)).max())
        t_fast = best_time(lambda f=fast, e=extra: f(poses, spin, kappa, length, *e), repeat)
        t_ref = best_time(lambda r=ref, e=extra: r(*small, *e), repeat)
        fast_rate = n_arcs / t_fast
        ref_rate = ref_n / t_ref
        row = {
            "name": name,
            "arcs_per_s": fast_rate,
            "reference_arcs_per_s": ref_rate,
            "speedup_vs_reference": fast_rate / ref_rate,
            "first_call_s": first_call,
            "max_abs_diff_mm": diff,
        }
        if extra:
            row["points_per_s"] = fast_rate * n_samples
        row["summary"] = (
            f"{fast_rate / 1e6:8.2f} M arcs/s  (numpy reference {ref_rate / 1e6:.2f} M/s, "
            f"x{fast_rate / ref_rate:.1f}; first call {first_call:.2f} s)"
        )
        results.append(row)
    return {
        "benchmark": "kinematics",
        "machine": machine_info(),
        "inputs": {
            "n_arcs": n_arcs,
            "n_samples": n_samples,
            "repeat": repeat,
            "seed": seed,
            "reference_n_arcs": ref_n,
        },
        "results": results,
    }
