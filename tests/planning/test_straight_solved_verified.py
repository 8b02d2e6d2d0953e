"""Solved means verified, for the straight multi-needle planner: every needle a plan holds
passes verify_multi, which re-derives the planner's certificate from the record and
reports the same clearance (the straight clearance rule of needlekit.constants)."""

import json

import numpy as np
import pytest

from needlekit.anatomy.primitives import Capsule, Sphere
from needlekit.anatomy.scene import Role, Scene, Structure
from needlekit.constants import (
    RECORD_DECIMALS,
    RECORD_ROUNDING_ALLOWANCE_MM,
    STRAIGHT_CHECK_STEP_MM,
    STRAIGHT_NEAR_STEP_MM,
)
from needlekit.planning.interface import Termination
from needlekit.planning.straight.certify import certify_needle, record_point
from needlekit.planning.straight.planner import LiuOptions, LiuPlanner, MultiNeedleProblem
from needlekit.planning.straight.problem import StraightNeedle, StraightProblem
from needlekit.planning.straight.sequence import plan_needles
from needlekit.planning.straight.verify import verify_multi

# the boundary case: skin sphere of radius 100 at the origin, target 50 mm below its top,
# an obstacle sphere 25 mm above the target whose inflated radius is 25 sin(15 deg): the
# direction theta from +z clears it by 25 sin(theta) - rho - r, so theta = 15 deg clears it
# by exactly gamma, and the length to the skin grows with theta
TARGET = np.array([0.0, 0.0, 50.0])
CENTRE = np.array([0.0, 0.0, 75.0])
R_NEEDLE, GAMMA = 0.5, 1.0
RHO = 25.0 * np.sin(np.radians(15.0)) - R_NEEDLE - GAMMA


def _boundary_problem():
    scene = Scene(
        [
            Structure("skin", Role.ENTRY_SURFACE, Sphere([0, 0, 0], 100.0)),
            Structure("nodule", Role.OBSTACLE, Sphere(CENTRE, RHO)),
        ]
    )
    return StraightProblem(scene, TARGET, "skin", StraightNeedle(R_NEEDLE, 150.0), gamma_mm=GAMMA)


def _length(theta):
    c = np.cos(theta)
    return -50.0 * c + np.sqrt(7500.0 + 2500.0 * c * c)


def _record(plan):
    # what the command writes and a reader gets back
    return json.loads(json.dumps(plan.to_dict()))


def test_rule_constants_nest():
    # the dense certificate samples finer than the planner's tracing; the allowance covers
    # moving both ends of a segment by the record's rounding (sqrt(3) / 2 units of the
    # last decimal)
    assert STRAIGHT_CHECK_STEP_MM < STRAIGHT_NEAR_STEP_MM
    assert RECORD_ROUNDING_ALLOWANCE_MM >= np.sqrt(3) * 0.5 * 10.0**-RECORD_DECIMALS


def test_shortest_entry_on_the_boundary():
    problem = _boundary_problem()
    plan = plan_needles(problem, TARGET[None], resolution_deg=1.0)
    assert plan.solved
    e = plan.needles[0].entry
    # 15 deg clears by gamma exactly, and no certificate of a sampled segment reaches the
    # true minimum: the shortest certified entry is the next grid direction, 16 deg
    assert np.degrees(e.theta_rad) == pytest.approx(16.0, abs=1e-9)
    assert e.length_mm == pytest.approx(_length(np.radians(16.0)), abs=1e-5)
    true = 25.0 * np.sin(np.radians(16.0)) - RHO - R_NEEDLE  # 1.42044 mm
    assert true - STRAIGHT_NEAR_STEP_MM / 2 <= e.clearance_mm <= true
    assert e.clearance_mm >= GAMMA + RECORD_ROUNDING_ALLOWANCE_MM
    # the record's points are rounded; the check re-derives the planner's figure exactly
    rec = _record(plan)
    assert rec["needles"][0]["entry_mm"] == record_point(e.entry_mm).tolist()
    check = verify_multi(problem, rec)
    assert check.ok, check.violations
    row = check.metrics["needles"][0]
    assert row["clearance_mm"] == e.clearance_mm == plan.needles[0].to_dict()["clearance_mm"]
    assert row["length_mm"] == e.length_mm
    assert row["dense_clearance_mm"] >= row["planner_samples_clearance_mm"] - 1e-12


def test_the_boundary_direction_itself_fails_the_check():
    # a record of the 15 deg direction clears by exactly gamma: neither certificate proves
    # it (each is strictly below a smooth minimum), so the check refuses it
    problem = _boundary_problem()
    t = np.radians(15.0)
    u = np.array([np.sin(t), 0.0, np.cos(t)])
    entry = record_point(TARGET + _length(t) * u)
    rec = {"needles": [{"order": 1, "target_mm": TARGET.tolist(), "entry_mm": entry.tolist()}]}
    check = verify_multi(problem, rec)
    assert not check.ok
    assert any("below gamma" in v for v in check.violations)
    cert = certify_needle(problem, TARGET, entry)
    assert cert.planner_clearance_mm < cert.dense_clearance_mm < GAMMA
    assert cert.dense_clearance_mm > GAMMA - STRAIGHT_CHECK_STEP_MM / 2 - 1e-5


def _random_problem(seed):
    # two or three targets near the centre of a skin sphere, capsule vessels across their
    # shortest lines (so entries sit on the CFRW boundary), a random safety distance 0-1 mm
    rng = np.random.default_rng(seed)
    targets = rng.uniform(-12, 12, (int(rng.integers(2, 4)), 3))
    parts = [Structure("skin", Role.ENTRY_SURFACE, Sphere([0, 0, 0], 100.0))]
    for i, t in enumerate(targets):
        near = t / np.linalg.norm(t) * 100.0
        mid = t + rng.uniform(0.2, 0.6) * (near - t) + rng.normal(0, 1.0, 3)
        axis = np.cross(near - t, rng.normal(size=3))
        axis /= np.linalg.norm(axis)
        cap = Capsule(mid - 30 * axis, mid + 30 * axis, float(rng.uniform(2, 5)))
        parts.append(Structure(f"vessel{i}", Role.OBSTACLE, cap))
    parts.append(Structure("nodule", Role.OBSTACLE, Sphere(rng.uniform(-30, 30, 3), 6.0)))
    gamma = float(rng.uniform(0, 1))
    needle = StraightNeedle(float(rng.choice([0.5, 1.0])), 150.0)
    return StraightProblem(Scene(parts), targets[0], "skin", needle, gamma_mm=gamma), targets


def test_every_solved_multi_plan_passes_verify_with_the_same_clearance():
    solved = needles = 0
    for seed in range(8):
        problem, targets = _random_problem(seed)
        # through the planner interface, as ``needlekit multi`` plans (a generous budget:
        # a budget stop would only leave the plan unsolved, never unverified)
        planner = LiuPlanner(LiuOptions(resolution_deg=4.0))
        plan = planner.solve(MultiNeedleProblem(problem, targets), Termination(600.0))
        if not plan.solved:
            continue
        solved += 1
        check = verify_multi(problem, _record(plan))
        assert check.ok, (seed, check.violations)
        for row, n in zip(check.metrics["needles"], plan.needles, strict=True):
            needles += 1
            assert row["clearance_mm"] == n.entry.clearance_mm >= problem.gamma_mm
            assert row["length_mm"] == n.entry.length_mm
            if n.order > 1:
                assert row["needle_clearance_mm"] == n.needle_clearance_mm >= problem.gamma_mm
    assert solved >= 5 and needles >= 12
