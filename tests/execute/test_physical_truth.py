"""The physical truths behind the truth protocol: the rod (``mechanics``) driven by the
loop's commands as duty cycles and solved at 40 Hz, and the rod in the deforming organ
(``physical``)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from needlekit.errors import InvalidInputError
from needlekit.execute.physical import MechanicsSettings, MechanicsTruth
from needlekit.mechanics.insertion import MechanicalNeedle


def _rod(**kw):
    m = MechanicsSettings(inhomogeneity=0.0, **kw)
    return MechanicalNeedle(np.eye(4), m.needle_spec(), m.tissue_spec())


def test_the_plans_full_curvature_is_the_bevel_held_and_none_is_straight():
    # a command of 1 / r_min (the planner's) is a duty cycle of 1: the rod's own curvature
    held = MechanicsTruth(_rod(), 50.0)
    direct = _rod()
    for _ in range(400):  # 20 mm, 0.05 mm per loop step
        held.step(0.0, 1 / 50.0, 0.05, 0.025)
        direct.step(0.0, direct.kappa_max_per_mm, 0.05, 0.025)
    assert held.pose == pytest.approx(direct.pose, abs=1e-12)
    straight = MechanicsTruth(_rod(), 50.0)
    for _ in range(400):
        straight.step(0.0, 0.0, 0.05, 0.025)
    assert straight.pose[:3, 3] == pytest.approx([0.0, 0.0, 20.0], abs=1e-9)


def test_pooling_at_forty_hertz_follows_the_rod_stepped_every_command():
    # the loop's 5 ms steps pooled into 25 ms solves, against the rod solved at each step
    pooled, every = MechanicsTruth(_rod(), 50.0), _rod()
    k = every.kappa_max_per_mm
    for i in range(8000):  # 80 mm at 0.01 mm per step, half duty, one spin on the way
        spin = math.pi / 2 if i == 4000 else 0.0
        pooled.step(spin, 0.5 / 50.0, 0.01, 0.005)
        every.step(spin, 0.5 * k, 0.01, 0.005)
    assert pooled.solves == 8000 // 5
    assert pooled.inserted_mm == pytest.approx(80.0)
    # the roll is held over each 25 ms: the two paths part by a fraction of a step's bend
    assert np.linalg.norm(pooled.pose[:3, 3] - every.pose[:3, 3]) < 0.02


def test_between_solves_the_tip_goes_on_along_its_tangent():
    t = MechanicsTruth(_rod(), 50.0)
    for _ in range(5):
        t.step(0.0, 1 / 50.0, 0.01, 0.005)  # one solve
    solved = t.pose.copy()
    t.step(0.0, 1 / 50.0, 0.01, 0.005)
    t.step(0.0, 1 / 50.0, 0.01, 0.005)
    assert t.pose[:3, 3] == pytest.approx(solved[:3, 3] + 0.02 * solved[:3, 2], abs=1e-12)
    assert t.inserted_mm == pytest.approx(0.07)


@pytest.mark.parametrize(
    ("kw", "field"),
    [({"needle": "copper"}, "needle"), ({"tissue": "brain"}, "tissue"),
     ({"prebend_deg": 95.0}, "prebend_deg"), ({"prebend_deg": 10.0, "prebend_length_mm": 0.0},
     "prebend_length_mm"), ({"inhomogeneity": -0.1}, "inhomogeneity"),
     ({"solve_rate_hz": 0.0}, "solve_rate_hz")],
)  # fmt: skip
def test_bad_mechanics_settings_name_their_field(kw, field):
    with pytest.raises(InvalidInputError, match=field):
        MechanicsSettings(**kw)


@pytest.mark.realdata
@pytest.mark.slow
def test_the_tip_pushes_the_lung_target_on(medrad_dir):
    from needlekit.execute.deforming import tissue_model_for
    from needlekit.execute.plugins import TRUTHS, Setup
    from needlekit.execute.run import ExecutionSettings
    from needlekit.planning.steerable.plan import SteerablePlan
    from needlekit.scenario.loading import load_scenario
    from needlekit.studies.execute_lungs import lung_scenario_document

    sc = load_scenario("lung1.yaml", document=lung_scenario_document(1, 0.0, medrad_dir))
    start = sc.start.world_T_tip
    goal = np.asarray(sc.goal.point_mm)
    # straight at the target from the start point: the rod's straight insertion
    z = (goal - start[:3, 3]) / np.linalg.norm(goal - start[:3, 3])
    x = np.cross([0.0, 1.0, 0.0], z)
    x /= np.linalg.norm(x)
    pose = np.eye(4)
    pose[:3, :3] = np.column_stack([x, np.cross(z, x), z])
    pose[:3, 3] = start[:3, 3]
    depth = float(np.linalg.norm(goal - start[:3, 3]))
    plan = SteerablePlan(pose, np.array([[0.0, 0.0, depth]]))
    model = tissue_model_for(sc, plan, goal)
    settings = ExecutionSettings(tissue=model, mechanics=MechanicsSettings(inhomogeneity=0.0))
    truth = TRUTHS.get("physical")(Setup(pose, goal, 50.0, settings, np.random.default_rng(0)))
    assert model.record()["mesh_tetrahedra"] >= 50_000
    assert truth.target_mm() == pytest.approx(goal, abs=1e-9)
    while truth.inserted_mm < depth - 5.0:  # up to 5 mm short of the target
        truth.step(0.0, 0.0, 0.05, 0.025)
    moved = truth.target_mm() - goal
    # the tip's cutting load pushes the target on, along the insertion
    assert np.linalg.norm(moved) > 0.1 and moved @ z > 0.5 * np.linalg.norm(moved)
    # one way: the needle's path is not carried by its own push (no to_rest)
    assert not hasattr(truth, "to_rest")


def test_a_sliding_boundary_is_the_lungs_alone():
    from needlekit.execute.deforming import TissueModel

    with pytest.raises(InvalidInputError, match="boundary_mode"):
        TissueModel("liver", "folder", (0.0, 0.0, 0.0), (0.0, 0.0, 1.0), boundary_mode="sliding")
    with pytest.raises(InvalidInputError, match="boundary_mode"):
        TissueModel("lung", "folder", (0.0, 0.0, 0.0), (0.0, 0.0, 1.0), boundary_mode="slip")


@pytest.mark.realdata
@pytest.mark.slow
def test_lung_3s_sub_pleural_target_is_pinned_by_a_held_pleura_and_moves_when_it_slides(medrad_dir):
    # lung 3's nodule lies 4 mm beneath the pleura, in a tetrahedron of held surface nodes
    from needlekit.execute.deforming import tissue_model_for
    from needlekit.planning.steerable.plan import SteerablePlan
    from needlekit.scenario.loading import load_scenario
    from needlekit.studies.execute_lungs import lung_scenario_document

    sc = load_scenario("lung3.yaml", document=lung_scenario_document(3, 0.0, medrad_dir))
    goal = np.asarray(sc.goal.point_mm)
    pose = np.eye(4)
    pose[:3, 3] = goal - [0.0, 0.0, 20.0]
    plan = SteerablePlan(pose, np.array([[0.0, 0.0, 20.0]]))
    held = tissue_model_for(sc, plan, goal)
    assert held.pinned()["target"] == 1
    assert held.record()["pinned_points"]["target"] == 1
    assert "target" not in tissue_model_for(sc, plan, goal, "sliding").pinned()
