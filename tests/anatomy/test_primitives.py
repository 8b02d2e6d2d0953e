"""Analytic primitives: closed forms, dense brute force, scipy references, the Lipschitz
property, analytic gradients, poses, the unsafety of the radial estimate, and bad input.

Brute-force oracle: each surface is sampled on dense grids (>= 3e5 points). Every sample
is a surface point, so the true unsigned distance is at most the nearest-sample distance
``d_nn`` (checked exactly), and at least ``d_nn`` minus the covering radius of the
samples (measured with independent random surface points). The sign comes from an
independent inside test.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import pytest
from scipy.spatial import cKDTree

from needlekit.anatomy.fields import DistanceField, TransformedField
from needlekit.anatomy.primitives import (
    Box,
    Capsule,
    Cylinder,
    Ellipsoid,
    HalfSpace,
    Sphere,
    Superquadric,
    ellipsoid_distance,
    ellipsoid_distance_reference,
    radial_distance_approximation,
    superquadric_distance,
    superquadric_distance_reference,
)
from needlekit.errors import InvalidInputError
from needlekit.geometry.se3 import make_pose
from needlekit.geometry.so3 import so3_exp

EQ4_AXES = np.array([60.0 * 1000.0 ** (1 / 8), 0.1 * 1000.0**0.5, 0.1 * 1000.0**0.5])
EQ4_EXPONENTS = np.array([8.0, 2.0, 2.0])
POSE = make_pose(so3_exp([0.3, -0.5, 0.7]), [12.0, -7.0, 30.0])


def _liu_f(local):
    """Liu et al. Eq. 4 exactly as printed."""
    x, y, z = np.asarray(local).T
    return (x / 60.0) ** 8 + (y / 0.1) ** 2 + (z / 0.1) ** 2 - 1000.0


# ----------------------------------------------------------------------------------------
# surface samplers (independent of the module): each chart maps u in [0, 1]^2 to local
# surface points (NaN rows are outside the chart); grids give the dense set, random u the
# covering-radius probe.


def _frame(axis):
    u = np.asarray(axis, float) / np.linalg.norm(axis)
    v = np.cross(u, [1.0, 0.0, 0.0] if abs(u[0]) < 0.9 else [0.0, 1.0, 0.0])
    v /= np.linalg.norm(v)
    return u, v, np.cross(u, v)


def _sphere_charts(center, r, h):
    m = int(np.ceil(np.pi * r / h)) + 1

    def chart(u):
        theta = np.pi * u[:, 0]
        phi = 2.0 * np.pi * u[:, 1]
        s = np.sin(theta)
        return center + r * np.column_stack([s * np.cos(phi), s * np.sin(phi), np.cos(theta)])

    return [(chart, (m, 2 * m))]


def _capsule_charts(p0, p1, r, h):
    u_ax, v, w = _frame(np.subtract(p1, p0))
    length = np.linalg.norm(np.subtract(p1, p0))
    m_phi = int(np.ceil(2 * np.pi * r / h)) + 1

    def side(u):
        phi = 2 * np.pi * u[:, 1]
        radial = np.cos(phi)[:, None] * v + np.sin(phi)[:, None] * w
        return p0 + (u[:, 0] * length)[:, None] * u_ax + r * radial

    def cap(end, sign):
        def chart(u):
            theta = 0.5 * np.pi * u[:, 0]  # polar angle from the axis
            phi = 2 * np.pi * u[:, 1]
            s = np.sin(theta)
            d = (
                sign * np.cos(theta)[:, None] * u_ax
                + (s * np.cos(phi))[:, None] * v
                + (s * np.sin(phi))[:, None] * w
            )
            return end + r * d

        return chart

    m_cap = int(np.ceil(0.5 * np.pi * r / h)) + 1
    return [
        (side, (int(np.ceil(length / h)) + 1, m_phi)),
        (cap(np.asarray(p0, float), -1.0), (m_cap, m_phi)),
        (cap(np.asarray(p1, float), 1.0), (m_cap, m_phi)),
    ]


def _cylinder_charts(p0, p1, r, h):
    u_ax, v, w = _frame(np.subtract(p1, p0))
    length = np.linalg.norm(np.subtract(p1, p0))
    m_phi = int(np.ceil(2 * np.pi * r / h)) + 1

    def side(u):
        phi = 2 * np.pi * u[:, 1]
        radial = np.cos(phi)[:, None] * v + np.sin(phi)[:, None] * w
        return p0 + (u[:, 0] * length)[:, None] * u_ax + r * radial

    def cap(end):
        def chart(u):
            x = (2 * u[:, 0] - 1) * r
            y = (2 * u[:, 1] - 1) * r
            pts = end + x[:, None] * v + y[:, None] * w
            pts[x * x + y * y > r * r] = np.nan
            return pts

        return chart

    m_cap = int(np.ceil(2 * r / h)) + 1
    return [
        (side, (int(np.ceil(length / h)) + 1, m_phi)),
        (cap(np.asarray(p0, float)), (m_cap, m_cap)),
        (cap(np.asarray(p1, float)), (m_cap, m_cap)),
    ]


def _box_charts(half, h):
    charts = []
    for k in range(3):
        i, j = (k + 1) % 3, (k + 2) % 3
        for sign in (-1.0, 1.0):

            def chart(u, i=i, j=j, k=k, sign=sign):
                pts = np.empty((u.shape[0], 3))
                pts[:, i] = (2 * u[:, 0] - 1) * half[i]
                pts[:, j] = (2 * u[:, 1] - 1) * half[j]
                pts[:, k] = sign * half[k]
                return pts

            charts.append(
                (chart, (int(np.ceil(2 * half[i] / h)) + 1, int(np.ceil(2 * half[j] / h)) + 1))
            )
    return charts


def _superquadric_charts(a, e, h):
    """Per axis k: the graph x_k = a_k (1 - T_i - T_j)^(1/e_k) over a grid of (x_i, x_j),
    first octant only (the shapes are mirror-symmetric; queries are mirrored instead)."""
    charts = []
    for k in range(3):
        i, j = (k + 1) % 3, (k + 2) % 3

        def chart(u, i=i, j=j, k=k):
            xi, xj = u[:, 0] * a[i], u[:, 1] * a[j]
            s = (xi / a[i]) ** e[i] + (xj / a[j]) ** e[j]
            pts = np.empty((u.shape[0], 3))
            pts[:, i], pts[:, j] = xi, xj
            pts[:, k] = a[k] * np.maximum(1.0 - s, 0.0) ** (1.0 / e[k])
            pts[s > 1.0] = np.nan
            return pts

        charts.append((chart, (int(np.ceil(a[i] / h)) + 1, int(np.ceil(a[j] / h)) + 1)))
    return charts


def _plane_charts(point, normal, half_width, h):
    _, v, w = _frame(normal)
    m = int(np.ceil(2 * half_width / h)) + 1

    def chart(u):
        return (
            point
            + ((2 * u[:, 0] - 1) * half_width)[:, None] * v
            + ((2 * u[:, 1] - 1) * half_width)[:, None] * w
        )

    return [(chart, (m, m))]


def _dense(charts):
    out = []
    for chart, (m0, m1) in charts:
        g0, g1 = np.meshgrid(np.linspace(0, 1, m0), np.linspace(0, 1, m1), indexing="ij")
        pts = chart(np.column_stack([g0.ravel(), g1.ravel()]))
        out.append(pts[~np.isnan(pts[:, 0])])
    return np.concatenate(out)


def _random_surface(charts, n, rng):
    out = []
    for chart, _ in charts:
        pts = chart(rng.uniform(size=(n, 2)))
        out.append(pts[~np.isnan(pts[:, 0])])
    return np.concatenate(out)


def _to_world(pose, local):
    return local @ pose[:3, :3].T + pose[:3, 3]


def _to_local(pose, world):
    return (world - pose[:3, 3]) @ pose[:3, :3]


# ----------------------------------------------------------------------------------------
# the cases: a factory taking a pose, local surface charts, a local inside test


@dataclass
class Case:
    name: str
    make: Callable[[np.ndarray | None], DistanceField]
    charts: list
    inside: Callable[[np.ndarray], np.ndarray]
    pose: np.ndarray | None
    query_box: np.ndarray | None = None  # local box for queries (unbounded shapes)
    octant: bool = False  # charts cover the first octant of a mirror-symmetric shape


def _cases() -> list[Case]:
    cyl_p0, cyl_p1 = np.array([1.0, -2.0, 3.0]), np.array([-10.0, 15.0, 25.0])
    cap_p0, cap_p1 = np.array([0.0, 0.0, 0.0]), np.array([40.0, 5.0, -8.0])

    def in_cylinder(q):
        u = (cyl_p1 - cyl_p0) / np.linalg.norm(cyl_p1 - cyl_p0)
        s = (q - cyl_p0) @ u
        r = np.linalg.norm((q - cyl_p0) - s[:, None] * u, axis=1)
        return (s > 0) & (s < np.linalg.norm(cyl_p1 - cyl_p0)) & (r < 6.0)

    def in_capsule(q):
        d = cap_p1 - cap_p0
        s = np.clip((q - cap_p0) @ d / (d @ d), 0, 1)
        return np.linalg.norm(q - cap_p0 - s[:, None] * d, axis=1) < 4.0

    def in_superquadric(a, e):
        return lambda q: np.sum((np.abs(q) / a) ** e, axis=1) < 1.0

    half = np.array([20.0, 7.0, 3.0])
    ell_a = np.array([100.0, 10.0, 10.0])
    tri_a = np.array([30.0, 20.0, 8.0])
    mix_a, mix_e = np.array([40.0, 15.0, 6.0]), np.array([3.5, 6.0, 2.5])
    n_hat = np.array([1.0, 2.0, -2.0]) / 3.0
    return [
        Case(
            "sphere",
            lambda g: Sphere([5.0, -3.0, 2.0], 12.0, world_T_local=g),
            _sphere_charts(np.array([5.0, -3.0, 2.0]), 12.0, 0.1),
            lambda q: np.linalg.norm(q - [5.0, -3.0, 2.0], axis=1) < 12.0,
            POSE,
        ),
        Case(
            "capsule",
            lambda g: Capsule(cap_p0, cap_p1, 4.0, world_T_local=g),
            _capsule_charts(cap_p0, cap_p1, 4.0, 0.1),
            in_capsule,
            POSE,
        ),
        Case(
            "cylinder",
            lambda g: Cylinder(cyl_p0, cyl_p1, 6.0, world_T_local=g),
            _cylinder_charts(cyl_p0, cyl_p1, 6.0, 0.1),
            in_cylinder,
            POSE,
        ),
        Case(
            "box",
            lambda g: Box(half, world_T_local=g),
            _box_charts(half, 0.1),
            lambda q: np.all(np.abs(q) < half, axis=1),
            POSE,
        ),
        Case(
            "halfspace",
            lambda g: HalfSpace([1.0, 2.0, 3.0], 3.0 * n_hat, world_T_local=g),
            _plane_charts(np.array([1.0, 2.0, 3.0]), n_hat, 30.0, 0.12),
            lambda q: (q - [1.0, 2.0, 3.0]) @ n_hat < 0.0,
            POSE,
            query_box=np.array([[-8.0, -8.0, -8.0], [10.0, 12.0, 14.0]]),
        ),
        Case(
            "ellipsoid_100x10x10",
            lambda g: Ellipsoid(ell_a, world_T_local=g),
            _superquadric_charts(ell_a, np.full(3, 2.0), 0.08),
            in_superquadric(ell_a, 2.0),
            None,
            octant=True,
        ),
        Case(
            "ellipsoid_triaxial",
            lambda g: Ellipsoid(tri_a, world_T_local=g),
            _superquadric_charts(tri_a, np.full(3, 2.0), 0.08),
            in_superquadric(tri_a, 2.0),
            POSE,
            octant=True,
        ),
        Case(
            "superquadric_eq4",
            lambda g: Superquadric.from_liu(world_T_local=g),
            _superquadric_charts(EQ4_AXES, EQ4_EXPONENTS, 0.1),
            lambda q: _liu_f(q) < 0.0,
            None,
            octant=True,
        ),
        Case(
            "superquadric_mixed",
            lambda g: Superquadric(mix_a, mix_e, world_T_local=g),
            _superquadric_charts(mix_a, mix_e, 0.08),
            in_superquadric(mix_a, mix_e),
            POSE,
            octant=True,
        ),
    ]


CASES = _cases()
CASE_IDS = [c.name for c in CASES]


_OCTANTS = np.array([[sx, sy, sz] for sx in (1, -1) for sy in (1, -1) for sz in (1, -1)])


@dataclass
class Brute:
    case: Case
    field: DistanceField
    local_samples: np.ndarray
    tree: cKDTree
    covering_mm: float
    queries: np.ndarray  # world points

    @property
    def pose(self) -> np.ndarray:
        return self.case.pose if self.case.pose is not None else np.eye(4)

    def nearest_sample_distance(self, world: np.ndarray) -> np.ndarray:
        local = _to_local(self.pose, world)
        if self.case.octant:  # mirror the query into the sampled octant
            local = np.abs(local)
        return self.tree.query(local, workers=-1)[0]

    def world_samples(self) -> np.ndarray:
        local = self.local_samples
        if self.case.octant:
            local = (_OCTANTS[:, None, :] * local[None]).reshape(-1, 3)
        return _to_world(self.pose, local)


@functools.cache
def _brute(name: str) -> Brute:
    case = next(c for c in CASES if c.name == name)
    rng = np.random.default_rng(sum(map(ord, case.name)))
    pose = case.pose if case.pose is not None else np.eye(4)
    local = _dense(case.charts)
    tree = cKDTree(local)
    probe = _random_surface(case.charts, 4000, rng)
    covering = float(tree.query(probe, workers=-1)[0].max())
    if case.query_box is None:
        full = (_OCTANTS[:, None, :] * local[None]).reshape(-1, 3) if case.octant else local
        lb, ub = full.min(axis=0), full.max(axis=0)
        pad = 0.15 * (ub - lb) + 2.0
        local_q = rng.uniform(lb - pad, ub + pad, (2000, 3))
        # and points hugging the surface, both sides, in every octant
        near = _random_surface(case.charts, 200, rng)[:1000]
        if case.octant:
            near = near * _OCTANTS[rng.integers(0, 8, len(near))]
        near = near + rng.normal(scale=0.5, size=near.shape)
        local_q = np.concatenate([local_q, near])
    else:
        local_q = rng.uniform(*case.query_box, (3000, 3))
    return Brute(case, case.make(case.pose), local, tree, covering, _to_world(pose, local_q))


@pytest.fixture(scope="module", params=CASE_IDS)
def brute(request) -> Brute:
    return _brute(request.param)


# ----------------------------------------------------------------------------------------
# dense brute force


def test_dense_brute_force(brute):
    sd = brute.field.signed_distance(brute.queries)
    d_nn = brute.nearest_sample_distance(brute.queries)
    # every sample is a surface point: the true distance never exceeds d_nn
    assert np.all(np.abs(sd) <= d_nn + 1e-9), brute.case.name
    # and is within the covering radius of it
    gap = d_nn - np.abs(sd)
    assert gap.max() <= 1.2 * brute.covering_mm + 1e-9, (gap.max(), brute.covering_mm)
    assert brute.covering_mm < 0.1
    # sign from the independent inside test
    inside = brute.case.inside(_to_local(brute.pose, brute.queries))
    clear = np.abs(sd) > 1e-9
    assert np.array_equal((sd < 0)[clear], inside[clear])
    assert inside.any() and (~inside).any()


def test_bounds_contain_the_surface(brute):
    b = brute.field.bounds()
    assert b.shape == (2, 3)
    world = brute.world_samples()
    assert np.all(world >= b[0] - 1e-9)
    assert np.all(world <= b[1] + 1e-9)


def test_closest_point_is_on_the_surface_at_the_distance(brute):
    q = brute.queries[:500]
    sd = brute.field.signed_distance(q)
    c = brute.field.closest_point(q)
    assert np.allclose(np.linalg.norm(q - c, axis=1), np.abs(sd), atol=1e-9)
    tol = 1e-9 + 2 * brute.field.error_bound_mm
    assert np.all(np.abs(brute.field.signed_distance(c)) <= tol)


# ----------------------------------------------------------------------------------------
# Lipschitz, gradients, poses


def test_signed_distance_is_1_lipschitz(brute):
    rng = np.random.default_rng(7)
    p = brute.queries
    step = rng.normal(size=p.shape)
    step *= (rng.uniform(1e-3, 3.0, len(p)) / np.linalg.norm(step, axis=1))[:, None]
    q = p + step
    diff = np.abs(brute.field.signed_distance(p) - brute.field.signed_distance(q))
    bound = np.linalg.norm(step, axis=1) + 2 * brute.field.error_bound_mm + 1e-12
    assert np.all(diff <= bound)


def test_gradient_is_unit_and_matches_finite_differences(brute):
    p = brute.queries[:1500]
    g = brute.field.gradient(p)
    assert np.allclose(np.linalg.norm(g, axis=1), 1.0, atol=1e-12)
    fd = DistanceField._gradient(brute.field, p)
    # central differences are exact to ~1e-8 where the distance is smooth; they shrink
    # where the step straddles the medial axis (or the cylinder's rim), skip those
    smooth = np.abs(np.linalg.norm(fd, axis=1) - 1.0) < 1e-7
    assert smooth.mean() > 0.9
    assert np.abs(g[smooth] - fd[smooth]).max() < 1e-5


@pytest.mark.parametrize("case", CASES, ids=CASE_IDS)
def test_gradient_on_the_medial_axis_is_still_a_unit_vector(case):
    field = case.make(None)
    b = field.bounds()
    finite = np.isfinite(b).all(axis=0)
    centre = np.zeros(3)
    centre[finite] = 0.5 * (b[0, finite] + b[1, finite])
    pts = centre + np.vstack([np.zeros(3), 1e-9 * np.eye(3), -1e-9 * np.eye(3)])
    g = field.gradient(pts)
    assert np.all(np.isfinite(g))
    assert np.allclose(np.linalg.norm(g, axis=1), 1.0, atol=1e-12)
    c = field.closest_point(pts)
    assert np.allclose(np.linalg.norm(c - pts, axis=1), np.abs(field.signed_distance(pts)))


@pytest.mark.parametrize("case", [c for c in CASES if c.pose is not None], ids=lambda c: c.name)
def test_posed_equals_unposed_on_transformed_points(case):
    rng = np.random.default_rng(3)
    world = rng.uniform(-60, 60, (800, 3)) + case.pose[:3, 3]
    posed, local = case.make(case.pose), case.make(None)
    local_pts = _to_local(case.pose, world)
    assert np.allclose(posed.signed_distance(world), local.signed_distance(local_pts), atol=1e-10)
    assert np.allclose(
        posed.signed_distance(world),
        TransformedField(local, case.pose).signed_distance(world),
        atol=1e-10,
    )
    assert np.allclose(
        posed.gradient(world), local.gradient(local_pts) @ case.pose[:3, :3].T, atol=1e-9
    )


# ----------------------------------------------------------------------------------------
# closed forms


def test_sphere_closed_form():
    s = Sphere([1.0, 2.0, 3.0], 5.0)
    pts = [[1.0, 2.0, 3.0], [1.0, 2.0, 8.0], [1.0, 2.0, 103.0], [4.0, 6.0, 3.0]]
    assert np.allclose(s.signed_distance(pts), [-5.0, 0.0, 95.0, 0.0])
    assert np.allclose(s.gradient([1.0, 2.0, 10.0]), [0, 0, 1])
    assert np.isclose(np.linalg.norm(s.gradient([1.0, 2.0, 3.0])), 1.0)  # centre: any unit


def test_box_closed_form():
    b = Box([1.0, 2.0, 3.0])
    pts = [
        [0, 0, 0],  # centre: nearest face is x
        [0.5, 0, 0],
        [3, 0, 0],  # beyond a face
        [3, 5, 0],  # beyond an edge
        [2, 4, 6],  # beyond a corner
        [1, 2, 3],  # the corner
    ]
    want = [-1.0, -0.5, 2.0, np.hypot(2, 3), np.sqrt(1 + 4 + 9), 0.0]
    assert np.allclose(b.signed_distance(pts), want)
    assert np.allclose(b.gradient([[0.5, 0, 0], [-3, 0, 0]]), [[1, 0, 0], [-1, 0, 0]])
    assert np.allclose(b.gradient([2, 4, 6]), np.array([1, 2, 3]) / np.sqrt(14))


def test_cylinder_closed_form_including_rim():
    c = Cylinder([0, 0, -5], [0, 0, 5], 2.0)
    pts = [
        [0, 0, 0],  # centre: side is nearer (2 < 5)
        [0, 0, 4.5],  # near the top cap
        [0, 0, 9],  # on the axis, beyond the cap
        [7, 0, 0],  # beside the side
        [5, 0, 9],  # beyond the rim: distance to the circle edge
        [2, 0, 5],  # on the rim
    ]
    want = [-2.0, -0.5, 4.0, 5.0, 5.0, 0.0]
    assert np.allclose(c.signed_distance(pts), want)
    assert np.allclose(c.gradient([5, 0, 9]), [0.6, 0, 0.8])
    assert np.allclose(c.gradient([0, 0, -9]), [0, 0, -1])


def test_capsule_closed_form():
    c = Capsule([0, 0, 0], [10, 0, 0], 1.0)
    assert np.allclose(
        c.signed_distance([[5, 0, 0], [5, 3, 0], [-3, 0, 0], [13, 4, 0]]), [-1, 2, 2, 4]
    )
    ball = Capsule([1, 1, 1], [1, 1, 1], 2.0)  # equal ends: a sphere
    assert np.isclose(ball.signed_distance([1, 1, 5]), 2.0)
    g = c.gradient([5, 0, 0])  # on the axis: any unit vector perpendicular to it
    assert np.isclose(np.linalg.norm(g), 1.0) and abs(g[0]) < 1e-12


def test_halfspace_closed_form():
    h = HalfSpace([0, 0, 1], [0, 0, -4])  # inside is z > 1
    assert np.allclose(h.signed_distance([[0, 0, 3], [5, 5, 0]]), [-2, 1])
    assert np.allclose(h.gradient([7, 8, 9]), [0, 0, -1])
    b = h.bounds()
    assert b[0, 2] == 1.0 and np.isinf(b[1, 2]) and np.all(np.isinf(b[:, :2]))


def test_ellipsoid_closed_forms_on_axes_and_centre():
    a = np.array([100.0, 10.0, 5.0])
    e = Ellipsoid(a)
    assert np.isclose(e.signed_distance([0, 0, 0]), -5.0)  # centre: the smallest axis
    assert np.isclose(e.signed_distance([150, 0, 0]), 50.0)  # on the long axis, outside
    assert np.isclose(e.signed_distance([0, 30, 0]), 20.0)
    assert np.isclose(e.signed_distance([0, 0, -7]), 2.0)
    # inside on the long axis, deep: the closest point leaves the axis. In the x-z plane
    # x = a^2 p / (a^2 - c^2) is the closest-point abscissa (Eberly's degenerate branch)
    p = 50.0
    x = a[0] ** 2 * p / (a[0] ** 2 - a[2] ** 2)
    z = a[2] * np.sqrt(1 - (x / a[0]) ** 2)
    assert np.isclose(e.signed_distance([p, 0, 0]), -np.hypot(x - p, z))
    # near the tip on the long axis the tip itself is closest
    assert np.isclose(e.signed_distance([99.9, 0, 0]), -0.1)
    # sphere and spheroid: equal semi-axes
    s = Ellipsoid([7.0, 7.0, 7.0])
    pts = np.random.default_rng(0).normal(size=(200, 3)) * 8
    assert np.allclose(s.signed_distance(pts), np.linalg.norm(pts, axis=1) - 7, atol=1e-12)
    assert np.isclose(s.signed_distance([0, 0, 0]), -7.0)
    spheroid = Ellipsoid([10.0, 4.0, 4.0])  # rotationally symmetric about x
    assert np.isclose(spheroid.signed_distance([3, 6, 0]), spheroid.signed_distance([3, 0, 6]))
    assert np.isclose(spheroid.signed_distance([0, 0, 0]), -4.0)


def _ellipsoid_points(a, rng, n):
    """Random points, with slices on coordinate planes and axes, at the centre, on and
    hugging the surface, and far away."""
    p = rng.uniform(-1.6, 1.6, (n, 3)) * a
    s = n // 8
    p[:s, 0] = 0.0  # coordinate planes
    p[s : 2 * s, 2] = 0.0
    p[2 * s : 2 * s + s // 2, 1:] = 0.0  # axes
    p[2 * s + s // 2 : 3 * s, :2] = 0.0
    p[3 * s] = 0.0  # centre
    surf = p[4 * s : 6 * s]
    surf /= np.sqrt(np.sum((surf / a) ** 2, axis=1))[:, None]  # on the surface
    surf[::2] *= 1.0 + rng.normal(scale=1e-6, size=(len(surf[::2]), 1))  # and hugging it
    p[6 * s :] *= rng.uniform(0, 40, (n - 6 * s, 1))  # far
    return p


@pytest.mark.parametrize(
    "axes",
    [(100, 10, 10), (30, 20, 8), (8, 20, 30), (7, 7, 7), (5, 9, 5), (50, 1, 0.2), (1e-3, 2, 3)],
)
def test_ellipsoid_kernel_matches_plain_reference(axes):
    a = np.array(axes, float)
    p = _ellipsoid_points(a, np.random.default_rng(1), 1200)
    sd, x = ellipsoid_distance(p, a)
    sd_ref, x_ref = ellipsoid_distance_reference(p, a)
    scale = max(1.0, a.max())
    assert np.abs(sd - sd_ref).max() <= 1e-12 * scale * 40
    assert np.allclose(np.sum((x / a) ** 2, axis=1), 1.0, atol=1e-12)
    # distances agree even on the medial axis, where the closest points may differ
    assert np.allclose(np.linalg.norm(p - x, axis=1), np.abs(sd), atol=1e-12 * scale * 40)
    assert np.allclose(np.linalg.norm(p - x_ref, axis=1), np.abs(sd_ref), atol=1e-9)


def test_ellipsoid_matches_scipy_multistart():
    a = np.array([60.0, 25.0, 9.0])
    rng = np.random.default_rng(2)
    p = _ellipsoid_points(a, rng, 40)
    sd, _ = ellipsoid_distance(p, a)
    sd_ref, _ = superquadric_distance_reference(p, a, [2.0, 2.0, 2.0], n_starts=4)
    assert np.abs(sd - sd_ref).max() <= 1e-6
    # the reference is a minimum over true surface points: never below the exact distance
    assert np.all(np.abs(sd) <= np.abs(sd_ref) + 1e-9)


def test_superquadric_with_exponent_two_is_the_ellipsoid():
    a = np.array([40.0, 12.0, 5.0])
    p = _ellipsoid_points(a, np.random.default_rng(4), 3000)
    sq, _ = superquadric_distance(p, a, [2.0, 2.0, 2.0])
    el, _ = ellipsoid_distance(p, a)
    assert np.abs(sq - el).max() <= 1e-9


EXACT_FUNCTIONS = {
    "ellipsoid": ellipsoid_distance,
    "ellipsoid_reference": ellipsoid_distance_reference,
    "superquadric_2": lambda p, a: superquadric_distance(p, a, [2.0, 2.0, 2.0]),
    "superquadric_mixed": lambda p, a: superquadric_distance(p, a, [32.0, 2.0, 8.0]),
}


@pytest.mark.parametrize("name", list(EXACT_FUNCTIONS))
def test_tiny_subnormal_and_huge_coordinates(name):
    fn = EXACT_FUNCTIONS[name]
    a = np.array([10.0, 5.0, 2.0])
    tiny = np.array([[1e-300] * 3, [5e-324] * 3, [1e-310, 2.0, 1e-310], [0.0, -5e-324, 3.0]])
    snapped = np.array([[0.0, 0, 0], [0, 0, 0], [0, 2, 0], [0, 0, 3]])
    sd, x = fn(tiny, a)
    assert np.all(np.isfinite(x))
    assert np.allclose(sd, fn(snapped, a)[0], rtol=0, atol=1e-12)
    assert np.allclose(sd[[0, 1, 3]], [-2.0, -2.0, 1.0])
    huge = np.array([[1e12, 0.0, 0.0], [0.0, -3e11, 0.0], [1e9, 1e9, 1e9]])
    sd, x = fn(huge, a)
    assert np.all(np.isfinite(x))
    assert np.allclose(sd[:2], [1e12 - 10.0, 3e11 - 5.0], rtol=1e-15)
    assert np.isclose(sd[2], np.linalg.norm(huge[2] - x[2]), rtol=1e-14)


def _superquadric_points(a, e, rng, n):
    inside = rng.uniform(-1, 1, (8 * n, 3)) * a
    inside = inside[np.sum((np.abs(inside) / a) ** e, axis=1) < 1.0][: n // 2]
    inside[:4, 1] = 0.0  # on coordinate planes and axes
    inside[4:6, 1:] = 0.0
    direction = rng.normal(size=(n - len(inside), 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    outside = direction * rng.uniform(0, 300, (len(direction), 1))
    outside += rng.uniform(-1, 1, outside.shape) * a
    return np.concatenate([inside, outside])


@pytest.mark.parametrize(
    ("axes", "exponents"),
    [(EQ4_AXES, EQ4_EXPONENTS), ((50.0, 20.0, 5.0), (3.5, 5.0, 2.5)), ((10, 10, 10), (16, 16, 16))],
    ids=["eq4", "mixed", "rounded_cube"],
)
def test_superquadric_matches_scipy_multistart(axes, exponents):
    a, e = np.asarray(axes, float), np.asarray(exponents, float)
    p = _superquadric_points(a, e, np.random.default_rng(5), 36)
    sd, x = superquadric_distance(p, a, e)
    sd_ref, _ = superquadric_distance_reference(p, a, e, n_starts=4)
    assert np.abs(sd - sd_ref).max() <= 1e-6
    assert np.all(np.abs(sd) <= np.abs(sd_ref) + 1e-9)
    assert np.allclose(np.sum((np.abs(x) / a) ** e, axis=1), 1.0, atol=1e-12)


@pytest.mark.slow
@pytest.mark.parametrize("seed", range(3))
def test_superquadric_matches_scipy_multistart_many_shapes(seed):
    rng = np.random.default_rng(100 + seed)
    a = rng.uniform(1, 80, 3)
    e = rng.choice([2.0, 2.5, 3.0, 4.0, 8.0, 12.0, 32.0], 3)
    p = _superquadric_points(a, e, rng, 200)
    sd, _ = superquadric_distance(p, a, e)
    sd_ref, _ = superquadric_distance_reference(p, a, e, n_starts=8)
    assert np.all(np.abs(sd) <= np.abs(sd_ref) + 1e-9)
    assert np.abs(sd - sd_ref).max() <= 1e-6


def test_liu_eq4_mapping():
    head = Superquadric.from_liu()
    assert np.allclose(head.semi_axes_mm, EQ4_AXES)
    assert np.array_equal(head.exponents, EQ4_EXPONENTS)
    # points on Eq. 4's zero set (as printed) are on the surface
    rng = np.random.default_rng(6)
    x = rng.uniform(-140, 140, 300)
    phi = rng.uniform(0, 2 * np.pi, 300)
    rho = np.sqrt((1000.0 - (x / 60.0) ** 8) * 0.01)
    pts = np.column_stack([x, rho * np.cos(phi), rho * np.sin(phi)])
    assert np.abs(_liu_f(pts)).max() < 1e-9
    assert np.abs(head.signed_distance(pts)).max() < 1e-9
    # the inside-outside value is 1 there, and below 1 at the centre
    assert np.allclose(head.inside_outside(pts), 1.0)
    assert head.inside_outside([0, 0, 0]) == 0.0
    # posed by Eq. 6's T_obs
    posed = Superquadric.from_liu(world_T_local=POSE)
    assert np.abs(posed.signed_distance(_to_world(POSE, pts))).max() < 1e-9


def test_barr_form_with_equal_exponents():
    s = Superquadric.from_barr(10, 20, 30, 0.5, 0.5)
    assert np.allclose(s.exponents, 4.0)
    assert np.allclose(s.semi_axes_mm, [10, 20, 30])
    with pytest.raises(InvalidInputError, match="eps2"):
        Superquadric.from_barr(10, 20, 30, 0.5, 0.8)
    with pytest.raises(InvalidInputError, match="eps1"):
        Superquadric.from_barr(10, 20, 30, 1.5, 1.5)  # concave (exponent < 2)


# ----------------------------------------------------------------------------------------
# the radial estimate is unsafe, the exact distance is not


@pytest.mark.parametrize(
    ("name", "median_factor", "max_factor"),
    [("superquadric_eq4", 8.0, 15.0), ("ellipsoid_100x10x10", 3.0, 4.5)],
)
def test_radial_estimate_overestimates_clearance_near_elongated_shapes(
    name, median_factor, max_factor
):
    oracle = _brute(name)
    field = oracle.case.make(None)
    a = field.semi_axes_mm
    e = getattr(field, "exponents", np.full(3, 2.0))
    # points 2 to 8 mm beside the long side, away from the centre
    rng = np.random.default_rng(8)
    n = 400
    x = rng.uniform(0.3, 0.9, n) * a[0] * rng.choice([-1, 1], n)
    phi = rng.uniform(0, 2 * np.pi, n)
    side = a[1] * np.maximum(1 - np.abs(x / a[0]) ** e[0], 0) ** (1 / e[1])
    r = side + rng.uniform(2, 8, n)
    p = np.column_stack([x, r * np.cos(phi), r * np.sin(phi)])
    exact = field.signed_distance(p)
    radial = radial_distance_approximation(p, a, e)
    brute = oracle.nearest_sample_distance(p)  # the case has no pose
    # the exact distance never claims more clearance than the brute force allows
    assert np.all(exact <= brute + 1e-9)
    ratio = radial / exact
    assert np.all(radial >= exact - 1e-9)  # radial is only ever an upper bound
    assert np.median(ratio) > median_factor  # "several times over"
    assert ratio.max() > max_factor
    assert np.all(radial > brute)  # and it overshoots even the coarse brute force


def test_radial_estimate_matches_closed_form_for_equal_exponents():
    a = np.array([30.0, 10.0, 5.0])
    p = np.random.default_rng(9).normal(size=(100, 3)) * 30
    f = np.sum((p / a) ** 4, axis=1)
    want = np.linalg.norm(p, axis=1) * (1 - f ** (-1 / 4))
    assert np.allclose(radial_distance_approximation(p, a, [4, 4, 4]), want, atol=1e-9)
    assert np.allclose(
        radial_distance_approximation(_to_world(POSE, p), a, [4, 4, 4], world_T_local=POSE),
        want,
        atol=1e-9,
    )


# ----------------------------------------------------------------------------------------
# error bounds, repr, bad input


def test_error_bounds_and_repr():
    assert Sphere([0, 0, 0], 1).error_bound_mm == 0.0
    assert Box([1, 1, 1]).error_bound_mm == 0.0
    assert 0 < Ellipsoid([1, 2, 3]).error_bound_mm <= 1e-9
    assert 0 < Superquadric.from_liu().error_bound_mm <= 1e-6
    assert repr(Sphere([0, 0, 0], 2)) == "Sphere(center_mm=(0, 0, 0), radius_mm=2)"
    assert repr(Box([1, 2, 3])) == "Box(half_extents_mm=(1, 2, 3))"
    assert "world_T_local" in repr(Ellipsoid([1, 2, 3], world_T_local=POSE))
    for f in (
        Superquadric.from_liu(),
        Cylinder([0, 0, 0], [0, 0, 1], 1),
        HalfSpace([0] * 3, [1, 0, 0]),
    ):
        assert len(repr(f)) < 120


BAD_INPUTS = [
    (lambda: Sphere([0, 0, 0], 0.0), "radius_mm"),
    (lambda: Sphere([0, 0, 0], -1.0), "radius_mm"),
    (lambda: Sphere([0, 0, np.nan], 1.0), "center_mm"),
    (lambda: Sphere([0, 0], 1.0), "center_mm"),
    (lambda: Sphere([0, 0, 0], float("nan")), "radius_mm"),
    (lambda: Ellipsoid([1.0, 0.0, 2.0]), "semi_axes_mm"),
    (lambda: Ellipsoid([1.0, 2.0]), "semi_axes_mm"),
    (lambda: Ellipsoid([1.0, 2.0, np.inf]), "semi_axes_mm"),
    (lambda: Ellipsoid([1, 2, 3], world_T_local=np.eye(3)), "world_T_local"),
    (lambda: Ellipsoid([1, 2, 3], world_T_local=2 * np.eye(4)), "world_T_local"),
    (lambda: Capsule([0, 0, 0], [1, 1], 1.0), "p1_mm"),
    (lambda: Capsule([0, 0, 0], [1, 1, 1], 0.0), "radius_mm"),
    (lambda: Cylinder([0, 0, 0], [0, 0, 0], 1.0), "p1_mm"),
    (lambda: Cylinder([0, 0, 0], [0, 0, 1], -2.0), "radius_mm"),
    (lambda: Cylinder(["a", 0, 0], [0, 0, 1], 2.0), "p0_mm"),
    (lambda: Box([1, -1, 1]), "half_extents_mm"),
    (lambda: HalfSpace([0, 0, 0], [0, 0, 0]), "normal_mm"),
    (lambda: HalfSpace([0, 0, np.nan], [0, 0, 1]), "point_mm"),
    (lambda: Superquadric([1, 1, 1], [1.5, 2, 2]), "exponents"),
    (lambda: Superquadric([1, 1, 1], [2, 2, 100]), "exponents"),
    (lambda: Superquadric([1, 0, 1], [2, 2, 2]), "semi_axes_mm"),
    (lambda: Superquadric.from_liu(level=0.0), "level"),
    (lambda: Superquadric.from_liu(scales_mm=(60, 0.1)), "scales_mm"),
    (lambda: Sphere([0, 0, 0], 1).signed_distance([[0, 0]]), "points"),
    (lambda: Sphere([0, 0, 0], 1).signed_distance([0, np.nan, 0]), "points"),
    (lambda: ellipsoid_distance([0, 0, 0], [1, 1, -1]), "semi_axes_mm"),
    (lambda: superquadric_distance([0, 0, 0], [1, 1, 1], [2, 2]), "exponents"),
    (lambda: radial_distance_approximation([1, 0, 0], [1, 1, 1], [2, 2, 1]), "exponents"),
    (
        lambda: superquadric_distance_reference([1, 0, 0], [1, 1, 1], [2] * 3, n_starts=0),
        "n_starts",
    ),
]


@pytest.mark.parametrize(("make", "field"), BAD_INPUTS, ids=[f for _, f in BAD_INPUTS])
def test_bad_input_names_the_argument(make, field):
    with pytest.raises(InvalidInputError, match=f"^{field}:"):
        make()


def test_single_point_and_batch_shapes():
    s = Superquadric.from_liu()
    assert s.signed_distance([0.0, 5.0, 0.0]).shape == ()
    assert s.gradient([0.0, 5.0, 0.0]).shape == (3,)
    assert s.closest_point(np.zeros((4, 3))).shape == (4, 3)
    sd, x = ellipsoid_distance(np.zeros((0, 3)), [1, 2, 3])
    assert sd.shape == (0,) and x.shape == (0, 3)
