"""``needlekit plan``, ``sweep`` and ``verify``: steerable-needle planning on scenarios."""

from __future__ import annotations

import argparse
import json

import numpy as np

from needlekit.cli._common import EXIT_OK
from needlekit.errors import NeedlekitError


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
