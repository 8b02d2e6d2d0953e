"""The ``needlekit`` command line: a thin layer over the library.

Every command returns an exit status; errors in the input print one line
``error: <message>`` on stderr and exit with status 2.
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import os
import sys
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from needlekit import __version__
from needlekit.errors import NeedlekitError

__all__ = ["main"]

EXIT_OK = 0
EXIT_USAGE = 2


class _Parser(argparse.ArgumentParser):
    """argparse with one-line errors (``error: ...``, exit 2)."""

    def error(self, message: str):  # type: ignore[override]
        self.exit(EXIT_USAGE, f"error: {message}\n")


def _numbers(count: int, what: str):
    def parse(text: str) -> list[float]:
        parts = [p for p in text.replace(",", " ").split() if p]
        try:
            values = [float(p) for p in parts]
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}") from None
        if len(values) != count:
            raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}")
        if not all(math.isfinite(v) for v in values):
            raise argparse.ArgumentTypeError(f"must be finite numbers, got {text!r}")
        return values

    return parse


def _positive(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number > 0, got {text!r}") from None
    if not (math.isfinite(v) and v > 0):
        raise argparse.ArgumentTypeError(f"must be a finite number > 0, got {text!r}")
    return v


def _non_negative(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number >= 0, got {text!r}") from None
    if not (math.isfinite(v) and v >= 0):
        raise argparse.ArgumentTypeError(f"must be a finite number >= 0, got {text!r}")
    return v


def _positive_int(text: str) -> int:
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number > 0, got {text!r}") from None
    if v <= 0:
        raise argparse.ArgumentTypeError(f"expected a whole number > 0, got {text!r}")
    return v


def _problem_overrides(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--start-pose",
        type=Path,
        help="4x4 start pose text file (RAS mm), instead of the scenario's",
    )
    p.add_argument(
        "--goal",
        type=_numbers(3, "three numbers x,y,z (mm)"),
        metavar="X,Y,Z",
        help="goal point (RAS mm)",
    )
    p.add_argument("--r-min-mm", type=_positive, help="minimum radius of curvature (mm)")
    p.add_argument("--needle-diameter-mm", type=_positive, help="needle diameter (mm)")


def _build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="needlekit",
        description="Planning and executing robot-assisted needle insertions.",
        epilog="Units: mm, rad (degrees where an option says _deg), s. World frame: RAS.",
    )
    parser.add_argument("--version", action="version", version=f"needlekit {__version__}")
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more log output")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)

    kin = sub.add_parser(
        "kinematics", help="bevel-tip needle kinematics: forward and inverse steering"
    )
    kin_sub = kin.add_subparsers(dest="kin_command", metavar="MODE", parser_class=_Parser)

    fwd = kin_sub.add_parser(
        "forward",
        help="tip trajectory of the 3D bevel-tip model for piecewise-constant inputs",
        description=(
            "Forward steering: propagate the tip pose exactly for segments of constant "
            "insertion speed u1 (mm/s) and spin rate u2 (rad/s)."
        ),
    )
    fwd.add_argument(
        "--kappa-per-mm", type=_non_negative, required=True, help="needle curvature (1/mm)"
    )
    fwd.add_argument(
        "--segment",
        type=_numbers(3, "three numbers u1_mm_s,u2_rad_s,duration_s"),
        action="append",
        required=True,
        metavar="U1,U2,T",
        help="one input segment; repeat for several",
    )
    fwd.add_argument(
        "--start-pose", type=Path, help="4x4 start pose text file (RAS mm); default identity"
    )
    fwd.add_argument(
        "--dt-s", type=_positive, default=None, help="sampling interval of the printed trajectory"
    )
    fwd.add_argument("--json", action="store_true", help="print JSON instead of a table")

    inv = kin_sub.add_parser(
        "inverse",
        help="single-arc inverse steering from a tip pose to target points",
        description=(
            "Inverse steering with the transformation-matrix method: the arc (alpha, r, "
            "phi, l) from the tip through each target, and the shortest arc-then-line path "
            "when --r-min-mm is given."
        ),
    )
    inv.add_argument(
        "--target",
        type=_numbers(3, "three numbers x,y,z (mm)"),
        action="append",
        required=True,
        metavar="X,Y,Z",
        help="target point in the world frame (mm); repeat for several",
    )
    inv.add_argument(
        "--start-pose", type=Path, help="4x4 start pose text file (RAS mm); default identity"
    )
    inv.add_argument(
        "--r-min-mm", type=_positive, help="minimum radius of curvature; tighter arcs are an error"
    )
    inv.add_argument("--json", action="store_true", help="print JSON instead of a table")

    sub.add_parser(
        "schema",
        help="print the JSON Schema of scenario files",
        description="Print the JSON Schema (draft 2020-12) that scenario files are validated against.",
    )

    scene = sub.add_parser("scene", help="inspect and render the anatomy of a scenario")
    scene_sub = scene.add_subparsers(dest="scene_command", metavar="ACTION", parser_class=_Parser)
    info = scene_sub.add_parser(
        "info", help="summarise the structures: role, extent, voxel size, volume"
    )
    info.add_argument("scenario", type=Path, help="scenario file (YAML)")
    info.add_argument("--json", action="store_true", help="print JSON instead of a table")
    render = scene_sub.add_parser(
        "render", help="write a self-contained interactive 3D view (HTML)"
    )
    render.add_argument("scenario", type=Path, help="scenario file (YAML)")
    render.add_argument("--out", type=Path, required=True, help="output HTML file")
    render.add_argument(
        "--max-cells",
        type=_positive_int,
        default=160,
        help="surface resolution: samples per axis (default 160)",
    )

    planp = sub.add_parser(
        "plan",
        help="plan a curved (steerable) needle path for a scenario",
        description="Plan with RCS*, RCS or RRT and write plan.json; exit 0 with a plan, 1 without.",
    )
    planp.add_argument("scenario", type=Path, help="scenario file (YAML)")
    _problem_overrides(planp)
    planp.add_argument(
        "--planner",
        choices=["rcs_star", "rcs", "rrt"],
        help="planner (default: the scenario's, else rcs_star)",
    )
    planp.add_argument(
        "--out", type=Path, default=Path("plan.json"), help="plan file to write (default plan.json)"
    )
    planp.add_argument(
        "--time-limit-s", type=_positive, help="planning budget (default: the scenario's, else 1 s)"
    )
    planp.add_argument("--seed", type=int, help="seed of randomised planners")

    sw = sub.add_parser(
        "sweep",
        help="plan over the start directions of the effective puncture region (Feng et al.)",
        description="Sample start directions around the scenario's start point, keep those at least "
        "min_puncture_angle_deg from the entry surface, plan from each, and write sweep.json.",
    )
    sw.add_argument("scenario", type=Path, help="scenario file (YAML)")
    _problem_overrides(sw)
    sw.add_argument(
        "--planner",
        choices=["rcs_star", "rcs", "rrt"],
        default="rcs_star",
        help="planner (default rcs_star)",
    )
    sw.add_argument(
        "--out",
        type=Path,
        default=Path("sweep.json"),
        help="sweep table to write (default sweep.json)",
    )
    sw.add_argument(
        "--directions",
        type=_positive_int,
        default=544,
        help="candidate directions on the sphere (default 544)",
    )
    sw.add_argument(
        "--time-limit-s", type=_positive, default=0.5, help="budget per direction (default 0.5 s)"
    )
    sw.add_argument("--seed", type=int, default=0, help="seed of randomised planners")

    ver = sub.add_parser(
        "verify",
        help="re-check a plan file independently; exit 1 on any violation",
        description="Check clearance, curvature, length, heading, entry angle and goal tolerance of a plan.",
    )
    ver.add_argument("scenario", type=Path, help="scenario file (YAML)")
    ver.add_argument("plan", type=Path, help="plan file (plan.json)")
    _problem_overrides(ver)
    ver.add_argument("--json", action="store_true", help="print JSON instead of text")

    demo = sub.add_parser("demo", help="run the main demonstration job and write its outputs")
    demo.add_argument(
        "--out", type=Path, default=Path("out/demo"), help="output folder (default out/demo)"
    )

    bench = sub.add_parser(
        "bench", help="benchmarks that record machine, versions, inputs and figures"
    )
    bench_sub = bench.add_subparsers(dest="bench_command", metavar="SUITE", parser_class=_Parser)
    bk = bench_sub.add_parser("kinematics", help="arcs propagated and sampled per second")
    bk.add_argument("--out", type=Path, help="write the record as JSON here")
    bk.add_argument("--arcs", type=_positive_int, default=200_000, help="arcs per batch")
    bk.add_argument(
        "--samples", type=_positive_int, default=32, help="points per sampled arc (>= 2)"
    )
    bk.add_argument(
        "--repeat", type=_positive_int, default=5, help="timed repetitions (best is kept)"
    )
    bf = bench_sub.add_parser(
        "fields", help="distance queries per second, field build times (incl. Med-RAD)"
    )
    bf.add_argument("--out", type=Path, help="write the record as JSON here")
    bf.add_argument(
        "--grid", type=_positive_int, default=256, help="edge of the cubic test grids (voxels)"
    )
    bf.add_argument(
        "--queries", type=_positive_int, default=2_000_000, help="points per timed query batch"
    )
    bf.add_argument(
        "--repeat", type=_positive_int, default=3, help="timed repetitions (best is kept)"
    )
    bf.add_argument(
        "--patients",
        type=_positive_int,
        nargs="+",
        default=[1],
        help="Med-RAD lung patients to load (default 1)",
    )
    bf.add_argument(
        "--medrad",
        type=Path,
        help="Med-RAD folder (default $NEEDLEKIT_MEDRAD or ../shared/data/med-rad)",
    )
    bs = bench_sub.add_parser(
        "steerable",
        help="curved-needle planners on the Med-RAD lungs (status, cost, time per case)",
    )
    bs.add_argument("--out", type=Path, help="write the record as JSON here")
    bs.add_argument(
        "--patients",
        type=_positive_int,
        nargs="+",
        default=[1, 2, 3, 4, 5],
        help="lung patients (default 1-5)",
    )
    bs.add_argument(
        "--radii",
        type=_positive,
        nargs="+",
        default=[50.0, 100.0],
        help="r_min values in mm (default 50 100)",
    )
    bs.add_argument(
        "--planners",
        nargs="+",
        default=["rcs_star", "rcs", "rrt"],
        choices=["rcs_star", "rcs", "rrt"],
        help="planners (default all three)",
    )
    bs.add_argument(
        "--time-limit-s",
        type=_positive,
        default=1.0,
        help="budget per case and planner (default 1 s)",
    )
    bs.add_argument(
        "--medrad",
        type=Path,
        help="Med-RAD folder (default $NEEDLEKIT_MEDRAD or ../shared/data/med-rad)",
    )
    return parser


# ---------------------------------------------------------------------------------------


def _start_pose(path: Path | None) -> np.ndarray:
    if path is None:
        return np.eye(4)
    from needlekit.io.poses import read_pose_txt

    return read_pose_txt(path)


def _fmt_table(headers: Sequence[str], rows: Sequence[Sequence[object]]) -> str:
    def cell(v: object) -> str:
        if isinstance(v, float):
            return "inf" if math.isinf(v) else f"{v:.4f}"
        return str(v)

    def numeric(text: str) -> bool:
        try:
            float(text)
        except ValueError:
            return text in ("-", "inf")
        return True

    text = [[cell(v) for v in row] for row in rows]
    widths = [
        max(len(h), *(len(r[i]) for r in text)) if text else len(h) for i, h in enumerate(headers)
    ]
    # text columns align left, numbers right
    left = [bool(text) and not all(numeric(r[i]) for r in text) for i in range(len(headers))]

    def line(cells: Sequence[str]) -> str:
        return "  ".join(
            c.ljust(w) if lft else c.rjust(w) for c, w, lft in zip(cells, widths, left, strict=True)
        ).rstrip()

    lines = [line(headers), "  ".join("-" * w for w in widths)]
    lines.extend(line(r) for r in text)
    return "\n".join(lines)


def _cmd_forward(args: argparse.Namespace) -> int:
    from needlekit.needle.bevel3d import propagate_bevel, simulate_bevel

    g0 = _start_pose(args.start_pose)
    segments = np.array(args.segment, dtype=float)
    if np.any(segments[:, 2] < 0):
        raise NeedlekitError("--segment: durations must be >= 0")
    if args.dt_s is None:
        ends = propagate_bevel(g0, segments, args.kappa_per_mm)
        times = np.concatenate([[0.0], np.cumsum(segments[:, 2])])
        poses = ends
    else:
        traj = simulate_bevel(g0, segments, args.kappa_per_mm, dt_s=args.dt_s)
        times, poses = traj.time_s, traj.world_T_tip
    if args.json:
        out = {
            "kappa_per_mm": args.kappa_per_mm,
            "segments": [
                {"u1_mm_s": float(a), "u2_rad_s": float(b), "duration_s": float(c)}
                for a, b, c in segments
            ],
            "time_s": times.tolist(),
            "points_mm": poses[:, :3, 3].tolist(),
            "directions": poses[:, :3, 2].tolist(),
            "final_pose": poses[-1].tolist(),
        }
        print(json.dumps(out, indent=2))
        return EXIT_OK
    rows = [
        [float(t), *(float(v) for v in g[:3, 3]), *(float(v) for v in g[:3, 2])]
        for t, g in zip(times, poses, strict=True)
    ]
    print(_fmt_table(["time_s", "x_mm", "y_mm", "z_mm", "dir_x", "dir_y", "dir_z"], rows))
    print("\nfinal pose (world_T_tip):")
    print(np.array2string(poses[-1], precision=6, suppress_small=True))
    return EXIT_OK


def _cmd_inverse(args: argparse.Namespace) -> int:
    from needlekit.needle.reachability import shortest_arc_line
    from needlekit.needle.transform_method import tm_inverse

    g0 = _start_pose(args.start_pose)
    targets = np.array(args.target, dtype=float)
    sol = tm_inverse(targets, g0, r_min_mm=args.r_min_mm)
    spin = sol.alpha_rad + 0.5 * np.pi  # twist-model spin, see needlekit.conventions
    spin = np.mod(spin + np.pi, 2 * np.pi) - np.pi
    arcline = shortest_arc_line(g0, targets, args.r_min_mm) if args.r_min_mm else None
    records = []
    for i, p in enumerate(targets):
        rec = {
            "target_mm": p.tolist(),
            "alpha_rad": float(sol.alpha_rad[i]),
            "spin_rad": float(spin[i]),
            "radius_mm": None if math.isinf(sol.radius_mm[i]) else float(sol.radius_mm[i]),
            "curvature_per_mm": float(sol.kappa_per_mm[i]),
            "phi_rad": float(sol.phi_rad[i]),
            "length_mm": float(sol.length_mm[i]),
        }
        if arcline is not None:
            rec["shortest_arc_line_mm"] = float(arcline.length_mm[i])
        records.append(rec)
    if args.json:
        print(json.dumps({"r_min_mm": args.r_min_mm, "arcs": records}, indent=2))
        return EXIT_OK
    headers = ["target", "alpha_deg", "spin_deg", "radius_mm", "phi_deg", "length_mm"]
    if arcline is not None:
        headers.append("arc+line_mm")
    rows = []
    for i, rec in enumerate(records):
        row: list[object] = [
            f"{i}",
            math.degrees(rec["alpha_rad"]),
            math.degrees(rec["spin_rad"]),
            float(sol.radius_mm[i]),
            math.degrees(rec["phi_rad"]),
            rec["length_mm"],
        ]
        if arcline is not None:
            row.append(rec["shortest_arc_line_mm"])
        rows.append(row)
    print(_fmt_table(headers, rows))
    return EXIT_OK


def _cmd_schema() -> int:
    from needlekit.io.scenario_schema import SCENARIO_SCHEMA

    print(json.dumps(SCENARIO_SCHEMA, indent=2))
    return EXIT_OK


def _fmt_extent(extent: np.ndarray) -> str:
    if not np.all(np.isfinite(extent)):
        return "unbounded"
    size = extent[1] - extent[0]
    return " x ".join(f"{v:.1f}" for v in size)


def _cmd_scene(args: argparse.Namespace, parser: argparse.ArgumentParser) -> int:
    from needlekit.io.scenario import load_scenario

    if args.scene_command not in ("info", "render"):
        parser.parse_args(["scene", "--help"])
        return EXIT_USAGE
    sc = load_scenario(args.scenario)
    if args.scene_command == "info":
        from needlekit.anatomy.summary import summarize_scene

        rows = summarize_scene(sc.scene)
        if args.json:
            out = {
                "scenario": str(args.scenario),
                "name": sc.name,
                "structures": [r.to_dict() for r in rows],
            }
            print(json.dumps(out, indent=2))
            return EXIT_OK
        print(
            f"scene: {sc.scene.name or sc.name or args.scenario.name}  ({len(rows)} structures, RAS mm)"
        )
        table = [
            [
                r.name,
                r.role,
                r.kind,
                _fmt_extent(r.extent_mm),
                "-" if r.voxel_size_mm is None else " x ".join(f"{v:.2f}" for v in r.voxel_size_mm),
                "inf" if not np.isfinite(r.volume_ml) else f"{r.volume_ml:.2f}",
                f"{r.error_bound_mm:.3f}",
            ]
            for r in rows
        ]
        print(
            _fmt_table(
                ["name", "role", "field", "extent_mm", "voxel_mm", "volume_ml", "error_mm"], table
            )
        )
        if sc.start is not None:
            print(f"start: {sc.start.name} at {np.round(sc.start.point_mm, 2).tolist()} mm")
        if sc.goal is not None:
            print(
                f"goal:  {sc.goal.name} at {np.round(sc.goal.point_mm, 2).tolist()} mm (tolerance {sc.goal.tolerance_mm:g} mm)"
            )
        return EXIT_OK
    from needlekit.report.scene3d import scene_figure, write_scene_html

    starts = None
    if sc.start is not None and sc.start.world_T_tip is not None:
        starts = sc.start.world_T_tip[None]
    elif sc.base is not None and getattr(sc.base, "start_poses", None) is not None:
        starts = sc.base.start_poses
    targets = None if sc.goal is None else sc.goal.point_mm[None]
    fig = scene_figure(sc.scene, start_poses=starts, targets_mm=targets, max_cells=args.max_cells)
    print(write_scene_html(fig, args.out))
    return EXIT_OK


def _problem_and_obstacles(args: argparse.Namespace):
    from needlekit.io.scenario import load_scenario
    from needlekit.planning.steerable.problem import SteerableProblem

    sc = load_scenario(args.scenario)
    overrides: dict = {}
    if args.start_pose is not None:
        from needlekit.io.poses import read_pose_txt

        overrides["start_pose"] = read_pose_txt(args.start_pose)
        overrides["start_point_mm"] = None
    if args.goal is not None:
        overrides["goal_mm"] = np.array(args.goal)
    if args.r_min_mm is not None:
        overrides["r_min_mm"] = args.r_min_mm
    if args.needle_diameter_mm is not None:
        overrides["needle_diameter_mm"] = args.needle_diameter_mm
    if sc.start is None and "start_pose" not in overrides:
        raise NeedlekitError(
            f"{args.scenario.name}: start: the scenario gives no start; pass --start-pose"
        )
    if sc.goal is None and "goal_mm" not in overrides:
        raise NeedlekitError(f"{args.scenario.name}: goal: the scenario gives no goal; pass --goal")
    if sc.start is None or sc.goal is None:  # fill what the scenario lacks
        from needlekit.io.scenario import GoalSpec, StartSpec

        start = sc.start or StartSpec(
            overrides["start_pose"][:3, 3], overrides["start_pose"], "--start-pose"
        )
        goal = sc.goal or GoalSpec(overrides["goal_mm"], 1.0, "--goal")
        sc = type(sc)(
            sc.name, sc.description, sc.scene, sc.needle, start, goal, sc.planner, sc.path, sc.base
        )
    problem = SteerableProblem.from_scenario(sc, **overrides)
    obstacles = None
    if hasattr(sc.base, "voxel_obstacles"):  # Med-RAD: the reference's exact voxel-centre test
        obstacles = sc.base.voxel_obstacles(problem.needle_diameter_mm, problem.safety_margin_mm)
    return sc, problem, obstacles


def _cmd_plan(args: argparse.Namespace) -> int:
    from needlekit.io.plans import write_plan_json
    from needlekit.planning.steerable.solve import solve

    sc, problem, obstacles = _problem_and_obstacles(args)
    planner = args.planner or sc.planner.get("name") or "rcs_star"
    budget = args.time_limit_s or sc.planner.get("time_limit_s") or 1.0
    seed = args.seed if args.seed is not None else sc.planner.get("seed")
    res = solve(problem, planner, time_limit_s=budget, obstacles=obstacles, seed=seed)
    write_plan_json(args.out, res, scenario=str(args.scenario))
    cost = "no plan" if not res.status.has_plan else f"cost {res.cost_mm:.4f} mm"
    cert = ", certified optimal at the finest resolution" if res.stats.get("certified") else ""
    print(f"{planner}: {res.status.value}, {cost}{cert} ({1000 * res.time_s:.1f} ms) -> {args.out}")
    if not res.status.has_plan and res.stats.get("reason"):
        print(f"reason: {res.stats['reason']}")
    return EXIT_OK if res.status.has_plan else 1


def _cmd_sweep(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from needlekit.io.files import write_json
    from needlekit.planning.steerable.sweep import sphere_directions, sweep

    _, problem, obstacles = _problem_and_obstacles(args)
    dirs = sphere_directions(args.directions)
    with tqdm(desc=f"sweep {args.planner}", unit="direction", disable=None) as bar:
        result = sweep(
            problem,
            args.planner,
            directions=dirs,
            time_limit_s=args.time_limit_s,
            obstacles=obstacles,
            seed=args.seed,
            progress=lambda _: bar.update(1),
        )
    write_json(args.out, {"scenario": str(args.scenario), **result.to_dict()})
    st = result.stats

    def mm(v):
        return "-" if v is None else f"{v:.4f}"

    print(
        f"{args.planner}: {st['n_effective']} of {st['n_directions']} directions effective, "
        f"{st['n_solved']} solved; best {mm(st['best_cost_mm'])} mm, mean {mm(st['mean_cost_mm'])} mm, "
        f"cost before the lowest {mm(st['cost_before_lowest_mm'])} mm -> {args.out}"
    )
    return EXIT_OK if st["n_solved"] else 1


def _cmd_verify(args: argparse.Namespace) -> int:
    from needlekit.io.plans import read_plan_json
    from needlekit.planning.steerable.verify import verify_plan

    _, problem, obstacles = _problem_and_obstacles(args)
    plan, _, _ = read_plan_json(args.plan)
    if plan is None:
        raise NeedlekitError(f"{args.plan.name}: primitives: the file holds no plan to verify")
    check = verify_plan(problem, plan, obstacles=obstacles)
    if args.json:
        print(
            json.dumps(
                {"ok": check.ok, "violations": list(check.violations), "metrics": check.metrics},
                indent=2,
            )
        )
    else:
        m = check.metrics
        print(
            f"{'ok' if check.ok else 'VIOLATED'}: length {m['length_mm']:.3f} mm, goal distance "
            f"{m['goal_distance_mm']:.3f} mm, max curvature {m['max_curvature_per_mm']:.5f} /mm, heading change "
            f"{m['max_heading_change_deg']:.2f} deg, min clearance {m['min_clearance_mm']:.3f} mm"
        )
        for v in check.violations:
            print(f"  - {v}")
    return EXIT_OK if check.ok else 1


def _cmd_demo(args: argparse.Namespace) -> int:
    from needlekit.anatomy.phantoms import PHANTOMS, make_phantom
    from needlekit.anatomy.summary import summarize_scene
    from needlekit.io.files import write_json
    from needlekit.report.kinematics import write_kinematics_figures
    from needlekit.report.scene3d import scene_figure, write_scenes_html

    out = Path(args.out)
    paths = write_kinematics_figures(out)
    for p in paths:
        print(p)
    print(out / "demo.json")
    figures, summary = [], {}
    for name in PHANTOMS:  # the built-in default cases
        ph = make_phantom(name)
        print(f"{name} phantom: {len(ph.scene)} structures", file=sys.stderr)
        figures.append(
            (
                f"{name} phantom (seed {ph.seed})",
                scene_figure(
                    ph.scene, start_poses=ph.start_poses, targets_mm=ph.targets_mm, max_cells=110
                ),
            )
        )
        summary[name] = {
            "seed": ph.seed,
            "structures": [r.to_dict() for r in summarize_scene(ph.scene)],
            "start_poses": np.asarray(ph.start_poses).tolist(),
            "targets_mm": np.asarray(ph.targets_mm).tolist(),
        }
    print(write_scenes_html(figures, out / "phantoms.html", title="needlekit built-in phantoms"))
    print(write_json(out / "phantoms.json", summary))
    return EXIT_OK


def _cmd_bench(args: argparse.Namespace, parser: argparse.ArgumentParser) -> int:
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
    elif args.bench_command == "steerable":
        from tqdm import tqdm

        from needlekit.benchmarks.steerable import run_steerable_benchmark

        total = len(args.patients) * 5 * len(args.radii) * len(args.planners)
        with tqdm(total=total, desc="bench steerable", unit="case", disable=None) as bar:
            record = run_steerable_benchmark(
                patients=tuple(args.patients),
                radii_mm=tuple(args.radii),
                planners=tuple(args.planners),
                time_limit_s=args.time_limit_s,
                medrad_dir=args.medrad,
                progress=lambda msg: (bar.set_postfix_str(msg, refresh=False), bar.update(1)),
            )
        for row in record["results"]:
            cost = "-" if row["cost_mm"] is None else f"{row['cost_mm']:.4f}"
            row["name"] = (
                f"lung{row['patient']} s{row['start']} r{row['r_min_mm']:g} {row['planner']}"
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
    else:
        parser.parse_args(["bench", "--help"])
        return EXIT_USAGE
    if args.out is not None:
        from needlekit.io.files import write_json

        write_json(args.out, record)
    print(format_record(record))
    return EXIT_OK


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; returns the exit status."""
    parser = _build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(
        level=logging.WARNING - 10 * min(args.verbose, 2),
        format="%(levelname)s %(name)s: %(message)s",
    )
    try:
        if args.command == "kinematics":
            if args.kin_command == "forward":
                return _cmd_forward(args)
            if args.kin_command == "inverse":
                return _cmd_inverse(args)
            parser.parse_args(["kinematics", "--help"])
        elif args.command == "schema":
            return _cmd_schema()
        elif args.command == "scene":
            return _cmd_scene(args, parser)
        elif args.command == "plan":
            return _cmd_plan(args)
        elif args.command == "sweep":
            return _cmd_sweep(args)
        elif args.command == "verify":
            return _cmd_verify(args)
        elif args.command == "demo":
            return _cmd_demo(args)
        elif args.command == "bench":
            return _cmd_bench(args, parser)
        else:
            parser.print_help()
            return EXIT_USAGE if argv else EXIT_OK
    except NeedlekitError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except BrokenPipeError:  # e.g. `needlekit schema | head`: the reader left early
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        return EXIT_OK
    return EXIT_USAGE


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
