"""The steerable-needle problem definition: defaults, validation, scenarios."""

from pathlib import Path

import numpy as np
import pytest

from needlekit.anatomy.primitives import Sphere
from needlekit.anatomy.scene import Role, Scene, Structure
from needlekit.errors import InvalidInputError
from needlekit.planning.result import PlanStatus
from needlekit.planning.steerable.problem import CostKind, SteerableProblem
from needlekit.scenario.loading import load_scenario
from needlekit.scenario.problems import problem_from_scenario

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"


@pytest.fixture
def scene():
    return Scene(
        [
            Structure("lung", Role.ALLOWED_REGION, Sphere([0, 0, 0], 100.0)),
            Structure("wall", Role.ENTRY_SURFACE, Sphere([0, 0, -60], 10.0)),
            Structure("nodule", Role.TARGET, Sphere([0, 0, 40], 5.0)),
        ]
    )


def test_defaults_and_derived_values(scene):
    g = np.eye(4)
    g[:3, 3] = [0, 0, -50]
    p = SteerableProblem(scene, goal_mm=[0, 0, 40], start_pose=g)
    assert np.allclose(p.start_point_mm, [0, 0, -50])
    assert p.r_min_mm == 50 and p.kappa_max_per_mm == pytest.approx(0.02)
    assert p.goal_tolerance_mm == 1.0 and p.max_length_mm == 150 and p.start_exclusion_mm == 3
    assert p.clearance_margin_mm == pytest.approx(0.5)
    assert p.entry_surface == "wall"  # the scene's entry surface
    assert p.cost is CostKind.PATH_LENGTH
    q = p.with_start_pose(np.eye(4))
    assert np.allclose(q.start_point_mm, 0.0) and q.r_min_mm == p.r_min_mm


def test_start_point_only_for_direction_sweeps(scene):
    p = SteerableProblem(scene, goal_mm=[0, 0, 40], start_point_mm=[0, 0, -50])
    assert p.start_pose is None and np.allclose(p.start_point_mm, [0, 0, -50])


@pytest.mark.parametrize(
    ("kw", "field"),
    [
        ({"goal_mm": [0, np.nan, 0]}, "goal_mm"),
        ({"start_pose": None, "start_point_mm": None}, "start_pose"),
        ({"start_pose": np.diag([2.0, 1, 1, 1])}, "start_pose"),
        ({"r_min_mm": 0.0}, "r_min_mm"),
        ({"goal_tolerance_mm": -1.0}, "goal_tolerance_mm"),
        ({"max_length_mm": np.inf}, "max_length_mm"),
        ({"needle_diameter_mm": 0.0}, "needle_diameter_mm"),
        ({"safety_margin_mm": -0.1}, "safety_margin_mm"),
        ({"min_puncture_angle_deg": 90.0}, "min_puncture_angle_deg"),
        ({"max_heading_change_deg": 0.0}, "max_heading_change_deg"),
        ({"start_exclusion_mm": np.nan}, "start_exclusion_mm"),
        ({"entry_surface": "pleura"}, "entry_surface"),
        ({"cost": "happiness"}, "happiness"),
    ],
)
def test_bad_problems_name_the_field(scene, kw, field):
    base = {"goal_mm": [0, 0, 40], "start_pose": np.eye(4)}
    base.update(kw)
    with pytest.raises((InvalidInputError, ValueError), match=field):
        SteerableProblem(scene, **base)


def test_from_scenario_with_overrides():
    sc = load_scenario(EXAMPLES / "toy.yaml")
    p = problem_from_scenario(sc)
    assert np.allclose(p.goal_mm, [20, 30, 40]) and p.r_min_mm == 50
    assert np.allclose(p.start_pose[:3, 2], np.array([0, 1, 0.3]) / np.linalg.norm([0, 1, 0.3]))
    q = problem_from_scenario(sc, r_min_mm=100.0, needle_diameter_mm=2.0)
    assert q.r_min_mm == 100 and q.clearance_margin_mm == pytest.approx(1.0)


def test_plan_status_knows_which_outcomes_carry_a_plan():
    assert PlanStatus.SOLVED.has_plan and PlanStatus.APPROXIMATE.has_plan
    assert not PlanStatus.INFEASIBLE.has_plan and not PlanStatus.TIMEOUT.has_plan
    assert PlanStatus("invalid_problem") is PlanStatus.INVALID_PROBLEM


def test_deriving_another_goal_or_direction_rebuilds_nothing_and_agrees(monkeypatch):
    # a transbronchial-like start on an airway wall: the entry surface and its normal come
    # from the fields near the start, which a derived problem must not query again
    from dataclasses import replace

    from needlekit.planning.steerable.rcs import solve_rcs

    airway = Sphere([0.0, 0.0, -4.0], 3.5)
    vessel = Sphere([6.0, -10.0, 30.0], 3.0)
    scene = Scene(
        [
            Structure("lung", Role.ALLOWED_REGION, Sphere([0, 0, 30], 120.0)),
            Structure("airway", Role.OBSTACLE, airway),
            Structure("vessel", Role.OBSTACLE, vessel),
        ]
    )
    base = SteerableProblem(
        scene, goal_mm=[0.0, -20.0, 60.0], start_pose=np.eye(4), min_puncture_angle_deg=20.0
    )
    assert base.entry_surface == "airway"
    pose = np.eye(4)
    c, s = np.cos(0.2), np.sin(0.2)
    pose[:3, :3] = [[1, 0, 0], [0, c, -s], [0, s, c]]
    calls = []
    original = SteerableProblem.tissue_normal
    monkeypatch.setattr(
        SteerableProblem, "tissue_normal", lambda self, p: calls.append(1) or original(self, p)
    )
    derived = base.with_start_pose(pose).with_goal([5.0, -15.0, 55.0])
    assert calls == []  # nothing near the start was asked again
    rebuilt = replace(base, start_pose=pose, start_point_mm=None, goal_mm=[5.0, -15.0, 55.0])
    assert calls  # a rebuild asks
    for name in ("entry_surface", "goal_mm", "start_pose", "start_point_mm", "puncture_normal"):
        np.testing.assert_array_equal(getattr(derived, name), getattr(rebuilt, name))
    a = solve_rcs(derived, time_limit_s=60.0, max_iterations=200)
    b = solve_rcs(rebuilt, time_limit_s=60.0, max_iterations=200)
    assert (a.status, a.cost_mm, a.stats["iterations"]) == (
        b.status,
        b.cost_mm,
        b.stats["iterations"],
    )
    with pytest.raises(InvalidInputError, match="goal_mm"):
        base.with_goal([np.nan, 0.0, 0.0])
    with pytest.raises(InvalidInputError, match="start_pose"):
        base.with_start_pose(np.zeros((4, 4)))
    moved = np.eye(4)
    moved[:3, 3] = [0.0, 0.0, 2.0]  # another start point: built again, entry surface too
    assert base.with_start_pose(moved).start_point_mm.tolist() == [0.0, 0.0, 2.0]
