"""The entry surface of a straight needle from a mesh or from the boundary of a mask,
beside the analytic surface they approximate."""

import json

import numpy as np
import pytest
import trimesh

from needlekit.anatomy.mesh import ExactMeshDistance
from needlekit.anatomy.primitives import Capsule, Sphere
from needlekit.anatomy.scene import Role, Scene, Structure
from needlekit.anatomy.voxel import VoxelSDF
from needlekit.cli import main
from needlekit.io.volumes import write_mask_nifti
from needlekit.planning.straight.cfrw import ENTRY_TOL_MM, cfrw_map
from needlekit.planning.straight.problem import StraightNeedle, StraightProblem

R = 60.0
VESSEL = Capsule([-40.0, 6.0, 25.0], [40.0, 6.0, 25.0], 3.0)


def _map(body):
    scene = Scene(
        [
            Structure("skin", Role.ENTRY_SURFACE, body),
            Structure("vessel", Role.OBSTACLE, VESSEL),
        ]
    )
    pr = StraightProblem(scene, [0.0, 0.0, 0.0], "skin", StraightNeedle(1.0, 100.0))
    return cfrw_map(pr, resolution_deg=5.0)


def _ball_mask(voxel_mm):
    n = int(np.ceil(R / voxel_mm)) + 4
    ax = (np.arange(-n, n + 1)) * voxel_mm
    x, y, z = np.meshgrid(ax, ax, ax, indexing="ij")
    affine = np.diag([voxel_mm, voxel_mm, voxel_mm, 1.0])
    affine[:3, 3] = -n * voxel_mm
    return (x * x + y * y + z * z) <= R * R, affine


@pytest.mark.slow
def test_mesh_and_mask_surfaces_give_the_sphere_map_within_their_bounds():
    exact = _map(Sphere([0.0, 0.0, 0.0], R))
    mesh = trimesh.creation.icosphere(subdivisions=4, radius=R)
    # the flat faces lie inside the sphere by at most their sagitta
    sagitta = R - float(np.min(np.linalg.norm(mesh.triangles_center, axis=1)))
    by_mesh = _map(ExactMeshDistance(mesh))
    mask, affine = _ball_mask(1.0)
    grid = VoxelSDF.from_mask(mask, affine)
    by_mask = _map(grid)
    assert np.allclose(exact.length_mm, R)
    ok = np.isfinite(by_mesh.length_mm)
    # the crossing is bisected to ENTRY_TOL_MM, its outer end reported
    assert ok.all() and np.all(by_mesh.length_mm <= R + ENTRY_TOL_MM)
    assert np.all(by_mesh.length_mm >= R - sagitta)
    # the mask's surface is the boundary of its voxel boxes: within its stated bound
    assert np.all(np.abs(by_mask.length_mm - R) <= grid.error_bound_mm)
    # the same obstacles, nearly the same directions: the clearances agree to the entry's
    # shift along the needle
    for m in (by_mesh, by_mask):
        both = np.isfinite(m.clearance_mm) & np.isfinite(exact.clearance_mm)
        assert np.max(np.abs(m.clearance_mm[both] - exact.clearance_mm[both])) <= 0.5
        assert abs(int(m.feasible.sum()) - int(exact.feasible.sum())) <= 0.02 * exact.blocked.size


SCENARIO = """\
version: 1
name: a mesh skin and a mask vessel
structures:
  - {{name: skin, role: entry_surface, mesh: {{path: {skin}, voxel_size_mm: 1.0}}}}
  - {{name: vessel, role: obstacle, mask: {{path: {vessel}}}}}
needle: {{diameter_mm: 2.0, max_length_mm: 100}}
straight:
  entry_surface: skin
  targets: [[0, 0, 0], [0, -12, 0]]
  gamma_mm: 1.5
  resolution_deg: 5
"""


def test_a_scenario_with_a_mesh_skin_and_a_mask_vessel_plans_and_verifies(tmp_path, capsys):
    skin = tmp_path / "skin.stl"
    trimesh.creation.icosphere(subdivisions=3, radius=R).export(skin)
    ax = np.arange(-50, 51) * 1.0
    x, y, z = np.meshgrid(ax, ax, ax, indexing="ij")
    tube = ((y - 6.0) ** 2 + (z - 25.0) ** 2 <= 9.0) & (np.abs(x) <= 40.0)
    affine = np.eye(4)
    affine[:3, 3] = -50.0
    vessel = write_mask_nifti(tmp_path / "vessel.nii.gz", tube, affine)
    path = tmp_path / "case.yaml"
    path.write_text(SCENARIO.format(skin=skin, vessel=vessel))
    out = tmp_path / "multi.json"
    assert main(["multi", str(path), "--out", str(out)]) == 0
    rec = json.loads(out.read_text())
    assert rec["status"] == "solved" and len(rec["needles"]) == 2
    for n in rec["needles"]:
        assert n["clearance_mm"] >= 1.5
        # the entry on the voxelised icosphere's surface
        assert R - 2.5 <= np.linalg.norm(n["entry_mm"]) <= R + 2.5
    assert main(["verify", str(path), str(out)]) == 0
    assert main(["cfrw", str(path), "--out", str(tmp_path / "cfrw.json")]) == 0
    assert "directions at 5 deg clear" in capsys.readouterr().out


@pytest.mark.parametrize("voxel_mm", [2.0])
def test_a_coarse_mask_surface_still_holds_its_bound(voxel_mm):
    mask, affine = _ball_mask(voxel_mm)
    grid = VoxelSDF.from_mask(mask, affine)
    m = _map(grid)
    assert np.all(np.abs(m.length_mm - R) <= grid.error_bound_mm)
