"""``needlekit bench execute``'s physical part: the coupled needle-tissue step and its
precomputation, per Med-RAD lung.

For each lung's plan, the organ (its mask, meshed in tetrahedra) is precomputed for the
plan's corridor twice, cold (an empty cache folder: mesh, factorisation, condensed
compliance) and warm (the same folder: read back); then the ``physical`` truth
(:class:`~needlekit.execute.deforming.DeformingTruth`: the rod in the deforming organ)
inserts along the plan as the loop drives it (0.01 mm and 5 ms per loop step, the plan's
commands), and every coupled step (the rod's solve, its loads to the organ, the organ's
answer: one per 25 ms, the 40 Hz sensor's period) is timed. Target: p99 at most 25 ms.
"""

from __future__ import annotations

import tempfile
import time

import numpy as np

from needlekit.benchmarks.timing import step_statistics
from needlekit.execute.deforming import DeformingTruth, load_compliance, tissue_model_for
from needlekit.execute.physical import MechanicsSettings
from needlekit.mechanics.insertion import MechanicalNeedle
from needlekit.tissue.runtime import DeformingTissue

__all__ = ["MECHANICS_STEP_P99_MS", "physics_row", "physics_summary"]

#: The coupled step's target: p99 within one period of the 40 Hz sensor.
MECHANICS_STEP_P99_MS: float = 25.0


class _Timed(DeformingTruth):
    """The physical truth with each coupled step's wall time kept."""

    def __init__(self, *a, **kw) -> None:
        self.step_s: list[float] = []
        super().__init__(*a, **kw)

    def _flush(self) -> None:
        if self._len <= 0.0:
            super()._flush()
            return
        t0 = time.perf_counter()
        super()._flush()
        self.step_s.append(time.perf_counter() - t0)


def physics_row(scenario, plan, goal_mm, r_min_mm: float, seed: int = 0) -> dict:
    """Precompute one lung's organ cold and warm and time the coupled step along its plan.

    Parameters
    ----------
    scenario : needlekit.scenario.loading.Scenario
        With a Med-RAD base.
    plan : SteerablePlan
    goal_mm : array_like, shape (3,)
    r_min_mm : float
        The plan's radius (its commands are duty cycles of it).
    seed : int

    Returns
    -------
    dict
        ``mesh_tetrahedra``, ``precompute_cold_s``, ``precompute_warm_s``,
        ``mechanics_step_ms`` (:func:`~needlekit.benchmarks.timing.step_statistics`, ms),
        ``mechanics_step_s`` (every step, s: :func:`physics_summary` pools and drops them),
        ``target_displacement_mm`` (the largest, on the way).
    """
    model = tissue_model_for(scenario, plan, goal_mm)
    with tempfile.TemporaryDirectory(prefix="needlekit-bench-tissue-") as cache:
        t0 = time.perf_counter()
        load_compliance(model, cache)
        cold = time.perf_counter() - t0
        t0 = time.perf_counter()
        comp = load_compliance(model, cache)
        warm = time.perf_counter() - t0
    m = MechanicsSettings(tissue="lung")
    needle = MechanicalNeedle(plan.start_pose, m.needle_spec(), m.tissue_spec(),
                              rng=np.random.default_rng(seed), inhomogeneity=m.inhomogeneity)  # fmt: skip
    truth = _Timed(needle, r_min_mm, m.solve_rate_hz, DeformingTissue(comp))
    for spin, kappa, length in plan.primitives:
        n = max(1, int(np.ceil(length / 0.01)))
        for i in range(n):
            truth.step(spin if i == 0 else 0.0, kappa, length / n, 0.005)
    stats = step_statistics(np.asarray(truth.step_s))
    return {
        "mesh_tetrahedra": int(comp.mesh.n_tets),
        "precompute_cold_s": cold,
        "precompute_warm_s": warm,
        "mechanics_steps": len(truth.step_s),
        "mechanics_step_ms": {k: v / 1e3 for k, v in stats.items() if k != "n"},
        "mechanics_step_s": list(truth.step_s),
        "target_displacement_mm": truth.max_target_displacement_mm,
    }


def physics_summary(rows: list[dict]) -> dict:
    """Pooled over the lungs: the coupled step's p50 and p99 (ms), the meshes' sizes and the
    precomputation's times.

    Parameters
    ----------
    rows : list of dict
        :func:`physics_row`'s (their ``mechanics_step_s`` are taken out).

    Returns
    -------
    dict
    """
    if not rows:
        return {}
    steps = np.concatenate([r.pop("mechanics_step_s") for r in rows]) * 1e3
    p99 = float(np.percentile(steps, 99))
    return {
        "mechanics_step_ms": {"p50": float(np.median(steps)), "p99": p99},
        "mechanics_steps": int(len(steps)),
        "mesh_tetrahedra": {
            "min": min(r["mesh_tetrahedra"] for r in rows),
            "max": max(r["mesh_tetrahedra"] for r in rows),
        },
        "precompute_cold_s": {"max": max(r["precompute_cold_s"] for r in rows)},
        "precompute_warm_s": {"max": max(r["precompute_warm_s"] for r in rows)},
        "mechanics_within_target": p99 <= MECHANICS_STEP_P99_MS,
        "mechanics_step_p99_target_ms": MECHANICS_STEP_P99_MS,
    }
