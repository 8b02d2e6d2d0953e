"""``needlekit bench kinematics|fields|steerable|execute|control|straight|approach|scale``."""

from __future__ import annotations

import argparse
from pathlib import Path

from needlekit.cli import _flags, _sizes
from needlekit.cli._common import (
    EXIT_OK,
    _count,
    _non_negative_mm,
    _Parser,
    _positive_int,
    _positive_mm,
    _seed,
)
from needlekit.cli._paths import add_input
from needlekit.constants import DEFAULT_TIME_LIMIT_S
from needlekit.errors import InvalidInputError, NeedlekitError


def _cmd_bench(args: argparse.Namespace) -> int:
    from needlekit.benchmarks.record import format_record

    record = args.bench_suite(args)
    if args.out is not None:
        from needlekit.io.files import write_json

        write_json(args.out, record)
    print(format_record(record))
    if "reference_app" in record:
        from needlekit.benchmarks.reference_comparison import format_comparison

        print(format_comparison(record["reference_app"]))
        if "screening" in record["reference_app"]:
            import sys

            from needlekit.benchmarks.target_screening import format_screening

            screening = record["reference_app"]["screening"]
            print(format_screening(screening))
            for case in screening["unsound"]:  # loudly, on stderr too
                print(f"SOUNDNESS BUG: {case['case']} target {case['target_mm']}: needlekit "
                      f"infeasible, the app {case['app_status']}", file=sys.stderr)  # fmt: skip
    return EXIT_OK


def _kinematics(args: argparse.Namespace) -> dict:
    from needlekit.benchmarks.kinematics import run_kinematics_benchmark

    if args.samples < 2:
        raise NeedlekitError("--samples: expected a whole number >= 2")
    return run_kinematics_benchmark(n_arcs=args.arcs, n_samples=args.samples, repeat=args.repeat)


def _fields(args: argparse.Namespace) -> dict:
    from needlekit.benchmarks.fields import run_fields_benchmark

    if args.grid < 8:
        raise NeedlekitError("--grid: expected a whole number >= 8")
    return run_fields_benchmark(
        grid_size=args.grid,
        n_queries=args.queries,
        repeat=args.repeat,
        medrad_dir=args.medrad,
        medrad_patients=tuple(args.patients),
    )


def _control(args: argparse.Namespace) -> dict:
    from needlekit.control.qp_registry import check_qp_solver

    check_qp_solver(args.qp_solver, "--qp-solver")  # by name, before the heavy imports
    from needlekit.benchmarks.control import run_control_benchmark

    return run_control_benchmark(
        trials=args.trials,
        seed=args.seed,
        adaptation_delay_ms=args.adaptation_delay_ms,
        qp_solver=args.qp_solver,
    )


def _steerable(args: argparse.Namespace) -> dict:
    from needlekit.planning.registry import check_planner_options

    for name in args.planners:  # by name, before any patient is read
        try:
            check_planner_options(name, family="steerable")
        except InvalidInputError as exc:
            raise InvalidInputError("--planners", exc.reason) from None
    from tqdm import tqdm

    from needlekit.benchmarks.steerable import run_steerable_benchmark

    patients = tuple(p for p in args.patients if p != 0)
    if args.sample_targets is None and args.target_seed is not None:
        raise InvalidInputError("--target-seed", "seeds --sample-targets: give that too")
    if args.sample_targets is not None and args.reference_app is None:
        raise InvalidInputError(
            "--sample-targets",
            "screens sampled targets beside the reference app: give --reference-app too",
        )
    per_patient = args.sample_targets or 5
    total = (len(patients) * per_patient * len(args.radii) + len(args.scenario)) * len(
        args.planners
    )
    with tqdm(total=total, desc="bench steerable", unit="case", disable=None) as bar:
        record = run_steerable_benchmark(
            patients=patients,
            radii_mm=tuple(args.radii),
            planners=tuple(args.planners),
            time_limit_s=args.time_limit_s,
            medrad_dir=args.medrad,
            scenarios=tuple(args.scenario),
            reference_app=args.reference_app,
            reference_work=args.reference_work,
            sample_targets=args.sample_targets or 0,
            target_seed=args.target_seed or 0,
            progress=lambda msg: (bar.set_postfix_str(msg, refresh=False), bar.update(1)),
        )
    for row in record["results"]:
        cost = "-" if row["cost_mm"] is None else f"{row['cost_mm']:.4f}"
        sample = f" t{row['sample']}" if "sample" in row else ""
        row["name"] = (
            f"{row['scenario']} {row['planner']}"
            if "scenario" in row
            else f"lung{row['patient']} s{row['start']}{sample} r{row['r_min_mm']:g} "
            f"{row['planner']}"
        )
        row["summary"] = (
            f"{row['status']:<10} {cost:>9} mm {1000 * row['time_s']:8.1f} ms"
            + (" certified" if row["certified"] else "")
            + (
                ""
                if row["reference_cost_mm"] == "n/a"
                else f"  (reference {row['reference_cost_mm']})"
            )
        )
    return record


def _straight(args: argparse.Namespace) -> dict:
    import sys

    from needlekit.benchmarks.straight import run_straight_benchmark

    return run_straight_benchmark(
        repeat=args.repeat,
        livers=tuple(n for n in args.livers if n != 0),
        medrad_dir=args.medrad,
        progress=lambda name: print(f"bench straight: {name}", file=sys.stderr),
    )


def _execute(args: argparse.Namespace) -> dict:
    import sys

    from needlekit.benchmarks.execute import run_execute_benchmark

    return run_execute_benchmark(
        tuple(p for p in args.patients if p != 0),
        margin_mm=args.margin_mm,
        replans=args.replans,
        trials=args.trials,
        seed=args.seed,
        medrad_dir=args.medrad,
        progress=lambda name: print(f"bench execute: {name}", file=sys.stderr),
        physics=not args.no_physics,
    )


def _approach(args: argparse.Namespace) -> dict:
    from needlekit.benchmarks.approach import run_approach_benchmark

    return run_approach_benchmark(repeat=args.repeat, medrad_dir=args.medrad)


def _scale(args: argparse.Namespace) -> dict:
    import sys

    from needlekit.benchmarks.scale import run_scale_benchmark, scale_settings

    settings = scale_settings(  # every flag checked before any work
        quick=args.quick,
        patients=args.patients,
        planners=args.planners,
        directions=args.directions,
        workers=args.workers,
        dask_workers=args.dask_workers,
        trials=args.trials,
        max_iterations=args.max_iterations,
        time_limit_s=args.time_limit_s,
        medrad_dir=args.medrad,
    )
    return run_scale_benchmark(
        settings, progress=lambda msg: print(f"bench scale: {msg}", file=sys.stderr)
    )


# -- the command lines ------------------------------------------------------------------------


def _suite(bench_sub, name: str, run, **kwargs) -> argparse.ArgumentParser:
    """A benchmark suite's parser, with ``--out`` (its record), run by ``run(args)``."""
    p = bench_sub.add_parser(name, **kwargs)
    _flags.add_record_out(p)
    p.set_defaults(command_handler=_cmd_bench, bench_suite=run, sizes=_sizes.bench_sizes)
    return p


def _repeat(p, default: int, help: str) -> None:
    p.add_argument("--repeat", type=_positive_int, default=default, help=help)


def _register_kinematics_fields(bench_sub) -> None:
    bk = _suite(bench_sub, "kinematics", _kinematics, help="arcs propagated and sampled per second")
    bk.add_argument("--arcs", type=_positive_int, default=200_000, help="arcs per batch")
    bk.add_argument(
        "--samples", type=_positive_int, default=32, help="points per sampled arc (>= 2)"
    )
    _repeat(bk, 5, "timed repetitions (best is kept)")
    bf = _suite(
        bench_sub,
        "fields",
        _fields,
        help="distance queries per second, field build times (incl. Med-RAD)",
    )
    bf.add_argument(
        "--grid", type=_positive_int, default=256, help="edge of the cubic test grids (voxels)"
    )
    bf.add_argument(
        "--queries", type=_positive_int, default=2_000_000, help="points per timed query batch"
    )
    _repeat(bf, 3, "timed repetitions (best is kept)")
    bf.add_argument(
        "--patients",
        type=_positive_int,
        nargs="+",
        default=[1],
        help="Med-RAD lung patients to load (default 1)",
    )
    _flags.add_medrad(bf)


def _register_control(bench_sub) -> None:
    from needlekit.cli.puncture import ADAPTATION_DELAY_MS, QP_SOLVER  # light: no numpy

    bc = _suite(
        bench_sub,
        "control",
        _control,
        help="time of a whole puncture-control step (kinematics, VFIs, QP, adaptation)",
    )
    bc.add_argument(
        "--trials", type=_positive_int, default=1, help="simulated punctures timed (default 1)"
    )
    _flags.SEED.add(bc, default=0, help="study seed of the trials (default 0)")
    ADAPTATION_DELAY_MS.add(
        bc,
        help="the adaptation as a job off the tick, applied MS ms after it starts (whole "
        "control periods; default 2; 0: inline, in the sample's tick)",
    )
    QP_SOLVER.add(
        bc,
        help="QP solver of the controller and the adaptation (default daqp; quadprog with "
        "pip install 'needlekit[quadprog]')",
    )


def _register_steerable(bench_sub) -> None:
    bs = _suite(
        bench_sub,
        "steerable",
        _steerable,
        help="curved-needle planners on the Med-RAD lungs (status, cost, time per case)",
    )
    bs.add_argument(
        "--patients",
        type=_count,
        nargs="+",
        default=[1, 2, 3, 4, 5],
        help="lung patients (default 1-5; 0 for none)",
    )
    bs.add_argument(
        "--scenario",
        type=Path,
        nargs="+",
        default=[],
        metavar="FILE",
        help="scenario files to run as further cases (with --patients 0: these only)",
    )
    bs.add_argument(
        "--radii",
        type=_positive_mm,
        nargs="+",
        default=[50.0, 100.0],
        help="r_min values in mm (default 50 100)",
    )
    bs.add_argument(
        "--planners",
        nargs="+",
        default=["rcs_star", "rcs", "rrt"],
        metavar="NAME",
        help="registered planners (default rcs_star rcs rrt)",
    )
    _flags.TIME_LIMIT_S.add(
        bs,
        default=DEFAULT_TIME_LIMIT_S,
        help=f"budget per case and planner (default {DEFAULT_TIME_LIMIT_S:g} s)",
    )
    _flags.add_medrad(bs)
    add_input(
        bs,
        "--reference-app",
        metavar="PATH",
        help="a built rcs_star of the UNC reference planner: run it beside needlekit's "
        "rcs_star on every lung case, interleaved (its budget is its stock 1 s)",
    )
    bs.add_argument(
        "--reference-work",
        type=Path,
        metavar="DIR",
        help="folder for the reference app's case files (default: a temporary folder)",
    )
    bs.add_argument(
        "--sample-targets",
        type=_positive_int,
        metavar="N",
        help="with --reference-app: instead of each patient's own target, N targets drawn "
        "in its lung (free voxels 35-90 mm ahead of a random start, within 90 deg of its "
        "direction, clear for the 1 mm needle), each run by both beside each other; the "
        "summary counts the app's 'not connected' refusals and needlekit's answers to them",
    )
    bs.add_argument(
        "--target-seed",
        type=_seed,
        metavar="S",
        help="seed of the sampled targets (numpy default_rng; default 0)",
    )


def _register_execute(bench_sub) -> None:
    be = _suite(
        bench_sub,
        "execute",
        _execute,
        help="closed-loop execution on the Med-RAD lungs: re-plan latency (warm and cold), "
        "the feedback step, and the physical truth's coupled needle-tissue step",
    )
    be.add_argument(
        "--patients", type=_count, nargs="+", default=[1, 2, 3, 4, 5],
        help="lung patients (default 1-5)",
    )  # fmt: skip
    be.add_argument(
        "--margin-mm", type=_non_negative_mm, default=0.0,
        help="the scenarios' clearance margin (default 0)",
    )  # fmt: skip
    be.add_argument(
        "--replans", type=_positive_int, default=20, help="tips re-planned per lung (default 20)"
    )
    be.add_argument(
        "--trials", type=_positive_int, default=2,
        help="closed-loop trials per lung whose feedback steps are timed (default 2)",
    )  # fmt: skip
    be.add_argument(
        "--no-physics", action="store_true",
        help="leave out the physical truth (its organ's precomputation and coupled step)",
    )  # fmt: skip
    _flags.SEED.add(be, default=0, help="seed of the tips and trials (default 0)")
    _flags.add_medrad(be)


def _register_liver_suites(bench_sub) -> None:
    ba = _suite(
        bench_sub,
        "approach",
        _approach,
        help="approach analysis on Med-RAD liver 4 beside Slicer's PercutaneousApproachAnalysis "
        "(its VTK procedure, when vtk is installed)",
    )
    _repeat(ba, 3, "timed runs per side (median, min)")
    _flags.add_medrad(ba)
    bt = _suite(
        bench_sub,
        "straight",
        _straight,
        help="straight multi-needle planning: 1-degree CFRW map, layer, whole plan, check",
    )
    _repeat(bt, 3, "timed runs per stage (median, min)")
    bt.add_argument(
        "--livers",
        type=_count,
        nargs="+",
        default=[4],
        help="Med-RAD livers, each from examples/medrad_liverN.yaml (default 4; 0 for none)",
    )
    _flags.add_medrad(bt)


def _register_scale(bench_sub) -> None:
    bsc = _suite(
        bench_sub,
        "scale",
        _scale,
        help="how cost grows: planning vs path length and obstacle density, sweeps vs "
        "directions and workers, the control study vs trials",
        description="Preparation of one Med-RAD lung (cold, warm); RCS* on every start of "
        "each lung against the straight distance and the obstacle density around it; Feng's "
        "goal 1 on lung 5 swept at several sizes here, on process pools and on local Dask "
        "clusters; the puncture study at several sizes. About 15 min on 2 cores (--quick: "
        "about 1 min; flags given win). `needlekit report` draws the record.",
    )
    _flags.QUICK.add(bsc, help="lung 1, 34 and 68 directions, 1 and 2 trials in this process")
    bsc.add_argument(
        "--patients", type=_count, nargs="+", help="Med-RAD lungs (default 1-5; 0 for none)"
    )
    bsc.add_argument(
        "--planners",
        nargs="+",
        metavar="NAME",
        help="registered planners of the planning series (default rcs_star)",
    )
    # the sizes of the series: lists, not the one sweep's or executor's flags of the same name
    bsc.add_argument(
        "--directions",
        type=_count,
        nargs="+",
        help="sweep sizes (default 34 68 136 272 544; 0 for no sweep)",
    )
    bsc.add_argument(
        "--workers",
        type=_positive_int,
        nargs="+",
        help="worker processes of the sweeps and the study (default 1 2; 1: this process)",
    )
    bsc.add_argument(
        "--dask-workers",
        type=_count,
        nargs="+",
        metavar="N",
        help="local Dask clusters of the sweeps (default 4, more than the cores on a "
        "2-core machine; 0 for none)",
    )
    bsc.add_argument(
        "--trials", type=_count, nargs="+", help="study sizes (default 1 2 5 10; 0 for none)"
    )
    _flags.MAX_ITERATIONS.add(bsc, help="iteration budget per planner run (default 1000)")
    _flags.TIME_LIMIT_S.add(
        bsc, help="time cap per planner run, only reached on a loaded machine (default 30)"
    )
    _flags.add_medrad(bsc)


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``bench SUITE`` to the ``needlekit`` parser.

    Parameters
    ----------
    sub : argparse._SubParsersAction
        The top-level parser's sub-commands.

    Returns
    -------
    None
    """
    bench = sub.add_parser(
        "bench", help="benchmarks that record machine, versions, inputs and figures"
    )
    bench_sub = bench.add_subparsers(
        dest="bench_command", metavar="SUITE", parser_class=_Parser, required=True
    )
    _register_kinematics_fields(bench_sub)
    _register_control(bench_sub)
    _register_steerable(bench_sub)
    _register_execute(bench_sub)
    _register_liver_suites(bench_sub)
    _register_scale(bench_sub)
