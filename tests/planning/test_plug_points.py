"""Plug points of the steerable core: a collision checker written outside needlekit runs
through planning, the plan check and a sweep; a cost objective declares the bound RCS*
certifies with (and RCS* says why it cannot certify without one)."""

import math

import numpy as np
import pytest

from needlekit.anatomy.collision import (
    ClearanceCertificate,
    CollisionChecker,
    collision_checker_names,
    make_collision_checker,
    register_collision_checker,
    unregister_collision_checker,
)
from needlekit.anatomy.primitives import Capsule, Sphere
from needlekit.anatomy.scene import Role, Scene, Structure
from needlekit.errors import InvalidInputError
from needlekit.planning.result import PlanStatus
from needlekit.planning.steerable.cost import CostObjective, PathLength
from needlekit.planning.steerable.problem import SteerableProblem
from needlekit.planning.steerable.rcs import solve_rcs
from needlekit.planning.steerable.solve import solve
from needlekit.planning.steerable.sweep import sweep
from needlekit.planning.steerable.verify import verify_plan

GOAL = np.array([0.0, -20.0, 60.0])
BALL_CENTRE, BALL_RADIUS = np.array([0.0, -8.0, 31.0]), 3.0


class ExactBall:
    """A user's checker: one ball obstacle, exact distances, no field at all."""

    name = "exact_ball"
    reads_scene = False

    def __init__(self, setup):
        self.centre = np.asarray(setup.options["centre"], dtype=float)
        self.keep = setup.options["radius"] + 0.5 * setup.needle_diameter_mm
        self.half_gap = 0.5 * setup.spacing_mm
        self.calls = 0

    def _gap(self, points):
        return np.linalg.norm(points - self.centre, axis=1) - self.keep

    def collides(self, points):
        self.calls += 1
        return bool((self._gap(points) < self.half_gap).any())

    def goal_collides(self, goal_mm):
        return bool(self._gap(np.asarray(goal_mm, float).reshape(1, 3))[0] < 0.0)

    def certify(self, points, spacing_mm):
        gap = self._gap(points)
        sampled = float(gap.min())
        certified = sampled - 0.5 * spacing_mm
        bad = None if certified >= 0.0 else f"collision: {certified:.4f} mm from the ball"
        return ClearanceCertificate(int((gap < 0.5 * spacing_mm).sum()), sampled, certified, bad)

    def connected(self, goal_mm, **limits):
        return None

    def warm_up(self):
        pass


@pytest.fixture
def exact_ball():
    register_collision_checker("exact_ball", ExactBall)
    yield
    unregister_collision_checker("exact_ball")


def _scene(*obstacles):
    structures = [Structure("region", Role.ALLOWED_REGION, Sphere([0, 0, 30], 120.0))]
    structures += [Structure(f"obstacle{i}", Role.OBSTACLE, f) for i, f in enumerate(obstacles)]
    return Scene(structures)


def _problem(scene, **kw):
    return SteerableProblem(scene, goal_mm=GOAL, start_pose=np.eye(4), r_min_mm=50.0, **kw)


def test_a_users_collision_checker_runs_through_plan_verify_and_sweep(exact_ball):
    assert "exact_ball" in collision_checker_names()
    # the scene's own obstacle is elsewhere: only the user's ball is in the way
    scene = _scene(Sphere([40.0, 40.0, 100.0], 2.0))
    options = {"centre": BALL_CENTRE.tolist(), "radius": BALL_RADIUS}
    problem = _problem(scene, collision_model="exact_ball", collision_options=options)
    checker = problem.collision_checker()
    assert isinstance(checker, CollisionChecker) and checker.name == "exact_ball"
    res = solve(problem, "rcs_star", time_limit_s=60.0, max_iterations=400)
    assert res.status is PlanStatus.SOLVED
    assert checker.calls > 0  # the planner asked the user's checker
    check = verify_plan(problem, res.plan)
    assert check.ok and check.metrics["collision_model"] == "exact_ball"
    # independent: every sample of the plan keeps the needle off the ball
    pts = res.plan.points_mm(0.05)
    assert (np.linalg.norm(pts - BALL_CENTRE, axis=1) - BALL_RADIUS - 0.5).min() > 0.0
    # the same problem with the field model ignores the user's ball: the direct connection
    direct = solve(_problem(scene), "rcs_star", time_limit_s=60.0)
    assert direct.cost_mm < res.cost_mm
    assert not verify_plan(problem, direct.plan).ok  # and the user's checker refuses it
    dirs = np.array([[0.0, 0.0, 1.0], [0.0, -0.2, 1.0]])
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    point_problem = SteerableProblem(
        scene,
        goal_mm=GOAL,
        start_point_mm=[0.0, 0.0, 0.0],
        r_min_mm=50.0,
        collision_model="exact_ball",
        collision_options=options,
        entry_normal=[0.0, 0.0, 1.0],
    )
    sw = sweep(point_problem, "rcs_star", directions=dirs, max_iterations=400, time_limit_s=60.0)
    solved = [r for r in sw.results if r.status is PlanStatus.SOLVED]
    assert len(solved) == 2
    for r in solved:
        assert verify_plan(point_problem.with_start_pose(r.start_pose), r.plan).ok


def test_checker_registry_refuses_what_it_cannot_use(exact_ball):
    with pytest.raises(InvalidInputError, match="built-in"):
        register_collision_checker("field", ExactBall)
    with pytest.raises(InvalidInputError, match="already registered"):
        register_collision_checker("exact_ball", ExactBall)
    with pytest.raises(InvalidInputError, match="collision_model"):
        _problem(_scene(), collision_model="no_such_checker")
    register_collision_checker("not_a_checker", lambda setup: object())
    try:
        with pytest.raises(InvalidInputError, match="not a CollisionChecker"):
            _problem(_scene(), collision_model="not_a_checker")
    finally:
        unregister_collision_checker("not_a_checker")
    problem = _problem(_scene(Sphere([40.0, 40.0, 100.0], 2.0)))
    assert make_collision_checker("field", _setup_of(problem)).name == "field"


def _setup_of(problem):
    from needlekit.anatomy.collision import CollisionSetup

    return CollisionSetup(
        problem.scene, problem.needle_diameter_mm, 0.0, problem.start_point_mm, 3.0, 0.5
    )


class Scaled:
    """A cost of ``factor`` per mm, declaring ``bound`` as its lower bound per mm."""

    def __init__(self, factor, bound):
        self.name, self.factor, self.lower_bound_per_mm = "scaled", factor, bound

    def motion_cost(self, pose, spin, kappa, length, spacing_mm=0.5):
        return self.factor * length


def _blocked():
    return _scene(Capsule([-20.0, -8.0, 31.0], [20.0, -8.0, 31.0], 3.0))


def test_a_cost_below_the_length_certifies_with_its_own_bound():
    length = solve_rcs(_problem(_blocked()), time_limit_s=60.0, max_iterations=300)
    half = solve_rcs(
        _problem(_blocked(), cost=Scaled(0.5, 0.5)), time_limit_s=60.0, max_iterations=300
    )
    assert isinstance(Scaled(0.5, 0.5), CostObjective)
    assert half.status is PlanStatus.SOLVED and length.status is PlanStatus.SOLVED
    # proportional costs: the same search order, the same path, half the cost
    assert half.stats["iterations"] == length.stats["iterations"]
    assert half.cost_mm == pytest.approx(0.5 * length.cost_mm, rel=1e-12)
    np.testing.assert_allclose(half.plan.primitives, length.plan.primitives)


def test_a_cost_without_a_bound_is_not_certified_and_says_why():
    free = _scene(Sphere([40.0, 40.0, 100.0], 2.0))
    bounded = solve_rcs(_problem(free, cost=Scaled(2.0, 2.0)), time_limit_s=60.0)
    assert bounded.stats["certified"] and bounded.stats["iterations"] == 5
    unbounded = solve_rcs(
        _problem(free, cost=Scaled(2.0, None)), time_limit_s=60.0, max_iterations=2000
    )
    assert unbounded.status is PlanStatus.SOLVED and not unbounded.stats["certified"]
    assert "no lower bound" in unbounded.stats["not_certified"]
    assert unbounded.cost_mm >= bounded.cost_mm - 1e-9
    with pytest.raises(InvalidInputError, match="lower_bound_per_mm"):
        _problem(free, cost=Scaled(1.0, -1.0))
    assert _problem(free).objective.lower_bound_per_mm == PathLength.lower_bound_per_mm == 1.0
    assert math.isclose(_problem(free, cost="clearance").objective.lower_bound_per_mm, 1.0)


TOY_BALL = """\
version: 1
name: toy lung with a ball only a user's checker knows
structures:
  - {name: lung,   role: allowed_region, ellipsoid: {semi_axes_mm: [80, 60, 100]}}
  - {name: airway, role: obstacle, cylinder: {p0_mm: [0, -20, -90], p1_mm: [0, -20, 90], radius_mm: 8}}
needle: {diameter_mm: 1.0, r_min_mm: 50}
start: {point_mm: [0, -12, 0], direction: [0, 1, 0.3]}
goal: {point_mm: [20, 30, 40], tolerance_mm: 1.0}
planner: {name: rcs_star, time_limit_s: 60.0, seed: 0}
collision_model: exact_ball
collision_options: {centre: [6.0, 14.2, 16.0], radius: 3.0}
"""


def test_a_users_collision_checker_runs_through_the_commands(exact_ball, tmp_path, capsys):
    import json

    from needlekit.cli import main

    scen = tmp_path / "ball.yaml"
    scen.write_text(TOY_BALL)
    plain = tmp_path / "plain.yaml"  # the same scene with the field model: no ball
    plain.write_text(TOY_BALL.split("collision_model:")[0])
    out, out_plain = tmp_path / "plan.json", tmp_path / "plain.json"
    assert main(["plan", str(scen), "--out", str(out), "--max-iterations", "400"]) == 0
    assert main(["plan", str(plain), "--out", str(out_plain), "--max-iterations", "400"]) == 0
    plan, direct = json.loads(out.read_text()), json.loads(out_plain.read_text())
    assert plan["status"] == direct["status"] == "solved"
    assert plan["stats"]["collision_model"] == "exact_ball"
    assert plan["cost_mm"] > direct["cost_mm"]  # the ball costs a detour
    capsys.readouterr()
    assert main(["verify", str(scen), str(out)]) == 0
    assert main(["verify", str(scen), str(out_plain)]) == 1  # through the ball
    assert "collision" in capsys.readouterr().out
    sweep_out = tmp_path / "sweep.json"
    code = main(
        [
            "sweep",
            str(scen),
            "--out",
            str(sweep_out),
            "--directions",
            "6",
            "--max-iterations",
            "200",
        ]
    )
    assert code == 0
    rows = json.loads(sweep_out.read_text())
    assert "exact_ball" in json.dumps(rows)
    scen.with_name("typo.yaml").write_text(TOY_BALL.replace("exact_ball", "exact_bal"))
    assert main(["plan", str(scen.with_name("typo.yaml"))]) == 2
    err = capsys.readouterr().err
    assert "collision_model" in err and "exact_ball" in err and err.count("\n") == 1
