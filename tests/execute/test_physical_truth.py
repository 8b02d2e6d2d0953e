"""The physical truths behind the truth protocol: the rod (``mechanics``) driven by the
loop's commands as duty cycles and solved at 40 Hz, and the rod in the deforming organ
(``physical``)."""

from __future__ import annotations

import math
from dataclasses import replace

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


def test_a_carried_rod_keeps_its_offset_through_its_solves():
    carried, still = MechanicsTruth(_rod(), 50.0), MechanicsTruth(_rod(), 50.0)
    v = np.array([1.0, -2.0, 0.5])
    for i in range(400):  # 20 mm: carried by v at 5 mm, between two solves
        if i == 100:
            carried.step(0.0, 1 / 50.0, 0.05, 0.01)
            carried.carry(v)
            still.step(0.0, 1 / 50.0, 0.05, 0.01)
            continue
        carried.step(0.0, 1 / 50.0, 0.05, 0.025)
        still.step(0.0, 1 / 50.0, 0.05, 0.025)
    assert carried.pose[:3, 3] == pytest.approx(still.pose[:3, 3] + v, abs=1e-12)
    assert carried.pose[:3, :3] == pytest.approx(still.pose[:3, :3], abs=1e-12)
    pts = np.asarray(carried.shaft_loads()["points_mm"]) - np.asarray(still.shaft_loads()["points_mm"])
    assert pts == pytest.approx(np.tile(v, (len(pts), 1)), abs=1e-3)


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


def _lung1_straight(medrad_dir):
    """Med-RAD lung 1's physical truth with a straight plan from its start at its target:
    (truth, plan, goal, insertion axis, depth)."""
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
    return truth, plan, goal, z, depth, settings


@pytest.mark.realdata
@pytest.mark.slow
def test_the_tip_pushes_the_lung_target_on(medrad_dir):
    truth, _, goal, z, depth, _ = _lung1_straight(medrad_dir)
    assert truth.target_mm() == pytest.approx(goal, abs=1e-9)
    while truth.inserted_mm < depth - 5.0:  # up to 5 mm short of the target
        truth.step(0.0, 0.0, 0.05, 0.025)
    moved = truth.target_mm() - goal
    # the tip's cutting load pushes the target on, along the insertion
    assert np.linalg.norm(moved) > 0.1 and moved @ z > 0.5 * np.linalg.norm(moved)
    # one way: the needle's path is not carried by its own push, only by breathing
    tip = truth.pose[None, :3, 3]
    assert truth.to_rest(tip) == pytest.approx(tip, abs=1e-12)


@pytest.mark.realdata
@pytest.mark.slow
def test_the_lung_breathes_through_its_mesh_and_a_needle_let_go_rides_with_it(medrad_dir):
    truth, _, goal, _, _, _ = _lung1_straight(medrad_dir)
    d = np.array([0.0, 0.0, -5.0])  # the lung preset's full breath, inferior
    truth.breathe(d)
    moved = truth.target_mm() - goal
    # the pleura moves by w d, w from 0 at the apex to 1 at the base: the target by part of d
    assert 0.5 < moved @ d / (d @ d) < 1.0
    truth.breathe(np.zeros(3))
    while truth.inserted_mm < 20.0:
        truth.step(0.0, 0.0, 0.05, 0.025)
    d0, d1 = np.array([0.0, 0.0, -1.0]), np.array([0.0, 0.0, -4.0])
    truth.breathe(d0)
    here = truth.to_rest(truth.pose[None, :3, 3])
    # the world point is the rest point carried by the organ's breathing, exactly inverted
    back = here + truth.tissue.breathing_field(here, d0)
    assert back == pytest.approx(truth.pose[None, :3, 3], abs=1e-6)
    shift = truth.riding(d0, d1)
    truth.step(0.0, 0.0, 0.0, 0.025)
    truth.carry(shift)
    truth.breathe(d1)
    # let go, the tip rides with the tissue at it: the same point of the lung at rest
    assert truth.to_rest(truth.pose[None, :3, 3]) == pytest.approx(here, abs=1e-5)
    # and that is not the rigid shift of the breathing trace
    assert np.linalg.norm(shift - (d1 - d0)) > 0.1


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
    from needlekit.tissue.compliance import locate
    from needlekit.tissue.fem import organ_boundary

    sc = load_scenario("lung3.yaml", document=lung_scenario_document(3, 0.0, medrad_dir))
    goal = np.asarray(sc.goal.point_mm)
    # A 3 mm plan ending at the target: its corridor is 3 points (9 load cases to solve
    # for, where a 20 mm plan's 15 points took 45). Whether the target is pinned is its
    # tetrahedron's alone: the mesh (the organ body, seeded at the target) and its held
    # nodes do not depend on the corridor, which sets only the loads (C's columns) and
    # the vessels tracked beside it; checked below from the mesh and the boundary.
    pose = np.eye(4)
    pose[:3, 3] = goal - [0.0, 0.0, 3.0]
    plan = SteerablePlan(pose, np.array([[0.0, 0.0, 3.0]]))
    held = tissue_model_for(sc, plan, goal)
    assert held.pinned()["target"] == 1
    assert held.record()["pinned_points"]["target"] == 1
    # the same from the mesh: every node of the target's tetrahedron is a held one
    mesh = held.compliance().mesh
    tet, _, inside = locate(mesh, goal[None])
    assert inside[0] and np.isin(mesh.tets[tet[0]], organ_boundary(mesh, "lung").held).all()
    assert "target" not in tissue_model_for(sc, plan, goal, "sliding").pinned()


@pytest.mark.realdata
@pytest.mark.slow
def test_gated_in_a_breathing_lung_the_needle_cuts_only_while_it_advances(medrad_dir):
    from needlekit.execute.breathing import PRESETS, Policy
    from needlekit.execute.plugins import Models
    from needlekit.execute.run import LoopHooks, execute_plan

    _, plan, goal, _, _, settings = _lung1_straight(medrad_dir)
    settings = replace(settings, models=Models(truth="physical"))
    trace = PRESETS["lung"].trace(np.random.default_rng(3), 400.0)
    runs = {name: execute_plan(plan, goal, 50.0, closed_loop=True, seed=2, settings=settings,
                               hooks=LoopHooks(breathing=Policy(name, trace)))
            for name in ("gate", "ignore")}  # fmt: skip
    gate, ignore = (np.asarray(runs[k].points_rest_mm) for k in ("gate", "ignore"))
    assert len(gate) == len(runs["gate"].points_mm) and len(ignore) == len(runs["ignore"].points_mm)
    # held still in the world while the lung moves (ignore), the tip is mapped back by up
    # to the breathing at it (about 0.6 of the preset's 5 mm there) and sweeps through the
    # tissue besides its insertion; let go between windows (gate), it rides with its
    # tissue, and its rest path is its insertion alone, a point every 0.25 mm
    length = lambda p: float(np.linalg.norm(np.diff(p, axis=0), axis=1).sum())  # noqa: E731
    assert np.max(np.linalg.norm(ignore - np.asarray(runs["ignore"].points_mm), axis=1)) > 2.0
    assert length(ignore) > 1.1 * runs["ignore"].inserted_mm  # measured 1.23
    assert length(gate) == pytest.approx(runs["gate"].inserted_mm, rel=0.03)  # measured 1.017
    assert len(gate) == pytest.approx(runs["gate"].inserted_mm / 0.25, abs=3)
    # the controller knows the belt's motion, not the lung's at the tip: riding, its filter
    # follows the tip sensor, and refuses none of its samples (taking the belt's motion for
    # the tip's, it refused 11-19 per insertion on lung 1 and 75-93 on lung 2)
    assert runs["gate"].guard["rejected"] == {}
