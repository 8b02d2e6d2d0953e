"""The batched sphere tracing of the straight needle's clearance
(``segment_clearance_bound``) against the plain one it is held to
(``segment_clearance_bound_reference``, one sample of every segment at a time): the same
bounds and the same arc lengths, bit for bit, on seeded random segments through unions of
primitives, and fewer calls to the field where a segment runs near an obstacle."""

import numpy as np
import pytest

from needlekit.anatomy.fields import BoundedField, DistanceField, union
from needlekit.anatomy.primitives import Capsule, Ellipsoid, Sphere, Superquadric
from needlekit.planning.straight.cfrw import bounds
from needlekit.planning.straight.cfrw.bounds import (
    segment_clearance_bound,
    segment_clearance_bound_reference,
)


class _Counting(DistanceField):
    """A field's values, counting the calls and the points asked for."""

    def __init__(self, field: DistanceField) -> None:
        self.field = field
        self.error_bound_mm = field.error_bound_mm
        self.calls = 0
        self.points = 0

    def _signed_distance(self, points):
        return self.field._signed_distance(points)

    def capped_distance(self, points, cap_mm):
        self.calls += 1
        self.points += len(points)
        return self.field.capped_distance(points, cap_mm)

    def bounds(self):
        return self.field.bounds()


class _FarIsInfinite(DistanceField):
    """A sphere whose points beyond 25 mm of its centre answer +inf (a lower bound above
    any cap), to hold the trace's rule for a sample without a finite neighbour."""

    error_bound_mm = 0.0

    def __init__(self) -> None:
        self.sphere = Sphere([0.0, 0.0, 0.0], 6.0)

    def _signed_distance(self, points):
        d = self.sphere._signed_distance(points)
        return np.where(np.linalg.norm(points, axis=1) > 25.0, np.inf, d)

    def bounds(self):
        return self.sphere.bounds()


def _pose(rng) -> np.ndarray:
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    if np.linalg.det(q) < 0:
        q[:, 0] = -q[:, 0]
    g = np.eye(4)
    g[:3, :3] = q
    g[:3, 3] = rng.uniform(-10.0, 10.0, 3)
    return g


def _obstacles(rng) -> DistanceField:
    """Vessel-like superquadrics, an ellipsoid, a capsule and a sphere (one bounded)."""
    parts = [
        Superquadric([30.0, 2.5, 2.5], [8.0, 2.0, 2.0], _pose(rng)),
        Superquadric([20.0, 3.0, 4.0], [4.0, 2.0, 3.0], _pose(rng)),
        Ellipsoid([8.0, 5.0, 3.0], _pose(rng)),
        Capsule(rng.uniform(-20, 20, 3), rng.uniform(-20, 20, 3), 2.0),
    ]
    inner = Sphere(rng.uniform(-15, 15, 3), 3.0)
    parts.append(BoundedField(inner, Sphere(inner.center_mm, 4.0)))
    return union(*parts)


def _segments(rng, n: int):
    """Segments from around the obstacles, some of length 0, some starting inside one."""
    o = rng.uniform(-25.0, 25.0, (n, 3))
    u = rng.normal(size=(n, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    L = rng.uniform(0.0, 60.0, n)
    L[:3] = 0.0
    return o, u, L


def _same(field, o, u, L, **kw) -> None:
    got = segment_clearance_bound(field, o, u, L, **kw)
    want = segment_clearance_bound_reference(field, o, u, L, **kw)
    assert np.array_equal(got[0], want[0])
    assert np.array_equal(got[1], want[1])


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize(
    ("cap_mm", "step_mm"),
    [(12.5, 0.5), (2.52, 0.02), (3.0, 0.05), (0.5, 1.0)],
)
def test_batched_trace_equals_the_one_by_one_trace(seed, cap_mm, step_mm):
    rng = np.random.default_rng(seed)
    field = _obstacles(rng)
    o, u, L = _segments(rng, 150)
    _same(field, o, u, L, cap_mm=cap_mm, step_mm=step_mm)


def test_the_rule_for_samples_without_a_finite_neighbour_is_kept():
    rng = np.random.default_rng(7)
    o, u, L = _segments(rng, 200)
    _same(_FarIsInfinite(), 0.5 * o, u, L, cap_mm=4.0, step_mm=0.1)


def test_a_small_round_gives_the_same_answer(monkeypatch):
    rng = np.random.default_rng(3)
    field = _obstacles(rng)
    o, u, L = _segments(rng, 120)
    want = segment_clearance_bound_reference(field, o, u, L, cap_mm=3.0, step_mm=0.05)
    monkeypatch.setattr(bounds, "TRACE_MAX_SAMPLES", 50)
    monkeypatch.setattr(bounds, "TRACE_MAX_AHEAD", 3)
    got = segment_clearance_bound(field, o, u, L, cap_mm=3.0, step_mm=0.05)
    assert np.array_equal(got[0], want[0]) and np.array_equal(got[1], want[1])


def test_a_run_near_an_obstacle_takes_few_calls():
    # 60 mm along a tube 1 mm from its surface: 1200 near steps of 0.05 mm, one call each
    # in the plain trace
    tube = _Counting(Capsule([0.0, 0.0, -100.0], [0.0, 0.0, 100.0], 2.0))
    o, u, L = np.array([[3.0, 0.0, -30.0]]), np.array([[0.0, 0.0, 1.0]]), np.array([60.0])
    got = segment_clearance_bound(tube, o, u, L, cap_mm=1.5, step_mm=0.05)
    fast = (tube.calls, tube.points)
    tube.calls = tube.points = 0
    want = segment_clearance_bound_reference(tube, o, u, L, cap_mm=1.5, step_mm=0.05)
    assert np.array_equal(got[0], want[0]) and np.array_equal(got[1], want[1])
    assert tube.calls > 1200
    assert fast[0] <= 30
    assert fast[1] == tube.points  # no sample asked for that the trace does not take
