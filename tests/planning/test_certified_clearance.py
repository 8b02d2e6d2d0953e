"""Certified clearance: a plan that touches an obstacle is never approved.

A ball of radius 10 mm segmented on 2 mm voxels is the obstacle (the exact sphere is the
oracle). A 1 mm needle on a line 10.5 mm from its centre touches it: exact clearance 0 mm.
The distance grid built from the mask reads 0.22 mm more there (its stated error bound is
2.1 mm), so a check that does not subtract the bound approves the plan.
"""

import json

import nibabel as nib
import numpy as np
import pytest

from needlekit.anatomy.primitives import Sphere
from needlekit.cli import main
from needlekit.io.plans import write_plan_json
from needlekit.planning.result import PlanStatus
from needlekit.planning.steerable.plan import SteerablePlan
from needlekit.planning.steerable.rcs import solve_rcs
from needlekit.planning.steerable.result import PlanResult
from needlekit.planning.steerable.validity import MotionValidator
from needlekit.planning.steerable.verify import verify_plan
from needlekit.scenario.problems import load_problem

VOXEL_MM = 2.0
BALL_RADIUS_MM = 10.0
#: the needle's axis: parallel to z, 10.5 mm from the centre at 15 degrees from x
AXIS_XY_MM = 10.5 * np.array([np.cos(np.radians(15.0)), np.sin(np.radians(15.0))])
BALL = Sphere([0.0, 0.0, 0.0], BALL_RADIUS_MM)


def _ball_mask():
    idx = np.arange(-12, 13)  # voxel centres -24 .. 24 mm
    centres = np.stack(np.meshgrid(idx, idx, idx, indexing="ij"), -1) * VOXEL_MM
    mask = np.linalg.norm(centres, axis=-1) <= BALL_RADIUS_MM
    affine = np.diag([VOXEL_MM, VOXEL_MM, VOXEL_MM, 1.0])
    affine[:3, 3] = -12 * VOXEL_MM
    return mask, affine


def _exact_clearance(points, radius=0.5):
    """Exact clearance of a needle of that radius from the true ball."""
    return BALL.signed_distance(points) - radius


@pytest.fixture
def scenario(tmp_path):
    mask, affine = _ball_mask()
    nib.save(nib.Nifti1Image(mask.astype(np.uint8), affine), tmp_path / "ball.nii.gz")
    path = tmp_path / "ball.yaml"
    x, y = AXIS_XY_MM.tolist()
    path.write_text(
        "version: 1\n"
        "structures:\n"
        "  - {name: ball, role: obstacle, mask: {path: ball.nii.gz}}\n"
        "needle: {diameter_mm: 1.0, r_min_mm: 50, start_exclusion_mm: 0}\n"
        f"start: {{point_mm: [{x}, {y}, -20], direction: [0, 0, 1]}}\n"
        f"goal: {{point_mm: [{x}, {y}, 20], tolerance_mm: 1.0}}\n"
    )
    return path


def _straight(problem):
    return SteerablePlan(problem.start_pose, np.array([[0.0, 0.0, 39.0]]))


def test_the_plan_touches_the_ball_exactly(scenario):
    _, problem = load_problem(scenario)
    pts = _straight(problem).points_mm(0.01)
    assert _exact_clearance(pts).min() == pytest.approx(0.0, abs=1e-9)
    field = problem.scene.obstacle_field(0.0)
    assert field.error_bound_mm == pytest.approx(2.098, abs=1e-3)
    # the grid reads more than the truth: without its bound the plan would pass
    assert field.signed_distance(pts).min() - 0.5 == pytest.approx(0.223, abs=1e-3)


def test_verify_refuses_the_touching_plan_and_reports_a_certified_bound(scenario):
    _, problem = load_problem(scenario)
    check = verify_plan(problem, _straight(problem))
    assert not check.ok and check.violations[0].startswith("collision: certified clearance")
    m = check.metrics
    assert m["min_clearance_mm"] == pytest.approx(0.223, abs=1e-3)  # what used to approve it
    assert m["certified_clearance_mm"] < 0.0
    assert m["collision_model"] == "field"


def test_the_planners_validity_check_refuses_the_straight_motion(scenario):
    _, problem = load_problem(scenario)
    validator = MotionValidator(problem)
    assert validator.checker.threshold_mm == pytest.approx(
        problem.scene.obstacle_field(0.5).error_bound_mm + 0.25
    )
    assert not validator.motion_valid(problem.start_pose, 0.0, 0.0, 39.0)


def test_needlekit_verify_exits_1_on_the_touching_plan(scenario, tmp_path, capsys):
    _, problem = load_problem(scenario)
    plan = _straight(problem)
    res = PlanResult(
        PlanStatus.SOLVED, "hand", plan, plan.length_mm, 0.0, problem.goal_mm, {}, plan.start_pose
    )
    write_plan_json(tmp_path / "plan.json", res)
    assert main(["verify", str(scenario), str(tmp_path / "plan.json"), "--json"]) == 1
    report = json.loads(capsys.readouterr().out)
    assert not report["ok"] and report["metrics"]["certified_clearance_mm"] < 0


@pytest.mark.slow
def test_rcs_star_plans_around_it_with_exact_clearance(scenario):
    # from a start pointing at the ball's side, the plan must bend away: the exact distance
    # to the voxel cubes (the oracle) stays above the needle radius along the whole path
    _, problem = load_problem(scenario)
    res = solve_rcs(problem, time_limit_s=60.0, max_iterations=3000)
    assert res.status is PlanStatus.SOLVED
    assert res.stats["certified_clearance_mm"] >= 0.0
    exact = _exact_clearance(res.plan.points_mm(0.01)).min()
    assert exact >= res.stats["certified_clearance_mm"] > 0.0
    assert res.cost_mm > 39.0  # longer than the straight line it may not take
