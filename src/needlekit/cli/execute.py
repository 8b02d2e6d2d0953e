"""``needlekit execute``: a plan carried out in simulated tissue, open loop beside closed
loop, over many trials (docs/execute.md)."""

from __future__ import annotations

import argparse
from pathlib import Path

from needlekit._numbers import MIN_POSITIVE
from needlekit.cli import _flags, _sizes
from needlekit.cli._common import (
    EXIT_OK,
    _non_negative,
    _non_negative_mm,
    _numbers,
    _positive,
    _positive_int,
    _positive_mm,
    _seed,
    _speed_mm_s,
    number,
)
from needlekit.cli._paths import add_input, add_output
from needlekit.cli._verdicts import execute_failures, summary_table
from needlekit.constants import STOP_CLEARANCE_MM
from needlekit.errors import InvalidInputError

#: What ``needlekit execute`` writes in its --out folder.
EXECUTE_FILES = ("execute.json",)

#: Upper ends of the noise flags: beyond them the model is not a needle in tissue.
NOISE_LIMITS = {
    "orientation_noise_rad": 0.05,  # per 0.1 s: 0.5 rad per second of insertion
    "deflection_sd": 0.2,  # mm per mm: the tip pushed 20 mm off over 100 mm
}
#: ``--radius-sd-mm`` at most this fraction of r_min (a radius 5 SD short stays > 0).
RADIUS_SD_FRACTION = 0.2

_EPILOG = """\
example:
  needlekit plan examples/medrad_lung1.yaml --out out/lung1/plan.json
  needlekit execute examples/medrad_lung1.yaml out/lung1/plan.json --trials 100 --seed 0 \\
      --out out/lung1 --workers 2
  needlekit execute examples/medrad_lung1.yaml out/lung1/plan.json --replay-trial 17 --out out/t17
  needlekit multi examples/medrad_liver4.yaml --out out/liver4/multi.json
  needlekit execute examples/medrad_liver4.yaml out/liver4/multi.json --trials 20 \
      --out out/liver4 --workers 2
"""


#: ``--breathing-direction``: a direction, three numbers (made a unit vector by Breathing).
_vector3 = _numbers(3, "X,Y,Z (three numbers)", container=tuple)
#: The ranges :class:`needlekit.execute.breathing.Breathing` keeps, refused at the parser.
_BREATHING_AMPLITUDE = number(0.0, 50.0, unit="mm")
_BREATHING_PERIOD = number(1.0, 20.0, unit="s")
_BREATHING_SHAPE = number(1, 6, integer=True)


def check_noise_flags(args: argparse.Namespace) -> None:
    """The noise flags' values within :data:`NOISE_LIMITS`, before any work.

    Parameters
    ----------
    args : argparse.Namespace

    Returns
    -------
    None

    Raises
    ------
    InvalidInputError
        Named by the flag.
    """
    _guard(args)  # --hold-timeout-s within its range
    for name, top in NOISE_LIMITS.items():
        v = getattr(args, name)
        if v is not None and v > top:
            flag = "--" + name.replace("_", "-")
            raise InvalidInputError(flag, f"expected at most {top:g}, got {v:g}")
    _breathing(args)  # the breathing values too


def _check_flags(args: argparse.Namespace) -> None:
    """Every flag's value, before the anatomy loads."""
    from needlekit.cli.execute_models import check_physics_flags, checked_models
    from needlekit.cli.execute_multi import check_trial_flags
    from needlekit.cli.execute_sensing import check_sensing_flags

    args.models = checked_models(args)  # first: light (the guard's check loads numba)
    check_physics_flags(args)
    check_sensing_flags(args)
    check_noise_flags(args)
    check_trial_flags(args)
    if args.tip_from_igtl is not None and args.igtl is None:
        raise InvalidInputError(
            "--tip-from-igtl", "takes the tip from the --igtl link: give that too"
        )
    if args.igtl is not None:
        from needlekit.execute.igtl_link import parse_address

        parse_address(args.igtl)
        if args.replay_trial is None and args.trials != 1:
            raise InvalidInputError(
                "--igtl", "streams one insertion: give --replay-trial K (or --trials 1)"
            )
        if args.executor != "serial" or args.workers is not None:
            raise InvalidInputError(
                "--igtl", "streams from this process: no --executor or --workers"
            )


def execute_options(args: argparse.Namespace, r_min_mm: float):
    """The trials' options from the flags of :func:`add_noise_flags`.

    Parameters
    ----------
    args : argparse.Namespace
    r_min_mm : float
        The needle's radius of curvature (``--radius-sd-mm`` is held to a fifth of it).

    Returns
    -------
    ExecuteOptions
    """
    from dataclasses import replace

    from needlekit.execute.faults import PROFILES
    from needlekit.execute.needle_sim import ExecutionNoise
    from needlekit.execute.replan import ReplanPolicy
    from needlekit.execute.run import ExecutionSettings
    from needlekit.execute.trials import ExecuteOptions

    noise = ExecutionNoise()
    if args.orientation_noise_rad is not None:
        noise = replace(noise, orientation_sigma_rad=args.orientation_noise_rad)
    if args.radius_sd_mm is not None:
        top = RADIUS_SD_FRACTION * r_min_mm
        if args.radius_sd_mm > top:
            raise InvalidInputError(
                "--radius-sd-mm",
                f"expected at most {top:g} ({RADIUS_SD_FRACTION:g} r_min), got {args.radius_sd_mm:g}",
            )
        noise = replace(noise, radius_sigma_mm=args.radius_sd_mm)
    if args.deflection_sd is not None:
        noise = replace(noise, deflection_sigma=args.deflection_sd)
    policy = ReplanPolicy(
        cross_track_mm=args.cross_track_mm,
        time_limit_s=args.replan_time_limit_s,
        max_iterations=args.replan_iterations,
        delay_s=None if args.replan_delay_ms is None else args.replan_delay_ms / 1e3,
        warm_start=not args.no_warm_start,
    )
    settings = ExecutionSettings(
        insertion_speed_mm_s=args.speed_mm_s, noise=noise, guard=_guard(args),
        faults=None if args.faults is None else PROFILES[args.faults],
        stop_clearance_mm=None if args.no_proximity_stop else args.stop_clearance_mm,
        **({"models": args.models} if getattr(args, "models", None) is not None else {}),
    )  # fmt: skip
    if hasattr(args, "replanner"):
        policy = replace(policy, planner=args.replanner)
    names: tuple = ("em",)
    if hasattr(args, "sensing"):  # execute's own flags (not study execute-lungs')
        from needlekit.cli.execute_sensing import sensing_policy

        sensing, names = sensing_policy(args)
        settings = replace(settings, sensing=sensing)
    return ExecuteOptions(settings, policy, replan=not args.no_replan, breathing=_breathing(args),
                          sensing=names)  # fmt: skip


def _guard(args: argparse.Namespace):
    """The sensor guard's policy from ``--on-fault`` and ``--hold-timeout-s``."""
    from needlekit.execute.guard import GuardSpec

    try:
        return GuardSpec(on_fault=args.on_fault, hold_timeout_s=args.hold_timeout_s)
    except InvalidInputError as exc:
        flag = "--on-fault" if exc.field == "on_fault" else "--hold-timeout-s"
        raise InvalidInputError(flag, exc.reason) from None


#: The profiles of ``--faults`` (:data:`needlekit.execute.faults.PROFILES`, named here so
#: that the parser does not import the simulation).
FAULT_PROFILES: tuple[str, ...] = ("dropout", "freeze", "distortion", "jitter", "nan", "replan",
                                   "mixed")  # fmt: skip


#: ``--hold-timeout-s`` at most this (s): an hour held is a procedure abandoned.
HOLD_TIMEOUT_MAX_S: float = 3600.0
#: ``--hold-timeout-s``: a number through the gate, in (0, HOLD_TIMEOUT_MAX_S] s.
_hold_timeout = number(MIN_POSITIVE, HOLD_TIMEOUT_MAX_S, unit="s")


#: The breathing flags, by the field of :class:`~needlekit.execute.breathing.Breathing` each
#: sets.
BREATHING_FLAGS = {
    "amplitude_mm": "--breathing-amplitude-mm",
    "period_s": "--breathing-period-s",
    "shape": "--breathing-shape",
    "direction": "--breathing-direction",
}


def _breathing(args: argparse.Namespace):
    """The breathing the flags ask for (None: none), each value checked and named by its
    flag."""
    from dataclasses import replace

    from needlekit.execute.breathing import PRESETS

    given = {f: getattr(args, flag[2:].replace("-", "_")) for f, flag in BREATHING_FLAGS.items()}
    given = {f: v for f, v in given.items() if v is not None}
    if args.breathing is None:
        if given:
            flag = BREATHING_FLAGS[next(iter(given))]
            raise InvalidInputError(flag, "changes the breathing: give --breathing lung|liver")
        return None
    try:
        return replace(PRESETS[args.breathing], **given)
    except InvalidInputError as exc:
        raise InvalidInputError(BREATHING_FLAGS.get(exc.field, "--breathing"), exc.reason) from None


def load_checked_plan(args: argparse.Namespace, record: dict | None = None):
    """The scenario's source and problem and the plan, the plan checked against the
    scenario (made for it, and passing its check) before any trial; each file read once.

    Parameters
    ----------
    args : argparse.Namespace
        ``scenario``, ``plan``, ``cache_dir``, ``no_cache``.
    record : dict, optional
        The plan file's document, already read (default: read it here).

    Returns
    -------
    (ScenarioSource, SteerableProblem, SteerablePlan, str)
        The source, its problem, the plan and the scenario's name.

    Raises
    ------
    InvalidInputError
        A plan with no path, made for another start or goal, or failing its check.
    """
    import numpy as np

    from needlekit.io.files import read_json_object
    from needlekit.io.scenario_schema import read_scenario_document
    from needlekit.planning.steerable.plan import plan_from_dict
    from needlekit.planning.steerable.verify import verify_plan
    from needlekit.scenario.problems import ScenarioSource

    document = read_scenario_document(args.scenario)  # a bad one: before the anatomy loads
    if record is None:
        record = read_json_object(args.plan, "plan")
    plan, goal = plan_from_dict(record, Path(args.plan).name)
    if plan is None:
        raise InvalidInputError("plan", f"{args.plan.name} holds no plan to carry out")
    source = ScenarioSource.of(
        args.scenario, cache_dir=args.cache_dir, use_cache=not args.no_cache,
        safety_margin_mm=getattr(args, "safety_margin_mm", None),
    )  # fmt: skip
    scenario, problem = source.cached(document)  # the document read above, not read again
    swept = getattr(args, "any_start_direction", False)
    other = []
    if swept:  # a sweep's plan: the scenario's start point, the direction the sweep chose
        if not np.allclose(plan.start_pose[:3, 3], problem.start_pose[:3, 3], rtol=0.0, atol=1e-6):
            other.append("its start point")
    elif not np.allclose(plan.start_pose, problem.start_pose, rtol=0.0, atol=1e-6):
        other.append("its start pose")
    if not np.allclose(goal, problem.goal_mm, rtol=0.0, atol=1e-6):
        other.append("its goal")
    if other:
        hint = ""
        if other == ["its start pose"] and record.get("start_direction") == "swept":
            hint = " (a sweep chose its direction: --any-start-direction carries it out)"
        raise InvalidInputError(
            "plan",
            f"{args.plan.name} was made for another scenario: {' and '.join(other)} "
            f"{'differ' if len(other) > 1 else 'differs'} from {args.scenario.name}'s{hint}",
        )
    # held to the start point and the entry-angle rule, as `verify --any-start-direction`
    check = verify_plan(problem.with_free_start_direction() if swept else problem, plan)
    if not check.ok:
        raise InvalidInputError(
            "plan", f"{args.plan.name} fails its check against {args.scenario.name}: "
            + "; ".join(check.violations)
        )  # fmt: skip
    if swept:
        problem = problem.with_start_pose(plan.start_pose)
    return source, problem, plan, scenario.name or args.scenario.name


def _cmd_execute(args: argparse.Namespace) -> int:
    from needlekit.io.files import read_json_object

    try:
        record, unread = read_json_object(args.plan, "plan"), None
    except InvalidInputError as exc:
        record, unread = {}, exc  # said after the flags
    if "needles" in record:  # a straight multi-needle plan: the robot inserts it
        from needlekit.cli.execute_multi import run_multi

        return run_multi(args, record)
    if args.registration_sd_mm is not None:
        raise InvalidInputError("--registration-sd-mm", "applies to a multi plan (multi.json)")
    _check_flags(args)
    from tqdm import tqdm

    from needlekit.batch import open_executor
    from needlekit.execute.trials import read_partial_execute, run_execute_study
    from needlekit.io.results import scenario_reference

    if unread is not None:
        raise unread
    source, problem, plan, name = load_checked_plan(args, record)
    options = execute_options(args, 1.0 / problem.kappa_max_per_mm)
    if args.models.truth in ("mechanics", "physical"):
        from needlekit.cli.execute_models import physics_options, say_model

        options = physics_options(args, source.cached()[0], plan, problem, options)
        say_model(options.settings, problem)
    trials = [args.replay_trial] if args.replay_trial is not None else list(range(args.trials))
    resume = None
    if args.resume:
        resume = read_partial_execute(args.out, name, plan, args.seed, trials, options)
    hooks, link = _live_link(args, options) if args.igtl is not None else (None, None)
    with (
        open_executor(
            args.executor, workers=args.workers, address=args.scheduler, dashboard=args.dashboard
        ) as ex,
        tqdm(
            total=len(trials), initial=len(resume or ()), desc="execute", unit="trial", disable=None
        ) as bar,  # fmt: skip
    ):
        study = run_execute_study(
            args.out, source, plan, trials=trials, seed=args.seed, options=options,
            executor=None if args.executor == "serial" else ex,
            progress=lambda _: bar.update(1), resume=resume, scenario_name=name, hooks=hooks,
            scenario_file=scenario_reference(args.scenario, Path(args.out) / "execute.json"),
        )  # fmt: skip
    if link is not None:
        link.flush()
        link.close()
        print(_link_line(link, hooks, study.document))
    if args.report is not None:
        from needlekit.report.execute_report import write_execute_report

        write_execute_report(args.report, study.document, problem, plan)
    s = study.document["summary"]
    print(summary_table(s))
    for c in s["crashed"]:
        print(f"  trial {c['trial']} crashed: {c['error']}")
    print(f"-> {study.path}")
    if args.report is not None:
        print(f"-> {args.report}")
    failures = execute_failures(s)
    for line in failures:
        print(f"exit 1: {line}")
    return EXIT_OK if not failures else 1


def _link_line(link, hooks, document: dict) -> str:
    """What went over the link, in one line."""
    line = f"OpenIGTLink: {link.sent} messages sent"
    dropped = getattr(link.endpoint, "dropped", 0)
    if dropped:
        line += f" ({dropped} dropped: the other end did not read them)"
    if hooks.sensor is not None:
        line += f", {hooks.sensor.received} tip poses received"
        trials = document["trials"]
        loop = trials[0].get("closed_loop", {}) if trials else {}
        rejected = loop.get("rejected") or {}
        if rejected:
            line += " (rejected: " + ", ".join(f"{n} {k}" for k, n in rejected.items()) + ")"
    return line


def _live_link(args: argparse.Namespace, options):
    """The closed loop's hooks for ``--igtl``: the link publishes every sensor period,
    and with ``--tip-from-igtl`` it is the sensor."""
    from needlekit.execute.igtl_link import IGTLLink, IGTLTipSensor
    from needlekit.execute.run import LoopHooks

    link = IGTLLink(args.igtl, realtime=args.igtl_realtime, wait_s=args.igtl_wait_s)
    sensor = None if args.tip_from_igtl is None else IGTLTipSensor(link, args.tip_from_igtl)
    period = 1.0 / options.settings.sensor.rate_hz
    hooks = LoopHooks(sensor=sensor, observe=link.publish, observe_every_s=period,
                      notify=say_fault)  # fmt: skip
    return hooks, link


#: How :func:`say_fault` names each kind of fault.
FAULT_WORDS = {
    "stopped": "no tip samples arrive",
    "frozen": "the tip samples are frozen (the same value, or a timestamp that does not advance)",
    "non_finite": "the tip samples are not finite (NaN or infinite)",
    "invalid": "the tip samples are not a rigid pose",
    "jump": "the tip samples jump farther than the needle can have moved",
    "gated": "the tip samples disagree with the needle's motion (innovation gate)",
    "replan_failed": "a re-plan failed",
    "replan_overrun": "a re-plan came back too late",
}
#: ... and each action.
ACTION_WORDS = {
    "hold": "the needle is held",
    "abort": "the insertion is aborted",
    "kept_plan": "the last verified plan is kept",
}


def say_fault(event: dict) -> None:
    """Say a sensor guard's event in one line on stderr, as it happens.

    Parameters
    ----------
    event : dict
        ``{"time_s", "kind", "action"}`` (:class:`~needlekit.execute.guard.SensorGuard`).

    Returns
    -------
    None
    """
    import sys

    what = FAULT_WORDS.get(event["kind"], event["kind"])
    if event["action"] == "resume":
        line = (f"t={event['time_s']:.3f} s: good tip samples again after "
                f"{event.get('held_s', 0.0):.2f} s held ({event['kind']}): the insertion resumes")  # fmt: skip
    else:
        line = f"t={event['time_s']:.3f} s: {what}: {ACTION_WORDS.get(event['action'], event['action'])}"
    print(line, file=sys.stderr, flush=True)


def add_noise_flags(p) -> None:
    """The needle's, the tissue's and the closed loop's flags (``execute`` and ``study
    execute-lungs``).

    Parameters
    ----------
    p : argparse.ArgumentParser

    Returns
    -------
    None
    """
    noise = p.add_argument_group("the needle and the tissue (defaults: docs/execute.md)")
    noise.add_argument("--orientation-noise-rad", type=_non_negative, metavar="RAD",
                       help="orientation noise SD per 0.1 s of insertion (default pi/2000)")  # fmt: skip
    noise.add_argument("--radius-sd-mm", type=_non_negative_mm, metavar="MM",
                       help="SD of the needle's radius of curvature (default 3)")  # fmt: skip
    noise.add_argument("--deflection-sd", type=_non_negative, metavar="MM_PER_MM",
                       help="SD of the tissue's lateral push per mm inserted (default 0.01)")  # fmt: skip
    noise.add_argument("--speed-mm-s", type=_speed_mm_s, default=2.0,
                       help="insertion speed (default 2 mm/s)")  # fmt: skip
    br = p.add_argument_group(
        "breathing (each trial also runs closed loop under ignore, gate and track)"
    )
    br.add_argument("--breathing", choices=["lung", "liver"],
                    help="the anatomy moves: lung 5 mm or liver 13 mm superior-inferior, 4 s")  # fmt: skip
    br.add_argument("--breathing-amplitude-mm", type=_BREATHING_AMPLITUDE, metavar="MM",
                    help="peak displacement (0-50 mm)")  # fmt: skip
    br.add_argument("--breathing-period-s", type=_BREATHING_PERIOD, metavar="S",
                    help="cycle (1-20 s)")  # fmt: skip
    br.add_argument("--breathing-shape", type=_BREATHING_SHAPE, metavar="N",
                    help="n of sin^(2n): the end-exhale plateau (1-6; default 2)")  # fmt: skip
    br.add_argument("--breathing-direction", type=_vector3, metavar="X,Y,Z",
                    help="direction of the inhale displacement, RAS (default 0,0,-1: inferior)")  # fmt: skip
    loop = p.add_argument_group("the closed loop")
    loop.add_argument("--no-replan", action="store_true", help="feedback to the plan only")
    loop.add_argument("--no-warm-start", action="store_true",
                      help="re-plan without the rest of the plan as RCS*'s first best")  # fmt: skip
    loop.add_argument("--cross-track-mm", type=_positive_mm, default=0.5,
                      help="re-plan when the estimate is this far off the plan (default 0.5)")  # fmt: skip
    loop.add_argument("--stop-clearance-mm", type=_non_negative_mm, default=STOP_CLEARANCE_MM,
                      help="stop inserting once the estimated tip is this close to an obstacle, "
                      "at most half the plan's margin (default %(default)s)")  # fmt: skip
    loop.add_argument("--no-proximity-stop", action="store_true",
                      help="never stop on the estimated tip's clearance")  # fmt: skip
    loop.add_argument("--replan-time-limit-s", type=_positive, default=0.025,
                      help="RCS*'s budget per re-plan (default 0.025)")  # fmt: skip
    loop.add_argument("--replan-iterations", type=_positive_int, metavar="N",
                      help="RCS*'s iteration budget per re-plan (reproducible runs)")  # fmt: skip
    loop.add_argument("--replan-delay-ms", type=_non_negative, metavar="MS",
                      help="the time a re-plan takes in the simulation (default: the "
                      "search's measured time; a fixed value replays exactly)")  # fmt: skip
    fault = p.add_argument_group(
        "faults: every sample is checked, and stale or lying input holds the needle"
    )
    fault.add_argument("--faults", choices=FAULT_PROFILES, metavar="PROFILE",
                       help="inject faults into the simulated sensor and the re-plans, from "
                       "each trial's seed: " + ", ".join(FAULT_PROFILES) + " (docs/execute.md)")  # fmt: skip
    fault.add_argument("--on-fault", choices=["hold", "abort"], default="hold",
                       help="when the input fails: hold the needle until good input returns "
                       "(default), or abort the insertion")  # fmt: skip
    fault.add_argument("--hold-timeout-s", type=_hold_timeout, default=10.0, metavar="S",
                       help="the longest hold before the insertion is aborted (default 10, "
                       "at most 3600)")  # fmt: skip


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``execute`` to the ``needlekit`` parser.

    Parameters
    ----------
    sub : argparse._SubParsersAction
        The top-level parser's sub-commands.

    Returns
    -------
    None
    """
    ex = sub.add_parser(
        "execute",
        help="carry a plan out in simulated tissue: open loop beside closed loop (tracked "
        "tip, feedback, re-planning), many trials",
        description="Insert a steerable plan with a needle that does not follow its model "
        "(orientation noise, curvature spread, tissue push), open loop and closed loop on the "
        "same draws, and write DIR/execute.json. Exit 1 when a run crossed an obstacle (open "
        "loop, closed loop, or the closed loop under any --breathing policy: ignore, gate or "
        "track, or any --sensing policy run side by side), a trial crashed, an insertion was aborted on a sensor fault (--on-fault "
        "abort, or a hold longer than --hold-timeout-s), or one was stopped with its estimated tip near an obstacle "
        "(--stop-clearance-mm); each reason is printed on a line "
        "'exit 1: ...'. A straight multi plan (multi.json) is inserted by the simulated Panda "
        "under Tang et al.'s controller, needle after needle, the placed needles kept off by "
        "VFIs; exit 1 when a needle touched a placed one, left its constraints, or a trial "
        "crashed.",
        epilog=_EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    add_input(ex, "scenario", help="scenario file (YAML): anatomy, needle, margin")
    add_input(ex, "plan", help="plan file (plan.json) made for the scenario")
    add_output(ex, "--report", metavar="PAGE",
               help="also write a self-contained HTML page: one trial animated in 3D, the "
               "errors open beside closed loop, the re-plan latency, the literature")  # fmt: skip
    ex.add_argument("--trials", type=_positive_int, default=100, help="trials (default 100)")
    ex.add_argument("--replay-trial", type=_seed, metavar="K",
                    help="run trial K alone, as it ran among --trials (its seed)")  # fmt: skip
    ex.mistaken_flags["--trial"] = (
        "; did you mean --trials N (how many trials) or --replay-trial K (run trial K alone)?"
    )
    _flags.SEED.add(ex, default=0, help="root seed (default 0)")
    ex.add_argument("--any-start-direction", action="store_true",
                    help="carry out a sweep's plan: held to the scenario's start point and "
                    "the entry-angle rule, from the direction the sweep chose (as verify "
                    "--any-start-direction checks it)")  # fmt: skip
    ex.add_argument("--safety-margin-mm", type=_non_negative_mm, metavar="MM",
                    help="the margin the plan is checked against and re-plans keep (mm), "
                    "instead of the scenario's needle.safety_margin_mm (give the one the "
                    "plan was made with: plan --safety-margin-mm)")  # fmt: skip
    _flags.OUT.add(
        ex, folder=True, contents=EXECUTE_FILES, default="out/execute",
        help="output folder (default out/execute)",
    )  # fmt: skip
    add_noise_flags(ex)
    from needlekit.cli.execute_models import add_model_flags
    from needlekit.cli.execute_sensing import add_sensing_flags

    add_model_flags(ex)
    add_sensing_flags(ex)
    live = ex.add_argument_group("a live link to 3D Slicer (pip install 'needlekit[igtl]')")
    live.add_argument("--igtl", metavar="[HOST:]PORT",
                      help="stream the closed-loop insertion over OpenIGTLink (tip TRANSFORMs, "
                      "the plan as POLYDATA, the state as STRING at the sensor rate): listen on "
                      "PORT, or connect to HOST:PORT (Slicer's OpenIGTLinkIF; port 18944)")  # fmt: skip
    live.add_argument("--tip-from-igtl", metavar="NAME",
                      help="take the sensed tip from incoming TRANSFORMs named NAME (a tracker "
                      "behind PLUS: NeedleToTracker) instead of the simulated sensor")  # fmt: skip
    live.add_argument("--igtl-realtime", type=_non_negative, default=1.0, metavar="FACTOR",
                      help="simulated seconds per second while streaming (default 1; 0: as "
                      "fast as it runs)")  # fmt: skip
    live.add_argument("--igtl-wait-s", type=_non_negative, default=30.0, metavar="S",
                      help="how long to wait for the other end (default 30)")  # fmt: skip
    robot = ex.add_argument_group("a multi plan (multi.json), inserted by the robot")
    robot.add_argument("--registration-sd-mm", type=_non_negative_mm, metavar="MM",
                       help="the anatomy lies offset from where the robot believes it: SD "
                       "per axis of one offset per trial (default 0, at most 10)")  # fmt: skip
    _flags.add_cache_options(ex)
    _flags.add_executor_options(ex)
    _flags.RESUME.add(
        ex, help="carry on from the DIR/execute.partial.json an interrupted run wrote"
    )
    from needlekit.cli.execute_multi import STEERABLE_ONLY

    _flags.PLOTLY.add(ex)
    ex.set_defaults(
        command_handler=_cmd_execute,
        sizes=_sizes.execute_sizes,
        steerable_defaults={d: ex.get_default(d) for d in STEERABLE_ONLY},
    )
