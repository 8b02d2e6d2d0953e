"""``needlekit bench control``: the time of every control step of the puncture controller.

Trials of the puncture study (:mod:`needlekit.studies.puncture_study`) run with the
controller timed at every step (:func:`needlekit.control.procedure.run_trial`'s
``timings``): guide-line update, the adaptation when a needle sample arrived (every 10th
step at 100 Hz) or the application of its update, convergence and loss checks, kinematics,
VFIs and the QP; the simulated robot, sensors and logging are not counted. Each kind of
step gets its own statistics (n, median, p90, p99, p99.9, max in us):

- ``control``: a tick without adaptation work;
- ``control+adaptation``: a needle sample's tick with the adaptation inline
  (``--adaptation-delay-ms 0``);
- ``control+apply``: with the adaptation off the tick (``--adaptation-delay-ms D``, D > 0;
  the default D = 2), the tick that takes a job's update;
- ``adaptation_job``: that job, which another thread or process would run; held against its
  budget of D control periods (overruns counted);
- ``ticks``: every tick the 1 kHz loop runs (all but the jobs), the figure the robot sees.

Every tick kind gets its own verdict (:func:`~needlekit.benchmarks.timing.tick_verdict`:
median <= 100 us (the control loop's budget), and Franka's budget for each kind on its
own, p99 <= 300 us and p99.9 <= 1 ms), as do all ticks pooled. The record
also counts the garbage collections during the timed trials (``gc.callbacks``: collections
per generation and their pauses) and states the load average before and after, and the
machine (:func:`~needlekit.benchmarks.record.machine_info`).

As references run in the same process: the arm's kinematics (tip pose and pose Jacobian)
in needlekit's numba kernel and in ``dqrobotics`` (``fkm`` + ``pose_jacobian``), and, where
the optional package is installed, the TRO 2022 adaptive controller's C++ wheel on its own
example (:mod:`needlekit.benchmarks.tro2022`), with needlekit / TRO ratios.
"""

from __future__ import annotations

import gc
import os
import time
from array import array
from dataclasses import replace
from typing import Any

import numpy as np

from needlekit.benchmarks import tro2022 as _tro
from needlekit.benchmarks.record import machine_info
from needlekit.benchmarks.timing import TICK_TARGET_US, step_statistics, tick_verdict
from needlekit.control.qp_registry import get_qp_solver
from needlekit.errors import InvalidInputError
from needlekit.studies.puncture_study import (
    PunctureScenario,
    TrialOptions,
    run_puncture_trial,
    sample_trial,
    trial_settings,
)

__all__ = [
    "STEP_KINDS",
    "TICK_TARGET_US",
    "run_control_benchmark",
    "step_statistics",
    "tick_verdict",
]

#: The kinds of timed step :func:`needlekit.control.procedure.run_trial` reports.
STEP_KINDS = ("control", "control+adaptation", "control+apply", "adaptation_job")


class _StepRecorder:
    """``timings`` for :func:`run_trial` that stores into flat arrays, not a list of tuples
    (millions of tuples would feed the garbage collector being measured)."""

    def __init__(self) -> None:
        self.phases: list[str] = []
        self.phase_code = array("b")
        self.kind_code = array("b")
        self.seconds = array("d")
        self._kinds = {k: i for i, k in enumerate(STEP_KINDS)}

    def append(self, entry: tuple) -> None:
        phase, kind, seconds = entry
        if phase not in self.phases:
            self.phases.append(phase)
        self.phase_code.append(self.phases.index(phase))
        self.kind_code.append(self._kinds[kind])
        self.seconds.append(seconds)

    def arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Phase names per step, kind names per step, seconds per step."""
        phases = np.array(self.phases or [""], dtype=object)[np.asarray(self.phase_code, int)]
        kinds = np.array(STEP_KINDS, dtype=object)[np.asarray(self.kind_code, int)]
        return phases, kinds, np.asarray(self.seconds, dtype=float)


class _GCWatch:
    """Counts the garbage collections (per generation) and times their pauses."""

    def __init__(self) -> None:
        self.collections = [0, 0, 0]
        self.pauses: list[float] = []
        self._t0 = 0.0

    def __call__(self, phase: str, info: dict) -> None:
        if phase == "start":
            self._t0 = time.perf_counter()
        else:
            self.pauses.append(time.perf_counter() - self._t0)
            self.collections[info["generation"]] += 1

    def __enter__(self) -> _GCWatch:
        gc.callbacks.append(self)
        return self

    def __exit__(self, *exc) -> None:
        gc.callbacks.remove(self)

    def record(self) -> dict[str, Any]:
        p = np.asarray(self.pauses) * 1e6
        return {
            "collections_by_generation": list(self.collections),
            "pause_us_total": float(p.sum()),
            "pause_us_max": float(p.max()) if len(p) else 0.0,
            "gc_enabled": gc.isenabled(),
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


def _tro2022_reference(needlekit: dict[str, dict], steps_per_target: int = 400) -> dict:
    """The TRO 2022 wheel's own example step (:mod:`needlekit.benchmarks.tro2022`), or the
    reason it was skipped; with needlekit / TRO ratios of the medians and p99s.

    ``needlekit`` maps ``"adaptive"`` (needlekit's step with the adaptation: the inline
    tick, or the off-tick job) and ``"control"`` (a tick without it) to their statistics;
    they are held against TRO's ``FULL`` and ``TASK_ONLY`` steps.
    """
    ref = _tro.tro2022_reference(steps_per_target)
    if ref["status"] != "measured":
        return ref
    ratios = {}
    for ours, theirs in (("adaptive", "full"), ("control", "task_only")):
        mine = needlekit.get(ours) or {}
        if mine.get("n"):
            ratios[f"{ours}_vs_{theirs}"] = {q: mine[q] / ref[theirs][q] for q in ("median", "p99")}
    return ref | {"ratios_needlekit_over_tro": ratios}


def run_control_benchmark(
    trials: int = 1,
    seed: int = 0,
    kinematics_calls: int = 2000,
    adaptation_delay_ms: float = 2.0,
    tro2022: bool = True,
    qp_solver: str = "daqp",
) -> dict[str, Any]:
    """Time the controller's steps over whole simulated punctures.

    Parameters
    ----------
    trials : int
        Trials of the puncture study to run (trial ``i`` as in the study with ``seed``).
    seed : int
    kinematics_calls : int
        Configurations for the kinematics reference.
    adaptation_delay_ms : float
        The adaptation off the tick, applied this long after its job starts (a whole number
        of control periods; default 2, as the study; 0: inline, in the sample's tick).
    tro2022 : bool
        Run the TRO 2022 yardstick (when its package imports).
    qp_solver : str
        The controller's and the adaptation's QP solver (a registered name,
        :func:`needlekit.control.qp_registry.get_qp_solver`).

    Returns
    -------
    dict
        ``benchmark``, ``machine``, ``inputs``, ``step_us`` (every tick), ``step_us_by_kind``
        (n, median, p90, p99, p99.9, max; with its own ``verdict`` for each tick kind),
        ``adaptation_job`` (budget and overruns, when off the tick), ``step_us_by_phase``, ``gc``, ``load_average`` (before and after),
        ``trial_status``, ``wall_s``, ``tro2022`` and ``results`` (rows for the summary).
    """
    from needlekit.control.procedure import run_trial
    from needlekit.control.schedule import delay_steps_from_ms

    if not isinstance(trials, int) or trials < 1:
        raise InvalidInputError("trials", f"expected a whole number >= 1, got {trials!r}")
    scenario = PunctureScenario()
    warm = sample_trial(scenario, np.random.default_rng(0), 0)[0]
    adaptation, procedure, spec = trial_settings(scenario, TrialOptions(), warm.nominal_parameters)
    delay = delay_steps_from_ms(adaptation_delay_ms, procedure.dt_s)
    get_qp_solver(qp_solver)  # an unknown name or a missing extra fails before any trial
    options = TrialOptions(adaptation_delay_steps=delay, qp_solver=qp_solver)
    for d in dict.fromkeys((0, delay)):  # a short warm-up: kernels load, caches fill
        run_trial(
            warm, np.random.default_rng(0), adaptation=adaptation, needle_sensor=spec,
            scope_sensor=spec,
            procedure=replace(
                procedure, phase_timeout_s=0.5, adaptation_delay_steps=d, qp_solver=qp_solver
            ),
        )  # fmt: skip
    seeds = np.random.SeedSequence(seed).spawn(trials)
    rec = _StepRecorder()
    load_before = list(os.getloadavg())
    t0 = time.perf_counter()
    with _GCWatch() as gc_watch:
        statuses = [
            run_puncture_trial(scenario, options, i, seeds[i], timings=rec)["status"]
            for i in range(trials)
        ]
    wall = time.perf_counter() - t0
    load_after = list(os.getloadavg())
    all_ticks, by_kind, by_phase, job = _tick_statistics(rec, delay * procedure.dt_s * 1e6)
    adaptive = by_kind["adaptation_job" if delay else "control+adaptation"]
    tro = (
        _tro2022_reference({"adaptive": adaptive, "control": by_kind["control"]})
        if tro2022
        else {"name": "tro2022", "status": "skipped", "reason": "not requested"}
    )
    gc_record = gc_watch.record()
    rows = _rows(all_ticks, by_kind, by_phase, job, gc_record, (load_before, load_after), tro)
    rows.append(_kinematics_reference(kinematics_calls, seed))
    return {
        "benchmark": "control",
        "machine": machine_info(),
        "inputs": {
            "trials": trials,
            "seed": seed,
            "control_rate_hz": round(1.0 / procedure.dt_s),
            "needle_sensor_hz": spec.rate_hz,
            "history_keyframes": options.history_keyframes,
            "adaptation_delay_ms": delay * procedure.dt_s * 1e3,
            "qp_solver": qp_solver,
        },
        "targets_us": dict(TICK_TARGET_US),
        "step_us": all_ticks,
        "step_us_by_kind": by_kind,
        "adaptation_job": job,
        "step_us_by_phase": by_phase,
        "gc": gc_record,
        "load_average": {"before": load_before, "after": load_after},
        "trial_status": statuses,
        "wall_s": wall,
        "tro2022": tro,
        "results": rows,
    }


def _tick_statistics(rec: _StepRecorder, budget_us: float) -> tuple:
    """Every tick's statistics, each kind's (with its own verdict for the tick kinds), each
    phase's, and the jobs against their budget (None when the adaptation runs inline)."""
    phases, kinds, secs = rec.arrays()
    ticks = kinds != "adaptation_job"
    all_ticks = step_statistics(secs[ticks])
    all_ticks["verdict"] = tick_verdict(all_ticks)
    by_kind = {}
    for kind in STEP_KINDS:
        st = step_statistics(secs[kinds == kind])
        if st["n"] and kind != "adaptation_job":
            st["verdict"] = tick_verdict(st)
        by_kind[kind] = st
    by_phase = {p: step_statistics(secs[ticks & (phases == p)]) for p in rec.phases}
    job = None
    if budget_us:
        jobs_us = secs[kinds == "adaptation_job"] * 1e6
        over = int(np.count_nonzero(jobs_us > budget_us))
        job = {
            "budget_us": budget_us,
            "overruns": over,
            "overrun_fraction": over / len(jobs_us) if len(jobs_us) else 0.0,
        }
    return all_ticks, by_kind, by_phase, job


def _rows(all_ticks, by_kind, by_phase, job, gc_record, loads, tro) -> list[dict]:
    def verdict(st):
        v = st.get("verdict") or {}
        if v.get("pass") is None:
            return ""
        missed = [q for q, key in _VERDICT_KEYS if not v[key]]
        return "  PASS" if v["pass"] else "  FAIL (" + ", ".join(missed) + ")"

    rows = [
        {
            "name": "every tick (1 kHz loop)",
            "summary": _short(all_ticks) + verdict(all_ticks) + " (target for every tick kind: "
            f"median <= {TICK_TARGET_US['median']:g} us, p99 <= {TICK_TARGET_US['p99']:g} us, "
            f"p99.9 <= {TICK_TARGET_US['p99.9']:g} us)",
        }
    ]
    for kind, st in by_kind.items():
        if st["n"]:
            rows.append({"name": f"  {kind}", "summary": _short(st) + verdict(st)})
    if job is not None:
        rows.append(
            {
                "name": "  job vs its budget",
                "summary": f"{job['overruns']} of {by_kind['adaptation_job']['n']} jobs over "
                f"{job['budget_us']:.0f} us ({100 * job['overrun_fraction']:.1f} %)",
            }
        )
    rows += [{"name": f"  phase {p}", "summary": _short(st)} for p, st in by_phase.items()]
    g = gc_record
    rows.append(
        {
            "name": "garbage collections",
            "summary": "generations 0/1/2: " + "/".join(map(str, g["collections_by_generation"]))
            + f", pauses {g['pause_us_total'] / 1e3:.1f} ms in all, {g['pause_us_max']:.0f} us max",
        }
    )  # fmt: skip
    rows.append(
        {
            "name": "load average (1/5/15 min)",
            "summary": "before " + "/".join(f"{x:.2f}" for x in loads[0])
            + ", after " + "/".join(f"{x:.2f}" for x in loads[1]),
        }
    )  # fmt: skip
    if tro["status"] != "measured":
        rows.append({"name": "TRO 2022 wheel", "summary": f"skipped: {tro['reason']}"})
    else:
        ratio = tro.get("ratios_needlekit_over_tro", {})
        for key, label in (("full", "with adaptation"), ("task_only", "without")):
            ours = "adaptive_vs_full" if key == "full" else "control_vs_task_only"
            r = ratio.get(ours)
            rows.append(
                {
                    "name": f"TRO 2022 {label}",
                    "summary": _short(tro[key])
                    + ("" if r is None else f"; needlekit/TRO median x{r['median']:.2f}"),
                }
            )
    return rows


def _short(st: dict) -> str:
    if not st.get("n"):
        return "no steps"
    p999 = f", p99.9 {st['p99.9']:7.1f} us" if "p99.9" in st else ""
    return (
        f"median {st['median']:6.1f} us, p99 {st['p99']:6.1f} us{p999}, max {st['max']:7.1f} us "
        f"({st['n']} steps)"
    )


_VERDICT_KEYS = (("median", "median_ok"), ("p99", "p99_ok"), ("p99.9", "p999_ok"))
