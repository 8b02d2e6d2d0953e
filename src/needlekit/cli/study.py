"""``needlekit study``: studies over many real cases, one table each."""

from __future__ import annotations

import argparse

from needlekit.cli import _flags, _sizes
from needlekit.cli._common import (
    EXIT_OK,
    _fmt_table,
    _non_negative_mm,
    _Parser,
    _positive,
    _positive_int,
    _positive_mm,
    number,
)
from needlekit.errors import InvalidInputError

#: What ``needlekit study feng-lungs`` writes in its --out folder (as
#: ``needlekit.studies.feng_lungs.FENG_LUNGS_FILES``; a test keeps them equal).
FENG_LUNGS_FILES = (
    "goal1/scenario.yaml",
    "goal1/sweep.json",
    "goal1/plan.json",
    "goal2/scenario.yaml",
    "goal2/sweep.json",
    "goal2/plan.json",
    "feng_lungs.json",
    "report.html",
)
#: What ``needlekit study execute-lungs`` writes in its --out folder (the lungs' folders
#: beside it).
EXECUTE_LUNGS_FILES = ("execute_lungs.json",)


def _cmd_study_livers(args: argparse.Namespace) -> int:
    from needlekit.io.medrad_paths import chosen_patients

    # a wrong folder or patient is said before the heavy imports (liver_cases says it again)
    chosen_patients("liver", args.medrad, args.livers, patients_flag="--livers")
    from tqdm import tqdm

    from needlekit.planning.straight.coverage import fraction_text
    from needlekit.studies.liver_study import liver_cases, read_partial_livers, run_liver_study

    cases = liver_cases(args.medrad, args.livers)  # bad folders and patients fail here, at once
    resume = None
    if args.resume:  # the partial record agrees with this run, before any case
        resume = read_partial_livers(
            args.out,
            cases,
            medrad_dir=args.medrad,
            gammas_mm=args.gamma,
            resolution_deg=args.resolution_deg,
        )
    with tqdm(total=len(cases) * len(args.gamma), desc="livers", unit="case", disable=None) as bar:

        def progress(row: dict) -> None:
            bar.update(1)
            bar.set_postfix_str(f"liver {row['patient']} {row['nodule']}: {row['status']}")

        record = run_liver_study(
            args.out,
            medrad_dir=args.medrad,
            livers=args.livers,
            gammas_mm=args.gamma,
            resolution_deg=args.resolution_deg,
            cache_dir=args.cache_dir,
            use_cache=not args.no_cache,
            progress=progress,
            resume=resume,
        )
    rows = []
    for r in record["rows"]:
        clear = None if r["min_clearance_mm"] is None else f"{r['min_clearance_mm']:.2f}"
        check = {True: "ok", False: "VIOLATED", None: "-"}[r["verified"]]
        rows.append(
            [
                r["patient"], r["nodule"], r["start"], f"{r['gamma_mm']:g}", r["status"],
                f"{r['needles_planned']} of {r['needles_chosen']}",
                f"{fraction_text(r['coverage'])} ({fraction_text(r['tumour_coverage'])})", clear,
                f"{r['healthy_ablated_ml']:.1f}", f"{r['plan_s']:.1f}", check,
            ]
        )  # fmt: skip
    print(
        _fmt_table(
            ["liver", "nodule", "start", "gamma mm", "status", "needles", "coverage (tumour)",
             "min clear mm", "healthy mL", "plan s", "check"],
            rows,
            why={"min clear mm": "no needle placed", "check": "no plan to check"},
        )
    )  # fmt: skip
    for r in record["rows"]:
        if r["reason"]:
            print(f"liver {r['patient']} {r['nodule']} gamma {r['gamma_mm']:g}: {r['reason']}")
    s = record["summary"]
    print(
        f"{s['cases']} cases: {s['covered']} covered, {s['not_covered']} not covered, "
        f"{s['blocked']} blocked; {s['verified']} plans checked ok, {s['violations']} "
        f"violations ({record['wall_s']:.0f} s) -> {args.out}"
    )
    return EXIT_OK if s["violations"] == 0 else 1


def _cmd_study_feng_lungs(args: argparse.Namespace) -> int:
    from needlekit.studies.feng_lungs import feng_patient_folder

    feng_patient_folder(args.medrad)  # a wrong folder is said before the heavy imports
    from needlekit.batch import open_executor
    from needlekit.cli._common import sweep_progress
    from needlekit.studies.feng_lungs import run_feng_lungs
    from needlekit.studies.feng_timing import timing_verdict

    with (
        open_executor(
            args.executor, workers=args.workers, address=args.scheduler, dashboard=args.dashboard
        ) as ex,
        sweep_progress() as progress,
    ):
        study = run_feng_lungs(
            args.out,
            time_limit_s=args.time_limit_s,
            directions=args.directions,
            max_iterations=args.max_iterations,
            quick=args.quick,
            seed=args.seed,
            rrt_connection=args.rrt_connection,
            executor=None if args.executor == "serial" else ex,
            progress=progress,
            medrad_dir=args.medrad,
            cache_dir=args.cache_dir,
            use_cache=not args.no_cache,
            resume=args.resume,
        )
    record = study.record
    rows = []
    for goal, rec in record["goals"].items():
        feng = record["feng"]["table4"][goal]
        for name, t in rec["table4"].items():
            c = rec["checks"][name]
            rows.append(
                [
                    goal, name, f"{t['n_solved']} of {t['n_effective']}", feng[name]["n_solved"],
                    t["best_cost_mm"], t["mean_cost_mm"], feng[name]["mean_cost_mm"],
                    t["cost_before_lowest_mm"], feng[name]["cost_before_lowest_mm"],
                    f"{t['solved_not_direct']}", f"{c['passed']} of {c['solved']}",
                ]
            )  # fmt: skip
    print(
        _fmt_table(
            ["target", "planner", "solved", "Feng", "best mm", "mean mm", "Feng mean mm",
             "before lowest mm", "Feng before mm", "not direct", "checked ok"],
            rows,
            why=dict.fromkeys(
                ("best mm", "mean mm", "Feng mean mm", "before lowest mm", "Feng before mm"),
                "no direction solved, so no cost",
            ),
        )
    )  # fmt: skip
    for goal, rec in record["goals"].items():
        if rec["order"] is None:
            print(f"{goal}: a planner solved no direction: Feng's order cannot be judged")
            continue
        verdict = "holds" if rec["order_holds"] else "does not hold"
        order = " < ".join(rec["order"])
        print(f"{goal}: mean costs {order}; Feng's rcs_star < rrt < rcs {verdict}")
    for path in study.files.values():
        print(f"-> {path}")
    t = record["timing"]
    print(timing_verdict(t))
    prep = ", ".join(f"{w} {s:.1f} s" for w, s in t["prep_s_by_worker"].items())
    print(f"patient prepared: here {t['main_prep_s']:.1f} s; per worker {prep}")
    failed = [
        f"{goal} {name}: {len(c['failures'])} plans"
        for goal, rec in record["goals"].items()
        for name, c in rec["checks"].items()
        if c["failures"] or (c["best"] is not None and not c["best"]["ok"])
    ]
    if failed:
        print("error: plans failed their independent check: " + "; ".join(failed))
        return 1
    # a target no planner reaches from any direction is a failed case
    reached = all(
        any(t["n_solved"] for t in rec["table4"].values()) for rec in record["goals"].values()
    )
    return EXIT_OK if reached else 1


def _lungs_physics(args: argparse.Namespace):
    """The physical study's needle and plan choice from the flags (None: kinematic), every
    flag checked before any work."""
    from needlekit.cli.execute_models import check_physics_flags, mechanics_from_flags
    from needlekit.cli.execute_sensing import check_sensing_flags

    check_physics_flags(args)  # resolves the default truth, physical
    check_sensing_flags(args)
    if args.truth == "kinematic":
        for flag, default in (("r_min_mm", None), ("sensing", ("em",))):
            if getattr(args, flag) != default:
                raise InvalidInputError("--" + flag.replace("_", "-"),
                                        "applies to --truth physical, not kinematic")  # fmt: skip
        return None
    for flag, default in (("pilot_trials", PILOT_TRIALS), ("crossing_probability", CROSSING_PROBABILITY)):
        if getattr(args, flag) != default:
            raise InvalidInputError("--" + flag.replace("_", "-"),
                                    "sets the kinematic study's margin: applies to --truth kinematic")  # fmt: skip
    from needlekit.studies.execute_lungs_physical import PHYSICAL_R_MIN_MM, PhysicalLungs

    mech = mechanics_from_flags(args, "lung")
    names = tuple(args.sensing or ("em",))
    return PhysicalLungs(mechanics=mech, boundary=args.tissue_boundary,
                         r_min_mm=args.r_min_mm or PHYSICAL_R_MIN_MM,
                         calibration_insertions=args.calibration_insertions,
                         judged="checkpoints" if "checkpoints" in names else names[0])  # fmt: skip


def _cmd_study_execute_lungs(args: argparse.Namespace) -> int:
    from needlekit.cli.execute import check_noise_flags

    check_noise_flags(args)
    physics = _lungs_physics(args)
    from tqdm import tqdm

    from needlekit.batch import open_executor
    from needlekit.cli.execute import execute_options
    from needlekit.execute.plugins import Models
    from needlekit.studies.execute_lungs import LUNG_R_MIN_MM, run_execute_lungs

    args.models = Models(truth=args.truth)
    options = execute_options(args, LUNG_R_MIN_MM if physics is None else physics.r_min_mm)
    patients = tuple(args.patients)
    with (
        open_executor(
            args.executor, workers=args.workers, address=args.scheduler, dashboard=args.dashboard
        ) as ex,
        tqdm(
            total=len(patients) * args.trials, desc="execute-lungs", unit="trial", disable=None
        ) as bar,  # fmt: skip
    ):
        record = run_execute_lungs(
            args.out, patients=patients, trials=args.trials, seed=args.seed, options=options,
            executor=None if args.executor == "serial" else ex, progress=lambda _: bar.update(1),
            medrad_dir=args.medrad, pilot_trials=args.pilot_trials,
            crossing_probability=args.crossing_probability, resume=args.resume, physics=physics,
            say=tqdm.write,
        )  # fmt: skip
    if physics is not None:
        return _say_physical_lungs(record, args.out)
    rows = []
    for c in record["cases"]:
        if c["status"] != "done":
            rows.append([f"lung {c['patient']}", c["status"], *[None] * 9])
            continue
        cl, op = c["closed_loop"], c["open_loop"]
        rows.append([
            f"lung {c['patient']}", "done", f"{c['margin_wanted_mm']:.2f}",
            f"{c['margin_mm']:.2f}", f"{op['mean_error_mm']:.2f}", f"{cl['mean_error_mm']:.3f}",
            f"{cl['sd_error_mm']:.3f}", f"{100 * cl['within_1mm']:.0f}",
            f"{cl['violated']} / {op['violated']}", f"{cl['replans_mean']:.2f}",
            "yes" if c["holds"] else "NO",
        ])  # fmt: skip
    heads = ["case", "status", "margin wanted mm", "kept mm", "open mean mm", "closed mean mm",
             "sd mm", "% <= 1 mm", "crossed (closed / open)", "re-plans", "targets hold"]  # fmt: skip
    print(_fmt_table(heads, rows, why=dict.fromkeys(heads[2:], "the case did not run (status)")))
    brows = [
        [f"lung {c['patient']}", name, f"{b['mean_error_mm']:.3f}", f"{b['sd_error_mm']:.3f}",
         f"{100 * b['within_1mm']:.0f}", b["violated"], f"{b['procedure_s']:.1f}"]
        for c in record["cases"] for name, b in c.get("breathing", {}).items()
    ]  # fmt: skip
    if brows:
        print("\nbreathing, closed loop per policy (errors and crossings in the tissue):")
        print(_fmt_table(["case", "policy", "mean mm", "sd mm", "% <= 1 mm", "crossed",
                          "procedure s"], brows))  # fmt: skip
    print(
        f"targets: closed-loop mean <= 0.5 mm, >= 95 % within 1 mm, no crossing: "
        f"{'hold' if record['holds'] else 'DO NOT hold'} ({record['wall_s']:.0f} s) -> {args.out}"
    )
    return EXIT_OK if record["holds"] else 1


def _say_physical_lungs(record: dict, out) -> int:
    """The physical study's table: per lung and sensing policy, the closed loop's error
    (mean +- SD, p95, max), crossings, scans and how far the target moved."""

    def err(b):
        return f"{b['mean_error_mm']:.2f} +- {b['sd_error_mm']:.2f}, {b['p95_error_mm']:.2f}, {b['max_error_mm']:.2f}"

    rows = []
    for c in record["cases"]:
        if c["status"] != "done":
            rows.append([f"lung {c['patient']}", c["status"], *[None] * 8])
            continue
        for i, (name, b) in enumerate(c.get("sensing", {"em": c["closed_loop"]}).items()):
            rows.append([
                f"lung {c['patient']}" if i == 0 else "",
                f"start {c['start']}, {c['margin_mm']:.1f} mm" if i == 0 else "",
                err(c["open_loop"]) if i == 0 else "", name, err(b), b["violated"],
                b.get("stopped_near_obstacle", 0),
                "-" if b.get("scans") is None else f"{b['scans']:.1f}",
                "-" if b.get("target_moved_mm") is None else f"{b['target_moved_mm']:.2f}",
                ("yes" if c["holds"] else "NO") if i == 0 else "",
            ])  # fmt: skip
    heads = ["case", "plan", "open loop mm", "sensing", "closed loop mm", "crossed", "stopped",
             "scans", "target moved mm", "goal holds"]  # fmt: skip
    print(_fmt_table(heads, rows, why=dict.fromkeys(heads[2:], "the case did not run (status)")))
    print("(errors: mean +- SD, p95, max)")
    print(
        f"goal: closed-loop mean <= 1.0 mm, p95 <= 2.0 mm, no crossing: "
        f"{'holds' if record['holds'] else 'DOES NOT hold'} ({record['wall_s']:.0f} s) -> {out}"
    )
    return EXIT_OK if record["holds"] else 1


def _register_execute_lungs(study_sub) -> None:
    from needlekit.cli.execute import add_noise_flags
    from needlekit.cli.execute_models import add_mechanics_flags
    from needlekit.cli.execute_sensing import add_sensing_flags

    se = study_sub.add_parser(
        "execute-lungs",
        help="plans carried out in simulated tissue on the Med-RAD lungs, open beside closed "
        "loop",
        description="For each Med-RAD lung (start 1 to its target): the margin the execution "
        "noise asks for (a pilot's deviation, k sigma), the largest the anatomy allows, the "
        "plan, and --trials trials open and closed loop as `needlekit execute` runs them. "
        "Writes DIR/lungN/{scenario.yaml,plan.json,execute.json} and DIR/execute_lungs.json. "
        "Exit 1 when a case misses the targets (closed-loop mean <= 0.5 mm, >= 95 %% within "
        "1 mm, no crossing).",
    )
    _flags.OUT.add(se, folder=True, contents=EXECUTE_LUNGS_FILES, required=True,
                   help="output folder")  # fmt: skip
    se.add_argument("--patients", type=_positive_int, nargs="+", default=[1, 2, 3, 4, 5],
                    help="lung patients (default 1-5)")  # fmt: skip
    se.add_argument(
        "--trials", type=_positive_int, default=100, help="trials per lung (default 100)"
    )
    _flags.SEED.add(se, default=0, help="root seed (default 0)")
    se.add_argument("--pilot-trials", type=_positive_int, default=PILOT_TRIALS,
                    help="--truth kinematic: closed-loop trials that measure the deviation "
                    f"(default {PILOT_TRIALS})")  # fmt: skip
    se.add_argument("--crossing-probability", type=_probability, default=CROSSING_PROBABILITY,
                    help="--truth kinematic: per recorded point, that the margin is set for "
                    f"(default {CROSSING_PROBABILITY:g})")  # fmt: skip
    se.add_argument("--truth", choices=("physical", "kinematic"), default=None,
                    help="the needle: physical (default: bent by mechanics in a lung that "
                    "deforms; each lung planned from a start and direction it reaches) or "
                    "kinematic (the planner's own, from start 1 with the pilot's margin)")  # fmt: skip
    se.add_argument("--r-min-mm", type=_positive_mm, metavar="MM",
                    help="--truth physical: the radius the plans are made for (default 150)")  # fmt: skip
    add_mechanics_flags(se)
    add_sensing_flags(se)
    add_noise_flags(se)
    _flags.add_medrad(se)
    _flags.add_executor_options(se)
    _flags.RESUME.add(
        se,
        help="carry on from the DIR/execute_lungs.partial.json an interrupted run wrote (the "
        "lungs done kept, the one under way from its margin, plan and trials done)",
    )
    se.set_defaults(command_handler=_cmd_study_execute_lungs, sizes=_sizes.execute_lungs_sizes)


#: The kinematic study's pilot (``--pilot-trials``) and the crossing probability its margin
#: is set for (``--crossing-probability``; as ``needlekit.studies.execute_lungs``, which
#: the parser does not import).
PILOT_TRIALS: int = 10
CROSSING_PROBABILITY: float = 0.001

#: ``--crossing-probability``: a probability in (0, 0.5].
_probability = number(0.0, 0.5, low_open=True)


def _register_livers(study_sub) -> None:
    sl = study_sub.add_parser(
        "livers",
        help="every Med-RAD liver nodule ablated by straight needles",
        description="For each Med-RAD liver, each start pose and its nodule, and each gamma: "
        "targets chosen to cover the nodule plus margin, trajectories planned as `needlekit "
        "multi` plans examples/medrad_liver4.yaml, every planned needle re-checked; what "
        "blocks a case that is not covered is said.",
    )
    _flags.OUT.add(sl, default="livers.json", help="study record (default livers.json)")
    sl.add_argument("--livers", type=_positive_int, nargs="+", help="patients (default every one)")
    sl.add_argument(
        "--gamma",
        type=_non_negative_mm,
        nargs="+",
        default=[1.5, 3.0],
        metavar="MM",
        help="safety distances (default 1.5 3)",
    )
    sl.add_argument("--resolution-deg", type=_positive, help="CFRW grid step (default 1)")
    _flags.add_medrad(sl)
    _flags.add_cache_options(sl)
    _flags.RESUME.add(
        sl,
        help="carry on from the record an interrupted run wrote beside --out "
        "(X.partial.json: Ctrl-C keeps the cases done): the same livers, gammas and "
        "settings; only the rest is planned",
    )
    sl.set_defaults(command_handler=_cmd_study_livers, sizes=_sizes.livers_sizes)


def _register_feng_lungs(study_sub) -> None:
    sf = study_sub.add_parser(
        "feng-lungs",
        help="Feng et al.'s effective-region protocol on a Med-RAD lung, two targets",
        description="Feng et al.'s protocol on real anatomy: Med-RAD lung 5 from start 1's "
        "point, their needle (2 mm, r_min 50 mm, l_max 100 mm, alpha 20 deg, tau 1 mm), 544 "
        "start directions, RCS*, RCS and RRT 1 s each, to the given target and a second one "
        "(Feng's goal offset). Writes per target the scenario, sweep.json and the best RCS* "
        "plan, feng_lungs.json (Table 4 beside Feng's) and report.html. Exit 1 when a plan "
        "fails its independent check or no planner reaches a target.",
    )
    _flags.OUT.add(sf, folder=True, contents=FENG_LUNGS_FILES, required=True, help="output folder")
    _flags.TIME_LIMIT_S.add(sf, help="budget per direction and planner (default 1)")
    _flags.DIRECTIONS.add(sf, help="candidate start directions (default 544)")
    _flags.MAX_ITERATIONS.add(sf, help="iteration budget per direction (default none)")
    _flags.SEED.add(sf, default=0, help="seed of RRT (default 0)")
    _flags.QUICK.add(
        sf, help="136 directions, 300 iterations per direction (a minute or so; flags given win)"
    )
    _flags.RRT_CONNECTION.add(
        sf,
        default="arc",
        help="RRT's goal connection: one arc to the target (default, the reference "
        "implementation's rule behind Feng's tables) or arc then line",
    )
    _flags.add_medrad(sf)
    _flags.add_cache_options(sf)
    _flags.add_executor_options(sf)
    _flags.RESUME.add(
        sf,
        help="carry on from the goal1/ and goal2/sweep.partial.json an interrupted run wrote "
        "(Ctrl-C keeps the directions done): the same settings; only the rest is planned",
    )
    _flags.PLOTLY.add(sf)
    sf.set_defaults(command_handler=_cmd_study_feng_lungs, sizes=_sizes.feng_lungs_sizes)


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``study livers|feng-lungs|execute-lungs`` to the ``needlekit`` parser.

    Parameters
    ----------
    sub : argparse._SubParsersAction
        The top-level parser's sub-commands.

    Returns
    -------
    None
    """
    study = sub.add_parser("study", help="studies over many real cases, one table each")
    study_sub = study.add_subparsers(
        dest="study_command", metavar="STUDY", parser_class=_Parser, required=True
    )
    _register_livers(study_sub)
    _register_feng_lungs(study_sub)
    _register_execute_lungs(study_sub)
