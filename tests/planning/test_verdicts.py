"""Verdicts a pre-check proves (answered before any search step), nothing silently
dropped, and one collision model per problem giving the same answer on every route."""

import json
import math
from pathlib import Path

import numpy as np
import pytest

from needlekit.anatomy.primitives import Capsule, HalfSpace, Sphere
from needlekit.anatomy.scene import Role, Scene, Structure
from needlekit.cli import main
from needlekit.errors import InvalidInputError
from needlekit.geometry.se3 import pose_from_direction
from needlekit.planning.result import PlanStatus
from needlekit.planning.steerable.problem import SteerableProblem
from needlekit.planning.steerable.solve import solve
from needlekit.planning.steerable.sweep import sweep
from needlekit.scenario.problems import load_problem, problem_from_scenario

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
PLANNERS = ("rcs_star", "rcs", "rrt")


def _scene(*obstacles):
    parts = [Structure("body", Role.ALLOWED_REGION, Sphere([0.0, 0.0, 0.0], 200.0))]
    parts += [Structure(f"o{i}", Role.OBSTACLE, f) for i, f in enumerate(obstacles)]
    return Scene(parts)


def _problem(goal, *obstacles, **kw):
    return SteerableProblem(_scene(*obstacles), goal_mm=goal, start_pose=np.eye(4), **kw)


@pytest.mark.parametrize("planner", PLANNERS)
def test_a_goal_beyond_the_heading_cone_is_infeasible_before_searching(planner):
    p = _problem([0.0, -40.0, 20.0], max_heading_change_deg=45.0)  # 63 deg off the axis
    res = solve(p, planner, time_limit_s=5.0)
    assert res.status is PlanStatus.INFEASIBLE and res.stats["iterations"] == 0
    assert "heading limit of 45 deg" in res.stats["reason"]


@pytest.mark.parametrize("planner", PLANNERS)
def test_a_goal_behind_the_start_is_infeasible_before_searching(planner):
    p = _problem([0.0, 0.0, -40.0])  # 40 mm straight behind, heading limit 90 deg
    res = solve(p, planner, time_limit_s=5.0)
    assert res.status is PlanStatus.INFEASIBLE and res.stats["iterations"] == 0


@pytest.mark.parametrize("planner", PLANNERS)
def test_a_goal_whose_shortest_path_exceeds_l_max_is_infeasible(planner):
    # 90 mm away but 60 degrees to the side: the shortest r_min = 50 path is longer
    goal = 90.0 * np.array([0.0, -np.sin(np.radians(60)), np.cos(np.radians(60))])
    p = _problem(goal, max_length_mm=100.0)
    res = solve(p, planner, time_limit_s=5.0)
    assert res.status is PlanStatus.INFEASIBLE and res.stats["iterations"] == 0
    assert "shortest curvature-bounded path" in res.stats["reason"]


@pytest.mark.parametrize("planner", PLANNERS)
def test_a_goal_inside_the_r_min_torus_is_outside_the_reachable_set(planner):
    p = _problem([0.0, -10.0, 10.0])  # deep inside the turning circle
    res = solve(p, planner, time_limit_s=5.0)
    assert res.status is PlanStatus.INFEASIBLE and "reachable set" in res.stats["reason"]


@pytest.mark.parametrize("planner", PLANNERS)
def test_a_goal_inside_an_obstacle_is_said_so(planner):
    p = _problem([0.0, 0.0, 60.0], Sphere([0.0, 0.0, 60.0], 5.0))
    res = solve(p, planner, time_limit_s=5.0)
    assert res.status is PlanStatus.INVALID_PROBLEM
    assert res.stats["reason"] == "goal lies inside an obstacle (for this needle)"


@pytest.mark.parametrize("planner", PLANNERS)
def test_a_start_direction_below_the_puncture_angle_is_invalid(planner):
    # entry surface: the skin z = 0 of the body z >= 0; the start direction is 10 deg from it
    wall = HalfSpace([0.0, 0.0, 0.0], [0.0, 0.0, -1.0])
    scene = Scene([Structure("skin", Role.ENTRY_SURFACE, wall),
                   Structure("body", Role.ALLOWED_REGION, Sphere([0, 0, 0], 200.0))])  # fmt: skip
    start = pose_from_direction(
        [0.0, 0.0, 0.0], [np.cos(np.radians(10)), 0.0, np.sin(np.radians(10))]
    )
    p = SteerableProblem(
        scene, goal_mm=[50.0, 0.0, 10.0], start_pose=start, min_puncture_angle_deg=20.0
    )
    assert p.puncture_normal == pytest.approx([0.0, 0.0, 1.0])  # into the body
    res = solve(p, planner, time_limit_s=5.0)
    assert res.status is PlanStatus.INVALID_PROBLEM
    assert (
        "10.00 deg with the skin surface, below the minimum puncture angle 20"
        in res.stats["reason"]
    )


def test_an_undefined_entry_normal_is_an_error_not_a_skipped_check():
    # the start sits at the centre of a sphere: the distance gradient vanishes there
    scene = Scene([Structure("airway", Role.OBSTACLE, Sphere([0.0, 0.0, 0.0], 2.0))])
    with pytest.raises(
        InvalidInputError, match="entry_surface: the normal of 'airway' is undefined"
    ):
        SteerableProblem(
            scene, goal_mm=[0, 0, 50.0], start_pose=np.eye(4), min_puncture_angle_deg=20.0
        )
    # a given normal is the documented way out, and it is recorded
    p = SteerableProblem(scene, goal_mm=[0, 0, 50.0], start_pose=np.eye(4),
                         min_puncture_angle_deg=20.0, entry_normal=[0.0, 0.0, 2.0])  # fmt: skip
    assert p.puncture_normal.tolist() == [0.0, 0.0, 1.0]
    assert p.metadata["puncture_normal_source"] == "entry_normal"
    # the lung phantom's start leaves the airway through its wall: the outward normal
    _, lung = load_problem(EXAMPLES / "lung_phantom.yaml")
    assert lung.metadata["puncture_normal_source"] == "outward normal of airways"
    lone = Scene([Structure("body", Role.ALLOWED_REGION, Sphere([0, 0, 0], 200.0))])
    with pytest.raises(
        InvalidInputError, match=r"no entry surface.*min_puncture_angle_deg = 20 cannot"
    ):
        SteerableProblem(
            lone, goal_mm=[0, 0, 50.0], start_pose=np.eye(4), min_puncture_angle_deg=20.0
        )


def test_the_collision_model_is_explicit():
    scene = _scene(Capsule([-5, 10, 30], [5, 10, 30], 2.0))
    with pytest.raises(
        InvalidInputError, match="voxel_obstacles: the voxel_centres collision model needs"
    ):
        SteerableProblem(
            scene, goal_mm=[0, 0, 50.0], start_pose=np.eye(4), collision_model="voxel_centres"
        )
    with pytest.raises(
        InvalidInputError, match="collision_model: expected one of field, voxel_centres"
    ):
        SteerableProblem(scene, goal_mm=[0, 0, 50.0], start_pose=np.eye(4), collision_model="mesh")


def test_a_phantom_scenario_cannot_ask_for_voxel_centres(tmp_path, capsys):
    text = (EXAMPLES / "toy.yaml").read_text() + "collision_model: voxel_centres\n"
    (tmp_path / "toy.yaml").write_text(text)
    assert main(["plan", str(tmp_path / "toy.yaml"), "--out", str(tmp_path / "p.json")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: collision_model: voxel_centres needs obstacle voxels")


def test_verify_works_with_a_half_space_entry_surface(tmp_path, capsys):
    scenario = tmp_path / "wall.yaml"
    scenario.write_text(
        "version: 1\n"
        "structures:\n"
        "  - {name: skin, role: entry_surface, half_space: {point_mm: [0, 0, 0], normal_mm: [0, 0, -1]}}\n"
        "  - {name: body, role: allowed_region, sphere: {center_mm: [0, 0, 60], radius_mm: 100}}\n"
        "  - {name: target, role: target, sphere: {center_mm: [0, 10, 60], radius_mm: 5}}\n"
        "needle: {min_puncture_angle_deg: 30, start_exclusion_mm: 0}\n"
        "start: {point_mm: [0, 0, 0], direction: [0, 0, 1]}\n"
        "goal: {point_mm: [0, 10, 60]}\n"
    )
    out = tmp_path / "plan.json"
    assert main(["plan", str(scenario), "--out", str(out)]) == 0
    capsys.readouterr()
    assert main(["verify", str(scenario), str(out), "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["ok"] and report["metrics"]["puncture_angle_deg"] == pytest.approx(90.0)


def _routes(scenario: Path, tmp_path: Path):
    """(status, cost) through needlekit plan, problem_from_scenario + solve, sweep and bench."""
    out = tmp_path / "plan.json"
    code = main(["plan", str(scenario), "--out", str(out), "--max-iterations", "5000",
                 "--time-limit-s", "60"])  # fmt: skip
    plan = json.loads(out.read_text())
    problem = problem_from_scenario(scenario)
    direct = solve(problem, "rcs_star", time_limit_s=60.0, max_iterations=5000)
    swept = sweep(problem, "rcs_star", directions=[problem.start_pose[:3, 2]],
                  time_limit_s=60.0, max_iterations=5000).results[0]  # fmt: skip
    bench = tmp_path / "bench.json"
    assert main(["bench", "steerable", "--patients", "0", "--scenario", str(scenario),
                 "--planners", "rcs_star", "--out", str(bench)]) == 0  # fmt: skip
    row = json.loads(bench.read_text())["results"][0]
    return code, [
        (plan["status"], round(plan["cost_mm"], 6)),
        (direct.status.value, round(direct.cost_mm, 6)),
        (swept.status.value, round(swept.cost_mm, 6)),
        (row["status"], round(row["cost_mm"], 6)),
    ]


def test_one_scenario_one_verdict_on_every_route_field_model(tmp_path):
    code, answers = _routes(EXAMPLES / "toy.yaml", tmp_path)
    assert code == 0 and answers == [answers[0]] * 4 and answers[0][0] == "solved"


@pytest.mark.realdata
@pytest.mark.slow
def test_one_scenario_one_verdict_on_every_route_voxel_centres(tmp_path):
    code, answers = _routes(EXAMPLES / "medrad_lung1.yaml", tmp_path)
    assert code == 0 and answers == [("solved", 58.257322)] * 4


def _shell_problem(hole: bool):
    """A goal inside a closed shell of obstacle voxels (1 mm), with or without a hole on the
    side facing the start."""
    from needlekit.anatomy.occupancy import VoxelObstacles

    idx = np.arange(-40, 41)
    g = np.stack(np.meshgrid(idx, idx, idx, indexing="ij"), -1).astype(float)
    r = np.linalg.norm(g - [0.0, 0.0, 20.0], axis=-1)
    occ = (r >= 8.0) & (r <= 10.0)
    if hole:  # a 6 mm wide tunnel through the shell toward the start
        occ &= ~((np.hypot(g[..., 0], g[..., 1]) <= 3.0) & (g[..., 2] < 20.0))
    affine = np.eye(4)
    affine[:3, 3] = -40.0
    scene = Scene([Structure("body", Role.ALLOWED_REGION, Sphere([0, 0, 0], 100.0))])
    start = np.eye(4)
    start[:3, 3] = [0.0, 0.0, -30.0]
    obstacles = VoxelObstacles(occ, affine, needle_diameter_mm=1.0)
    return SteerableProblem(scene, goal_mm=[0.0, 0.0, 20.0], start_pose=start,
                            collision_model="voxel_centres", voxel_obstacles=obstacles)  # fmt: skip


@pytest.mark.parametrize("planner", PLANNERS)
def test_a_goal_walled_off_from_the_start_is_proved_infeasible(planner):
    res = solve(_shell_problem(hole=False), planner, time_limit_s=30.0)
    assert res.status is PlanStatus.INFEASIBLE and res.stats["iterations"] == 0
    assert res.stats["reason"].startswith("reachable workspace is not connected to the goal")


@pytest.mark.parametrize("planner", ["rcs_star", "rrt"])
def test_a_tunnel_to_the_goal_keeps_it_reachable(planner):
    # straight down the tunnel: the fill finds the way, and the planners go through it
    res = solve(_shell_problem(hole=True), planner, time_limit_s=60.0, max_iterations=400)
    assert res.status is PlanStatus.SOLVED and res.cost_mm == pytest.approx(49.0, abs=1e-9)


def test_the_connectivity_proof_holds_only_where_samples_are_finer_than_voxels():
    from needlekit.anatomy.voxel_connectivity import goal_connected

    p = _shell_problem(hole=False)
    kw = {"max_length_mm": 150.0, "goal_tolerance_mm": 1.0, "exclusion_mm": 3.0}
    assert (
        goal_connected(p.voxel_obstacles, p.start_point_mm, p.goal_mm, spacing_mm=0.5, **kw)[0]
        is False
    )
    assert (
        goal_connected(p.voxel_obstacles, p.start_point_mm, p.goal_mm, spacing_mm=1.0, **kw)[0]
        is None
    )


def _pocket_problem(opening: str, max_heading_change_deg: float = 90.0):
    """A goal in a pocket of free space inside a closed shell of obstacle voxels (1 mm),
    opened by a 6 mm wide hole on the side facing the start ("near"), away from it
    ("far"), or not at all ("none"). The start looks at the goal from 50 mm."""
    from needlekit.anatomy.occupancy import VoxelObstacles

    idx = np.arange(-40, 41)
    g = np.stack(np.meshgrid(idx, idx, idx, indexing="ij"), -1).astype(float)
    r = np.linalg.norm(g - [0.0, 0.0, 20.0], axis=-1)
    occ = (r >= 8.0) & (r <= 10.0)
    axis = np.hypot(g[..., 0], g[..., 1]) <= 3.0
    if opening == "near":
        occ &= ~(axis & (g[..., 2] < 20.0))
    elif opening == "far":
        occ &= ~(axis & (g[..., 2] > 20.0))
    affine = np.eye(4)
    affine[:3, 3] = -40.0
    scene = Scene([Structure("body", Role.ALLOWED_REGION, Sphere([0, 0, 0], 100.0))])
    start = np.eye(4)
    start[:3, 3] = [0.0, 0.0, -30.0]
    obstacles = VoxelObstacles(occ, affine, needle_diameter_mm=1.0)
    return SteerableProblem(scene, goal_mm=[0.0, 0.0, 20.0], start_pose=start,
                            collision_model="voxel_centres", voxel_obstacles=obstacles,
                            max_heading_change_deg=max_heading_change_deg)  # fmt: skip


def _connected(p, **limits):
    from needlekit.anatomy.voxel_connectivity import goal_connected

    return goal_connected(
        p.voxel_obstacles, p.start_point_mm, p.goal_mm, max_length_mm=p.max_length_mm,
        goal_tolerance_mm=p.goal_tolerance_mm, exclusion_mm=p.start_exclusion_mm,
        spacing_mm=0.5, **limits,
    )[0]  # fmt: skip


@pytest.mark.parametrize("planner", PLANNERS)
def test_a_pocket_open_only_away_from_the_start_is_proved_sealed(planner):
    # the hole faces away: a path would have to pass the goal and turn back, beyond the
    # 90 deg heading limit; the ellipsoid alone (no limits) still sees the way round
    p = _pocket_problem("far")
    res = solve(p, planner, time_limit_s=30.0, max_iterations=1)
    assert res.status is PlanStatus.INFEASIBLE and res.stats["iterations"] == 0
    assert res.stats["reason"].startswith("reachable workspace is not connected to the goal")
    assert _connected(p) is True
    # a heading limit beyond 90 deg makes the cones no proof: back to the ellipsoid (r 20:
    # the goal, 50 mm away, is past the diameter, so Schur's bound on the length is off)
    wide = _pocket_problem("far", max_heading_change_deg=120.0)
    limits = {"start_direction": wide.start_pose[:3, 2], "r_min_mm": 20.0}
    assert _connected(wide, max_heading_change_deg=120.0, **limits) is True
    assert _connected(wide, max_heading_change_deg=90.0, **limits) is False
    # with the problem's r 50, no valid path is longer than 100 asin(0.51) = 53.5 mm, too
    # short to go round the shell: sealed whatever the heading limit
    limits["r_min_mm"] = wide.r_min_mm
    assert _connected(wide, max_heading_change_deg=120.0, **limits) is False


def test_a_pocket_open_toward_the_start_stays_connected():
    p = _pocket_problem("near")
    limits = {"start_direction": p.start_pose[:3, 2], "r_min_mm": p.r_min_mm,
              "max_heading_change_deg": p.max_heading_change_deg}  # fmt: skip
    assert _connected(p, **limits) is True
    assert _connected(_pocket_problem("none"), **limits) is False
    res = solve(p, "rcs_star", time_limit_s=60.0, max_iterations=400)
    assert res.status is PlanStatus.SOLVED and res.cost_mm == pytest.approx(49.0, abs=1e-9)


def _pinhole_problem(hole_voxels: int, needle_diameter_mm: float = 1.5):
    """The pocket of :func:`_pocket_problem` opened toward the start by a square tunnel
    ``hole_voxels`` wide (1 mm voxels). A 1.5 mm needle keeps 0.75 mm plus the voxels'
    half-diagonal, 1.62 mm, from every obstacle centre: a tunnel one voxel wide leaves
    1 mm, so no valid path enters; one five voxels wide leaves 2 mm."""
    from needlekit.anatomy.occupancy import VoxelObstacles

    idx = np.arange(-40, 41)
    g = np.stack(np.meshgrid(idx, idx, idx, indexing="ij"), -1).astype(float)
    r = np.linalg.norm(g - [0.0, 0.0, 20.0], axis=-1)
    occ = (r >= 8.0) & (r <= 10.0)
    half = hole_voxels // 2
    tunnel = (np.abs(g[..., 0]) <= half) & (np.abs(g[..., 1]) <= half) & (g[..., 2] < 20.0)
    occ &= ~tunnel
    affine = np.eye(4)
    affine[:3, 3] = -40.0
    scene = Scene([Structure("body", Role.ALLOWED_REGION, Sphere([0, 0, 0], 100.0))])
    start = np.eye(4)
    start[:3, 3] = [0.0, 0.0, -30.0]
    obstacles = VoxelObstacles(occ, affine, needle_diameter_mm=needle_diameter_mm)
    return SteerableProblem(scene, goal_mm=[0.0, 0.0, 20.0], start_pose=start,
                            collision_model="voxel_centres", voxel_obstacles=obstacles,
                            needle_diameter_mm=needle_diameter_mm)  # fmt: skip


@pytest.mark.parametrize("planner", PLANNERS)
def test_a_pinhole_the_needle_cannot_pass_is_sealed_by_the_finer_cells(planner):
    # the voxels' own fill passes the one-voxel tunnel (its centres keep 1 mm, more than
    # the 0.73 mm a voxel centre must keep); cells half a voxel wide must keep 1.16 mm and
    # close it. The search runs the finer proof once it has found nothing for a while.
    res = _sealed_only_by_finer_cells(_pinhole_problem(1), planner)
    assert res.stats["iterations"] > 0  # found during the search, not before it


def _sealed_only_by_finer_cells(p, planner):
    """Assert that the voxels' fill connects the goal, cells half a voxel wide do not, and
    the planner answers infeasible with that reason; return its result."""
    limits = {"start_direction": p.start_pose[:3, 2], "r_min_mm": p.r_min_mm,
              "max_heading_change_deg": p.max_heading_change_deg}  # fmt: skip
    assert _connected(p, **limits) is True
    assert _connected(p, subdivide=2, **limits) is False
    res = solve(p, planner, time_limit_s=60.0)
    assert res.status is PlanStatus.INFEASIBLE, (res.status, res.stats.get("reason"))
    assert "cells half a voxel wide" in res.stats["reason"]
    return res


def test_a_tunnel_the_needle_can_pass_stays_connected_at_every_cell_size():
    p = _pinhole_problem(5)
    limits = {"start_direction": p.start_pose[:3, 2], "r_min_mm": p.r_min_mm,
              "max_heading_change_deg": p.max_heading_change_deg}  # fmt: skip
    assert [_connected(p, subdivide=f, **limits) for f in (1, 2, 3)] == [True] * 3
    res = solve(p, "rcs_star", time_limit_s=60.0, max_iterations=2000)
    assert res.status is PlanStatus.SOLVED and res.cost_mm == pytest.approx(49.0, abs=1e-9)


def test_finer_cells_are_free_exactly_where_brute_force_says():
    # _free at a finer cell's index coordinates (between voxel centres) against the
    # distances to every obstacle centre outside the start exclusion
    from needlekit.anatomy.occupancy import voxel_centre
    from needlekit.anatomy.voxel_connectivity import _free

    rng = np.random.default_rng(5)
    occ = rng.random((12, 11, 10)) < 0.08
    affine = np.diag([0.55, 0.6, 0.7, 1.0])
    affine[:3, 3] = [3.0, -2.0, 1.0]
    centres = np.argwhere(occ) @ affine[:3, :3].T + affine[:3, 3]
    start, excl = centres[0] + 0.1, 0.8
    kept = centres[np.linalg.norm(centres - start, axis=1) >= excl]
    for f in (2, 3):
        for _ in range(400):
            ijk = rng.integers(0, (np.array(occ.shape) - 1) * f + 1) / f
            x = np.array(voxel_centre(affine, *ijk))
            free_r = rng.uniform(0.2, 1.5)
            want = bool(np.all(np.linalg.norm(kept - x, axis=1) >= free_r))
            assert _free(occ, affine, *ijk, start, excl, free_r) is want


@pytest.mark.parametrize("opening", ["near", "far", "none"])
def test_the_reached_set_kinds_agree(opening):
    # the fills keep a hash set while small and a flag per voxel after DENSE_AFTER: the
    # verdict and the count of reached voxels do not depend on when (or whether) they
    # switch (the sealed pockets fill past the first cap, so 500 switches between rounds)
    from needlekit.anatomy.voxel_connectivity import FIRST_CAP, goal_connected

    p = _pocket_problem(opening)
    kw = {"max_length_mm": p.max_length_mm, "goal_tolerance_mm": p.goal_tolerance_mm,
          "exclusion_mm": p.start_exclusion_mm, "spacing_mm": 0.5,
          "start_direction": p.start_pose[:3, 2], "r_min_mm": p.r_min_mm,
          "max_heading_change_deg": p.max_heading_change_deg}  # fmt: skip
    args = (p.voxel_obstacles, p.start_point_mm, p.goal_mm)
    answers = {goal_connected(*args, dense_after=n, **kw) for n in (-1, 0, 500, 10**9)}
    assert len(answers) == 1
    verdict, reached = answers.pop()
    assert verdict is (opening == "near")
    assert (reached < FIRST_CAP) if opening == "near" else (reached > FIRST_CAP)


def _random_path(rng, r_min, step=0.02, length=120.0):
    """Points of a random path from the origin along +z: curvature vector normal to the
    tangent, at most 1 / r_min (often the maximum), until the heading passes 90 deg.

    The vectors are kept as three floats each (a step is a handful of arithmetic on them,
    which numpy's small arrays would spend most of their time setting up)."""
    x0 = x1 = x2 = 0.0
    t0, t1, t2 = 0.0, 0.0, 1.0
    pts = [(x0, x1, x2)]
    k0 = k1 = k2 = kappa = 0.0
    for n in range(int(length / step)):
        if n % int(rng.integers(50, 1500)) == 0:  # a new arc: spin and curvature
            k0, k1, k2 = rng.normal(size=3).tolist()
            kappa = min(rng.choice([1.0, rng.uniform()]), 1.0) / r_min
        # the curvature vector: kvec's part normal to the tangent, of length kappa
        dot = k0 * t0 + k1 * t1 + k2 * t2
        a0, a1, a2 = k0 - dot * t0, k1 - dot * t1, k2 - dot * t2
        s = kappa / max(math.sqrt(a0 * a0 + a1 * a1 + a2 * a2), 1e-12)
        u0, u1, u2 = t0 + step * (a0 * s), t1 + step * (a1 * s), t2 + step * (a2 * s)
        norm = math.sqrt(u0 * u0 + u1 * u1 + u2 * u2)
        u0, u1, u2 = u0 / norm, u1 / norm, u2 / norm
        if u2 < 0.0:
            break
        x0, x1, x2 = (
            x0 + step * 0.5 * (t0 + u0),
            x1 + step * 0.5 * (t1 + u1),
            x2 + step * 0.5 * (t2 + u2),
        )
        t0, t1, t2 = u0, u1, u2
        pts.append((x0, x1, x2))
    return np.array(pts)


@pytest.fixture(scope="module")
def region_paths():
    """``(r_min, points, goal, offset)`` of the 90 random paths both cell sizes of
    :func:`test_every_point_of_a_valid_path_lies_in_the_region` walk (the same draws for
    either: made once); ``offset`` is in units of the grid's spacing."""
    rng = np.random.default_rng(7)
    out = []
    for r_min in (20.0, 50.0, 100.0):
        for n in range(30):
            pts = _random_path(rng, r_min, length=120.0 if n % 2 else rng.uniform(20.0, 150.0))
            end = pts[-1] + rng.uniform(-0.5, 0.5, 3)  # a goal within tau of the end
            out.append((r_min, pts, end, rng.uniform(-0.5, 0.5, 3)))
    return out


@pytest.mark.parametrize("subdivide", [1, 2])
def test_every_point_of_a_valid_path_lies_in_the_region(subdivide, region_paths):
    # subdivide 2: the finer proof's cells, half a voxel wide, whose half-diagonal h the
    # region is grown by
    from needlekit.anatomy.voxel_connectivity import _in_region, _region

    spacing = np.array([0.55, 0.55, 0.7]) / subdivide
    h = 0.5 * float(np.linalg.norm(spacing))
    d = np.array([0.0, 0.0, 1.0])
    assert len(region_paths) == 90  # 30 paths for each r_min of 20, 50 and 100 mm
    for r_min, pts, end, unit_offset in region_paths:
        # every part of the region at once: Schur's bound for this goal (where it
        # applies), the cones, the torus and the turn-then-straight bound
        geo = _region(d, r_min, 90.0, 150.0, 1.0, h, 0.25 * 0.5**2, float(np.linalg.norm(end)))
        offset = unit_offset * spacing  # where the grid's centres sit
        cells = np.rint((pts - offset) / spacing) * spacing + offset
        assert np.all(np.linalg.norm(cells - pts, axis=1) <= h + 1e-12)
        inside = [_in_region(c[0], c[1], c[2], np.zeros(3), d, end, geo) for c in cells]
        assert all(inside), (r_min, int(np.argmin(inside)))
        # and the points themselves keep r_min from the torus's circle of centres
        a, b = pts[:, 2], np.hypot(pts[:, 0], pts[:, 1])
        assert np.all(np.hypot(a, b - r_min) >= r_min - 1e-6)


@pytest.mark.parametrize(("r_min", "l_max"), [(35.0, 100.0), (50.0, 150.0), (100.0, 150.0)])
def test_no_valid_path_is_longer_than_schurs_arc(r_min, l_max):
    # Schur's bound (module notes) on random curvature-bounded paths of every length up to
    # l_max, no heading limit on the region: each path is no longer than the bound for its
    # goal (within tau of its end), and every point within h of it lies in the region
    from needlekit.anatomy.voxel_connectivity import _in_region, _region, longest_path

    rng = np.random.default_rng(11)
    h, tau = 0.6, 1.0
    d = np.array([0.0, 0.0, 1.0])
    shorter = 0
    for _ in range(40):
        pts = _random_path(rng, r_min, length=float(rng.uniform(20.0, l_max)))
        goal = pts[-1] + rng.uniform(-1.0, 1.0, 3) * tau / np.sqrt(3.0)
        bound = longest_path(l_max, r_min, float(np.linalg.norm(goal)), tau)
        length = float(np.linalg.norm(np.diff(pts, axis=0), axis=1).sum())
        assert length <= bound + 1e-9
        shorter += bound < l_max
        geo = _region(d, r_min, 180.0, l_max, tau, h, 0.0, chord_mm=np.linalg.norm(goal))
        step = rng.normal(size=pts.shape)
        moved = pts + step / np.linalg.norm(step, axis=1)[:, None] * h
        inside = [_in_region(c[0], c[1], c[2], np.zeros(3), d, goal, geo) for c in moved]
        assert all(inside), (r_min, int(np.argmin(inside)))
    assert shorter >= 20  # the bound took part (it needs |g - s| + tau < 2 r, l_max short)


def test_schurs_arc_bounds_the_region_to_a_thin_ellipsoid():
    # a goal 60 mm ahead, r 50: no valid path is longer than the arc of radius 50 over the
    # chord, 100 asin(0.6) = 64.35 mm (the arc itself is one), so the region is the
    # ellipsoid of that focal sum: 11.6 mm wide at its middle where l_max = 150 mm allows 70
    from needlekit.anatomy.voxel_connectivity import _in_region, _region, longest_path

    goal, d = np.array([0.0, 0.0, 60.0]), np.array([0.0, 0.0, 1.0])
    arc = 100.0 * np.arcsin(0.6)
    assert longest_path(150.0, 50.0, 60.0, 0.0) == pytest.approx(arc, abs=1e-3)  # slacks
    geo = _region(d, 50.0, 180.0, 150.0, 0.0, 0.0, 0.0, chord_mm=60.0)
    half = np.sqrt((arc / 2) ** 2 - 30.0**2)
    assert _in_region(half - 1e-3, 0.0, 30.0, np.zeros(3), d, goal, geo)
    assert not _in_region(0.0, half + 1e-3, 30.0, np.zeros(3), d, goal, geo)
    # points of the arc itself lie inside
    for phi in np.linspace(0.0, 2 * np.arcsin(0.6), 9):
        x = 50.0 * np.cos(np.arcsin(0.6)) - 50.0 * np.cos(np.arcsin(0.6) - phi)
        z = 30.0 - 50.0 * np.sin(np.arcsin(0.6) - phi)
        assert _in_region(x, 0.0, z, np.zeros(3), d, goal, geo), phi
    # no bound: a goal past the diameter (r 25), or l_max long enough for a loop past pi r
    assert longest_path(150.0, 25.0, 60.0, 0.0) == 150.0
    assert longest_path(150.0, 30.0, 50.0, 0.0) == 150.0
    assert longest_path(60.0, 30.0, 50.0, 0.0) == pytest.approx(60.0 * np.arcsin(50 / 60), abs=1e-3)


def test_the_turn_then_straight_bound_keeps_the_shortest_path_and_cuts_the_ellipsoid():
    # a goal 80 mm away, 47 deg off the start direction (r 50): every point of its own
    # shortest path (turn on the r circle, then straight) stays in the region, while
    # points of the ellipsoid that no short path passes are cut: a path through them must
    # first turn to them, then reach the goal, longer than Schur's bound allows
    from needlekit.anatomy.voxel_connectivity import _in_region, _region
    from needlekit.needle.reachability import shortest_arc_line

    d, r = np.array([0.0, 0.0, 1.0]), 50.0
    goal = 80.0 * np.array([np.sin(np.radians(47.0)), 0.0, np.cos(np.radians(47.0))])
    geo = _region(d, r, 90.0, 150.0, 1.0, 0.6, 0.25 * 0.5**2, chord_mm=80.0)
    path = shortest_arc_line(np.eye(4), goal[None], r)  # its circle's centre at +x r
    beta, s = float(path.turn_rad[0]), np.linspace(0.0, float(path.length_mm[0]), 200)
    arc, line = s[s <= r * beta] / r, s[s > r * beta] - r * beta
    end = np.array([r - r * np.cos(beta), 0.0, r * np.sin(beta)])
    tangent = np.array([np.sin(beta), 0.0, np.cos(beta)])
    pts = np.vstack([np.stack([r - r * np.cos(arc), 0 * arc, r * np.sin(arc)], 1),
                     end + line[:, None] * tangent])  # fmt: skip
    assert np.linalg.norm(pts[-1] - goal) < 1e-6
    assert all(_in_region(*p, np.zeros(3), d, goal, geo) for p in pts)
    no_bound = geo.copy()
    no_bound[8] = 0.0
    rng = np.random.default_rng(3)
    cand = rng.uniform([-10.0, -30.0, 0.0], [70.0, 30.0, 80.0], (20000, 3))
    kept = np.array([_in_region(*c, np.zeros(3), d, goal, no_bound) for c in cand])
    cut = np.array([not _in_region(*c, np.zeros(3), d, goal, geo) for c in cand[kept]])
    assert kept.sum() > 500 and 0.05 < cut.mean() < 0.95


# Lung 1 targets for which the UNC reference prints "Reachable workspace is not connected to
# the goal!" (rcs_star 0 0 1, r_min 50) and the sound region proves it too (start, target).
_LUNG1_SEALED = [
    (2, [115.2144716035016, 151.41531942429202, 1181.6688017578572]),
    (3, [90.63070592903479, 173.79176685473982, 1167.069244538841]),
    (5, [48.254392417071614, 209.70823312612774, 1232.7625326090133]),
    # from `needlekit bench steerable --patients 1 --radii 50 --planners rcs_star
    # --reference-app PATH --sample-targets 120` (docs/steerable.md): targets 11, 15, 16,
    # 105, 117 (target 37 the reference also refuses: the search's finer proof, below)
    (4, [66.86444091796875, 208.0142059326172, 1287.3471043109894]),
    (1, [87.24334716796875, 184.8813934326172, 1285.947065114975]),
    (1, [113.68084716796875, 150.1821746826172, 1194.9445173740387]),
    (1, [93.30194091796875, 183.7798309326172, 1168.343772649765]),
    (3, [61.35662841796875, 192.5923309326172, 1164.1436550617218]),
    # the same with 40 targets and --target-seed 1: targets 14, 38, 39
    (5, [61.35662841796875, 176.6196746826172, 1149.4432435035706]),
    (3, [79.53240966796875, 182.6782684326172, 1164.1436550617218]),
    (2, [86.14178466796875, 198.6509246826172, 1278.946869134903]),
]


@pytest.mark.realdata
@pytest.mark.parametrize(("start", "target"), _LUNG1_SEALED)
def test_lung_targets_the_reference_finds_sealed_are_proved_infeasible(medrad_lung1, start, target):
    case = medrad_lung1
    p = SteerableProblem(
        case.scene, goal_mm=target, start_pose=case.start(start).world_T_tip, r_min_mm=50.0,
        needle_diameter_mm=1.0, goal_tolerance_mm=1.0, max_length_mm=150.0,
        max_heading_change_deg=90.0, start_exclusion_mm=3.0, collision_model="voxel_centres",
        voxel_obstacles=case.voxel_obstacles(needle_diameter_mm=1.0),
    )  # fmt: skip
    res = solve(p, "rcs_star", time_limit_s=30.0, max_iterations=1)
    assert res.status is PlanStatus.INFEASIBLE and res.stats["iterations"] == 0
    assert res.stats["reason"].startswith("reachable workspace is not connected to the goal")


@pytest.mark.realdata
@pytest.mark.parametrize("planner", PLANNERS)
def test_the_lung_target_only_finer_cells_seal_is_proved_infeasible(medrad_lung1, planner):
    # target 37 of the screening (start 2, 80 mm ahead, 47 deg off the axis): the voxels'
    # fill connects it (the start sits in gaps a voxel wide); cells half a voxel wide close
    # the start in a few hundred cells
    case = medrad_lung1
    p = SteerableProblem(
        case.scene, goal_mm=[48.69, 183.78, 1153.64], start_pose=case.start(2).world_T_tip,
        r_min_mm=50.0, needle_diameter_mm=1.0, goal_tolerance_mm=1.0, max_length_mm=150.0,
        max_heading_change_deg=90.0, start_exclusion_mm=3.0, collision_model="voxel_centres",
        voxel_obstacles=case.voxel_obstacles(needle_diameter_mm=1.0),
    )  # fmt: skip
    _sealed_only_by_finer_cells(p, planner)
