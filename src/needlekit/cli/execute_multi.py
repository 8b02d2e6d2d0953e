"""``needlekit execute SCENARIO multi.json``: a straight multi-needle plan inserted by the
simulated Panda under Tang et al.'s controller, needle after needle (docs/execute.md,
"The straight plan, inserted by the robot")."""

from __future__ import annotations

import argparse
from pathlib import Path

from needlekit.cli._common import EXIT_OK, _fmt_table
from needlekit.errors import InvalidInputError

#: ``execute``'s flags that belong to a steerable plan's insertion: given with a multi
#: plan, they are refused (``dest`` names; their defaults are read from the parser).
STEERABLE_ONLY = (
    "orientation_noise_rad", "radius_sd_mm", "deflection_sd", "speed_mm_s", "breathing",
    "breathing_amplitude_mm", "breathing_period_s", "breathing_shape", "breathing_direction",
    "no_replan", "no_warm_start", "cross_track_mm", "stop_clearance_mm", "no_proximity_stop", "replan_time_limit_s", "replan_iterations",
    "replan_delay_ms", "igtl", "tip_from_igtl", "igtl_realtime", "igtl_wait_s", "faults",
    "on_fault", "hold_timeout_s", "safety_margin_mm", "sensor", "estimator",
    "feedback", "replanner", "sensing", "checkpoint_every_mm", "scan_s", "confirm_scans",
    "image_sigma_mm",
    "tracking_rate_hz", "tracking_sigma_mm", "tracking_latency_ms", "retarget_mm",
    "any_start_direction", "tissue_boundary", "calibration_insertions",
)  # fmt: skip
#: ``--registration-sd-mm`` at most this: beyond it the robot works on another patient.
REGISTRATION_SD_MAX_MM = 10.0


def check_trial_flags(args: argparse.Namespace) -> None:
    """``--replay-trial`` below ``--trials``, and not with ``--resume`` (both kinds of plan).

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
    if args.replay_trial is not None and args.replay_trial >= args.trials:
        raise InvalidInputError(
            "--replay-trial", f"expected a trial number below --trials ({args.trials}), got {args.replay_trial}"
        )
    if args.replay_trial is not None and args.resume:
        raise InvalidInputError("--resume", "carries on a whole study, not one --replay-trial")


def check_multi_flags(args: argparse.Namespace) -> None:
    """The flags of a multi plan's insertion, before any work.

    Parameters
    ----------
    args : argparse.Namespace

    Returns
    -------
    None

    Raises
    ------
    InvalidInputError
        A steerable-only flag given, ``--resume`` with ``--replay-trial``, or a bad value; named
        by its flag.
    """
    defaults = args.steerable_defaults
    for dest in STEERABLE_ONLY:
        if getattr(args, dest) != defaults[dest]:
            flag = "--" + dest.replace("_", "-")
            raise InvalidInputError(flag, "applies to a steerable plan; the plan is a multi plan")
    from needlekit.cli.execute_models import check_physics_flags, resolve_truth
    from needlekit.execute.straight_physics import STRAIGHT_TRUTHS

    resolve_truth(args)
    if args.truth not in STRAIGHT_TRUTHS:
        raise InvalidInputError(
            "--truth", f"a multi plan's needle is one of {', '.join(STRAIGHT_TRUTHS)}, got {args.truth!r}"
        )
    check_physics_flags(args)
    check_trial_flags(args)
    sd = args.registration_sd_mm
    if sd is not None and sd > REGISTRATION_SD_MAX_MM:
        raise InvalidInputError(
            "--registration-sd-mm", f"expected at most {REGISTRATION_SD_MAX_MM:g}, got {sd:g}"
        )


def load_checked_multi(args: argparse.Namespace, record: dict):
    """The scenario's multi-needle problem and the plan, checked: made for this scenario
    (its targets, or inside its coverage region), passing ``verify``, and aimed as the
    scenario's deformation model moves the targets.

    Parameters
    ----------
    args : argparse.Namespace
    record : dict
        The ``multi.json`` document.

    Returns
    -------
    (Scenario, MultiNeedleProblem, tuple or None)
        The scenario, its problem, and its coverage (region, zone) when it has one.

    Raises
    ------
    InvalidInputError
        A plan not solved, made for another scenario, failing its check, or aimed for
        another deformation model.
    """
    import numpy as np

    from needlekit.cli.straight import _document, _multi_problem
    from needlekit.planning.straight.deformation import PlacedNeedle
    from needlekit.planning.straight.sequence import MultiNeedlePlan
    from needlekit.planning.straight.verify import verify_multi

    name = args.plan.name
    doc = _document(args)  # before the anatomy loads
    plan = MultiNeedlePlan.from_dict(record, name)
    if not plan.solved:
        raise InvalidInputError(
            "plan", f"{name} is not a solved plan ({plan.reason or 'no reason'})"
        )
    sc, multi, _ = _multi_problem(args, doc)
    coverage = None
    if isinstance(sc.straight.get("targets"), str):
        from needlekit.scenario.straight import coverage_region

        region, settings = coverage_region(sc, multi.problem)
        coverage = (region, settings["zone"])
        pts = region.points_mm
        far = [n.order for n in plan.needles
               if np.min(np.linalg.norm(pts - n.planned_target_mm, axis=1)) > 2.0 * max(region.spacing_mm)]  # fmt: skip
    else:
        targets = np.asarray(multi.targets_mm, float)
        far = [n.order for n in plan.needles
               if np.min(np.linalg.norm(targets - n.planned_target_mm, axis=1)) > 1e-4]  # fmt: skip
    if far:
        raise InvalidInputError(
            "plan", f"{name} was made for another scenario: needle {far[0]}'s target is not "
            f"one of {args.scenario.name}'s"
        )  # fmt: skip
    check = verify_multi(multi.problem, record)
    if not check.ok:
        raise InvalidInputError(
            "plan", f"{name} fails its check against {args.scenario.name}: "
            + "; ".join(check.violations)
        )  # fmt: skip
    placed = []
    r = multi.problem.needle.radius_mm
    for n in sorted(plan.needles, key=lambda n: n.order):
        want = np.asarray(n.planned_target_mm, float)
        if multi.deformation is not None and placed:
            want = want + np.asarray(multi.deformation.displacement(want[None], placed))[0]
        if np.linalg.norm(want - n.target_mm) > 1e-3:
            raise InvalidInputError(
                "plan", f"{name}: needle {n.order} is aimed {np.linalg.norm(want - n.target_mm):.3f}"
                f" mm from where {args.scenario.name}'s deformation model moves its target"
            )  # fmt: skip
        placed.append(PlacedNeedle(n.target_mm, n.entry.entry_mm, r))
    return sc, multi, coverage


def straight_physics(args: argparse.Namespace, scenario):
    """The needle and organ ``--truth mechanics|physical`` asks for (None: the rigid needle).

    Parameters
    ----------
    args : argparse.Namespace
    scenario : needlekit.scenario.loading.Scenario

    Returns
    -------
    needlekit.execute.straight_physics.StraightPhysics or None

    Raises
    ------
    InvalidInputError
        ``--truth physical`` given on a scenario without a Med-RAD organ (the default
        ``physical`` becomes ``mechanics`` there).
    """
    if args.truth == "kinematic":
        return None
    from needlekit.cli.execute_models import mechanics_from_flags, no_organ
    from needlekit.execute.straight_physics import StraightPhysics
    from needlekit.io.medrad import MedradCase
    from needlekit.tissue.medrad_organ import ORGAN_FILES

    base = getattr(scenario, "base", None)
    organ = base.organ if isinstance(base, MedradCase) and base.organ in ORGAN_FILES else None
    mech = mechanics_from_flags(args, organ, straight=True)
    if args.truth == "physical" and organ is None:
        no_organ(args, args.scenario.name)
    return StraightPhysics(args.truth, mech, organ, None if organ is None else str(base.folder),
                           cache_dir=None if args.cache_dir is None else str(args.cache_dir),
                           use_cache=not args.no_cache)  # fmt: skip


def run_multi(args: argparse.Namespace, record: dict) -> int:
    """``execute`` on a multi plan (the handler's branch).

    Parameters
    ----------
    args : argparse.Namespace
    record : dict

    Returns
    -------
    int
        0 when every needle was placed without touching a placed one or leaving its
        constraints and no trial crashed, else 1.
    """
    check_multi_flags(args)
    from tqdm import tqdm

    from needlekit.batch import open_executor
    from needlekit.io.results import scenario_reference
    from needlekit.studies.execute_multi import run_multi_execution

    sc, multi, coverage = load_checked_multi(args, record)
    physics = straight_physics(args, sc)
    trials = [args.replay_trial] if args.replay_trial is not None else list(range(args.trials))
    with (
        open_executor(
            args.executor, workers=args.workers, address=args.scheduler, dashboard=args.dashboard
        ) as ex,
        tqdm(total=len(trials), desc="execute", unit="trial", disable=None) as bar,
    ):
        run = run_multi_execution(
            args.out, record, multi, trials=trials, seed=args.seed, coverage=coverage,
            registration_sd_mm=args.registration_sd_mm or 0.0,
            executor=None if args.executor == "serial" else ex,
            progress=lambda _: bar.update(1), scenario_name=sc.name or args.scenario.name,
            resume=args.resume,
            scenario_file=scenario_reference(args.scenario, Path(args.out) / "execute.json"),
            physics=physics,
        )  # fmt: skip
    if args.report is not None:
        from needlekit.report.execute_multi_report import write_multi_execute_report

        write_multi_execute_report(args.report, run.document, multi.problem.scene, record)
    s = run.document["summary"]
    print(multi_table(s))
    for c in s["crashed"]:
        print(f"  trial {c['trial']} crashed: {c['error']}")
    print(f"-> {run.path}")
    if args.report is not None:
        print(f"-> {args.report}")
    bad = s["touched"] or s["constraints"]["total"] or s["crashed"]
    return EXIT_OK if not bad else 1


def multi_table(s: dict) -> str:
    """Per-needle errors, then all needles beside Liu et al.'s, touches and coverage.

    Parameters
    ----------
    s : dict
        ``summary`` of a multi ``execute.json``.

    Returns
    -------
    str
    """
    rows = []
    for order, r in s["by_needle"].items():
        e, sh = r["error_mm"], r["target_shift_mm"]
        rows.append([f"needle {order}", e.get("mean"), e.get("sd"), e.get("max"),
                     sh.get("mean")])  # fmt: skip
    e = s["error_mm"]
    rows.append(["all needles", e.get("mean"), e.get("sd"), e.get("max"), None])
    for lit in s["literature"]:
        rows.append([lit["source"], lit["mean_mm"], lit["sd_mm"], None, None])
    text = _fmt_table(["", "error mean mm", "sd mm", "max mm", "target shift mm"], rows, why={
        "max mm": "the published studies give a mean and an SD only",
        "target shift mm": "a shift is per needle: none for all needles together or a "
        "published study",
    })  # fmt: skip
    gap = s["min_needle_gap_mm"]
    text += (
        f"\n{s['needles']} needles in {s['trials']} trials: {len(s['touched'])} touched a placed "
        f"needle (smallest gap {'-' if gap is None else f'{gap:.2f}'} mm), "
        f"{s['constraints']['total']} left their constraints"
    )
    if "coverage" in s:
        c = s["coverage"]
        text += (
            f"\ncoverage of tumour + margin: mean {c['coverage']['mean']:.4f}, min "
            f"{c['coverage']['min']:.4f} ({c['fully_covered']} of {c['coverage']['n']} trials full)"
        )
    return text
