"""Every entry the straight family reports as a solution passes the plan check's
certificate (the straight clearance rule of needlekit.constants, as a record holds the
needle): the exhaustive reference (best_on_map, ``needlekit cfrw``'s ``best``), the paper's
grid-refinement search, and ``needlekit approach``'s chosen line; a candidate that fails it
is dropped and the next one taken."""

import json
from dataclasses import replace

import numpy as np
import pytest
import trimesh

from needlekit.anatomy.mesh import ExactMeshDistance
from needlekit.anatomy.primitives import Capsule, Sphere
from needlekit.anatomy.scene import Role, Scene, Structure
from needlekit.planning.straight.approach import approach_analysis
from needlekit.planning.straight.certify import certify_needle, certify_segment, record_point
from needlekit.planning.straight.cfrw import Blocked, cfrw_map
from needlekit.planning.straight.entry import (
    Entry,
    Objective,
    ParametricSurface,
    best_direction,
    best_on_map,
    certified_best,
    grid_refinement_entry,
)
from needlekit.planning.straight.problem import StraightNeedle, StraightProblem
from needlekit.planning.straight.verify import verify_multi

SKIN_R = 100.0


def _sphere_surface():
    # S(u, v): the skin sphere by polar angle u from +z and azimuth v
    def point(u, v):
        u, v = np.broadcast_arrays(np.asarray(u, float), np.asarray(v, float))
        return SKIN_R * np.stack([np.sin(u) * np.cos(v), np.sin(u) * np.sin(v), np.cos(u)], -1)

    return ParametricSurface(
        point, lambda u, v: point(u, v) / SKIN_R, (0.0, np.pi), (-np.pi, np.pi)
    )


def _random_problem(seed):
    # one target near the centre of a skin sphere, a capsule vessel across its shortest
    # line (so the entry sits on the CFRW boundary), a nodule, a safety distance 0-1 mm
    rng = np.random.default_rng(seed)
    t = rng.uniform(-12, 12, 3)
    near = t / np.linalg.norm(t) * SKIN_R
    mid = t + rng.uniform(0.2, 0.6) * (near - t) + rng.normal(0, 1.0, 3)
    axis = np.cross(near - t, rng.normal(size=3))
    axis /= np.linalg.norm(axis)
    parts = [
        Structure("skin", Role.ENTRY_SURFACE, Sphere([0, 0, 0], SKIN_R)),
        Structure("vessel", Role.OBSTACLE, Capsule(mid - 30 * axis, mid + 30 * axis,
                                                   float(rng.uniform(2, 5)))),
        Structure("nodule", Role.OBSTACLE, Sphere(rng.uniform(-30, 30, 3), 6.0)),
    ]  # fmt: skip
    needle = StraightNeedle(float(rng.choice([0.5, 1.0])), 150.0)
    up = near / SKIN_R  # Sigma's z toward the nearest skin point: the search box holds it
    return StraightProblem(Scene(parts), t, "skin", needle, gamma_mm=float(rng.uniform(0, 1)),
                           up=up, theta_range_deg=(0, 70))  # fmt: skip


def _single_record(e: Entry) -> dict:
    # a one-needle multi.json as written and read back
    row = {"order": 1, **e.to_dict()}
    return json.loads(json.dumps({"needles": [row]}))


def _assert_certified(problem, e: Entry):
    # the entry is held as the record holds it, and the certificate of those very points
    # passes with the clearance and length the entry reports
    assert e.entry_mm.tolist() == record_point(e.entry_mm).tolist()
    assert e.target_mm.tolist() == record_point(e.target_mm).tolist()
    cert = certify_needle(problem, e.target_mm, e.entry_mm)
    assert cert.passes(problem.gamma_mm)
    assert cert.clearance_mm == e.clearance_mm and cert.length_mm == e.length_mm
    # written and read back, it is the same trajectory and verify_multi agrees
    back = Entry.from_dict(json.loads(json.dumps(e.to_dict())), "entry")
    assert back.entry_mm.tolist() == e.entry_mm.tolist()
    assert back.clearance_mm == e.clearance_mm
    check = verify_multi(problem, _single_record(e))
    row = check.metrics["needles"][0]
    assert row["clearance_mm"] == e.clearance_mm >= problem.gamma_mm
    assert row["length_mm"] == e.length_mm
    return check


def test_every_reported_entry_passes_the_certificate():
    found = 0
    for seed in range(6):
        problem = _random_problem(seed)
        m = cfrw_map(problem, resolution_deg=6.0)
        for obj in Objective:
            e = best_on_map(m, obj)
            if e is None:
                continue
            found += 1
            check = _assert_certified(problem, e)
            if obj is Objective.MIN_LENGTH:  # the map's own angle limits hold as well
                assert check.ok, (seed, check.violations)
        g = grid_refinement_entry(m, _sphere_surface(), max_iterations=40)
        if g is not None:
            found += 1
            _assert_certified(problem, g)  # (a local search: not always the map's best)
    assert found >= 15


def _boundary_problem():
    # a nodule straight above the target: the shortest line (theta 0) runs through it; the
    # direction theta from +z clears it by 25 sin(theta) - rho - r, gamma exactly at 15 deg
    rho = 25.0 * np.sin(np.radians(15.0)) - 0.5 - 1.0
    scene = Scene([
        Structure("skin", Role.ENTRY_SURFACE, Sphere([0, 0, 0], SKIN_R)),
        Structure("nodule", Role.OBSTACLE, Sphere([0.0, 0.0, 75.0], rho)),
    ])  # fmt: skip
    return StraightProblem(scene, [0.0, 0.0, 50.0], "skin", StraightNeedle(0.5, 150.0),
                           gamma_mm=1.0)  # fmt: skip


def test_the_reference_falls_back_when_a_direction_fails_its_certificate():
    problem = _boundary_problem()
    m = cfrw_map(problem, resolution_deg=1.0)
    honest = best_on_map(m)
    assert np.degrees(honest.theta_rad) == pytest.approx(16.0, abs=1e-9)
    # a map that wrongly calls theta = 0 free (through the nodule) and the shortest: the
    # map's figures pick it, the certificate refuses it and the next best is reported
    blocked = m.blocked.copy()
    blocked[0, 0] = Blocked.FREE
    clearance = m.clearance_mm.copy()
    clearance[0, 0] = 5.0
    wrong = replace(m, blocked=blocked, clearance_mm=clearance)
    assert best_direction(wrong).theta_rad == 0.0
    e, cert, why = certified_best(wrong)
    assert e is not None and why == ""
    assert e.entry_mm.tolist() == honest.entry_mm.tolist()
    assert cert.clearance_mm == e.clearance_mm >= 1.0
    assert certify_needle(problem, record_point(problem.target_mm),
                          record_point([0, 0, SKIN_R])).clearance_mm < 0  # fmt: skip


def test_the_grid_search_refuses_members_that_fail_the_certificate(monkeypatch):
    problem = _boundary_problem()
    m = cfrw_map(problem, resolution_deg=2.0)
    honest = grid_refinement_entry(m, _sphere_surface())
    assert honest.clearance_mm >= 1.0
    # membership that calls every direction clear (theta = 0 through the nodule, the
    # nearest skin point, included): only the certificate keeps the search out of it
    monkeypatch.setattr(type(m), "clearance_of", lambda self, t, p, **kw: np.full(len(t), 9.0))
    e = grid_refinement_entry(m, _sphere_surface())
    _assert_certified(problem, e)
    assert np.degrees(e.theta_rad) > 15.0
    # no certified entry is nearer than the 15 degree one (the true boundary)
    c = np.cos(np.radians(15.0))
    assert e.length_mm >= -50.0 * c + np.sqrt(7500.0 + 2500.0 * c * c)


def test_approach_reports_a_certified_line():
    # seeded skins and obstacle spheres; the chosen line as recorded passes the rule
    for seed in range(3):
        rng = np.random.default_rng(seed)
        skin = trimesh.creation.icosphere(subdivisions=3, radius=60.0)
        balls = []
        for _ in range(3):
            b = trimesh.creation.icosphere(subdivisions=2, radius=float(rng.uniform(4, 8)))
            b.apply_translation(rng.uniform(-30, 30, 3))
            balls.append(b)
        field = ExactMeshDistance(trimesh.util.concatenate(balls))
        gamma, r = float(rng.uniform(0, 1)), 0.5
        target = rng.uniform(-5, 5, 3)
        a = approach_analysis(target, skin, balls, field=field, needle_radius_mm=r,
                              gamma_mm=gamma)  # fmt: skip
        best = a.shortest()
        assert best is not None
        cert = certify_segment(field, record_point(target), np.array(best["entry_mm"]),
                               radius_mm=r, gamma_mm=gamma)  # fmt: skip
        assert cert.passes(gamma)
        assert cert.clearance_mm == best["clearance_mm"] and cert.length_mm == best["length_mm"]
        assert a.accessible[best["face"]]
        rec = json.loads(json.dumps(a.to_dict(per_face=False)))
        assert rec["needlekit"]["shortest"] == best
    # without a field a thickness cannot be checked: nothing is chosen
    a = approach_analysis([0.0, 0.0, 0.0], skin, balls, needle_radius_mm=0.5)
    assert a.shortest() is None and a.shortest(paa=True) is not None
