"""``needlekit plan``, ``sweep`` and ``verify``: steerable-needle planning on scenarios."""

from __future__ import annotations

import argparse
import sys

from needlekit.cli import _flags, _sizes
from needlekit.cli._common import (
    EXIT_OK,
    _Formatter,
    _non_negative,
    _non_negative_mm,
    _numbers,
    _positive_int,
    _positive_mm,
    _speed_mm_s,
    _step_mm,
    sweep_progress,
)
from needlekit.cli._paths import add_input, add_output
from needlekit.cli._verdicts import clearance_line, dynamic_summary, flags_named, say_plan
from needlekit.errors import InvalidInputError, NeedlekitError
from needlekit.io.files import json_text
from needlekit.io.results import scenario_reference


def _pose_override(args: argparse.Namespace):
    if args.start_pose is None:
        return None
    from needlekit.io.poses import read_pose_txt

    return read_pose_txt(args.start_pose)


def _source(args: argparse.Namespace):
    from needlekit.scenario.problems import ScenarioSource

    return ScenarioSource.of(
        args.scenario,
        start_pose=_pose_override(args),
        goal_mm=args.goal,
        r_min_mm=args.r_min_mm,
        needle_diameter_mm=args.needle_diameter_mm,
        cache_dir=getattr(args, "cache_dir", None),
        use_cache=not getattr(args, "no_cache", False),
        safety_margin_mm=getattr(args, "safety_margin_mm", None),
    )


def _document(args: argparse.Namespace) -> dict:
    """The scenario's document, read and checked against the schema (no anatomy, no numba)."""
    from needlekit.io.scenario_schema import read_scenario_document

    return read_scenario_document(args.scenario)


def _flag_options(args: argparse.Namespace, names: tuple[str, ...]) -> dict:
    """Per planner name, what the flags give it: ``--option`` (typed and named as the
    planner declares) and ``--rrt-connection``."""
    from needlekit.cli._options import planner_flag_options

    flags = planner_flag_options(args.option, names)
    if args.rrt_connection is not None:
        if "connection" in flags.get("rrt", {}):
            raise InvalidInputError("--option connection", "also given as --rrt-connection")
        flags.setdefault("rrt", {})["connection"] = args.rrt_connection
    if args.seed is not None and any("seed" in o for o in flags.values()):
        raise InvalidInputError("--option seed", "also given as --seed")
    return flags


def _settings(args: argparse.Namespace, doc: dict):
    """The scenario's planner block under the flags: the planners asked for (the first the
    main one), their names, families and option names checked once, here, before any
    planner module is imported (:meth:`PlannerSettings.build` checks the values)."""
    from needlekit.scenario.planners import planner_settings

    block = doc.get("planner") or {}
    names = args.planner or [block.get("name") or "rcs_star"]
    names = tuple(dict.fromkeys([names] if isinstance(names, str) else names))
    flags = _flag_options(args, names)
    return planner_settings(
        block,
        names=names,
        time_limit_s=args.time_limit_s,
        seed=args.seed,
        max_iterations=args.max_iterations,
        options=flags,
    )


def _cmd_plan(args: argparse.Namespace) -> int:
    doc = _document(args)
    settings = _settings(args, doc)
    planner = settings.name
    if args.dynamic:
        dynamic = _check_dynamic(args, doc)
    else:
        _refuse_dynamic_flags(args)
        if args.goals is not None:
            _check_goals(args, planner)
    # every check on the input done: now the planners (numba)
    if args.dynamic:
        return _plan_dynamic(args, doc, settings, dynamic)
    built = settings.build()  # the values of the options checked, before the anatomy
    if args.goals is not None:
        return _plan_goals(args, doc, settings, built[planner])

    from needlekit.planning.steerable.solve import solve

    sc, problem = _source(args).load(doc)
    res = solve(problem, built[planner], termination=settings.termination())
    from needlekit.cli.report import write_plan_and_page

    write_plan_and_page(args, sc, problem, res)
    code = say_plan(res, problem, built[planner], settings, args.out)
    if args.report is not None:
        print(f"drew the plan -> {args.report}")
    return code


#: The flags that only go with ``plan --dynamic``.
_DYNAMIC_FLAGS = {
    "insertion_speed_mm_s": "--insertion-speed-mm-s",
    "step_mm": "--step-mm",
    "predict": "--predict",
    "lookahead_s": "--lookahead-s",
}


def _refuse_dynamic_flags(args: argparse.Namespace) -> None:
    for dest, flag in _DYNAMIC_FLAGS.items():
        if getattr(args, dest, None) is not None:
            raise InvalidInputError(flag, "only goes with --dynamic")


def _check_dynamic(args: argparse.Namespace, doc: dict) -> dict:
    """What ``plan --dynamic`` needs from the flags and the document, checked before any
    planner module is imported (:func:`needlekit.scenario.dynamic.checked_dynamic_settings`
    checks the values)."""
    if args.goals is not None:
        raise InvalidInputError("--dynamic", "plans to the scenario's goal; drop --goals")
    from needlekit.scenario.dynamic import dynamic_block  # light: no planner module

    return dynamic_block(doc, args.scenario.name, {d: getattr(args, d) for d in _DYNAMIC_FLAGS})


def _plan_dynamic(args: argparse.Namespace, doc: dict, settings, dynamic: dict) -> int:
    """``needlekit plan --dynamic``: re-plan from the tip among the scenario's moving
    obstacles, beside the plan made once at t = 0 and executed open-loop (each cycle plans
    with a seed of its own, so with a planner of its own)."""
    from needlekit.io.files import staged_outputs, write_json
    from needlekit.planning.steerable.dynamic import replan_among_moving
    from needlekit.scenario.dynamic import checked_dynamic_settings, moving_case

    kw = checked_dynamic_settings(dynamic)
    sc, static, moving = moving_case(_source(args), doc)
    res = replan_among_moving(static, moving, **kw, **settings.replanning())
    record = {"scenario": scenario_reference(args.scenario, args.out), **res.to_dict()}
    with staged_outputs():
        write_json(args.out, record)
        if args.report is not None:
            from needlekit.report.dynamic_report import write_dynamic_report

            write_dynamic_report(args.report, static, res, title=sc.name or args.scenario.name)
    for line in dynamic_summary(res):
        print(line)
    print(f"-> {args.out}" + ("" if args.report is None else f", {args.report}"))
    return EXIT_OK if res.reached else 1


def _check_goals(args: argparse.Namespace, planner: str) -> None:
    """``plan --goals``: the flags that go with it."""
    if args.goal is not None:
        raise InvalidInputError("--goals", "give the targets with --goals or --goal, not both")
    if args.multi == "one-tree" and planner != "rrt":
        raise InvalidInputError("--multi", f"one-tree grows an RRT tree; --planner is {planner}")


def _plan_goals(args: argparse.Namespace, doc: dict, settings, planner_instance) -> int:
    """``needlekit plan --goals``: a plan to each target, per target or from one tree."""
    import numpy as np

    from needlekit.io.files import staged_outputs, write_json
    from needlekit.planning.result import PlanStatus
    from needlekit.planning.steerable.solve import solve

    planner = settings.name
    goals = np.asarray(args.goals, dtype=float)
    _, problem = _source(args).load(doc)
    from needlekit.scenario.extent import anatomy_box, check_inside_anatomy

    box = anatomy_box(problem.scene)
    for g in goals:  # each target where the anatomy is, before any search
        check_inside_anatomy(g, box, "--goals")
    if args.multi == "one-tree":  # one RRT tree (the flags checked the planner is RRT)
        results = planner_instance.solve_multi(problem, goals, settings.termination())
    else:  # the lecture's procedure: from the start node again for each target
        results = [
            solve(problem.with_goal(g), planner_instance, termination=settings.termination())
            for g in goals
        ]
    record = {
        "planner": planner,
        "mode": args.multi,
        "scenario": scenario_reference(args.scenario, args.out),
        "targets": [r.to_dict() for r in results],
    }
    with staged_outputs():
        write_json(args.out, record)
        if args.report is not None:
            from needlekit.report.steerable_report import write_goals_report

            write_goals_report(args.report, problem, results, planner=planner, mode=args.multi)
    for i, r in enumerate(results, start=1):
        cost = "no plan" if not r.status.has_plan else f"cost {r.cost_mm:.4f} mm"
        why = "" if r.status is PlanStatus.SOLVED else f" ({r.stats.get('reason', '')})"
        print(f"target {i} {np.round(r.goal_mm, 3).tolist()}: {r.status.value}, {cost}{why}")
    solved = sum(r.status is PlanStatus.SOLVED for r in results)
    print(f"{planner} ({args.multi}): {solved} of {len(results)} targets solved -> {args.out}")
    return EXIT_OK if solved == len(results) else 1


def _cmd_sweep(args: argparse.Namespace) -> int:
    doc = _document(args)
    settings = _settings(args, doc)
    # every check on the input done: now the planners (numba)
    from needlekit.batch import open_executor
    from needlekit.planning.steerable.sweep import healpix_directions, sphere_directions
    from needlekit.studies.sweep_study import run_sweep_study

    built = settings.build()  # the values of the options checked, before the anatomy
    if args.healpix is not None:
        dirs = healpix_directions(args.healpix)
    else:
        dirs = sphere_directions(args.directions)
    resume = None
    if args.resume:  # the partial file agrees with this run, before any anatomy
        from needlekit.studies.sweep_study import read_partial_sweep, sweep_settings

        margin = args.safety_margin_mm  # the flag's, else the scenario's (before the anatomy)
        if margin is None:
            margin = float((doc.get("needle") or {}).get("safety_margin_mm", 0.0))

        resume = read_partial_sweep(
            args.out,
            list(built),
            dirs,
            sweep_settings(built, settings.time_limit_s, settings.max_iterations, settings.seed,
                           margin),  # the margin the problem will keep
        )
    source = _source(args)
    source.cached(doc)  # load (and check) the scenario before starting any worker
    with (
        open_executor(
            args.executor, workers=args.workers, address=args.scheduler, dashboard=args.dashboard
        ) as ex,
        sweep_progress() as progress,
    ):
        study = run_sweep_study(
            source,
            args.out,
            plan_path=args.plan,
            report_path=args.report,
            planners=list(built.values()),
            directions=dirs,
            time_limit_s=settings.time_limit_s,
            max_iterations=settings.max_iterations,
            seed=settings.seed,
            executor=None if args.executor == "serial" else ex,
            progress=progress,
            resume=resume,
        )

    def mm(v):
        return "-" if v is None else f"{v:.4f}"

    for planner, result in study.sweeps.items():
        st = result.stats
        print(
            f"{planner}: {st['n_effective']} of {st['n_directions']} directions effective, "
            f"{st['n_solved']} solved; best {mm(st['best_cost_mm'])} mm, "
            f"mean {mm(st['mean_cost_mm'])} mm, cost before the lowest "
            f"{mm(st['cost_before_lowest_mm'])} mm ({st['time_s']:.1f} s)"
        )
    for path in study.files.values():
        print(f"-> {path}")
    if study.check is not None and not study.check.ok:
        print("error: the best plan failed its check: " + "; ".join(study.check.violations))
        return 1
    return EXIT_OK if any(r.stats["n_solved"] for r in study.sweeps.values()) else 1


def _cmd_verify(args: argparse.Namespace) -> int:
    from needlekit.io.files import read_json_object

    # a malformed file fails here, before the anatomy loads; a multi-needle record
    # (multi.json) is checked by the straight planner's rules
    doc = read_json_object(args.plan, "plan")
    if "needles" in doc:
        from needlekit.cli.straight import verify_multi_file

        return verify_multi_file(args, doc)
    scenario = _document(args)  # a bad scenario file too, before numba
    from needlekit.planning.steerable.verify import verify_plan
    from needlekit.scenario.results import read_plan_json

    plan, _, data = read_plan_json(args.plan)
    if plan is None:
        raise NeedlekitError(f"{args.plan.name}: primitives: the file holds no plan to verify")
    _, problem = _source(args).load(scenario)
    if args.any_start_direction:  # a sweep's plan: its start point, any direction
        problem = problem.with_free_start_direction()
    check = verify_plan(problem, plan, expected_cost_mm=data.get("cost_mm"))
    if args.json:
        out = {"ok": check.ok, "violations": list(check.violations), "metrics": check.metrics,
               "safety_margin_mm": problem.safety_margin_mm}  # fmt: skip
        print(json_text(out, "--json", indent=2))
    else:
        m = check.metrics
        print(
            f"{'ok' if check.ok else 'VIOLATED'}: cost {m['cost']:.4f}, length {m['length_mm']:.3f} mm, goal distance "
            f"{m['goal_distance_mm']:.3f} mm, max curvature {m['max_curvature_per_mm']:.5f} /mm, heading change "
            f"{m['max_heading_change_deg']:.2f} deg"
        )
        print(clearance_line(m, problem.safety_margin_mm))
        for v in check.violations:
            print(f"  - {v}")
    turned = any(v.startswith("start: the plan's insertion direction") for v in check.violations)
    if turned and data.get("start_direction") == "swept":
        print(
            "note: a sweep chose this plan's start direction; --any-start-direction holds it "
            "to the start point and the entry-angle rule instead",
            file=sys.stderr,
        )
    return EXIT_OK if check.ok else 1


# -- the command lines ------------------------------------------------------------------------

_PLAN_EPILOG = """\
modes (exit 0 with a plan to every goal, 1 without):
  one goal       needlekit plan examples/toy.yaml --goal 20,30,40 --out plan.json
  several goals  needlekit plan examples/toy.yaml --goals 20,30,40 -10,25,45 --report goals.html
  moving         needlekit plan src/needlekit/data/lung_phantom_moving.yaml --dynamic --out dynamic.json

planner options: --option NAME=VALUE, typed as the planner declares them, e.g.
  needlekit plan examples/toy.yaml --planner rcs_star --option resolution.max_length_mm=8
  needlekit plan examples/toy.yaml --planner rrt --option connection=arc --seed 3
"""


def _problem_overrides(p) -> None:
    """What may replace the scenario's problem: start pose, goal, needle."""
    add_input(
        p, "--start-pose", help="4x4 start pose text file (RAS mm), instead of the scenario's"
    )
    p.add_argument(
        "--goal",
        type=_numbers(3, "three numbers x,y,z (mm)"),
        metavar="X,Y,Z",
        help="goal point (RAS mm)",
    )
    p.add_argument("--r-min-mm", type=_positive_mm, help="minimum radius of curvature (mm)")
    p.add_argument("--needle-diameter-mm", type=_positive_mm, help="needle diameter (mm)")
    p.add_argument(
        "--safety-margin-mm",
        type=_non_negative_mm,
        metavar="MM",
        help="clearance the path keeps beyond the needle's radius (mm), instead of the "
        "scenario's needle.safety_margin_mm",
    )


def _rrt_connection(p) -> None:
    _flags.RRT_CONNECTION.add(
        p,
        help="RRT's greedy goal connection: arc then line (default) or one arc to the target "
        "(the reference implementation's rule, behind Feng et al.'s tables)",
    )


def _plan_planner_group(planp: argparse.ArgumentParser) -> None:
    g = planp.add_argument_group(
        "planner", "which planner, its options and its budget (every mode)"
    )
    g.add_argument(
        "--planner",
        metavar="NAME",
        help="a registered planner: rcs_star, rcs, rrt or one a plug-in registers "
        "(default: the scenario's, else rcs_star)",
    )
    _flags.add_option(g)
    _flags.TIME_LIMIT_S.add(g, help="planning budget (default: the scenario's, else 1 s)")
    _flags.SEED.add(g, help="seed of randomised planners (default: the scenario's, else 0)")
    _flags.MAX_ITERATIONS.add(
        g,
        help="iteration budget besides the time limit (reproducible runs; default: the scenario's)",
    )
    _rrt_connection(g)


def _plan_mode_groups(planp: argparse.ArgumentParser) -> None:
    goals = planp.add_argument_group(
        "several goals",
        "--goals X,Y,Z ...: a plan from the start to each target, written together to --out "
        "(with --report, drawn on one page)",
    )
    goals.add_argument(
        "--goals",
        type=_numbers(3, "three numbers x,y,z (mm)"),
        nargs="+",
        metavar="X,Y,Z",
        help="several targets (RAS mm): a plan to each, written together to --out",
    )
    goals.add_argument(
        "--multi",
        choices=["per-target", "one-tree"],
        default="per-target",
        help="with --goals: a new search from the start for each target, as the lecture "
        "does (default), or one RRT tree for all of them (rrt only)",
    )
    dyn = planp.add_argument_group(
        "moving obstacles",
        "--dynamic: among the scenario's moving obstacles, advance along each plan and plan "
        "again from the tip; beside it, the plan made once at t = 0 executed open-loop",
    )
    dyn.add_argument(
        "--dynamic",
        action="store_true",
        help="among the scenario's moving obstacles: advance --step-mm along each plan, then "
        "plan again from the tip; also the plan made once at t = 0, executed open-loop",
    )
    dyn.add_argument(
        "--insertion-speed-mm-s",
        type=_speed_mm_s,
        help="with --dynamic: insertion speed (default: the scenario's dynamic block)",
    )
    dyn.add_argument(
        "--step-mm",
        type=_step_mm,
        help="with --dynamic: advance between re-plans (default: the scenario's, else 5 mm)",
    )
    dyn.add_argument(
        "--predict",
        choices=["arrival", "swept", "snapshot"],
        help="with --dynamic: plan against each moving obstacle wherever it may be when the "
        "tip passes (default), swept over the next advance, or where it is now",
    )
    dyn.add_argument(
        "--lookahead-s",
        type=_non_negative,
        help="with --predict swept: how long to sweep (default: the advance's time)",
    )


def _register_plan(sub) -> None:
    planp = sub.add_parser(
        "plan",
        help="plan a curved (steerable) needle path for a scenario",
        description="Plan with RCS*, RCS or RRT and write plan.json; exit 0 with a plan, 1 "
        "without. Three modes: one goal (the scenario's, or --goal), several goals (--goals) "
        "and moving obstacles (--dynamic).",
        epilog=_PLAN_EPILOG,
        formatter_class=_Formatter,
    )
    add_input(planp, "scenario", help="scenario file (YAML)")
    one = planp.add_argument_group(
        "the problem (one goal)",
        "the scenario's start, goal and needle, or these instead; without --goals or "
        "--dynamic, one plan to the goal",
    )
    _problem_overrides(one)
    _plan_planner_group(planp)
    _plan_mode_groups(planp)
    out = planp.add_argument_group("output")
    _flags.OUT.add(out, default="plan.json", help="plan file to write (default plan.json)")
    add_output(
        out,
        "--report",
        help="also write the plan's page (HTML: the path in the anatomy, its check, its "
        "motions); with --goals or --dynamic, the page of the plans",
    )
    _flags.add_cache_options(planp.add_argument_group("anatomy cache (Med-RAD scenarios)"))
    _flags.PLOTLY.add(planp)
    planp.set_defaults(command_handler=flags_named(_cmd_plan))


def _register_sweep(sub) -> None:
    sw = sub.add_parser(
        "sweep",
        help="plan over the start directions of the effective puncture region (Feng et al.)",
        description="Sample start directions around the scenario's start point, keep those at least "
        "min_puncture_angle_deg from the entry surface, plan from each, and write sweep.json; "
        "exit 0 when some direction is solved and the best plan passes its check, else 1.",
    )
    add_input(sw, "scenario", help="scenario file (YAML)")
    _problem_overrides(sw)
    _flags.add_cache_options(sw)
    sw.add_argument(
        "--planner",
        nargs="+",
        metavar="NAME",
        help="registered planner(s) to compare (default: the scenario's, else rcs_star)",
    )
    _flags.add_option(
        sw,
        help="a planner option, typed as the planner declares it (repeatable), given to each "
        "planner compared that has it; a field as OPTION.FIELD, e.g. resolution.max_length_mm=8",
    )
    _flags.OUT.add(sw, default="sweep.json", help="sweep table to write (default sweep.json)")
    add_output(sw, "--plan", help="also write the first planner's best plan here")
    add_output(sw, "--report", help="also write a self-contained HTML report (Fig. 8, Fig. 9)")
    _flags.DIRECTIONS.add(sw, default=544, help="candidate directions on the sphere (default 544)")
    _flags.TIME_LIMIT_S.add(
        sw, help="budget per direction (default: the scenario's, else 1 s as Feng et al.)"
    )
    _flags.SEED.add(sw, help="seed of randomised planners (default: the scenario's, else 0)")
    sw.add_argument(
        "--healpix",
        type=_positive_int,
        metavar="NSIDE",
        help="use the 12 NSIDE^2 equal-area HEALPix directions instead of --directions",
    )
    _flags.MAX_ITERATIONS.add(
        sw,
        help="iteration budget per direction besides the time limit (reproducible sweeps; "
        "default: the scenario's)",
    )
    _flags.add_executor_options(sw)
    _rrt_connection(sw)
    _flags.RESUME.add(
        sw,
        help="carry on from the record an interrupted run wrote beside --out "
        "(sweep.partial.json beside sweep.json): only the rest is planned",
    )
    _flags.PLOTLY.add(sw)
    sw.set_defaults(command_handler=flags_named(_cmd_sweep), sizes=_sizes.sweep_sizes)


def _register_verify(sub) -> None:
    ver = sub.add_parser(
        "verify",
        help="re-check a plan file independently; exit 1 on any violation",
        description="Check clearance, curvature, length, heading, entry angle and goal tolerance "
        "of a plan against the scenario (its safety margin, or --safety-margin-mm); exit 0 when "
        "every rule holds, exit 1 on any violation.",
    )
    add_input(ver, "scenario", help="scenario file (YAML)")
    add_input(ver, "plan", help="plan file (plan.json)")
    _problem_overrides(ver)
    ver.add_argument(
        "--any-start-direction",
        action="store_true",
        help="hold the plan to the start point only, its direction free within the entry-angle "
        "rule (a sweep's best plan); by default it must start in the scenario's (or "
        "--start-pose's) direction too",
    )
    _flags.add_cache_options(ver)
    _flags.JSON.add(ver, help="print JSON instead of text")
    ver.set_defaults(command_handler=flags_named(_cmd_verify))


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``plan``, ``sweep`` and ``verify`` to the ``needlekit`` parser.

    Parameters
    ----------
    sub : argparse._SubParsersAction
        The top-level parser's sub-commands.

    Returns
    -------
    None
    """
    _register_plan(sub)
    _register_sweep(sub)
    _register_verify(sub)
