"""The voxel mesher: conforming, positively oriented, the organ's volume, outward surface;
and on a Med-RAD lung."""

import numpy as np
import pytest

from needlekit.tissue.meshing import (
    dihedral_angles_deg,
    mesh_mask,
    shape_quality,
)


def _ball(n=30, r=12.0, spacing=(1.0, 1.0, 1.0)):
    ijk = np.indices((n, n, n)).transpose(1, 2, 3, 0) - (n - 1) / 2
    return np.linalg.norm(ijk, axis=3) <= r, np.diag([*spacing, 1.0])


def _surface_volume(mesh):
    """Divergence theorem: V = 1/3 sum over outward faces of (area normal . centroid)."""
    p = mesh.nodes_mm[mesh.boundary_faces()]
    an = 0.5 * np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    return float(np.sum(np.einsum("ij,ij->i", an, p.mean(axis=1))) / 3.0)


def test_ball_mesh_conforming_oriented_and_of_the_right_volume():
    mask, aff = _ball()
    mesh = mesh_mask(mask, aff, target_tets=6000)
    vol = mesh.volumes_mm3()
    assert mesh.n_tets >= 6000 and np.all(vol > 0)
    # conforming: every interior face shared by exactly two tetrahedra, so the surface
    # alone encloses the summed volume (outward: positive)
    assert np.isclose(_surface_volume(mesh), vol.sum(), rtol=1e-12)
    assert abs(vol.sum() - mask.sum()) / mask.sum() < 0.05
    assert dihedral_angles_deg(mesh.nodes_mm, mesh.tets).min() > 44.9  # Kuhn, cubes: 45
    # a Kuhn tetrahedron of the unit cube: V = 1/6, edges 1, 1, 1, sqrt 2, sqrt 2, sqrt 3
    kuhn = 6 * np.sqrt(2) / 6 / (10 / 6) ** 1.5
    assert np.allclose(shape_quality(mesh.nodes_mm, mesh.tets), kuhn, rtol=1e-12)


def test_left_handed_affine_and_anisotropic_voxels():
    mask, _ = _ball(spacing=(1, 1, 1))
    aff = np.diag([-0.8, -0.8, 2.0, 1.0])  # LPS-like axes, thick slices
    mesh = mesh_mask(mask[:, :, ::2], aff, target_tets=3000)
    assert np.all(mesh.volumes_mm3() > 0)
    assert _surface_volume(mesh) > 0


def test_components_dropped_or_chosen_by_seed():
    mask = np.zeros((40, 20, 20), bool)
    mask[2:18, 2:18, 2:18] = True  # a big block
    mask[22:38, 4:16, 4:16] = True  # another
    mask[39, 0, 0] = True  # a speck
    both = mesh_mask(mask, np.eye(4), cell_mm=2.0)
    one = mesh_mask(mask, np.eye(4), cell_mm=2.0, seed_mm=[30.0, 10.0, 10.0])
    assert one.n_tets < both.n_tets and one.nodes_mm[:, 0].min() > 20


@pytest.mark.slow
@pytest.mark.realdata
def test_medrad_lung1_meshes_to_50k_positive_tetrahedra(medrad_dir):
    from needlekit.io.medrad_paths import patient_folder
    from needlekit.io.volumes import read_mask

    folder = patient_folder("lung", 1, medrad_dir)
    m = read_mask(folder / "pleuralBoundary.nii.gz")
    mesh = mesh_mask(m.data, m.affine)
    assert mesh.n_tets >= 50_000
    assert np.all(mesh.volumes_mm3() > 0)
    assert dihedral_angles_deg(mesh.nodes_mm, mesh.tets).min() > 40.0
    assert abs(mesh.volumes_mm3().sum() / (m.data.sum() * np.prod(m.spacing_mm)) - 1) < 0.02
