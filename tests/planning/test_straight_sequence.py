"""Several straight needles in sequence (Liu et al. 2016, Fig. 4), and the entry search."""

import numpy as np
import pytest

from needlekit.anatomy.primitives import Capsule, Sphere
from needlekit.anatomy.scene import Role, Scene, Structure
from needlekit.errors import InvalidInputError
from needlekit.geometry.segments import segment_distances
from needlekit.planning.straight.cfrw import cfrw_map
from needlekit.planning.straight.entry import (
    Objective,
    ParametricSurface,
    best_on_map,
    grid_refinement_entry,
    pareto_front,
)
from needlekit.planning.straight.problem import StraightNeedle, StraightProblem
from needlekit.planning.straight.sequence import plan_needles

SKIN_R = 100.0


def _scene():
    return Scene(
        [
            Structure("skin", Role.ENTRY_SURFACE, Sphere([0, 0, 0], SKIN_R)),
            Structure("vessel", Role.OBSTACLE, Capsule([-60, 5, 35], [60, 5, 35], 4.0)),
            Structure("vessel2", Role.OBSTACLE, Capsule([25, -60, 60], [25, 60, 60], 3.0)),
        ]
    )


def _problem(**kw):
    return StraightProblem(_scene(), [0, 0, 0], "skin", StraightNeedle(1.0, 150.0), **kw)


def _sphere_surface():
    # S(u, v): the skin sphere by polar angle u from +z and azimuth v
    def point(u, v):
        u, v = np.broadcast_arrays(np.asarray(u, float), np.asarray(v, float))
        return SKIN_R * np.stack([np.sin(u) * np.cos(v), np.sin(u) * np.sin(v), np.cos(u)], -1)

    def normal(u, v):
        return point(u, v) / SKIN_R

    return ParametricSurface(point, normal, (0.0, np.pi), (-np.pi, np.pi))


@pytest.fixture(scope="module")
def off_centre_map():
    # an off-centre target: the nearest skin point lies straight along +x
    pr = StraightProblem(_scene(), [40.0, -20.0, 10.0], "skin", StraightNeedle(1.0, 150.0),
                         up=[1.0, 0.0, 0.0], theta_range_deg=(0, 80))  # fmt: skip
    return cfrw_map(pr, resolution_deg=1.0)


def test_the_grid_search_agrees_with_the_exhaustive_reference(off_centre_map):
    m = off_centre_map
    ref = best_on_map(m)
    # the shortest trajectory is the skin's nearest point, when it is free: 100 - |target|
    assert ref.length_mm == pytest.approx(SKIN_R - np.linalg.norm(m.problem.target_mm), abs=0.1)
    found = grid_refinement_entry(m, _sphere_surface())
    assert found.length_mm <= ref.length_mm + 1e-6
    best = SKIN_R - np.linalg.norm(m.problem.target_mm)  # the analytic optimum
    assert found.length_mm == pytest.approx(best, abs=1e-6)
    assert found.clearance_mm >= m.problem.gamma_mm
    # Eq. 14: it stops along the surface normal (delta) or on a cell below epsilon
    assert found.normal_angle_deg < 0.01
    by_layer = grid_refinement_entry(m, _sphere_surface(), layer_h_mm=50.0)
    assert by_layer.entry_mm == pytest.approx(found.entry_mm, abs=1e-6)


def test_other_objectives_and_the_pareto_front(off_centre_map):
    m = off_centre_map
    shortest = best_on_map(m, "min_length")
    clearest = best_on_map(m, Objective.MAX_CLEARANCE)
    straight = best_on_map(m, "min_normal_angle")
    assert clearest.clearance_mm == pytest.approx(
        np.nanmax(np.where(m.feasible, m.clearance_mm, np.nan))
    )
    assert straight.normal_angle_deg == pytest.approx(
        np.nanmin(np.where(m.feasible, m.normal_angle_deg, np.nan))
    )
    front = pareto_front(m)
    L = m.length_mm[front[:, 0], front[:, 1]]
    C = m.clearance_mm[front[:, 0], front[:, 1]]
    assert np.all(np.diff(L) >= 0) and np.all(np.diff(C) > 0)  # the trade-off
    assert L[0] == pytest.approx(shortest.length_mm) and C[-1] == pytest.approx(
        clearest.clearance_mm
    )
    # brute force: nothing in the CFRW dominates a point of the front
    feas = np.argwhere(m.feasible)
    fl, fc = m.length_mm[feas[:, 0], feas[:, 1]], m.clearance_mm[feas[:, 0], feas[:, 1]]
    for length, clear in zip(L, C, strict=True):
        assert not np.any((fl <= length) & (fc >= clear) & ((fl < length) | (fc > clear)))


def test_three_needles_clear_each_other_and_the_anatomy():
    targets = np.array([[0.0, 0.0, 0.0], [0.0, -15.0, 0.0], [0.0, -30.0, 0.0]])  # Liu's targets
    plan = plan_needles(_problem(), targets, resolution_deg=3.0)
    assert plan.solved and plan.orders_tried == 6 and len(plan.needles) == 3
    f = _problem().obstacle_field()
    segs = []
    for n in plan.needles:
        e = n.entry
        assert e.clearance_mm >= 1.5 and np.linalg.norm(e.entry_mm) == pytest.approx(
            SKIN_R, abs=1e-3
        )
        t = np.linspace(0.0, 1.0, 20001)[:, None]
        pts = e.target_mm + t * (e.entry_mm - e.target_mm)
        exact = f.signed_distance(pts).min() - 1.0
        assert exact >= e.clearance_mm - 1e-9 and exact >= 1.5  # the oracle
        for tip, entry in segs:  # tubes of radius 1: axes at least 2 + gamma apart
            d = segment_distances(tip, entry, e.target_mm[None], e.entry_mm[None])[0]
            assert d - 2.0 >= 1.5
        if segs:
            assert n.needle_clearance_mm >= 1.5
        segs.append((e.target_mm, e.entry_mm))
    record = plan.to_dict()
    assert record["status"] == "solved" and [n["order"] for n in record["needles"]] == [1, 2, 3]


def test_targets_move_with_the_deformation():
    class Push:
        def displacement(self, points, placed):
            return np.tile([0.0, 0.0, 2.0 * len(placed)], (len(points), 1))

    targets = np.array([[0.0, 0.0, 0.0], [0.0, -15.0, 0.0]])
    plan = plan_needles(_problem(), targets, order=[0, 1], deformation=Push(), resolution_deg=4.0)
    assert plan.solved and plan.orders_tried == 1
    assert plan.needles[0].target_mm.tolist() == [0.0, 0.0, 0.0]
    assert plan.needles[1].target_mm.tolist() == [0.0, -15.0, 2.0]
    assert plan.needles[1].entry.target_mm.tolist() == [0.0, -15.0, 2.0]


def test_a_walled_off_target_says_what_blocks_it():
    scene = Scene(
        [
            Structure("skin", Role.ENTRY_SURFACE, Sphere([0, 0, 0], SKIN_R)),
            Structure("shell", Role.OBSTACLE, Sphere([0, 0, 0], 30.0)),
        ]
    )
    from needlekit.anatomy.fields import ComplementField

    hollow = Scene(
        [scene["skin"], Structure("shell", Role.OBSTACLE, ComplementField(Sphere([0, 0, 0], 20.0)))]
    )
    pr = StraightProblem(hollow, [0, 0, 0], "skin", StraightNeedle(1.0, 150.0))
    plan = plan_needles(pr, [[0.0, 0.0, 0.0]], resolution_deg=10.0)
    assert not plan.solved and "no trajectory in its CFRW" in plan.reason
    assert (
        plan.needles[0].blocked["clearance"]
        == plan.needles[0].blocked["free"] + plan.needles[0].blocked["clearance"]
    )
    with pytest.raises(InvalidInputError, match="order"):
        plan_needles(_problem(), [[0.0, 0, 0], [0, -15.0, 0]], order=[0, 0])


def test_capped_queries_of_placed_needles_certify_the_same_clearance():
    # the heads answer far points from their enclosing capsule: below the cap the
    # certified clearance is the same as with exact distances everywhere
    from needlekit.anatomy.needle_body import NeedleBody
    from needlekit.planning.straight.cfrw import segment_clearance_bound
    from needlekit.planning.straight.problem import directions_of

    body = NeedleBody([0.0, 0.0, 0.0], [0.0, 30.0, 95.0], radius_mm=1.0)

    class Exact:  # the same field without capped shortcuts
        error_bound_mm = body.error_bound_mm

        def capped_distance(self, p, cap):
            return body._signed_distance(p)

    rng = np.random.default_rng(3)
    u = directions_of(rng.uniform(0, 1.2, 200), rng.uniform(-np.pi, np.pi, 200), np.eye(4))
    origins = np.tile([0.0, -15.0, 0.0], (200, 1))
    lengths = np.full(200, 100.0)
    fast, _ = segment_clearance_bound(body, origins, u, lengths, cap_mm=12.5)
    slow, _ = segment_clearance_bound(Exact(), origins, u, lengths, cap_mm=12.5)
    assert np.allclose(fast, slow, atol=1e-9)
    assert (fast < 12.5 - 1e-6).sum() > 20  # some segments pass near the needle
