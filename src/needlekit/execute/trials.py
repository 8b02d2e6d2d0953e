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

import os
import time
import traceback
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np

from needlekit import __version__
from needlekit.batch import worker_cached
from needlekit.errors import InvalidInputError, raise_if_interrupt
from needlekit.execute.breathing import POLICIES, Breathing, Policy
from needlekit.execute.plugins import model_record
from needlekit.execute.proximity import ProximityStop, stop_distance_mm
from needlekit.execute.record import TrialRecord, path_record, trial_status
from needlekit.execute.replan import Replanner, ReplanPolicy, first_mm
from needlekit.execute.run import TIME_CAP_FACTOR, ExecutionSettings, LoopHooks, execute_plan
from needlekit.execute.summary import study_summary
from needlekit.execute.trial_runs import collect_trials
from needlekit.io.files import write_json
from needlekit.io.partial import read_partial
from needlekit.planning.steerable.plan import SteerablePlan

__all__ = [
    "EXECUTE_FILE",
    "ExecuteOptions",
    "models_record",
    "read_partial_execute",
    "run_execute_study",
    "run_execute_trial",
    "trial_seed",
]

#: What ``needlekit execute`` writes in its --out folder.
EXECUTE_FILE = "execute.json"


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
    sensing : tuple of str
        The sensing policies (:data:`~needlekit.execute.target_sensing.SENSING_POLICIES`):
        the closed loop runs under the first (``settings.sensing`` is set to it, its sensors'
        settings kept); with more than one, each trial also runs closed loop under each on
        the same draws (``sensing`` in the trial).
    """

    settings: ExecutionSettings = field(default_factory=ExecutionSettings)
    policy: ReplanPolicy = field(default_factory=ReplanPolicy)
    replan: bool = True
    breathing: Breathing | None = None
    sensing: tuple = ("em",)

    def __post_init__(self) -> None:
        if not isinstance(self.settings, ExecutionSettings):
            raise InvalidInputError("settings", "expected an ExecutionSettings")
        names = tuple(self.sensing)
        if not names or len(set(names)) != len(names):
            raise InvalidInputError("sensing", f"expected distinct policy names, got {names!r}")
        first = replace(self.settings.sensing, name=names[0])  # checks the name
        for name in names[1:]:
            replace(first, name=name)
        object.__setattr__(self, "sensing", names)
        object.__setattr__(self, "settings", replace(self.settings, sensing=first))
        if not isinstance(self.policy, ReplanPolicy):
            raise InvalidInputError("policy", "expected a ReplanPolicy")
        if self.breathing is not None and not isinstance(self.breathing, Breathing):
            raise InvalidInputError("breathing", "expected a Breathing")


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


def run_execute_trial(
    problem,
    judge,
    plan: SteerablePlan,
    seed,
    options: ExecuteOptions,
    loops: tuple[str, ...] = ("open_loop", "closed_loop"),
    hooks=None,
) -> TrialRecord:
    """One trial: the plan open loop, then closed loop, on the same needle.

    Parameters
    ----------
    problem : SteerableProblem
        The problem the plan was made for, its margin included: the re-plans' problem.
    judge : SteerableProblem
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
    TrialRecord
        Trial ``seed.spawn_key[-1]`` of root seed ``seed.entropy``: its runs as the module
        notes say (``cross_track_mm``: closed loop, the true tip's distance from the plan
        it follows at each recorded point), and its status
        (:func:`~needlekit.execute.record.trial_status`).
    """
    r_min = 1.0 / problem.kappa_max_per_mm
    out = {}
    for name in loops:
        closed = name == "closed_loop"
        rep = (
            Replanner(model_problem(problem, options.settings), options.policy)
            if closed and options.replan
            else None
        )
        run = execute_plan(plan, problem.goal_mm, r_min, closed_loop=closed, seed=seed,
                           settings=options.settings, replanner=rep,
                           hooks=hooks if closed else None,
                           stop=proximity_stop(problem, judge, options.settings) if closed
                           else None)  # fmt: skip
        extra = {} if rep is None else {"replans_refused": rep.refused,
                                        "warm_start_kept": rep.warm_kept}  # fmt: skip
        out[name] = replace(path_record(run, judge), **extra)
    breathing = sensing = None
    if options.breathing is not None and "closed_loop" in loops:
        breathing = _breathing_runs(problem, judge, plan, seed, options)
    if len(options.sensing) > 1 and "closed_loop" in loops:
        sensing = _sensing_runs(problem, judge, plan, seed, options, out["closed_loop"])
    judged = out.get("closed_loop", out.get("open_loop"))
    return TrialRecord(
        trial=int(seed.spawn_key[-1]), seed=int(seed.entropy),
        seed_spawn_key=tuple(int(k) for k in seed.spawn_key),
        status=trial_status(judged, problem.goal_tolerance_mm),
        open_loop=out.get("open_loop"), closed_loop=out.get("closed_loop"), breathing=breathing,
        sensing=sensing,
    )  # fmt: skip


def proximity_stop(problem, judge, settings: ExecutionSettings) -> ProximityStop | None:
    """A closed loop's stop near obstacles (:mod:`needlekit.execute.proximity`): the
    judge's checker, the stop distance from ``settings.stop_clearance_mm`` and the plan's
    margin (``problem.safety_margin_mm``); None when the setting is None.

    Parameters
    ----------
    problem : SteerableProblem
        The plan's problem, its margin included.
    judge : SteerableProblem
        The same anatomy without the margin.
    settings : ExecutionSettings

    Returns
    -------
    ProximityStop or None
    """
    if settings.stop_clearance_mm is None:
        return None
    stop = stop_distance_mm(settings.stop_clearance_mm, problem.safety_margin_mm)
    # the checker path_record judges the run with; the spacing is the recorded path's
    return ProximityStop(judge.collision_checker(), stop, settings.record_mm)


def model_problem(problem, settings):
    """The re-plans' problem: the plan's, for the needle the loop's model says it has (its
    calibrated radius, when it has one).

    Parameters
    ----------
    problem : SteerableProblem
    settings : ExecutionSettings

    Returns
    -------
    SteerableProblem
    """
    model = settings.model
    return problem if model is None else problem.with_r_min(model.r_min_mm)


def _sensing_runs(problem, judge, plan, seed, options: ExecuteOptions, first) -> dict:
    """The closed loop under each sensing policy, on the trial's needle, tip-sensor and
    target-sensor draws; the first policy's run is the trial's closed loop itself."""
    r_min = 1.0 / problem.kappa_max_per_mm
    s = options.settings
    out = {options.sensing[0]: first}
    for name in options.sensing[1:]:
        rep = (Replanner(model_problem(problem, s), options.policy)
               if options.replan else None)  # fmt: skip
        settings = replace(s, sensing=replace(s.sensing, name=name))
        run = execute_plan(plan, problem.goal_mm, r_min, closed_loop=True, seed=seed,
                           settings=settings, replanner=rep,
                           stop=proximity_stop(problem, judge, s))  # fmt: skip
        extra = {} if rep is None else {"replans_refused": rep.refused,
                                        "warm_start_kept": rep.warm_kept}  # fmt: skip
        out[name] = replace(path_record(run, judge), **extra)
    return out


def _breathing_runs(problem, judge, plan, seed, options: ExecuteOptions) -> dict:
    """The closed loop under each breathing policy, on the trial's needle and sensor draws
    and one breathing trace (the trial seed's third child)."""
    r_min = 1.0 / problem.kappa_max_per_mm
    s = options.settings
    horizon = TIME_CAP_FACTOR * (plan.length_mm + s.overrun_mm) / s.insertion_speed_mm_s
    child = np.random.SeedSequence(seed.entropy, spawn_key=(*seed.spawn_key, 2))
    trace = options.breathing.trace(np.random.default_rng(child), horizon)
    out = {}
    for name in POLICIES:
        rep = (
            Replanner(model_problem(problem, options.settings), options.policy)
            if options.replan
            else None
        )
        run = execute_plan(plan, problem.goal_mm, r_min, closed_loop=True, seed=seed,
                           settings=s, replanner=rep,
                           hooks=LoopHooks(breathing=Policy(name, trace)),
                           stop=proximity_stop(problem, judge, s))  # fmt: skip
        out[name] = replace(path_record(run, judge), procedure_s=float(run.procedure_s))
    return out


def _problems(source):
    """The scenario's problem and its margin-free twin (the judge), built once per worker."""
    _, problem = source.cached()
    return problem, source.without_margin()


def _run_job(job: tuple) -> dict:
    source, start, prims, options, seed, trial, hooks = job
    try:
        problem, judge = _problems(source)
        plan = SteerablePlan(np.asarray(start), np.asarray(prims))
        worker_cached(("execute warm-up", source, options.policy.planner),
                      lambda: warm_up_replanner(problem, plan, options.policy.planner))  # fmt: skip
        ss = trial_seed(seed, trial)
        return run_execute_trial(problem, judge, plan, ss, options, hooks=hooks).to_dict()
    except Exception as exc:  # recorded with its seed; the other trials go on
        raise_if_interrupt(exc)  # Ctrl-C is no trial's failure
        last = traceback.extract_tb(exc.__traceback__)[-1]
        where = f"{Path(last.filename).name}:{last.lineno}"
        error = f"{type(exc).__name__}: {exc} ({where})"
        return TrialRecord(trial, seed, (trial,), trial_status(None, 0.0, error),
                           error=error).to_dict()  # fmt: skip


def warm_up_replanner(problem, plan: SteerablePlan, planner: str = "rcs_star") -> None:
    """One re-plan from half-way along the plan, so that the trials' re-plans do not pay
    for the first search in this process (compiled kernels, caches): the set-up a
    navigation system does before the needle goes in.

    Parameters
    ----------
    problem : SteerableProblem
    plan : SteerablePlan
    planner : str
        The re-planner (a planner with the ``"warm_start"`` capability).

    Returns
    -------
    None
    """
    half = 0.5 * plan.length_mm
    pose = SteerablePlan(plan.start_pose, first_mm(plan.primitives, half)).end_pose()
    policy = ReplanPolicy(max_iterations=200, time_limit_s=5.0, planner=planner)
    Replanner(problem, policy).replan(pose, half, (plan, half))


def _settings_record(scenario_name: str, plan, seed: int, trials, options, margin) -> dict:
    return {
        "needlekit_version": __version__,
        "scenario": scenario_name,
        "plan_primitives": np.asarray(plan.primitives).tolist(),
        "seed": seed,
        "trials": trials,
        "margin_mm": margin,
        "options": asdict(options),
        **models_record(options),
    }


def models_record(options: ExecuteOptions) -> dict:
    """What ``execute.json`` says of the models a study ran with: a block per kind
    (``truth``, ``sensor``, ``estimator``, ``feedback``: name, factory, parameters;
    :func:`~needlekit.execute.plugins.model_record`) and the ``replanner`` (the planner
    that re-plans, or null without re-planning).

    Parameters
    ----------
    options : ExecuteOptions

    Returns
    -------
    dict
    """
    s = options.settings
    out = {kind: model_record(kind, getattr(s.models, kind), s)
           for kind in ("truth", "sensor", "estimator", "feedback")}  # fmt: skip
    # the loop's own needle model, calibrated on the truth (None: the simulator's)
    out["calibration"] = None if s.model is None else s.model.to_dict()
    policy = options.policy
    out["replanner"] = None if not options.replan else {
        "planner": policy.planner, "warm_start": policy.warm_start,
        "time_limit_s": policy.time_limit_s, "max_iterations": policy.max_iterations,
    }  # fmt: skip
    return out


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
