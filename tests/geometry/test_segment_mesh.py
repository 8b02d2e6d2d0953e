"""Segment-mesh intersection: the gridded numba kernels against a brute-force numpy oracle.

The oracle runs Moller-Trumbore over every triangle, written out in the same operation
order as the kernel, so the two must agree bit for bit: any_hit exactly, first_hit's ``t``
to 1e-12 and its face up to ties (several triangles met at the same ``t``). The one
exception, segments lying in a face's plane (rounding-noise determinant), has a test of
its own at the end.
"""

import numpy as np
import pytest
import trimesh

from needlekit.errors import InvalidInputError
from needlekit.geometry.segment_mesh import PARALLEL_MIN_SEGMENTS, SegmentMeshIntersector

# ----------------------------------------------------------------------------------------
# the oracle


def _mt(o, d, v0, e1, e2):
    """Moller-Trumbore, broadcast over the leading axes: ``t`` of the hit, inf if none."""
    ox, oy, oz = o[..., 0], o[..., 1], o[..., 2]
    dx, dy, dz = d[..., 0], d[..., 1], d[..., 2]
    e1x, e1y, e1z = e1[..., 0], e1[..., 1], e1[..., 2]
    e2x, e2y, e2z = e2[..., 0], e2[..., 1], e2[..., 2]
    px = dy * e2z - dz * e2y
    py = dz * e2x - dx * e2z
    pz = dx * e2y - dy * e2x
    det = e1x * px + e1y * py + e1z * pz
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        inv = 1.0 / det
        tx = ox - v0[..., 0]
        ty = oy - v0[..., 1]
        tz = oz - v0[..., 2]
        u = (tx * px + ty * py + tz * pz) * inv
        qx = ty * e1z - tz * e1y
        qy = tz * e1x - tx * e1z
        qz = tx * e1y - ty * e1x
        v = (dx * qx + dy * qy + dz * qz) * inv
        t = (e2x * qx + e2y * qy + e2z * qz) * inv
        hit = (det != 0.0) & (u >= 0.0) & (u <= 1.0) & (v >= 0.0) & (u + v <= 1.0)
        hit &= (t >= 0.0) & (t <= 1.0)
    return np.where(hit, t, np.inf)


def _triangles(vertices, faces):
    tri = np.asarray(vertices, dtype=float)[np.asarray(faces)]
    return tri[:, 0], tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]


def oracle(vertices, faces, p0, p1, chunk=128):
    """Every segment against every triangle: (hit (n,), smallest t (n,))."""
    v0, e1, e2 = _triangles(vertices, faces)
    t_min = np.full(p0.shape[0], np.inf)
    for s in range(0, p0.shape[0], chunk):
        o = p0[s : s + chunk, None, :]
        t = _mt(o, p1[s : s + chunk, None, :] - o, v0[None], e1[None], e2[None])
        t_min[s : s + chunk] = t.min(axis=1)
    return np.isfinite(t_min), t_min


def check_against_oracle(vertices, faces, p0, p1, **kwargs):
    """any_hit and first_hit of the grid equal the oracle's; returns the hit mask."""
    mesh = SegmentMeshIntersector(vertices, faces, **kwargs)
    want_hit, want_t = oracle(vertices, faces, p0, p1)
    hit = mesh.any_hit(p0, p1)
    np.testing.assert_array_equal(hit, want_hit)
    t, face = mesh.first_hit(p0, p1)
    np.testing.assert_array_equal(np.isfinite(t), want_hit)
    np.testing.assert_array_equal(face >= 0, want_hit)
    np.testing.assert_allclose(t[hit], want_t[hit], rtol=1e-12, atol=0.0)
    assert np.all(face[~hit] == -1) and np.all(np.isposinf(t[~hit]))
    # the face returned is one the oracle meets at the smallest t (one of them, on ties)
    v0, e1, e2 = _triangles(vertices, faces)
    f = face[hit]
    o = p0[hit]
    t_face = _mt(o, p1[hit] - o, v0[f], e1[f], e2[f])
    np.testing.assert_allclose(t_face, want_t[hit], rtol=1e-12, atol=0.0)
    return hit


# ----------------------------------------------------------------------------------------
# segment sets


def _unit(rng, n):
    x = rng.normal(size=(n, 3))
    return x / np.linalg.norm(x, axis=1, keepdims=True)


def sphere_segments(rng, vertices, faces, radius):
    """Inside, crossing, missing, tangent-ish, and aimed (to rounding) at edges and
    vertices of a sphere mesh centred at the origin."""
    n = 600
    parts = []
    # inside: both ends well within the sphere
    a = _unit(rng, n) * rng.uniform(0, 0.9 * radius, (n, 1))
    parts.append((a, _unit(rng, n) * rng.uniform(0, 0.9 * radius, (n, 1))))
    # crossing: one end inside, one outside (either way round)
    a = _unit(rng, n) * rng.uniform(0, 0.9 * radius, (n, 1))
    b = _unit(rng, n) * rng.uniform(1.1 * radius, 2.0 * radius, (n, 1))
    flip = rng.random(n) < 0.5
    parts.append((np.where(flip[:, None], a, b), np.where(flip[:, None], b, a)))
    # anywhere: random ends in a box around the sphere, and long segments missing it
    parts.append((rng.uniform(-1.6, 1.6, (n, 3)) * radius, rng.uniform(-1.6, 1.6, (n, 3)) * radius))
    c = _unit(rng, n) * 1.5 * radius
    parts.append((c + 3 * radius * np.array([1.0, 0.0, 0.0]), c - 3 * radius * np.array([1, 0, 0])))
    # tangent-ish: through a point near the surface, perpendicular to its radius
    p = _unit(rng, n)
    tangent = np.cross(p, _unit(rng, n))
    tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
    p = p * radius * rng.uniform(0.98, 1.01, (n, 1))
    half = rng.uniform(0.5, 30.0, (n, 1)) * tangent
    parts.append((p - half, p + half))
    # aimed at points of edges and at vertices, passing through or ending there (t = 1)
    edges = trimesh.geometry.faces_to_edges(np.asarray(faces))
    e = edges[rng.integers(0, len(edges), n)]
    s = rng.random((n, 1))
    on_edge = vertices[e[:, 0]] + s * (vertices[e[:, 1]] - vertices[e[:, 0]])
    start = rng.normal(0, 0.2 * radius, (n, 3))
    parts.append((start, start + 2.0 * (on_edge - start)))
    parts.append((start, on_edge))
    vertex = vertices[rng.integers(0, len(vertices), n)]
    parts.append((start, start + 2.0 * (vertex - start)))
    parts.append((start, vertex))
    p0 = np.concatenate([a for a, _ in parts])
    p1 = np.concatenate([b for _, b in parts])
    return np.ascontiguousarray(p0), np.ascontiguousarray(p1)


@pytest.fixture(scope="module")
def icosphere():
    mesh = trimesh.creation.icosphere(subdivisions=3, radius=50.0)
    return np.asarray(mesh.vertices), np.asarray(mesh.faces)


# ----------------------------------------------------------------------------------------
# (a) a sphere, (b) disjoint parts


def test_icosphere_random_segments_match_the_oracle(icosphere):
    vertices, faces = icosphere
    rng = np.random.default_rng(20240611)
    p0, p1 = sphere_segments(rng, vertices, faces, 50.0)
    assert p0.shape[0] >= PARALLEL_MIN_SEGMENTS  # the parallel kernel
    hit = check_against_oracle(vertices, faces, p0, p1)
    assert 0.2 < hit.mean() < 0.9
    # the serial kernel (small batches) gives the same answers
    mesh = SegmentMeshIntersector(vertices, faces)
    t_all, f_all = mesh.first_hit(p0, p1)
    for s in range(0, p0.shape[0], 700):
        t, f = mesh.first_hit(p0[s : s + 700], p1[s : s + 700])
        np.testing.assert_array_equal(t, t_all[s : s + 700])
        np.testing.assert_array_equal(f, f_all[s : s + 700])
        np.testing.assert_array_equal(
            mesh.any_hit(p0[s : s + 700], p1[s : s + 700]), f_all[s : s + 700] >= 0
        )


@pytest.mark.parametrize("cell_mm", [0.7, 4.0, 25.0, 500.0])
def test_any_cell_size_gives_the_same_answers(icosphere, cell_mm):
    vertices, faces = icosphere
    rng = np.random.default_rng(7)
    p0, p1 = sphere_segments(rng, vertices, faces, 50.0)
    check_against_oracle(vertices, faces, p0[::3], p1[::3], cell_mm=cell_mm)


def test_rotated_sphere_and_segments_on_cell_boundaries(icosphere):
    vertices, faces = icosphere
    rng = np.random.default_rng(11)
    rot = trimesh.transformations.random_rotation_matrix(rng.random(3))[:3, :3]
    vertices = vertices @ rot.T + [13.1, -7.7, 2.3]
    mesh = SegmentMeshIntersector(vertices, faces)
    p0, p1 = sphere_segments(rng, vertices - [13.1, -7.7, 2.3], faces, 50.0)
    p0 = p0[::2] + [13.1, -7.7, 2.3]
    p1 = p1[::2] + [13.1, -7.7, 2.3]
    # axis-parallel segments lying on the grid's cell faces and edges
    ticks = [
        mesh.grid_origin[a] + np.arange(mesh.grid_shape[a] + 1) * mesh.cell_mm for a in range(3)
    ]
    lines = []
    for a in range(3):
        b, c = (a + 1) % 3, (a + 2) % 3
        for yb in ticks[b]:
            for yc in ticks[c]:
                q0 = np.empty(3)
                q0[a], q0[b], q0[c] = ticks[a][0] - 5.0, yb, yc
                q1 = q0.copy()
                q1[a] = ticks[a][-1] + 5.0
                lines.append((q0, q1))
    q0 = np.array([q for q, _ in lines])
    q1 = np.array([q for _, q in lines])
    hit = check_against_oracle(
        vertices, faces, np.concatenate([p0, q0, q1]), np.concatenate([p1, q1, q0])
    )
    assert hit[p0.shape[0] :].any()


def test_several_disjoint_parts():
    box = trimesh.creation.box(extents=[20.0, 30.0, 10.0])
    cylinder = trimesh.creation.cylinder(radius=8.0, height=40.0, sections=24)
    cylinder.apply_translation([60.0, 5.0, -10.0])
    small = trimesh.creation.icosphere(subdivisions=2, radius=3.0)
    small.apply_translation([25.0, 40.0, 30.0])
    mesh = trimesh.util.concatenate([box, cylinder, small])
    vertices, faces = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    rng = np.random.default_rng(3)
    n = 3000
    lo, hi = vertices.min(axis=0) - 10.0, vertices.max(axis=0) + 10.0
    p0 = rng.uniform(lo, hi, (n, 3))
    p1 = p0 + rng.normal(0, 25.0, (n, 3))
    # and segments between the parts' centres (through the empty space between them)
    centres = np.array([[0.0, 0.0, 0.0], [60.0, 5.0, -10.0], [25.0, 40.0, 30.0]])
    i, j = rng.integers(0, 3, (2, 300))
    jitter = rng.normal(0, 2.0, (2, 300, 3))
    p0 = np.concatenate([p0, centres[i] + jitter[0]])
    p1 = np.concatenate([p1, centres[j] + jitter[1]])
    hit = check_against_oracle(vertices, faces, p0, p1)
    assert 0.1 < hit.mean() < 0.9
    # from inside the box out through the cylinder: the box is met first
    t, face = SegmentMeshIntersector(vertices, faces).first_hit([0.0, 0.0, 0.0], [80.0, 5.0, -10.0])
    assert face[0] < len(box.faces) and 0.0 < t[0] < 0.2


# ----------------------------------------------------------------------------------------
# (c) edges and vertices, (d) touching and stopping short


SQUARE_V = np.array([[0.0, 0.0, 0.0], [10.0, 0.0, 0.0], [10.0, 10.0, 0.0], [0.0, 10.0, 0.0]])
SQUARE_F = np.array([[0, 1, 2], [0, 2, 3]])


@pytest.mark.parametrize(
    "point",
    [
        [0.0, 0.0],  # vertices (two shared by both triangles, two of one)
        [10.0, 10.0],
        [10.0, 0.0],
        [0.0, 10.0],
        [5.0, 5.0],  # the shared diagonal
        [2.5, 2.5],
        [7.25, 7.25],
        [5.0, 0.0],  # the outer edges
        [10.0, 2.5],
        [6.5, 10.0],
        [0.0, 9.75],
    ],
)
@pytest.mark.parametrize("direction", [[0.0, 0.0, 1.0], [1.0, 2.0, 4.0], [-3.0, 0.5, -2.0]])
def test_segments_through_vertices_and_edges_hit(point, direction):
    # the coordinates are small dyadic numbers: the arithmetic is exact, so a segment
    # through an edge or vertex meets it exactly and must be counted
    mesh = SegmentMeshIntersector(SQUARE_V, SQUARE_F)
    x = np.array([point[0], point[1], 0.0])
    d = np.array(direction)
    p0, p1 = (x - d)[None], (x + d)[None]
    assert mesh.any_hit(p0, p1).tolist() == [True]
    t, face = mesh.first_hit(p0, p1)
    assert t[0] == 0.5
    v0, e1, e2 = _triangles(SQUARE_V, SQUARE_F)
    met = np.isfinite(_mt(p0, p1 - p0, v0, e1, e2))
    assert met.any() and met[face[0]]
    if point[0] == point[1]:  # on the diagonal both triangles are met: the smaller index
        assert met.all() and face[0] == 0
    check_against_oracle(SQUARE_V, SQUARE_F, p0, p1)


def test_segments_beside_the_square_miss():
    mesh = SegmentMeshIntersector(SQUARE_V, SQUARE_F)
    x = np.array([[-1e-9, 5.0, 0.0], [10.0 + 1e-9, 5.0, 0.0], [5.0, -1e-9, 0.0], [-1e-9, -1e-9, 0]])
    d = np.array([0.0, 0.0, 1.0])
    assert not mesh.any_hit(x - d, x + d).any()


def test_segment_ending_on_a_face_and_stopping_short():
    mesh = SegmentMeshIntersector(SQUARE_V, SQUARE_F)
    p0 = np.array([[3.0, 1.0, 5.0], [3.0, 1.0, 5.0], [3.0, 1.0, 0.0], [3.0, 1.0, 1e-9]])
    p1 = np.array([[3.0, 1.0, 0.0], [3.0, 1.0, 1e-9], [3.0, 1.0, 5.0], [3.0, 1.0, 5.0]])
    assert mesh.any_hit(p0, p1).tolist() == [True, False, True, False]
    t, face = mesh.first_hit(p0, p1)
    assert t[0] == 1.0 and face[0] == 0  # ends exactly on the face
    assert t[2] == 0.0 and face[2] == 0  # starts exactly on it
    assert np.isposinf(t[[1, 3]]).all() and (face[[1, 3]] == -1).all()
    # slanted, through a non-dyadic point: ending on the plane still counts
    q0 = np.array([[1.1, 2.3, 3.7]])
    q1 = np.array([[4.3, 0.9, 0.0]])
    assert mesh.any_hit(q0, q1).tolist() == [True]
    assert mesh.first_hit(q0, q1)[0][0] == 1.0
    check_against_oracle(SQUARE_V, SQUARE_F, np.concatenate([p0, q0]), np.concatenate([p1, q1]))


def test_in_plane_and_degenerate_segments_miss():
    mesh = SegmentMeshIntersector(SQUARE_V, SQUARE_F)
    p0 = np.array([[-5.0, 5.0, 0.0], [3.0, 3.0, 0.0], [3.0, 1.0, 0.0]])
    p1 = np.array([[15.0, 5.0, 0.0], [3.0, 3.0, 0.0], [3.0, 1.0, 0.0]])
    assert not mesh.any_hit(p0, p1).any()
    t, face = mesh.first_hit(p0, p1)
    assert np.isposinf(t).all() and (face == -1).all()


def test_single_pair_and_empty_batch(icosphere):
    mesh = SegmentMeshIntersector(*icosphere)
    hit = mesh.any_hit([0.0, 0.0, 0.0], [100.0, 0.0, 0.0])
    assert hit.shape == (1,) and hit[0]
    t, face = mesh.first_hit([0.0, 0.0, 0.0], [100.0, 0.0, 0.0])
    assert t.shape == (1,) and face.shape == (1,) and face.dtype == np.int64
    assert 0.49 < t[0] <= 0.5
    empty = np.zeros((0, 3))
    assert mesh.any_hit(empty, empty).shape == (0,)
    t, face = mesh.first_hit(empty, empty)
    assert t.shape == (0,) and face.shape == (0,)


def test_default_cell_size(icosphere):
    mesh = SegmentMeshIntersector(*icosphere)
    vertices, faces = icosphere
    tri = vertices[faces]
    mean_edge = np.linalg.norm(tri - np.roll(tri, 1, axis=1), axis=2).mean()
    assert mesh.cell_mm == pytest.approx(2.0 * mean_edge)
    assert mesh.n_faces == len(faces)
    # two tiny triangles far apart: the default grid stays within its cell budget
    tiny = np.array([[0.0, 0.0, 0.0], [1e-3, 0.0, 0.0], [0.0, 1e-3, 0.0]])
    v = np.concatenate([tiny, tiny + 1e4])
    f = [[0, 1, 2], [3, 4, 5]]
    mesh = SegmentMeshIntersector(v, f)
    assert 1_000_000 < np.prod(mesh.grid_shape) <= 2_000_000
    a = np.array([2e-4, 2e-4, 0.0])  # in the near triangle; a + 1e4 is in the far one
    p0 = np.array([a - [0.0, 0.0, 1.0], a - 0.1, a + 1e4 - [0.0, 0.0, 1e4]])
    p1 = np.array([a + [0.0, 0.0, 1.0], a + 1e4 + 0.1, a + 1e4 + [0.0, 0.0, 1.0]])
    assert check_against_oracle(v, f, p0, p1).all()


# ----------------------------------------------------------------------------------------
# (f) bad input


@pytest.mark.parametrize(
    ("vertices", "faces", "kwargs", "field"),
    [
        (np.zeros((4, 2)), [[0, 1, 2]], {}, "vertices"),
        (np.zeros((0, 3)), [[0, 1, 2]], {}, "vertices"),
        ([[0, 0, 0], [1, 0, np.nan], [0, 1, 0]], [[0, 1, 2]], {}, "vertices"),
        ([[0, 0, 0], [1, 0, np.inf], [0, 1, 0]], [[0, 1, 2]], {}, "vertices"),
        ("abc", [[0, 1, 2]], {}, "vertices"),
        (SQUARE_V, np.zeros((0, 3), int), {}, "faces"),
        (SQUARE_V, [[0, 1, 2, 3]], {}, "faces"),
        (SQUARE_V, [[0, 1, 4]], {}, "faces"),
        (SQUARE_V, [[0, -1, 2]], {}, "faces"),
        (SQUARE_V, [[0.0, 1.0, 2.0]], {}, "faces"),
        (SQUARE_V, SQUARE_F, {"cell_mm": 0.0}, "cell_mm"),
        (SQUARE_V, SQUARE_F, {"cell_mm": -1.0}, "cell_mm"),
        (SQUARE_V, SQUARE_F, {"cell_mm": np.nan}, "cell_mm"),
        (SQUARE_V, SQUARE_F, {"cell_mm": "big"}, "cell_mm"),
        (SQUARE_V * 1e6, SQUARE_F, {"cell_mm": 1e-3}, "cell_mm"),  # too many cells
    ],
)
def test_bad_mesh_input(vertices, faces, kwargs, field):
    with pytest.raises(InvalidInputError) as info:
        SegmentMeshIntersector(vertices, faces, **kwargs)
    assert info.value.field == field


@pytest.mark.parametrize(
    ("p0", "p1", "field"),
    [
        (np.zeros((4, 2)), np.zeros((4, 3)), "p0"),
        (np.zeros((4, 3, 1)), np.zeros((4, 3)), "p0"),
        (np.zeros((4, 3)), np.zeros(4), "p1"),
        (np.zeros((4, 3)), np.zeros((5, 3)), "p1"),
        ([[0.0, np.nan, 0.0]], [[1.0, 1.0, 1.0]], "p0"),
        ([[0.0, 0.0, 0.0]], [[1.0, np.inf, 1.0]], "p1"),
        ("here", [[1.0, 1.0, 1.0]], "p0"),
    ],
)
@pytest.mark.parametrize("method", ["any_hit", "first_hit"])
def test_bad_segment_input(p0, p1, field, method):
    mesh = SegmentMeshIntersector(SQUARE_V, SQUARE_F)
    with pytest.raises(InvalidInputError) as info:
        getattr(mesh, method)(p0, p1)
    assert info.value.field == field


def test_segments_in_face_planes_hit_a_subset_of_the_brute_force_hits(icosphere):
    # segments drawn in the plane of a face of a rotated sphere: the determinant of that
    # face is rounding noise, and so are its u, v, t; the brute-force test may then count
    # a "hit" anywhere in the plane, the grid only near the segment. The grid's hits are
    # always a subset, and every extra brute-force hit comes from such a face.
    vertices, faces = icosphere
    rng = np.random.default_rng(2)
    rot = trimesh.transformations.random_rotation_matrix(rng.random(3))[:3, :3]
    vertices = vertices @ rot.T + [3.3, -1.9, 7.1]
    n = 3000
    f = rng.integers(0, len(faces), n)
    v0, e1, e2 = _triangles(vertices, faces)
    ab = rng.uniform(-3.0, 4.0, (n, 4))
    p0 = v0[f] + ab[:, :1] * e1[f] + ab[:, 1:2] * e2[f]
    p1 = v0[f] + ab[:, 2:3] * e1[f] + ab[:, 3:4] * e2[f]
    mesh = SegmentMeshIntersector(vertices, faces)
    hit = mesh.any_hit(p0, p1)
    want, _ = oracle(vertices, faces, p0, p1)
    assert not np.any(hit & ~want)
    for s in np.flatnonzero(want & ~hit):
        d = p1[s] - p0[s]
        met = np.flatnonzero(np.isfinite(_mt(p0[s], d, v0, e1, e2)))
        det = np.einsum("ij,ij->i", e1[met], np.cross(d, e2[met]))
        scale = (
            np.linalg.norm(d) * np.linalg.norm(e1[met], axis=1) * np.linalg.norm(e2[met], axis=1)
        )
        assert np.all(np.abs(det) < 1e-12 * scale)
    # the others agree, first hits included
    same = ~(want & ~hit)
    check_against_oracle(vertices, faces, p0[same], p1[same])
