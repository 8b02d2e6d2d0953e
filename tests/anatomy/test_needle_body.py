"""NeedleBody: the placed needle as an obstacle (capsule tube + Eq. 4 superquadric head).

Brute-force oracle: the tube and the head surfaces are sampled densely in the world with
frames built here (independently of the module's frame). Every sample is a surface point,
so for a point outside the body the true distance is at most the nearest-sample distance
``d_nn`` and at least ``d_nn`` minus the covering radius of the samples (bounded here from
the sampling steps). Signs come from independent inside tests of the two solids.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from needlekit.anatomy.fields import DistanceField
from needlekit.anatomy.needle_body import (
    DEFAULT_SHAFT_OUTSIDE_MM,
    LIU_HEAD_EXPONENTS,
    LIU_HEAD_LEVEL,
    LIU_HEAD_SCALES_MM,
    NeedleBody,
    NeedleHead,
)
from needlekit.anatomy.primitives import SUPERQUADRIC_ERROR_BOUND_MM, Capsule, Superquadric
from needlekit.errors import InvalidInputError

EQ4_SEMI_AXES = np.array([60.0 * 1000.0 ** (1 / 8), 0.1 * 1000.0**0.5, 0.1 * 1000.0**0.5])
SMALL_HEAD = NeedleHead.from_dimensions(length_mm=24.0, diameter_mm=7.0)


def _basis(axis, rng):
    """Orthonormal (u, p, q) with u along ``axis``; p from a random vector (so not the
    module's rule)."""
    u = np.asarray(axis, float) / np.linalg.norm(axis)
    while True:
        r = rng.normal(size=3)
        p = r - (r @ u) * u
        if np.linalg.norm(p) > 0.1:
            break
    p /= np.linalg.norm(p)
    return u, p, np.cross(u, p)


def _capsule_samples(a, b, radius, step, rng):
    """Points on the capsule surface around segment a-b, at most ``step`` apart along
    both surface directions; returns (points, covering radius bound)."""
    u, p, q = _basis(b - a, rng)
    length = np.linalg.norm(b - a)
    s = np.linspace(0.0, length, int(np.ceil(length / step)) + 1)
    n_ang = int(np.ceil(2 * np.pi * radius / step))
    ang = np.linspace(0.0, 2 * np.pi, n_ang, endpoint=False)
    ring = np.cos(ang)[:, None] * p + np.sin(ang)[:, None] * q
    side = (a + s[:, None, None] * u + radius * ring[None]).reshape(-1, 3)
    # hemispheres: polar angle from the axis, rings at most `step` apart
    n_pol = int(np.ceil(0.5 * np.pi * radius / step)) + 1
    caps = []
    for centre, sign in ((a, -1.0), (b, 1.0)):
        for t in np.linspace(0.0, 0.5 * np.pi, n_pol):
            axial = sign * radius * np.cos(t) * u
            rad = radius * np.sin(t)
            m = max(int(np.ceil(2 * np.pi * rad / step)), 1)
            phi = np.linspace(0.0, 2 * np.pi, m, endpoint=False)
            ring_t = np.cos(phi)[:, None] * p + np.sin(phi)[:, None] * q
            caps.append(centre + axial + rad * ring_t)
    pts = np.concatenate([side, *caps])
    return pts, step  # neighbours <= step apart in two directions: covering <= step/sqrt2


def _head_profile(a, b, e):
    """(x, rho) points on the half profile of |x/a|^e + (rho/b)^2 = 1, rho >= 0, dense in
    arc length: a uniform grid in x joined with the angle chart that resolves the ends."""
    x1 = np.linspace(-a, a, 40001)
    eta = np.linspace(0.0, np.pi, 20001)
    c = np.cos(eta)
    x2 = a * np.sign(c) * np.abs(c) ** (2.0 / e)
    x = np.unique(np.concatenate([x1, x2]))
    rho = b * np.sqrt(np.clip(1.0 - np.abs(x / a) ** e, 0.0, None))
    return x, rho


def _head_samples(centre, axis, head, step, rng):
    a, b = head.semi_axes_mm[0], head.semi_axes_mm[1]
    e = head.exponents[0]
    u, p, q = _basis(axis, rng)
    x, rho = _head_profile(a, b, e)
    # thin the profile to about `step` of arc length
    arc = np.concatenate([[0.0], np.cumsum(np.hypot(np.diff(x), np.diff(rho)))])
    keep = np.unique(np.searchsorted(arc, np.arange(0.0, arc[-1], step)))
    keep = np.unique(np.concatenate([keep, [len(x) - 1]]))
    x, rho = x[keep], rho[keep]
    gap = np.max(np.hypot(np.diff(x), np.diff(rho)))
    n_ang = int(np.ceil(2 * np.pi * b / step))
    ang = np.linspace(0.0, 2 * np.pi, n_ang, endpoint=False)
    ring = np.cos(ang)[:, None] * p + np.sin(ang)[:, None] * q
    pts = centre + x[:, None, None] * u + rho[:, None, None] * ring[None]
    return pts.reshape(-1, 3), max(gap, 2 * np.pi * b / n_ang)


def _inside_capsule(points, a, b, radius):
    ab = b - a
    s = np.clip((points - a) @ ab / (ab @ ab), 0.0, 1.0)
    return np.linalg.norm(points - a - s[:, None] * ab, axis=1) - radius


def _inside_head(points, centre, axis, head):
    a, b = head.semi_axes_mm[0], head.semi_axes_mm[1]
    u = axis / np.linalg.norm(axis)
    rel = points - centre
    x = rel @ u
    rho = np.linalg.norm(rel - x[:, None] * u, axis=1)
    return np.abs(x / a) ** head.exponents[0] + (rho / b) ** 2 - 1.0


def _queries(tip, head_end, spread, n, rng):
    """Points scattered around the needle: along the axis with lateral offsets."""
    t = rng.uniform(-0.05, 1.05, n)
    lateral = rng.normal(size=(n, 3)) * rng.uniform(0.0, spread, (n, 1))
    return tip + t[:, None] * (head_end - tip) + lateral


DIRECTIONS = [
    [0.0, 0.0, 1.0],
    [0.0, 0.0, -1.0],
    [1.0, 0.0, 0.0],
    [0.0, -1.0, 0.0],
    [0.3, -0.5, 0.81],
    [-0.7, 0.1, -0.2],
    [1e-9, 1.0, 1e-9],
]


@pytest.mark.parametrize("insertion", DIRECTIONS)
@pytest.mark.parametrize("head", [SMALL_HEAD, None], ids=["head", "bare"])
def test_distance_matches_dense_samples_for_any_direction(insertion, head):
    rng = np.random.default_rng(DIRECTIONS.index(insertion))
    v = np.asarray(insertion) / np.linalg.norm(insertion)
    tip = np.array([12.0, -30.0, 55.0])
    entry = tip - 60.0 * v
    radius, outside = 0.8, 5.0
    body = NeedleBody(tip, entry, radius_mm=radius, head=head, shaft_outside_mm=outside)
    axis = -v
    head_start = entry + outside * axis
    tube_pts, tube_cover = _capsule_samples(tip, head_start, radius, 0.07, rng)
    sets = [tube_pts]
    cover = tube_cover
    head_end = head_start
    if head is not None:
        centre = head_start + 0.5 * head.length_mm * axis
        head_pts, head_cover = _head_samples(centre, axis, head, 0.07, rng)
        sets.append(head_pts)
        cover = max(cover, head_cover)
        head_end = head_start + head.length_mm * axis
    tree = cKDTree(np.concatenate(sets))
    q = _queries(tip, head_end, 8.0, 1500, rng)
    sd = body.signed_distance(q)
    inside = _inside_capsule(q, tip, head_start, radius) < 0.0
    if head is not None:
        inside |= _inside_head(q, centre, axis, head) < 0.0
    d_nn, _ = tree.query(q)
    out = ~inside
    assert out.sum() > 1000 and inside.sum() > 20
    # outside: exact distance to the union, bracketed by the samples
    assert np.all(sd[out] > 0.0)
    assert np.all(sd[out] <= d_nn[out] + 1e-6)
    assert np.all(sd[out] >= d_nn[out] - cover)
    # inside: negative (the sign is always right)
    assert np.all(sd[inside] < 0.0)
    # every sample is on the surface of its part, so on or inside the body
    allpts = np.concatenate(sets)
    some = allpts[rng.choice(len(allpts), 20000, replace=False)]
    assert np.all(body.signed_distance(some) <= 1e-6)
    # bounds contain every surface sample
    lo, hi = body.bounds()
    assert np.all(allpts >= lo - 1e-9) and np.all(allpts <= hi + 1e-9)


def test_eq4_head_against_dense_samples_and_its_dimensions():
    rng = np.random.default_rng(4)
    v = np.array([0.2, 0.9, -0.4])
    v /= np.linalg.norm(v)
    tip = np.array([-5.0, 10.0, 3.0])
    entry = tip - 80.0 * v
    body = NeedleBody(tip, entry, radius_mm=0.5)  # Eq. 4 head, on the skin
    head = body.head
    assert head == NeedleHead()
    np.testing.assert_allclose(head.semi_axes_mm, EQ4_SEMI_AXES, rtol=1e-14)
    np.testing.assert_allclose([head.length_mm, head.diameter_mm], [284.5648, 6.32456], atol=1e-4)
    axis = -v
    centre = entry + 0.5 * head.length_mm * axis
    head_pts, cover = _head_samples(centre, axis, head, 0.08, rng)
    tube_pts, _ = _capsule_samples(tip, entry, 0.5, 0.08, rng)
    tree = cKDTree(np.concatenate([head_pts, tube_pts]))
    q = _queries(tip, entry + head.length_mm * axis, 12.0, 2000, rng)
    sd = body.signed_distance(q)
    out = (_inside_head(q, centre, axis, head) > 0.0) & (_inside_capsule(q, tip, entry, 0.5) > 0)
    d_nn, _ = tree.query(q)
    assert out.sum() > 1500
    assert np.all(sd[out] <= d_nn[out] + 1e-6)
    assert np.all(sd[out] >= d_nn[out] - cover)
    assert np.all(sd[~out] < 0.0)


def test_eq4_as_printed_is_zero_on_the_head_surface_in_its_frame():
    body = NeedleBody([0.0, 0.0, 0.0], [30.0, 40.0, 0.0], radius_mm=0.5)
    rng = np.random.default_rng(0)
    # surface points of Eq. 4 in Sigma' (x' along the needle), placed by world_T_head
    x = rng.uniform(-1.0, 1.0, 200) * EQ4_SEMI_AXES[0]
    rho = EQ4_SEMI_AXES[1] * np.sqrt(1.0 - np.abs(x / EQ4_SEMI_AXES[0]) ** 8)
    ang = rng.uniform(0.0, 2 * np.pi, 200)
    local = np.stack([x, rho * np.cos(ang), rho * np.sin(ang)], axis=1)
    printed = (local[:, 0] / 60) ** 8 + (local[:, 1] / 0.1) ** 2 + (local[:, 2] / 0.1) ** 2
    np.testing.assert_allclose(printed, 1000.0, rtol=1e-12)
    world = local @ body.world_T_head[:3, :3].T + body.world_T_head[:3, 3]
    np.testing.assert_allclose(body.head_field.signed_distance(world), 0.0, atol=1e-6)


def test_frames_head_on_the_axis_just_outside_the_entry():
    tip = np.array([1.0, 2.0, 3.0])
    entry = np.array([1.0, 2.0, 3.0]) + np.array([3.0, 0.0, 4.0]) * 10.0  # 50 mm, axis (.6,0,.8)
    body = NeedleBody(tip, entry, radius_mm=0.5, head=SMALL_HEAD)
    axis = np.array([0.6, 0.0, 0.8])
    np.testing.assert_allclose(body.axis_unit, axis)
    assert body.inserted_length_mm == pytest.approx(50.0)
    assert DEFAULT_SHAFT_OUTSIDE_MM == 0.0
    np.testing.assert_allclose(body.head_start_mm, entry)
    pose = body.world_T_head
    np.testing.assert_allclose(pose[:3, 0], axis, atol=1e-15)  # x' along the needle
    np.testing.assert_allclose(pose[:3, :3].T @ pose[:3, :3], np.eye(3), atol=1e-14)
    assert np.linalg.det(pose[:3, :3]) == pytest.approx(1.0)
    centre = entry + 12.0 * axis
    np.testing.assert_allclose(pose[:3, 3], centre)
    # the head's far end, its centre's depth and its side, all on the axis / across it
    assert body.signed_distance(entry + 24.0 * axis) == pytest.approx(0.0, abs=1e-6)
    assert body.signed_distance(entry + 25.0 * axis) == pytest.approx(1.0, abs=1e-6)
    assert body.signed_distance(centre) == pytest.approx(-3.5, abs=1e-6)
    for perp in ([0.0, 1.0, 0.0], [0.8, 0.0, -0.6], [0.8 / 2**0.5, 0.5**0.5, -0.6 / 2**0.5]):
        p = centre + 5.5 * np.asarray(perp)
        assert body.signed_distance(p) == pytest.approx(2.0, abs=1e-6)
    # the tube: exact closed form along the shaft and ahead of the tip
    assert body.signed_distance(tip + 20.0 * axis + [0.0, 3.0, 0.0]) == pytest.approx(2.5)
    assert body.signed_distance(tip - 2.0 * axis) == pytest.approx(1.5)
    assert body.signed_distance(tip + 10.0 * axis) == pytest.approx(-0.5)


def test_shaft_outside_moves_the_head_out_and_extends_the_tube():
    tip = np.zeros(3)
    entry = np.array([0.0, 0.0, 40.0])
    body = NeedleBody(tip, entry, radius_mm=0.5, head=SMALL_HEAD, shaft_outside_mm=30.0)
    np.testing.assert_allclose(body.head_start_mm, [0.0, 0.0, 70.0])
    np.testing.assert_allclose(body.world_T_head[:3, 3], [0.0, 0.0, 82.0])
    # beside the shaft outside the body: the tube, 1.5 mm away
    assert body.signed_distance([2.0, 0.0, 55.0]) == pytest.approx(1.5)
    # the tube stops at the head start: its end is the head's near point
    np.testing.assert_allclose(body.tube.p1_mm, [0.0, 0.0, 70.0])
    assert body.signed_distance([0.0, 0.0, 94.0]) == pytest.approx(0.0, abs=1e-6)


def test_union_is_the_minimum_of_the_parts_and_error_bound_is_stated():
    rng = np.random.default_rng(7)
    body = NeedleBody([0.0, 0.0, 0.0], [10.0, -20.0, 60.0], radius_mm=1.0, head=SMALL_HEAD)
    q = rng.uniform(-40.0, 120.0, (500, 3))
    tube = Capsule(body.tip_mm, body.head_start_mm, 1.0)
    head = Superquadric(SMALL_HEAD.semi_axes_mm, SMALL_HEAD.exponents, body.world_T_head)
    np.testing.assert_array_equal(
        body.signed_distance(q), np.minimum(tube.signed_distance(q), head.signed_distance(q))
    )
    assert isinstance(body, DistanceField)
    assert body.error_bound_mm == SUPERQUADRIC_ERROR_BOUND_MM == 1e-6
    bare = NeedleBody([0.0, 0.0, 0.0], [10.0, -20.0, 60.0], radius_mm=1.0, head=None)
    assert bare.error_bound_mm == 0.0
    assert bare.head_field is None and bare.world_T_head is None
    np.testing.assert_array_equal(bare.signed_distance(q), tube.signed_distance(q))
    # single point in, scalar out; batch in, batch out
    assert np.ndim(body.signed_distance([1.0, 2.0, 3.0])) == 0
    # the gradient is a unit outward normal away from the medial axis
    g = body.gradient(q[np.abs(body.signed_distance(q)) > 0.5])
    np.testing.assert_allclose(np.linalg.norm(g, axis=1), 1.0, atol=1e-6)
    # inflating (needle radius + margin) works as for any field
    assert body.inflated(2.0).signed_distance([5.0, 0.0, 0.0]) == pytest.approx(
        body.signed_distance([5.0, 0.0, 0.0]) - 2.0
    )


def test_head_parameters_and_from_dimensions():
    head = NeedleHead()
    assert head.scales_mm == LIU_HEAD_SCALES_MM
    assert head.exponents == LIU_HEAD_EXPONENTS
    assert head.level == LIU_HEAD_LEVEL
    h = NeedleHead.from_dimensions(80.0, 8.0, axial_exponent=4.0)
    np.testing.assert_allclose(h.semi_axes_mm, [40.0, 4.0, 4.0])
    assert h.exponents == (4.0, 2.0, 2.0)
    with pytest.raises(AttributeError):
        head.level = 3.0  # frozen
    listed = NeedleHead(scales_mm=[60, 0.1, 0.1], exponents=[8, 2, 2], level=1000)
    assert listed == head and isinstance(listed.scales_mm, tuple)


@pytest.mark.parametrize(
    ("kwargs", "field"),
    [
        ({"scales_mm": (60.0, 0.1, 0.2)}, "scales_mm"),
        ({"scales_mm": (60.0, -0.1, -0.1)}, "scales_mm"),
        ({"scales_mm": (60.0, 0.1)}, "scales_mm"),
        ({"exponents": (8.0, 2.0, 4.0)}, "exponents"),
        ({"exponents": (1.0, 2.0, 2.0)}, "exponents"),
        ({"exponents": (40.0, 2.0, 2.0)}, "exponents"),
        ({"level": 0.0}, "level"),
        ({"level": float("nan")}, "level"),
    ],
)
def test_bad_head_parameters_name_the_field(kwargs, field):
    with pytest.raises(InvalidInputError, match=f"^{field}: "):
        NeedleHead(**kwargs)


@pytest.mark.parametrize(
    ("args", "kwargs", "field"),
    [
        (([0, 0, 0], [0, 0, 0]), {"radius_mm": 0.5}, "entry_mm"),
        (([0, 0, np.nan], [0, 0, 10]), {"radius_mm": 0.5}, "tip_mm"),
        (([0, 0, 0], [[0, 0, 10], [0, 0, 20]]), {"radius_mm": 0.5}, "entry_mm"),
        (([0, 0], [0, 0, 10]), {"radius_mm": 0.5}, "tip_mm"),
        (([0, 0, 0], [0, 0, 10]), {"radius_mm": 0.0}, "radius_mm"),
        (([0, 0, 0], [0, 0, 10]), {"radius_mm": 0.5, "shaft_outside_mm": -1.0}, "shaft_outside_mm"),
        (([0, 0, 0], [0, 0, 10]), {"radius_mm": 0.5, "head": "eq4"}, "head"),
        (([0, 0, 0], [0, 0, 10]), {"radius_mm": 0.5, "head": Superquadric.from_liu()}, "head"),
    ],
)
def test_bad_body_arguments_name_the_field(args, kwargs, field):
    with pytest.raises(InvalidInputError, match=f"^{field}: "):
        NeedleBody(*args, **kwargs)


def test_points_argument_is_checked():
    body = NeedleBody([0, 0, 0], [0, 0, 10], radius_mm=0.5, head=None)
    with pytest.raises(InvalidInputError, match=r"^points: "):
        body.signed_distance([[0.0, 1.0]])
    assert "NeedleBody(tip_mm=(0, 0, 0)" in repr(body)
