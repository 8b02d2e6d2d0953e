"""``needlekit bench kinematics|fields|steerable|control|straight|approach|scale``."""

from __future__ import annotations

import argparse

from needlekit.cli._common import EXIT_OK
from needlekit.errors import NeedlekitError


def _cmd_bench(args: argparse.Namespace) -> int:
    from needlekit.benchmarks.record import format_record

    if args.bench_command == "kinematics":
        from needlekit.benchmarks.kinematics import run_kinematics_benchmark

        if args.samples < 2:
            raise NeedlekitError("--samples: expected a whole number >= 2")
        record = run_kinematics_benchmark(
            n_arcs=args.arcs, n_samples=args.samples, repeat=args.repeat
        )
    elif args.bench_command == "fields":
        from needlekit.benchmarks.fields import run_fields_benchmark

        if args.grid < 8:
            raise NeedlekitError("--grid: expected a whole number >= 8")
        record = run_fields_benchmark(
            grid_size=args.grid,
            n_queries=args.queries,
            repeat=args.repeat,
            medrad_dir=args.medrad,
            medrad_patients=tuple(args.patients),
        )
    elif args.bench_command == "control":
        from needlekit.benchmarks.control import run_control_benchmark

        record = run_control_benchmark(
            trials=args.trials, seed=args.seed, adaptation_delay_ms=args.adaptation_delay_ms
        )
    elif args.bench_command == "steerable":
        from tqdm import tqdm

        from needlekit.benchmarks.steerable import run_steerable_benchmark

        patients = tuple(p for p in args.patients if p != 0)
        total = (len(patients) * 5 * len(args.radii) + len(args.scenario)) * len(args.planners)
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
                progress=lambda msg: (bar.set_postfix_str(msg, refresh=False), bar.update(1)),
            )
        for row in record["results"]:
            cost = "-" if row["cost_mm"] is None else f"{row['cost_mm']:.4f}"
            row["name"] = (
                f"{row['scenario']} {row['planner']}"
                if "scenario" in row
                else f"lung{row['patient']} s{row['start']} r{row['r_min_mm']:g} {row['planner']}"
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
    elif args.bench_command == "straight":
        import sys

        from needlekit.benchmarks.straight import run_straight_benchmark

        record = run_straight_benchmark(
            repeat=args.repeat,
            livers=tuple(n for n in args.livers if n != 0),
            medrad_dir=args.medrad,
            progress=lambda name: print(f"bench straight: {name}", file=sys.stderr),
        )
    elif args.bench_command == "approach":
        from needlekit.benchmarks.approach import run_approach_benchmark

        record = run_approach_benchmark(repeat=args.repeat, medrad_dir=args.medrad)
    elif args.bench_command == "scale":
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
        record = run_scale_benchmark(
            settings, progress=lambda msg: print(f"bench scale: {msg}", file=sys.stderr)
        )
    else:
        raise NeedlekitError(f"bench: unknown suite {args.bench_command!r}")
    if args.out is not None:
        from needlekit.io.files import write_json

        write_json(args.out, record)
    print(format_record(record))
    if "reference_app" in record:
        from needlekit.benchmarks.reference_comparison import format_comparison

        print(format_comparison(record["reference_app"]))
    return EXIT_OK
