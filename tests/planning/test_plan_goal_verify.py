"""Plans, the goal connection and the independent plan check."""

import numpy as np
import pytest

from needlekit.anatomy.primitives import Capsule, Sphere
from needlekit.anatomy.scene import Role, Scene, Structure
from needlekit.errors import InvalidInputError
from needlekit.geometry.se3 import make_pose, se3_exp
from needlekit.geometry.so3 import rot_x
from needlekit.needle.reachability import shortest_arc_line
from needlekit.planning.steerable.goal import goal_connection
from needlekit.planning.steerable.plan import SteerablePlan
from needlekit.planning.steerable.problem import SteerableProblem
from needlekit.planning.steerable.verify import verify_plan


def test_plan_geometry_and_json():
    plan = SteerablePlan(np.eye(4), [[0.0, 0.02, 25 * np.pi], [np.pi, 0.02, 25 * np.pi]])
    assert plan.length_mm == pytest.approx(50 * np.pi)
    # two quarter circles bending opposite ways: an S-curve, heading +z again at the end
    assert np.allclose(plan.end_pose()[:3, 3], [0, -100, 100], atol=1e-9)
    assert np.allclose(plan.end_pose()[:3, 2], [0, 0, 1], atol=1e-12)
    pts = plan.points_mm(0.5)
    assert np.allclose(pts[0], 0) and np.allclose(pts[-1], plan.end_pose()[:3, 3])
    assert np.linalg.norm(np.diff(pts, axis=0), axis=1).max() <= 0.5 + 1e-12
    d = plan.to_dict()
    assert d["primitives"][1] == {
        "rotation_rad": np.pi,
        "curvature_per_mm": 0.02,
        "length_mm": 25 * np.pi,
    }
    with pytest.raises(InvalidInputError, match="primitives"):
        SteerablePlan(np.eye(4), [[0.0, 0.0, -1.0]])
    assert SteerablePlan(np.eye(4), []).length_mm == 0.0


def test_goal_connection_ends_tau_short_and_is_as_long_as_the_shortest_path_minus_tau():
    rng = np.random.default_rng(0)
    r, tau = 40.0, 1.0
    for _ in range(200):
        g = se3_exp(np.concatenate([rng.normal(0, 30, 3), rng.normal(0, 1, 3)]))
        goal = g[:3, 3] + rng.uniform(-120, 120, 3)
        c = goal_connection(g, goal, r, tau)
        best = shortest_arc_line(g, goal, r)
        end = SteerablePlan(g, c.primitives).end_pose()[:3, 3] if c is not None else None
        if best.reachable[0]:
            assert c is not None
            assert c.length_mm == pytest.approx(
                max(best.length_mm[0] - tau, best.arc_length_mm[0]), abs=1e-9
            )
            assert np.linalg.norm(end - goal) == pytest.approx(c.end_distance_mm, abs=1e-7)
            assert c.end_distance_mm <= tau + 1e-9
        elif c is not None:  # just inside the torus: arc only, ending within tau
            assert c.primitives.shape == (1, 3)
            assert np.linalg.norm(end - goal) <= tau + 1e-9


def test_goal_connection_inside_behind_and_bad_input():
    c = goal_connection(np.eye(4), [0.0, -49.5, 49.9], 50.0, 1.0)  # 0.1 mm inside the circle
    assert c is not None and c.primitives.shape == (1, 3) and c.end_distance_mm < 1.0
    assert goal_connection(np.eye(4), [0.0, -40.0, 10.0], 50.0, 1.0) is None  # deep inside
    assert goal_connection(np.eye(4), [0.0, 0.0, -20.0], 50.0, 1.0) is None  # behind
    with pytest.raises(InvalidInputError, match="r_min_mm"):
        goal_connection(np.eye(4), [0.0, 0.0, 20.0], 0.0, 1.0)


@pytest.fixture
def toy():
    scene = Scene(
        [
            Structure("lung", Role.ALLOWED_REGION, Sphere([0, 0, 0], 200.0)),
            # the start leaves this airway through its wall: the default entry surface
            Structure("airway", Role.OBSTACLE, Sphere([0, 0, -10], 10.0)),
            Structure("vessel", Role.OBSTACLE, Capsule([-30, -30, 40], [30, -30, 40], 3.0)),
        ]
    )
    start = np.eye(4)  # on the airway's surface (top of the ball), heading out along +z
    return scene, start


def test_a_valid_plan_passes_every_check(toy):
    scene, start = toy
    goal = [0.0, 0.0, 80.0]
    prob = SteerableProblem(scene, goal_mm=goal, start_pose=start, min_puncture_angle_deg=20.0)
    v = verify_plan(prob, SteerablePlan(start, [[0.0, 0.0, 79.5]]))
    assert v.ok, v.violations
    assert v.metrics["puncture_angle_deg"] == pytest.approx(90.0)
    assert v.metrics["goal_distance_mm"] == pytest.approx(0.5)


@pytest.mark.parametrize(
    ("primitives", "overrides", "rule"),
    [
        ([[0.0, 0.03, 60.0]], {}, "curvature"),
        ([[0.0, 0.0, 79.5]], {"max_length_mm": 70.0}, "length"),
        ([[0.0, 0.0, 70.0]], {}, "goal"),
        ([[0.0, 0.02, 60.0], [np.pi, 0.02, 60.0]], {"max_heading_change_deg": 45.0}, "heading"),
        ([[0.0, 0.0, 60.0]], {"goal_mm": [0.0, -36.0, 48.0], "aim_at_vessel": True}, "collision"),
    ],
)
def test_each_violation_is_named(toy, primitives, overrides, rule):
    scene, start = toy
    if overrides.pop("aim_at_vessel", False):  # straight through the vessel at (0, -30, 40)
        start = make_pose(rot_x(np.arcsin(0.6)))
    kw = {"goal_mm": [0.0, 0.0, 80.0], "start_pose": start}
    kw.update(overrides)
    prob = SteerableProblem(scene, **kw)
    v = verify_plan(prob, SteerablePlan(start, primitives))
    assert not v.ok
    assert any(msg.startswith(rule) for msg in v.violations), v.violations


def test_puncture_angle_below_alpha_is_a_violation(toy):
    scene, _ = toy
    # leave the airway's top point at 10 degrees from its surface
    start = make_pose(rot_x(np.radians(80.0)))
    prob = SteerableProblem(
        scene, goal_mm=[0, -79.0, 14.0], start_pose=start, min_puncture_angle_deg=20.0
    )
    v = verify_plan(prob, SteerablePlan(start, [[0.0, 0.0, 80.0]]))
    assert any(m.startswith("puncture angle") for m in v.violations)
    assert v.metrics["puncture_angle_deg"] == pytest.approx(10.0, abs=1e-3)
