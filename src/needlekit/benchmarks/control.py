"""``needlekit bench control``: the time of a whole control step of the puncture controller.

A trial of the puncture study (:mod:`needlekit.studies.puncture_study`) runs with the
controller timed at every step (:func:`needlekit.control.procedure.run_trial`'s
``timings``): guide-line update, adaptation when a needle sample arrived (every 10th step
at 100 Hz), convergence and loss checks, kinematics, VFIs and the QP; the simulated robot,
sensors and logging are not counted. The record gives the median and percentiles over all
steps, per phase and for the steps with and without adaptation.

As a reference run in the same process, the arm's kinematics (tip pose and pose Jacobian)
are timed in needlekit's numba kernel and in ``dqrobotics`` (``fkm`` + ``pose_jacobian``).
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from needlekit.benchmarks.record import machine_info

__all__ = ["run_control_benchmark", "step_statistics"]


def step_statistics(seconds) -> dict[str, Any]:
    """``n``, ``median``, ``mean``, ``p90``, ``p99`` and ``max`` in microseconds.

    Parameters
    ----------
    seconds : array_like

    Returns
    -------
    dict
    """
    us = np.asarray(seconds, dtype=float) * 1e6
    if not len(us):
        return {"n": 0}
    return {
        "n": len(us),
        "median": float(np.median(us)),
        "mean": float(us.mean()),
        "p90": float(np.percentile(us, 90)),
        "p99": float(np.percentile(us, 99)),
        "max": float(us.max()),
    }


def _kinematics_reference(n: int, seed: int) -> dict[str, Any]:
    from needlekit.control.panda import PandaModel

    rng = np.random.default_rng(seed)
    model = PandaModel()
    ref = model.reference_robot()
    qs = rng.uniform(model.q_min, model.q_max, (n, 7))
    model.state(qs[0])  # compile / load the kernel
    t0 = time.perf_counter()
    for q in qs:
        model.state(q)
    ours = (time.perf_counter() - t0) / n
    t0 = time.perf_counter()
    for q in qs:
        ref.fkm(q)
        ref.pose_jacobian(q)
    theirs = (time.perf_counter() - t0) / n
    diff = 0.0
    for q in qs[:50]:
        x, r = model.state(q).tip_dq, ref.fkm(q).vec8()
        diff = max(diff, min(float(np.max(np.abs(x - r))), float(np.max(np.abs(x + r)))))
    return {
        "name": "kinematics",
        "us_per_call": ours * 1e6,
        "reference_us_per_call": theirs * 1e6,
        "speedup_vs_reference": theirs / ours,
        "max_abs_diff": diff,
        "summary": f"{ours * 1e6:7.1f} us per state vs dqrobotics {theirs * 1e6:7.1f} us "
        f"(x{theirs / ours:.1f}; our state also has every joint axis and origin)",
    }


def run_control_benchmark(trials: int = 1, seed: int = 0, kinematics_calls: int = 2000):
    """Time the controller's steps over whole simulated punctures.

    Parameters
    ----------
    trials : int
        Trials of the puncture study to run (trial ``i`` as in the study with ``seed``).
    seed : int
    kinematics_calls : int
        Configurations for the kinematics reference.

    Returns
    -------
    dict
        ``benchmark``, ``machine``, ``inputs``, ``step_us`` (all steps), ``step_us_by_phase``,
        ``step_us_adapting`` / ``step_us_not_adapting`` and ``results`` (rows for the
        summary, with the kinematics reference).
    """
    from dataclasses import replace

    from needlekit.control.procedure import run_trial
    from needlekit.studies.puncture_study import (
        PunctureScenario,
        TrialOptions,
        run_puncture_trial,
        sample_trial,
        trial_settings,
    )

    scenario, options = PunctureScenario(), TrialOptions()
    warm = sample_trial(scenario, np.random.default_rng(0), 0)[0]
    adaptation, procedure, spec = trial_settings(scenario, options, warm.nominal_parameters)
    run_trial(  # a short warm-up: numba kernels load, daqp and numpy caches fill
        warm, np.random.default_rng(0), procedure=replace(procedure, phase_timeout_s=0.5),
        adaptation=adaptation, needle_sensor=spec, scope_sensor=spec,
    )  # fmt: skip
    seeds = np.random.SeedSequence(seed).spawn(trials)
    timings: list = []
    t0 = time.perf_counter()
    statuses = [
        run_puncture_trial(scenario, options, i, seeds[i], timings=timings)["status"]
        for i in range(trials)
    ]
    wall = time.perf_counter() - t0
    phases = np.array([p for p, _, _ in timings])
    adapted = np.array([a for _, a, _ in timings], dtype=bool)
    secs = np.array([s for _, _, s in timings], dtype=float)
    all_steps = step_statistics(secs)
    not_adapting, adapting = step_statistics(secs[~adapted]), step_statistics(secs[adapted])
    by_phase = {p: step_statistics(secs[phases == p]) for p in dict.fromkeys(phases.tolist())}
    kin = _kinematics_reference(kinematics_calls, seed)
    rows = [
        {
            "name": "control step (all)",
            "summary": f"median {all_steps['median']:6.1f} us, p99 {all_steps['p99']:6.1f} us, "
            f"max {all_steps['max']:7.1f} us over {all_steps['n']} steps "
            f"(target: median <= 150 us)",
        },
        {"name": "  without adaptation", "summary": _short(not_adapting)},
        {"name": "  with adaptation", "summary": _short(adapting)},
    ]
    rows += [{"name": f"  phase {p}", "summary": _short(st)} for p, st in by_phase.items()]
    rows.append(kin)
    return {
        "benchmark": "control",
        "machine": machine_info(),
        "inputs": {
            "trials": trials,
            "seed": seed,
            "control_rate_hz": round(1.0 / procedure.dt_s),
            "needle_sensor_hz": spec.rate_hz,
            "history_keyframes": options.history_keyframes,
        },
        "step_us": all_steps,
        "step_us_not_adapting": not_adapting,
        "step_us_adapting": adapting,
        "step_us_by_phase": by_phase,
        "trial_status": statuses,
        "wall_s": wall,
        "results": rows,
    }


def _short(st: dict) -> str:
    if not st.get("n"):
        return "no steps"
    return f"median {st['median']:6.1f} us, p99 {st['p99']:6.1f} us ({st['n']} steps)"
