"""Monte Carlo of a plan carried out: every trial open loop and closed loop on the same
needle in the same tissue (``needlekit execute``).

Trial ``i`` draws everything from the ``i``-th child of ``SeedSequence(seed)`` (its ``entropy``
and ``spawn_key`` are written beside it, and ``--replay-trial K`` replays it alone): the needle's
radius, the tissue's push and the orientation noise, then the sensor's noise. The open-loop run
commands the plan's primitives; the closed-loop run tracks the tip, steers back to the plan and
re-plans from the estimated tip (:mod:`needlekit.execute.run`, :mod:`needlekit.execute.replan`).

What a run is judged by, on the true tip (never the estimate):

- ``final_error_mm``: its distance from the goal where the insertion stopped;
- ``min_clearance_mm``: the certified clearance of the executed path against the scenario's
  anatomy and collision model *without* the noise margin: the needle's surface to the obstacles,
  less half the gap between the recorded points and the model's stated error bound
  (:meth:`~needlekit.anatomy.collision.FieldChecker.certify`);
- ``violated``: the model's verdict on that path (an obstacle crossed, or a point that
  could not be checked); never hidden, and counted in the summary.

The plans and re-plans keep the scenario's ``needle.safety_margin_mm`` (the noise margin:
:func:`needlekit.execute.replan.noise_margin_mm`), written as ``margin_mm``. A trial that
raises is recorded with its seed and the error, and the others go on.
"""

from __future__ import annotations

import math
import os
import time
import traceback
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from needlekit import __version__
from needlekit.batch import worker_cached
from needlekit.errors import InvalidInputError, raise_if_interrupt
from needlekit.execute.breathing import POLICIES, Breathing, Policy
from needlekit.execute.replan import Replanner, ReplanPolicy, first_mm
from needlekit.execute.run import TIME_CAP_FACTOR, ExecutionSettings, LoopHooks, execute_plan
from needlekit.io.files import write_json
from needlekit.io.partial import read_partial
from needlekit.planning.steerable.plan import SteerablePlan
from needlekit.scenario.problems import problem_from_scenario
from needlekit.studies.trial_runs import collect_trials

__all__ = [
    "EXECUTE_FILE",
    "LUNG_R_MIN_MM",
    "LITERATURE",
    "ExecuteOptions",
    "loop_summary",
    "lung_scenario_document",
    "read_partial_execute",
    "run_execute_study",
    "run_execute_trial",
    "trial_seed",
]

#: What ``needlekit execute`` writes in its --out folder.
EXECUTE_FILE = "execute.json"

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


@dataclass(frozen=True)
class ExecuteOptions:
    """How each trial's insertions run.

    Attributes
    ----------
    settings : ExecutionSettings
        Speed, step, look-ahead, the needle's noise and the sensor.
    policy : ReplanPolicy
        When and how the closed loop re-plans.
    replan : bool
        Closed loop with re-planning (False: feedback to the original plan only).
    breathing : Breathing or None
        The anatomy breathing: each trial also runs closed loop under every policy of
        :data:`~needlekit.execute.breathing.POLICIES` (``breathing`` in the trial).
    """

    settings: ExecutionSettings = field(default_factory=ExecutionSettings)
    policy: ReplanPolicy = field(default_factory=ReplanPolicy)
    replan: bool = True
    breathing: Breathing | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.settings, ExecutionSettings):
            raise InvalidInputError("settings", "expected an ExecutionSettings")
        if not isinstance(self.policy, ReplanPolicy):
            raise InvalidInputError("policy", "expected a ReplanPolicy")
        if self.breathing is not None and not isinstance(self.breathing, Breathing):
            raise InvalidInputError("breathing", "expected a Breathing")


#: The needle of the lung scenarios (:func:`lung_scenario_document`): its r_min (mm).
LUNG_R_MIN_MM: float = 50.0


def lung_scenario_document(patient: int, margin_mm: float, medrad_dir=None) -> dict:
    """The scenario of Med-RAD lung ``patient``, start 1, to its target, as
    ``examples/medrad_lung1.yaml`` has it for patient 1 (the reference planner's needle and
    exact voxel-centre test), with a clearance margin.

    Parameters
    ----------
    patient : int
    margin_mm : float
        ``needle.safety_margin_mm``.
    medrad_dir : path-like, optional
        The Med-RAD folder (default: ``$NEEDLEKIT_MEDRAD`` or ``../shared/data/med-rad``).

    Returns
    -------
    dict
        A scenario document (:class:`~needlekit.scenario.problems.ScenarioSource.of_document`).
    """
    medrad = {"organ": "lung", "patient": int(patient)}
    if medrad_dir is not None:
        medrad["root"] = str(Path(medrad_dir).expanduser().resolve())
    return {
        "version": 1,
        "name": f"Med-RAD lung {patient}, start 1",
        "base": {"medrad": medrad},
        "needle": {
            "diameter_mm": 1.0,
            "r_min_mm": LUNG_R_MIN_MM,
            "max_length_mm": 150,
            "max_heading_change_deg": 90,
            "start_exclusion_mm": 3,
            "safety_margin_mm": float(margin_mm),
        },
        "start": {"case_start": "start1"},
        "goal": {"case_target": "target", "tolerance_mm": 1.0},
        "collision_model": "voxel_centres",
        "planner": {"name": "rcs_star", "time_limit_s": 1.0},
    }


def trial_seed(seed: int, trial: int) -> np.random.SeedSequence:
    """Trial ``trial``'s seed: ``SeedSequence(seed).spawn(n)[trial]`` for any ``n``.

    Parameters
    ----------
    seed, trial : int

    Returns
    -------
    numpy.random.SeedSequence

    Examples
    --------
    >>> import numpy as np
    >>> a = trial_seed(5, 3).generate_state(2)
    >>> bool(np.array_equal(a, np.random.SeedSequence(5).spawn(4)[3].generate_state(2)))
    True
    """
    return np.random.SeedSequence(seed, spawn_key=(int(trial),))


def _path_record(run, truth) -> dict:
    """One run's figures, its path judged against the anatomy without the margin."""
    pts = np.ascontiguousarray(run.points_mm, dtype=np.float64)
    gap = float(np.linalg.norm(np.diff(pts, axis=0), axis=1).max()) if len(pts) > 1 else 0.0
    cert = truth.collision_checker(max(gap, 1e-6)).certify(pts, max(gap, 1e-6))
    lat = [float(v) for v in run.replan_latency_s]
    guard = {}
    if run.guard is not None:  # closed loop: its faults, holds and rejected samples
        guard = {**run.guard, "procedure_s": float(run.procedure_s)}
        if run.faults_injected:
            guard["faults_injected"] = list(run.faults_injected)
    return {
        **guard,
        "final_error_mm": float(run.final_error_mm),
        "min_clearance_mm": _finite(cert.certified_clearance_mm),
        "sampled_clearance_mm": _finite(cert.sampled_clearance_mm),
        "violated": cert.violation is not None,
        "violation": cert.violation,
        "inserted_mm": float(run.inserted_mm),
        "estimate_error_mm": _finite(run.estimate_error_mm),
        "samples": int(run.samples),
        "replans": int(run.replans),
        "replan_attempts": len(lat),
        "replan_latency_s": lat,
        "points_mm": np.round(pts, 4).tolist(),
        "cross_track_mm": None
        if run.cross_track_mm is None
        else np.round(run.cross_track_mm, 4).tolist(),
        "replan_events": [
            {
                "asked_at_mm": a,
                "applied_at_mm": b,
                "points_mm": np.round(plan.points_mm(1.0), 3).tolist(),
            }
            for a, b, plan in run.replan_events
        ],
    }


def _finite(v):
    return None if v is None or not math.isfinite(float(v)) else float(v)


def run_execute_trial(
    problem,
    truth,
    plan: SteerablePlan,
    seed,
    options: ExecuteOptions,
    loops: tuple[str, ...] = ("open_loop", "closed_loop"),
    hooks=None,
) -> dict:
    """One trial: the plan open loop, then closed loop, on the same needle.

    Parameters
    ----------
    problem : SteerableProblem
        The problem the plan was made for, its margin included: the re-plans' problem.
    truth : SteerableProblem
        The same anatomy and collision model without the margin: the executed paths'
        judge.
    plan : SteerablePlan
    seed : numpy.random.SeedSequence
    options : ExecuteOptions
    loops : tuple of str
        The runs: ``"open_loop"``, ``"closed_loop"`` or both.
    hooks : LoopHooks, optional
        Attached to the closed-loop run (a live link, another sensor).

    Returns
    -------
    dict
        ``open_loop`` and ``closed_loop``, each as the module notes say (``cross_track_mm``:
        closed loop, the true tip's distance from the plan it follows at each recorded
        point).
    """
    r_min = 1.0 / problem.kappa_max_per_mm
    out = {}
    for name in loops:
        closed = name == "closed_loop"
        rep = Replanner(problem, options.policy) if closed and options.replan else None
        run = execute_plan(plan, problem.goal_mm, r_min, closed_loop=closed, seed=seed,
                           settings=options.settings, replanner=rep,
                           hooks=hooks if closed else None)  # fmt: skip
        out[name] = _path_record(run, truth)
        if rep is not None:
            out[name]["replans_refused"] = rep.refused
            out[name]["warm_start_kept"] = rep.warm_kept
    if options.breathing is not None and "closed_loop" in loops:
        out["breathing"] = _breathing_runs(problem, truth, plan, seed, options)
    return out


def _breathing_runs(problem, truth, plan, seed, options: ExecuteOptions) -> dict:
    """The closed loop under each breathing policy, on the trial's needle and sensor draws
    and one breathing trace (the trial seed's third child)."""
    r_min = 1.0 / problem.kappa_max_per_mm
    s = options.settings
    horizon = TIME_CAP_FACTOR * (plan.length_mm + s.overrun_mm) / s.insertion_speed_mm_s
    child = np.random.SeedSequence(seed.entropy, spawn_key=(*seed.spawn_key, 2))
    trace = options.breathing.trace(np.random.default_rng(child), horizon)
    out = {}
    for name in POLICIES:
        rep = Replanner(problem, options.policy) if options.replan else None
        run = execute_plan(plan, problem.goal_mm, r_min, closed_loop=True, seed=seed,
                           settings=s, replanner=rep,
                           hooks=LoopHooks(breathing=Policy(name, trace)))  # fmt: skip
        out[name] = {**_path_record(run, truth), "procedure_s": float(run.procedure_s)}
    return out


def _problems(source):
    """The scenario's problem and its margin-free twin, built once per worker."""
    sc, problem = source.cached()
    truth = worker_cached(
        ("execute truth", source), lambda: problem_from_scenario(sc, safety_margin_mm=0.0)
    )
    return problem, truth


def _run_job(job: tuple) -> dict:
    source, start, prims, options, seed, trial, hooks = job
    head = {"trial": trial, "seed": seed, "seed_spawn_key": [trial]}
    try:
        problem, truth = _problems(source)
        plan = SteerablePlan(np.asarray(start), np.asarray(prims))
        worker_cached(("execute warm-up", source), lambda: warm_up_replanner(problem, plan))
        ss = trial_seed(seed, trial)
        return {**head, **run_execute_trial(problem, truth, plan, ss, options, hooks=hooks)}
    except Exception as exc:  # recorded with its seed; the other trials go on
        raise_if_interrupt(exc)  # Ctrl-C is no trial's failure
        last = traceback.extract_tb(exc.__traceback__)[-1]
        where = f"{Path(last.filename).name}:{last.lineno}"
        return {**head, "error": f"{type(exc).__name__}: {exc} ({where})"}


def warm_up_replanner(problem, plan: SteerablePlan) -> None:
    """One re-plan from half-way along the plan, so that the trials' re-plans do not pay
    for the first search in this process (compiled kernels, caches): the set-up a
    navigation system does before the needle goes in.

    Parameters
    ----------
    problem : SteerableProblem
    plan : SteerablePlan

    Returns
    -------
    None
    """
    half = 0.5 * plan.length_mm
    pose = SteerablePlan(plan.start_pose, first_mm(plan.primitives, half)).end_pose()
    Replanner(problem, ReplanPolicy(max_iterations=200, time_limit_s=5.0)).replan(
        pose, half, (plan, half)
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


def _settings_record(scenario_name: str, plan, seed: int, trials, options, margin) -> dict:
    return {
        "needlekit_version": __version__,
        "scenario": scenario_name,
        "plan_primitives": np.asarray(plan.primitives).tolist(),
        "seed": seed,
        "trials": trials,
        "margin_mm": margin,
        "options": asdict(options),
    }


@dataclass
class ExecuteStudy:
    """What :func:`run_execute_study` produced: the document written, and its path."""

    document: dict
    path: Path


def run_execute_study(
    out_dir: str | os.PathLike,
    source,
    plan: SteerablePlan,
    *,
    trials: list[int],
    seed: int,
    options: ExecuteOptions | None = None,
    executor=None,
    progress: Callable[[dict], None] | None = None,
    resume: list[dict] | None = None,
    scenario_name: str = "",
    hooks=None,
    scenario_file: str | None = None,
) -> ExecuteStudy:
    """Run the trials and write ``out_dir/execute.json`` (atomically).

    Parameters
    ----------
    out_dir : path-like
    source : needlekit.scenario.problems.ScenarioSource
        The scenario (built once per worker).
    plan : SteerablePlan
        The plan to carry out (checked by the caller against the scenario).
    trials : list of int
        The trials' numbers (``range(n)``, or one trial replayed).
    seed : int
        Root seed (:func:`trial_seed`).
    options : ExecuteOptions, optional
    executor : concurrent.futures.Executor, optional
    progress : callable, optional
        Called with each finished trial.
    resume : list of dict, optional
        Trials an interrupted run finished (:func:`read_partial_execute`).
    scenario_name, scenario_file : str
        The scenario's name, and its path relative to ``out_dir`` (for ``needlekit report``).
    hooks : LoopHooks, optional
        Attached to every closed-loop run (a live link): trials then run in this process.

    Returns
    -------
    ExecuteStudy

    Raises
    ------
    Interrupted
        Ctrl-C: the trials finished are written marked partial.
    """
    options = options or ExecuteOptions()
    _, problem = source.cached()
    margin = float(problem.safety_margin_mm)
    head = _settings_record(scenario_name, plan, seed, list(trials), options, margin)
    path = Path(out_dir) / EXECUTE_FILE
    done = {r["trial"]: r for r in resume or ()}
    start, prims = plan.start_pose.tolist(), plan.primitives.tolist()
    if hooks is not None:  # a link or a tracker lives in this process
        executor = None
    t0 = time.perf_counter()
    records = collect_trials(
        list(trials), done, _run_job, lambda k: (source, start, prims, options, seed, k, hooks),
        executor=executor, partial_path=path, head=head, done_key="trials_done",
        progress=progress,
    )  # fmt: skip
    doc = {**head, "summary": study_summary(records, margin), "wall_s": time.perf_counter() - t0}
    doc |= ({} if scenario_file is None else {"scenario_file": scenario_file}) | {"trials": records}
    write_json(path, doc)
    return ExecuteStudy(doc, path)


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
    return {
        "trials": len(records),
        "crashed": [{"trial": r["trial"], "error": r["error"]} for r in records if "error" in r],
        "margin_mm": margin_mm,
        "open_loop": loop_summary([r["open_loop"] for r in ok]),
        "closed_loop": loop_summary([r["closed_loop"] for r in ok]),
        **_breathing_summary(ok),
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


def read_partial_execute(out_dir, scenario_name, plan, seed, trials, options) -> list[dict]:
    """The trials an interrupted run finished (``execute --resume``), from its signed
    ``execute.partial.json`` beside ``execute.json`` (:func:`needlekit.io.partial.read_partial`).

    Parameters
    ----------
    out_dir : path-like
    scenario_name, plan, seed, trials, options
        This run's: the file's.

    Returns
    -------
    list of dict

    Raises
    ------
    InvalidInputError
        (named ``--resume``) No such file, not partial, changed, or other settings.
    """
    path = Path(out_dir) / EXECUTE_FILE
    want = _settings_record(scenario_name, plan, seed, list(trials), options, None)
    data = read_partial(path, "execute", {k: v for k, v in want.items() if k != "margin_mm"})
    return list(data.get("trials_done") or [])
