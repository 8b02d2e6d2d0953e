"""Meshes: file formats, exact distance and inside tests against references, voxel SDFs
against the exact distance within their stated bounds, malformed input."""

import numpy as np
import pytest
import trimesh

from needlekit.anatomy.mesh import (
    ExactMeshDistance,
    _inside_by_parity,
    _point_triangle_dist2_batch,
    _point_triangle_dist2_reference,
    voxelize_mesh_sdf,
    winding_numbers,
    winding_numbers_reference,
)
from needlekit.errors import InvalidInputError
from needlekit.io.meshes import read_mesh, write_mesh


def box_sdf(points, half):
    q = np.abs(points) - half
    outside = np.linalg.norm(np.maximum(q, 0.0), axis=1)
    return outside + np.minimum(q.max(axis=1), 0.0)


def rotated(mesh, seed):
    m = mesh.copy()
    rot = trimesh.transformations.random_rotation_matrix(np.random.default_rng(seed).random(3))
    rot[:3, 3] = [3.0, -7.0, 11.0]
    m.apply_transform(rot)
    return m


@pytest.fixture(scope="module")
def sphere():
    return trimesh.creation.icosphere(subdivisions=3, radius=8.0)


@pytest.fixture(scope="module")
def annulus():
    """Non-convex and rotated: rays cross it up to four times."""
    return rotated(trimesh.creation.annulus(r_min=3.0, r_max=8.0, height=5.0), 1)


# ----------------------------------------------------------------------------------------
# kernels and the exact field


def test_point_triangle_distance_matches_reference_and_trimesh():
    rng = np.random.default_rng(0)
    tri = rng.normal(0, 5, (400, 3, 3))
    tri[:50, 2] = tri[:50, 0] + 1e-3 * rng.normal(size=(50, 3)) + (tri[:50, 1] - tri[:50, 0])
    points = rng.normal(0, 8, (400, 3))
    idx = np.arange(400)
    got = np.empty(400)
    _point_triangle_dist2_batch(points, np.ascontiguousarray(tri), idx, got)
    ref = np.array([_point_triangle_dist2_reference(points[i : i + 1], *tri[i])[0] for i in idx])
    assert np.allclose(got, ref, rtol=1e-9, atol=1e-9)
    mesh = trimesh.Trimesh(tri.reshape(-1, 3), np.arange(1200).reshape(-1, 3), process=False)
    _, dist, _ = trimesh.proximity.closest_point(mesh, points[:1])
    assert np.sqrt(min(_d2(points[0], t) for t in tri)) == pytest.approx(dist[0], abs=1e-9)


def _d2(p, t):
    out = np.empty(1)
    _point_triangle_dist2_batch(p[None], t[None].copy(), np.zeros(1, np.int64), out)
    return out[0]


def test_winding_numbers_kernel_matches_reference(annulus):
    pts = np.random.default_rng(1).uniform(-12, 12, (500, 3)) + annulus.centroid
    fast = winding_numbers(annulus, pts)
    assert np.abs(fast - winding_numbers_reference(annulus, pts)).max() < 1e-12
    assert np.all(np.abs(fast - np.round(fast)) < 1e-9)  # 0 or 1 off the surface


def test_exact_distance_of_a_box_is_the_analytic_one():
    half = np.array([5.0, 10.0, 15.0])
    field = ExactMeshDistance(trimesh.creation.box(extents=2 * half))
    pts = np.random.default_rng(2).uniform(-25, 25, (2000, 3))
    assert np.abs(field.signed_distance(pts) - box_sdf(pts, half)).max() < 1e-9
    assert np.allclose(field.bounds(), [-half, half])


def test_inside_test_ignores_orientation(sphere):
    inverted = sphere.copy()
    inverted.invert()
    pts = np.random.default_rng(3).uniform(-10, 10, (800, 3))
    a, b = ExactMeshDistance(sphere), ExactMeshDistance(inverted)
    assert np.array_equal(a.inside(pts), b.inside(pts))
    assert np.allclose(a.signed_distance(pts), b.signed_distance(pts))


def test_exact_gradient_is_unit_and_matches_finite_differences(sphere):
    field = ExactMeshDistance(sphere)
    pts = np.random.default_rng(4).normal(size=(200, 3))
    pts = (
        pts
        / np.linalg.norm(pts, axis=1, keepdims=True)
        * np.random.default_rng(5).uniform(9, 14, (200, 1))
    )
    g = field.gradient(pts)
    assert np.allclose(np.linalg.norm(g, axis=1), 1.0)
    step = 1e-5
    fd = np.stack(
        [
            (field.signed_distance(pts + step * e) - field.signed_distance(pts - step * e))
            / (2 * step)
            for e in np.eye(3)
        ],
        axis=1,
    )
    assert np.median(np.abs(fd - g).max(axis=1)) < 1e-6


# ----------------------------------------------------------------------------------------
# voxelisation


@pytest.mark.parametrize("name", ["aligned_box", "rotated_box", "sphere", "annulus", "inverted"])
def test_parity_signs_match_winding_numbers(name, sphere, annulus):
    meshes = {
        "aligned_box": trimesh.creation.box(extents=(10, 8, 6)),  # vertices and edges on rays
        "rotated_box": rotated(trimesh.creation.box(extents=(10, 8, 6)), 7),
        "sphere": sphere,
        "annulus": annulus,
    }
    mesh = meshes.get(name)
    if mesh is None:
        mesh = sphere.copy()
        mesh.invert()
    sdf = voxelize_mesh_sdf(mesh, 0.5 if "box" in name else 0.8, 1.5)
    exact = ExactMeshDistance(mesh)
    centres = sdf.voxel_centres()
    differ = (sdf.values.ravel() < 0) != exact.inside(centres)
    # only centres exactly on the surface (where inside is a matter of taste) may differ
    assert np.abs(exact.signed_distance(centres[differ])).max(initial=0.0) < 1e-9
    assert np.any(sdf.values < 0)


def test_parity_kernel_counts_rays_through_shared_vertices_once():
    # an octahedron with its vertices exactly on grid columns
    octa = trimesh.Trimesh(
        [[3, 0, 0], [-3, 0, 0], [0, 3, 0], [0, -3, 0], [0, 0, 3], [0, 0, -3]],
        [[0, 2, 4], [2, 1, 4], [1, 3, 4], [3, 0, 4], [2, 0, 5], [1, 2, 5], [3, 1, 5], [0, 3, 5]],
    )
    assert octa.is_watertight and octa.volume > 0
    origin = np.array([-5.0, -5.0, -5.0])
    inside = _inside_by_parity(np.ascontiguousarray(octa.triangles), origin, 1.0, (11, 11, 11))
    idx = np.indices((11, 11, 11)).reshape(3, -1).T + origin
    expected = np.abs(idx).sum(axis=1) < 3  # strictly inside |x| + |y| + |z| < 3
    on_surface = np.abs(idx).sum(axis=1) == 3
    assert np.array_equal(inside.ravel()[~on_surface], expected[~on_surface])


@pytest.mark.parametrize("h", [1.0, 0.6])
def test_voxel_sdf_within_bound_of_exact_distance(sphere, annulus, h):
    for mesh in (sphere, annulus):
        sdf = voxelize_mesh_sdf(mesh, h, 4.0)
        exact = ExactMeshDistance(mesh)
        r = 0.5 * np.sqrt(3) * h
        assert sdf.error_bound_mm == pytest.approx(2 * r, rel=1e-5)
        rng = np.random.default_rng(6)
        u = rng.uniform(0, np.array(sdf.shape) - 1, (1500, 3))
        pts = u @ sdf.affine[:3, :3].T + sdf.affine[:3, 3]
        d = exact.signed_distance(pts)
        err = np.abs(sdf.signed_distance(pts) - d)
        assert err.max() <= sdf.error_bound_mm
        # within exact_band - r of the surface all 8 corners are exact: bound r
        band = 2 * 2 * r
        near = np.abs(d) <= band - r
        assert near.sum() > 200
        assert err[near].max() <= r + 1e-5


def test_values_in_the_band_are_exact(sphere):
    sdf = voxelize_mesh_sdf(sphere, 0.8, 3.0, exact_band_mm=2.0)
    centres = sdf.voxel_centres()[::4]
    values = sdf.values.ravel()[::4]
    d = ExactMeshDistance(sphere).signed_distance(centres)
    band = np.abs(d) <= 2.0
    assert band.sum() > 500
    assert np.abs(values[band] - d[band]).max() < 1e-5  # float32
    assert np.abs(values - d).max() <= sdf.value_error_mm


def test_exact_everywhere_halves_the_bound(annulus):
    sdf = voxelize_mesh_sdf(annulus, 0.8, 3.0, exact_band_mm=np.inf)
    r = 0.5 * np.sqrt(3) * 0.8
    assert sdf.error_bound_mm == pytest.approx(r, rel=1e-5)
    pts = sdf.voxel_centres()[::7]
    assert (
        np.abs(sdf.signed_distance(pts) - ExactMeshDistance(annulus).signed_distance(pts)).max()
        < 1e-5
    )


# ----------------------------------------------------------------------------------------
# files


@pytest.mark.parametrize("ext", [".stl", ".obj", ".ply", ".vtk"])
def test_every_format_round_trips(tmp_path, annulus, ext):
    path = write_mesh(tmp_path / f"mesh{ext}", annulus)
    back = read_mesh(path)
    assert back.is_watertight
    assert len(back.faces) == len(annulus.faces)
    assert back.volume == pytest.approx(annulus.volume, rel=1e-6)
    pts = np.random.default_rng(8).uniform(-10, 10, (200, 3)) + annulus.centroid
    assert np.allclose(
        ExactMeshDistance(back).signed_distance(pts),
        ExactMeshDistance(annulus).signed_distance(pts),
        atol=1e-4,  # STL stores float32
    )


CUBE_51 = """# vtk DataFile Version 5.1
cube written by VTK 9 (quads)
ASCII
DATASET POLYDATA
POINTS 8 float
0 0 0 1 0 0 1 1 0
0 1 0 0 0 1 1 0 1
1 1 1 0 1 1
METADATA
INFORMATION 0

POLYGONS 7 24
OFFSETS vtktypeint64
0 4 8 12 16 20 24
CONNECTIVITY vtktypeint64
0 3 2 1 4 5 6 7 0 1 5 4
2 3 7 6 0 4 7 3 1 2 6 5
POINT_DATA 8
SCALARS dist float 1
LOOKUP_TABLE default
0 0 0 0 0 0 0 0
"""

CUBE_STRIPS_42 = """# vtk DataFile Version 4.2
two strips and two quads
ASCII

DATASET POLYDATA
POINTS 8 double
0 0 0 1 0 0 1 1 0 0 1 0
0 0 1 1 0 1 1 1 1 0 1 1
TRIANGLE_STRIPS 2 20
9 0 3 1 2 5 6 4 7 0
9 0 4 3 7 2 6 1 5 0
"""


def test_vtk_51_offsets_quads_and_metadata(tmp_path):
    path = tmp_path / "cube.vtk"
    path.write_text(CUBE_51)
    cube = read_mesh(path)
    assert len(cube.faces) == 12 and cube.is_watertight
    assert abs(cube.volume) == pytest.approx(1.0)


def test_vtk_triangle_strips(tmp_path):
    path = tmp_path / "strips.vtk"
    path.write_text(CUBE_STRIPS_42)
    mesh = read_mesh(path)
    assert len(mesh.faces) == 14
    assert np.allclose(mesh.bounds, [[0, 0, 0], [1, 1, 1]])


@pytest.mark.parametrize(
    ("name", "content", "match"),
    [
        ("missing.stl", None, "file not found"),
        ("mesh.off", b"OFF\n", "unsupported extension"),
        ("bad.stl", b"solid x\nfacet normal oops\n", "cannot read mesh|no triangles"),
        ("bin.vtk", b"# vtk DataFile Version 4.2\nt\nBINARY\nDATASET POLYDATA\n", "only ASCII"),
        ("grid.vtk", b"# vtk DataFile Version 4.2\nt\nASCII\nDATASET UNSTRUCTURED_GRID\n",
         "POLYDATA"),
        ("idx.vtk", b"# vtk DataFile Version 4.2\nt\nASCII\nDATASET POLYDATA\nPOINTS 3 float\n"
         b"0 0 0 1 0 0 0 1 0\nPOLYGONS 1 4\n3 0 1 7\n", "out of range"),
        ("short.vtk", b"# vtk DataFile Version 4.2\nt\nASCII\nDATASET POLYDATA\nPOINTS 3 float\n"
         b"0 0 0 1 0\n", "file ends"),
        ("none.vtk", b"# vtk DataFile Version 4.2\nt\nASCII\nDATASET POLYDATA\nPOINTS 1 float\n"
         b"0 0 0\n", "no POINTS or no POLYGONS"),
        ("text.vtk", b"hello\n\n\n\n", "legacy VTK"),
        ("field.vtk", b"# vtk DataFile Version 4.2\nt\nASCII\nDATASET POLYDATA\nFIELD f 1\n",
         "unsupported VTK section"),
    ],
)  # fmt: skip
def test_bad_mesh_files_name_the_file(tmp_path, name, content, match):
    path = tmp_path / name
    if content is not None:
        path.write_bytes(content)
    with pytest.raises(InvalidInputError, match=match) as info:
        read_mesh(path)
    assert info.value.field == str(path)


def test_open_or_inconsistent_meshes_are_refused(sphere):
    holed = sphere.copy()
    holed.update_faces(np.arange(len(holed.faces)) != 0)
    with pytest.raises(InvalidInputError, match=r"not watertight \(3 edges"):
        ExactMeshDistance(holed)
    with pytest.raises(InvalidInputError, match="not watertight"):
        voxelize_mesh_sdf(holed, 1.0)
    flipped = sphere.copy()
    faces = flipped.faces.copy()
    faces[0] = faces[0, ::-1]
    flipped.faces = faces
    with pytest.raises(InvalidInputError, match="inconsistent"):
        ExactMeshDistance(flipped)
    with pytest.raises(InvalidInputError, match=r"trimesh\.Trimesh"):
        ExactMeshDistance(np.zeros((3, 3)))
    with pytest.raises(InvalidInputError, match="voxel_size_mm"):
        voxelize_mesh_sdf(sphere, 0.0)
    with pytest.raises(InvalidInputError, match="padding_mm"):
        voxelize_mesh_sdf(sphere, 1.0, -1.0)
    with pytest.raises(InvalidInputError, match="unsupported extension"):
        write_mesh("mesh.off", sphere)
