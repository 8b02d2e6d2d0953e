"""Planning among moving obstacles: the motion (analytic), the swept and arrival fields
(brute force over fine time samples), the check of an executed path against obstacles as
they move (a collision a snapshot misses), the continuation problem from inside the
tissue, the re-planning loop against the plan made once at t = 0, the scenario block and
the command line."""

import contextlib
import io
import json
from pathlib import Path

import numpy as np
import pytest

from needlekit.anatomy.primitives import Capsule, Sphere
from needlekit.anatomy.scene import Role, Scene, Structure
from needlekit.cli import main
from needlekit.errors import InvalidInputError
from needlekit.planning.result import PlanStatus
from needlekit.planning.steerable.dynamic import (
    PREDICTIONS,
    DynamicStatus,
    continuation_problem,
    plan_static,
    replan_among_moving,
)
from needlekit.planning.steerable.moving import (
    SWEEP_STEP_MM,
    ArrivalField,
    Motion,
    MovingObstacle,
    certify_execution,
    path_samples,
)
from needlekit.planning.steerable.plan import SteerablePlan
from needlekit.planning.steerable.problem import SteerableProblem
from needlekit.planning.steerable.verify import VERIFY_SLACK, verify_plan
from needlekit.scenario.loading import parse_scenario

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
DATA = Path(__file__).resolve().parents[2] / "src" / "needlekit" / "data"


def _body():
    return Scene([Structure("body", Role.ALLOWED_REGION, Sphere([0.0, 0.0, 0.0], 200.0))])


def _problem(**kw):
    kw = {"goal_mm": [0.0, 0.0, 50.0], "start_pose": np.eye(4), "max_length_mm": 100.0,
          "start_exclusion_mm": 0.0, **kw}  # fmt: skip
    return SteerableProblem(_body(), **kw)


def _drifting_vessel():
    # across the straight path at z = 25 mm, 3.4 mm to its +y side at t = 0, drifting -y
    # at 0.4 mm/s: at 2 mm/s the tip gets there at 12.5 s, when the vessel's axis is 1.6 mm
    # on the other side: within the 1.5 mm radius plus the needle's 0.5 mm
    return MovingObstacle(
        "vessel", Capsule([-10, 3.4, 25], [10, 3.4, 25], 1.5), Motion([0, -0.4, 0])
    )


# -- motion ------------------------------------------------------------------------------


def test_motion_offsets_are_the_drift_plus_the_sinusoid_from_zero():
    m = Motion([0.5, 0.0, -1.0], amplitude_mm=[0.0, 3.0, 0.0], period_s=4.0, phase_deg=90.0)
    t = np.array([0.0, 1.0, 2.0, 4.0])
    # sin(pi t / 2 + pi / 2) - 1 = cos(pi t / 2) - 1: 0, -1, -2, 0
    want = np.array([[0, 0, 0], [0.5, -3.0, -1.0], [1.0, -6.0, -2.0], [2.0, 0.0, -4.0]])
    np.testing.assert_allclose(m.offset_mm(t), want, atol=1e-12)
    np.testing.assert_allclose(m.offset_mm(1.0), want[1], atol=1e-12)


def test_motion_speed_bound_holds_and_is_reached():
    m = Motion([0.3, 0.0, 0.0], amplitude_mm=[0.0, 2.0, 0.0], period_s=3.0)
    t = np.linspace(0.0, 6.0, 600_001)
    speed = np.linalg.norm(np.diff(m.offset_mm(t), axis=0), axis=1) / np.diff(t)
    bound = 0.3 + 2.0 * 2 * np.pi / 3.0
    assert m.max_speed_mm_s == pytest.approx(bound)
    assert speed.max() <= bound  # |v + a w cos| <= |v| + |a| w
    assert speed.max() == pytest.approx(np.hypot(0.3, 2.0 * 2 * np.pi / 3.0), rel=1e-6)
    assert Motion([0, 0, 2.0]).max_speed_mm_s == 2.0


@pytest.mark.parametrize(
    ("kw", "field"),
    [
        ({"amplitude_mm": [1, 0, 0]}, "period_s"),
        ({"amplitude_mm": [1, 0, 0], "period_s": 0.0}, "period_s"),
        ({"velocity_mm_s": [1, 0]}, "velocity_mm_s"),
        ({"velocity_mm_s": [np.nan, 0, 0]}, "velocity_mm_s"),
        ({"phase_deg": np.inf}, "phase_deg"),
    ],
)
def test_bad_motions_name_the_field(kw, field):
    with pytest.raises(InvalidInputError, match=f"^{field}:"):
        Motion(**kw)


def test_an_obstacle_at_a_time_is_the_shape_moved_there():
    ob = MovingObstacle("v", Capsule([-10, 0, 0], [10, 0, 0], 1.5), Motion([0, 2.0, 1.0]))
    moved = Capsule([-10, 5.0, 2.5], [10, 5.0, 2.5], 1.5)  # at t = 2.5 s
    pts = np.random.default_rng(0).uniform(-20, 20, size=(200, 3))
    np.testing.assert_allclose(ob.at(2.5).signed_distance(pts), moved.signed_distance(pts))


# -- swept and arrival fields ------------------------------------------------------------


def test_a_swept_ball_is_the_capsule_of_its_path():
    # a ball moving at constant velocity sweeps the capsule between its places: the oracle
    ob = MovingObstacle("ball", Sphere([0, 0, 0], 2.0), Motion([1.0, 0.5, 0.0]))
    swept = ob.swept(1.0, 5.0)
    exact = Capsule([1.0, 0.5, 0.0], [5.0, 2.5, 0.0], 2.0)
    pts = np.random.default_rng(1).uniform(-10, 15, size=(500, 3))
    d, true = swept.signed_distance(pts), exact.signed_distance(pts)
    outside = true > 0  # a union of balls is exact outside (inside: a bound on depth)
    assert np.all(d[outside] >= true[outside] - 1e-9)
    assert np.all(d[outside] - swept.error_bound_mm <= true[outside] + 1e-9)
    assert swept.error_bound_mm <= 0.5 * SWEEP_STEP_MM + 1e-12


def test_a_swept_breathing_obstacle_matches_brute_force_over_time():
    ob = MovingObstacle(
        "ball", Sphere([0, 0, 0], 1.0), Motion(amplitude_mm=[0, 0, 3.0], period_s=4.0)
    )
    swept = ob.swept(0.5, 2.5)
    pts = np.random.default_rng(2).uniform(-6, 6, size=(300, 3))
    times = np.linspace(0.5, 2.5, 20_001)
    brute = np.min([ob.field.signed_distance(pts - ob.motion.offset_mm(t)) for t in times], axis=0)
    d = swept.signed_distance(pts)
    assert np.all(d >= brute - 1e-9)
    assert np.all(d - swept.error_bound_mm <= brute + 1e-9)


def _random_plan(rng, r_min, length):
    """A random curvature-bounded plan from the identity pose, of total length ``length``."""
    cuts = np.sort(rng.uniform(0, length, size=3))
    lengths = np.diff(np.concatenate([[0.0], cuts, [length]]))
    rows = [[rng.uniform(0, 2 * np.pi), rng.uniform(0, 1 / r_min), ell] for ell in lengths]
    return SteerablePlan(np.eye(4), rows)


def test_the_arrival_window_holds_every_passing_of_curvature_bounded_paths():
    # Schur's comparison: a path of curvature <= 1/R passes a point at chord c from the tip
    # at an arc length between c and 2 R asin(c / 2R) (for lengths up to pi R)
    rng = np.random.default_rng(3)
    ob = MovingObstacle("ball", Sphere([0, 0, 30], 2.0), Motion([0.0, -0.3, 0.0]))
    field = ArrivalField(ob.field, ob.motion, 4.0, [0, 0, 0], 2.0, 50.0, 100.0)
    for _ in range(40):
        plan = _random_plan(rng, 50.0, rng.uniform(5.0, 100.0))
        pts, arcs = path_samples(plan, 0.5)
        lo, hi = field.window_s(pts)
        t_pass = 4.0 + arcs / 2.0
        assert np.all(lo <= t_pass + 1e-9) and np.all(t_pass <= hi + 1e-9)
        # so the field never overstates the clearance at the time the tip passes
        at_pass = ob.field.signed_distance(pts - ob.motion.offset_mm(t_pass))
        assert np.all(field.signed_distance(pts) - field.error_bound_mm <= at_pass + 1e-9)
    # the window is tight near the tip and along a straight line
    lo, hi = field.window_s([[0, 0, 20.0]])
    assert lo[0] == pytest.approx(4.0 + 10.0)
    assert hi[0] - lo[0] == pytest.approx((100 * np.arcsin(0.2) - 20) / 2.0)


# -- the check of an executed path -------------------------------------------------------


def _brute_force_clearance(obstacle, plan, speed, radius, dt=1e-3):
    """The tip's clearance to the moving obstacle, the tip every ``dt`` seconds (placed
    by the plain numpy arc propagation, not the kernels the check uses)."""
    from needlekit.geometry.arcs import propagate_arcs_reference

    poses = [plan.start_pose]
    for spin, kappa, length in plan.primitives:
        poses.append(propagate_arcs_reference(poses[-1], spin, kappa, length))
    ends = np.cumsum(plan.primitives[:, 2])
    times = np.arange(0.0, ends[-1] / speed, dt)
    s = times * speed
    i = np.searchsorted(ends, s, side="right")
    before = np.concatenate([[0.0], ends])[i]
    spin, kappa = plan.primitives[i, 0], plan.primitives[i, 1]
    tips = propagate_arcs_reference(np.array(poses)[i], spin, kappa, s - before)[:, :3, 3]
    d = obstacle.field.signed_distance(tips - obstacle.motion.offset_mm(times))
    return float(d.min()) - radius


def test_a_collision_a_snapshot_misses_is_caught_at_the_times_the_tip_passes():
    p = _problem()
    vessel = _drifting_vessel()
    straight = SteerablePlan(np.eye(4), [[0.0, 0.0, 49.0]])
    # at t = 0 the path is clear of the vessel by 1.4 mm (the snapshot a static plan sees)
    snapshot = SteerableProblem(
        Scene([*_body().structures, Structure("vessel", Role.OBSTACLE, vessel.at(0.0))]),
        goal_mm=[0, 0, 50.0], start_pose=np.eye(4), start_exclusion_mm=0.0,
    )  # fmt: skip
    assert verify_plan(snapshot, straight).ok
    check = certify_execution(p, [vessel], straight, 2.0)
    brute = _brute_force_clearance(vessel, straight, 2.0, 0.5)
    # the tip (0, 0, 2t) and the axis (y = 3.4 - 0.4t, z = 25) are closest where
    # (3.4 - 0.4t)^2 + (25 - 2t)^2 is least, at t = 102.72 / 8.32 s
    t = 102.72 / 8.32
    exact = np.hypot(3.4 - 0.4 * t, 25 - 2 * t) - 2.0
    assert exact == pytest.approx(-0.43107, abs=1e-5)
    assert brute == pytest.approx(exact, abs=1e-5)
    assert not check.ok and "moving obstacle 'vessel'" in check.violations[0]
    m = check.metrics
    assert m["certified_moving_clearance_mm"] <= brute <= m["moving_clearance_mm"] + 1e-9
    first, point = m["per_obstacle"]["vessel"]["first_contact"]
    assert 11.0 < first < t and point[2] == pytest.approx(2.0 * first, abs=1e-6)
    # the vessel swept over the insertion catches it too
    swept = vessel.swept(0.0, 24.5)
    assert swept.signed_distance(path_samples(straight, 0.25)[0]).min() - 0.5 < 0


def test_a_clear_execution_certifies_a_lower_bound_of_the_brute_force_clearance():
    p = _problem()
    vessel = MovingObstacle("vessel", Capsule([-10, 3.4, 25], [10, 3.4, 25], 1.5),
                            Motion([0, -0.05, 0], amplitude_mm=[0, 0, 1.0], period_s=4.0))  # fmt: skip
    straight = SteerablePlan(np.eye(4), [[0.0, 0.0, 49.0]])
    check = certify_execution(p, [vessel], straight, 2.0)
    brute = _brute_force_clearance(vessel, straight, 2.0, 0.5)
    m = check.metrics
    assert check.ok and brute > 0
    assert m["certified_moving_clearance_mm"] <= brute <= m["moving_clearance_mm"] + 1e-6
    assert brute - m["certified_moving_clearance_mm"] < 0.5  # h / 2 (1 + v_max / v) + ...
    # the inserted needle stays in the vessel's way after the tip passed: a lower figure
    assert m["shaft_clearance_mm"] <= brute


def test_an_unevaluable_clearance_is_a_violation():
    class Broken(Sphere):
        def _signed_distance(self, points):
            return np.full(len(points), np.nan)

    ob = MovingObstacle("broken", Broken([0, 0, 30], 1.0), Motion([0, 0, 0]))
    check = certify_execution(_problem(), [ob], SteerablePlan(np.eye(4), [[0, 0, 49.0]]), 2.0)
    assert not check.ok and any("could not be evaluated" in v for v in check.violations)


# -- continuing from inside the tissue ---------------------------------------------------


def test_a_continuation_starts_inside_the_tissue_with_the_budgets_left():
    # the original start punctures the entry surface at 30 degrees or more
    scene = Scene([Structure("skin", Role.ENTRY_SURFACE, Sphere([0, 0, 0], 200.0)),
                   Structure("room", Role.ALLOWED_REGION, Sphere([0, 0, 0], 250.0))])  # fmt: skip
    start = np.eye(4)
    start[:3, 3] = [0.0, 0.0, -200.0]
    p = SteerableProblem(scene, goal_mm=[0, 10, -140.0], start_pose=start,
                         min_puncture_angle_deg=30.0, max_heading_change_deg=60.0,
                         max_length_mm=100.0)  # fmt: skip
    done = SteerablePlan(start, [[np.pi, 1 / 50, 20.0]])  # turns 22.9 deg
    c = continuation_problem(p, done)
    assert c.start_inside and c.min_puncture_angle_deg == 0 and c.entry_surface is None
    assert c.puncture_normal is None and c.start_exclusion_mm == 0
    assert c.max_length_mm == pytest.approx(80.0)
    assert c.max_heading_change_deg == pytest.approx(60.0 - np.degrees(20 / 50), abs=1e-5)
    np.testing.assert_allclose(c.start_pose, done.end_pose())
    # a plan from the tip is not judged by a puncture angle there (the tip points into the
    # tissue at some angle to the skin's surface that means nothing inside)
    rest = SteerablePlan(c.start_pose, [[0.0, 0.0, 10.0]])
    v = verify_plan(c, rest, expected_cost_mm=None)
    assert v.metrics["puncture_angle_deg"] is None
    assert not any("puncture" in s for s in v.violations)
    # and what is inserted plus a continuation within its limits keeps the original limits
    whole = SteerablePlan(start, np.vstack([done.primitives, [[0.0, 1 / 50, 30.0]]]))
    assert np.degrees(50 / 50) > c.max_heading_change_deg  # a further 34.4 deg is too much
    assert verify_plan(p, whole).metrics["max_heading_change_deg"] == pytest.approx(
        np.degrees(50 / 50), abs=1e-6
    )


@pytest.mark.parametrize(
    ("kw", "field"),
    [
        ({"min_puncture_angle_deg": 10.0}, "min_puncture_angle_deg"),
        ({"entry_surface": "body"}, "entry_surface"),
        ({"entry_normal": [0, 0, 1.0]}, "entry_normal"),
        ({"start_inside": "yes"}, "start_inside"),
    ],
)
def test_a_start_inside_the_tissue_refuses_a_puncture(kw, field):
    with pytest.raises(InvalidInputError, match=f"^{field}:"):
        _problem(**{"start_inside": True, **kw})


def test_nothing_left_to_plan_with_is_an_error():
    p = _problem(max_length_mm=30.0)
    with pytest.raises(InvalidInputError, match=r"^executed: nothing left"):
        continuation_problem(p, SteerablePlan(np.eye(4), [[0, 0, 30.0]]))


# -- the loop ----------------------------------------------------------------------------


def test_replanning_reaches_the_goal_where_the_plan_made_at_t0_collides():
    p = _problem()
    vessel = _drifting_vessel()
    res = replan_among_moving(p, [vessel], insertion_speed_mm_s=2.0, step_mm=10.0,
                              max_iterations=300, time_limit_s=60.0, seed=0)  # fmt: skip
    assert res.status is DynamicStatus.REACHED and res.reached and res.check.ok
    assert len(res.cycles) == 5 and res.cycles[-1].advanced_mm <= 10.0
    assert [c.t_s for c in res.cycles] == pytest.approx([0.0, 5.0, 10.0, 15.0, 20.0])
    # an independent look at the executed path: the tip at fine time samples
    brute = _brute_force_clearance(vessel, res.executed, 2.0, 0.5)
    assert 0 <= res.check.metrics["certified_moving_clearance_mm"] <= brute
    assert res.check.metrics["goal_distance_mm"] <= 1.0
    # it passed behind the vessel (the side it left): the shaft stays clear too
    assert res.check.metrics["shaft_clearance_mm"] > 0
    # every cycle's plan passes the check of that cycle's problem (planner or kept), and
    # after the first cycle no puncture is asked of a start inside the tissue
    assert res.cycles[0].result.status is PlanStatus.SOLVED
    assert {c.source for c in res.cycles} <= {"planned", "kept"}
    static, check = res.static
    assert static.status is PlanStatus.SOLVED and not check.ok
    assert "moving obstacle 'vessel'" in check.violations[0]
    again = plan_static(p, [vessel], 2.0, max_iterations=300, time_limit_s=60.0, seed=0)
    assert again[0].cost_mm == static.cost_mm  # same seed, same budget, same plan
    record = json.loads(json.dumps(res.to_dict()))
    assert record["status"] == "reached" and record["static"]["check"]["ok"] is False
    assert len(record["cycles"]) == 5 and record["settings"]["predict"] == "arrival"


def test_knowing_only_where_the_vessel_is_now_gets_squeezed():
    # the vessel keeps drifting toward the side re-planning dodges to: without a prediction
    # of where it will be, the loop runs out of room (the documented limit of snapshots)
    res = replan_among_moving(_problem(), [_drifting_vessel()], insertion_speed_mm_s=2.0,
                              predict="snapshot", max_iterations=300, time_limit_s=60.0,
                              seed=0, compare_static=False)  # fmt: skip
    assert res.status in (DynamicStatus.NO_PLAN, DynamicStatus.UNSAFE)
    assert res.static is None and res.check.ok  # what was inserted is still safe


@pytest.mark.parametrize(
    ("kw", "field"),
    [
        ({"step_mm": 0.0}, "step_mm"),
        ({"insertion_speed_mm_s": -1.0}, "insertion_speed_mm_s"),
        ({"predict": "oracle"}, "predict"),
        ({"lookahead_s": 2.0}, "lookahead_s"),  # only with swept
        ({"predict": "swept", "lookahead_s": -1.0}, "lookahead_s"),
    ],
)
def test_bad_settings_name_the_field(kw, field):
    kw = {"insertion_speed_mm_s": 2.0, **kw}
    with pytest.raises(InvalidInputError, match=f"^{field}:"):
        replan_among_moving(_problem(), [_drifting_vessel()], **kw)


def test_bad_problems_and_obstacles_are_refused_before_planning():
    with pytest.raises(InvalidInputError, match=r"^moving\[0\].name: 'body'"):
        replan_among_moving(_problem(), [MovingObstacle("body", Sphere([0, 0, 9], 1), Motion())],
                            insertion_speed_mm_s=2.0)  # fmt: skip
    with pytest.raises(InvalidInputError, match=r"^moving\[0\]: expected a MovingObstacle"):
        replan_among_moving(_problem(), [Sphere([0, 0, 9], 1)], insertion_speed_mm_s=2.0)
    no_pose = SteerableProblem(_body(), goal_mm=[0, 0, 50.0], start_point_mm=[0, 0, 0])
    with pytest.raises(InvalidInputError, match=r"^start_pose:"):
        replan_among_moving(no_pose, [_drifting_vessel()], insertion_speed_mm_s=2.0)


def test_predictions_are_the_schemas():
    from needlekit.io.scenario_schema import SCENARIO_SCHEMA

    block = SCENARIO_SCHEMA["properties"]["dynamic"]["properties"]["predict"]
    assert tuple(block["enum"]) == PREDICTIONS


# -- scenarios and the command line ------------------------------------------------------


def _doc(**moving):
    return {
        "version": 1,
        "structures": [
            {"name": "body", "role": "allowed_region", "sphere": {"center_mm": [0, 0, 0], "radius_mm": 200}},
            {"name": "vessel", "role": "obstacle", "moving": moving or {"velocity_mm_s": [0.5, 1.0, 0]},
             "capsule": {"p0_mm": [-10, 3.4, 25], "p1_mm": [10, 3.4, 25], "radius_mm": 1.5}},
        ],
        "start": {"point_mm": [0, 0, 0], "direction": [0, 0, 1]},
        "goal": {"point_mm": [0, 0, 50]},
    }  # fmt: skip


def test_a_scenario_moving_block_is_read_in_ras_with_the_static_scene_beside():
    sc = parse_scenario({**_doc(), "frame": "LPS"})
    np.testing.assert_allclose(sc.moving["vessel"]["velocity_mm_s"], [-0.5, -1.0, 0.0])
    assert sc.static_scene.names == ["body"] and "vessel" in sc.scene.names
    assert parse_scenario({**_doc(), "structures": _doc()["structures"][:1]}).static_scene is None


@pytest.mark.parametrize(
    ("moving", "role", "match"),
    [
        ({"amplitude_mm": [0, 0, 1]}, "obstacle", r"structures\[1\].moving.period_s: a sinusoid"),
        ({"period_s": 4.0}, "obstacle", r"structures\[1\].moving.period_s: a period needs"),
        ({"velocity_mm_s": [1, 0, 0]}, "context", r"structures\[1\].moving: only obstacles"),
        ({"speed": 1}, "obstacle", r"structures\[1\].moving: unknown field 'speed'"),
    ],
)
def test_bad_moving_blocks_name_the_field(moving, role, match):
    doc = _doc(**moving)
    doc["structures"][1]["role"] = role
    with pytest.raises(InvalidInputError, match=match):
        parse_scenario(doc)


def test_the_schema_command_shows_the_moving_and_dynamic_blocks(capsys):
    assert main(["schema"]) == 0
    schema = json.loads(capsys.readouterr().out)
    assert "moving" in schema["properties"]["structures"]["items"]["properties"]
    assert "insertion_speed_mm_s" in schema["properties"]["dynamic"]["properties"]


def test_command_line_errors_are_one_line_before_any_anatomy(tmp_path, capsys):
    plain = EXAMPLES / "lung_phantom.yaml"
    moving = DATA / "lung_phantom_moving.yaml"
    out = str(tmp_path / "d.json")
    cases = [
        ([str(plain), "--step-mm", "3", "--out", out], "--step-mm: only goes with --dynamic"),
        ([str(plain), "--dynamic", "--out", out], "--dynamic: lung_phantom.yaml: no structure"),
        ([str(moving), "--dynamic", "--predict", "arrival", "--lookahead-s", "2", "--out", out],
         "lookahead_s: only goes with predict='swept'"),
        ([str(moving), "--dynamic", "--goals", "0,0,0", "1,1,1", "--out", out],
         "--dynamic: plans to the scenario's goal"),
    ]  # fmt: skip
    for argv, message in cases:
        assert main(["plan", *argv]) == 2
        err = capsys.readouterr().err
        assert err.startswith("error: ") and message in err and err.count("\n") == 1
    assert not (tmp_path / "d.json").exists()


@pytest.fixture(scope="module")
def example(tmp_path_factory):
    """``(result, page, stdout)`` of ``plan --dynamic`` on the shipped moving example."""
    d = tmp_path_factory.mktemp("dynamic")
    out, page = d / "dynamic.json", d / "dynamic.html"
    argv = ["plan", str(DATA / "lung_phantom_moving.yaml"), "--dynamic", "--out", str(out),
            "--report", str(page)]  # fmt: skip
    text = io.StringIO()
    with contextlib.redirect_stdout(text):
        assert main(argv) == 0
    return out, page, text.getvalue()


@pytest.mark.slow
def test_the_example_collides_when_planned_once_and_reaches_when_replanned(example):
    out, page, text = example
    assert "reached" in text and "executed open-loop: fails the check" in text
    record = json.loads(out.read_text())
    assert record["status"] == "reached" and record["check"]["ok"]
    assert record["settings"] == {"planner": "rrt", "insertion_speed_mm_s": 2.0, "step_mm": 5.0,
                                  "predict": "arrival", "lookahead_s": None}  # fmt: skip
    metrics = record["check"]["metrics"]
    assert metrics["certified_moving_clearance_mm"] > 0 and metrics["certified_clearance_mm"] > 0
    # the goal as verify judges it (its slack: 1.0000000000000007 mm was measured)
    assert metrics["goal_distance_mm"] <= 1.0 + VERIFY_SLACK and metrics["puncture_angle_deg"] >= 20.0
    static = record["static"]["check"]
    assert not static["ok"] and static["metrics"]["certified_moving_clearance_mm"] < 0
    assert static["metrics"]["certified_clearance_mm"] > 0  # clear of the anatomy at rest
    html = page.read_text()
    assert "plotly" in html and "drifting vessel at t = 0.0 s" in html


@pytest.mark.slow
@pytest.mark.browser
def test_the_example_pages_render_in_a_browser(example, rendered, tmp_path):
    """The page ``plan --dynamic --report`` drew and the one ``report`` draws from its
    result, in headless Chromium: every 3D view drawn, no console warning (``rendered``,
    tests/conftest.py)."""
    out, page, _ = example
    again = tmp_path / "report-dynamic.html"
    with contextlib.redirect_stdout(io.StringIO()):
        assert main(["report", str(out), "--out", str(again)]) == 0
    for path in (page, again):
        plots, pngs = rendered(path)
        assert plots >= 1 and pngs
