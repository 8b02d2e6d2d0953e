"""Med-RAD reader: on the real data (tests marked ``realdata``, which skip when it is
absent; the data comes from tests/conftest.py's fixtures) and on synthetic folders."""

import os
from pathlib import Path

import numpy as np
import pytest

from needlekit.anatomy.scene import Role
from needlekit.anatomy.voxel import VoxelSDF
from needlekit.errors import InvalidInputError
from needlekit.io.medrad import MEDRAD_ENV, list_patients, load_medrad, medrad_root
from needlekit.io.volumes import read_mask


@pytest.mark.realdata
def test_patients_are_listed(medrad_dir):
    assert list_patients("lung", medrad_dir) == [1, 2, 3, 4, 5]
    assert list_patients("liver", medrad_dir) == [1, 2, 3, 4, 5]


@pytest.mark.realdata
@pytest.mark.slow
def test_lung_case_has_the_promised_structures(medrad_lung1):
    lung1 = medrad_lung1
    roles = {s.name: s.role for s in lung1.scene.structures}
    assert roles == {
        "pleuralBoundary": Role.ALLOWED_REGION,
        "bronchialTree": Role.OBSTACLE,
        "vessels": Role.OBSTACLE,
        "fissures": Role.OBSTACLE,
        "nodule": Role.TARGET,
    }
    assert [s.name for s in lung1.starts] == [f"start{i}" for i in range(1, 6)]
    assert set(lung1.targets_mm) == {"target"}
    starts = np.array([s.world_T_tip[:3, 3] for s in lung1.starts])
    # the combined obstacle field equals the minimum over the per-structure fields
    rng = np.random.default_rng(0)
    pts = starts[:, None, :] + rng.normal(0, 5, (5, 40, 3))
    pts = pts.reshape(-1, 3)
    combined = lung1.scene.obstacle_field().signed_distance(pts)
    per = lung1.scene.signed_distance(
        pts, ["pleuralBoundary", "bronchialTree", "vessels", "fissures"]
    )
    ref = np.minimum.reduce(
        [-per["pleuralBoundary"], per["bronchialTree"], per["vessels"], per["fissures"]]
    )
    tol = lung1.scene.obstacle_field().error_bound_mm + lung1.scene["vessels"].field.error_bound_mm
    assert np.all(np.abs(combined - ref) <= tol)


def _airway_and_nodule(folder: Path):
    files = {p.name.lower(): p for p in folder.iterdir()}
    return files


@pytest.mark.realdata
@pytest.mark.slow
@pytest.mark.parametrize("patient", [1, 2, 3, 4, 5])
def test_lung_targets_in_nodule_and_starts_on_the_airway_wall(medrad_dir, patient):
    folder = medrad_dir / "Lungs" / "TumorTargetEnvironments" / f"Patient{patient}"
    nodule = VoxelSDF.from_mask(read_mask(folder / "nodule.nii.gz"))
    airway = VoxelSDF.from_mask(read_mask(folder / "bronchialTree.nii.gz"), padding_mm=5.0)
    case_target = np.loadtxt(folder / "target.txt")
    assert nodule.signed_distance(case_target) <= nodule.error_bound_mm
    for i in range(1, 6):
        pose = np.loadtxt(folder / f"start{i}.txt")
        d = float(airway.signed_distance(pose[:3, 3]))
        # on the wall: within 0.7 mm of the segmented airway (plus the field's bound)
        assert abs(d) <= 0.7 + airway.error_bound_mm, (patient, i, d)


@pytest.mark.realdata
@pytest.mark.slow
@pytest.mark.parametrize("patient", [1, 2, 3, 4, 5])
def test_liver_targets_lie_in_their_nodules(medrad_dir, patient):
    folder = medrad_dir / "Liver" / f"Patient{patient}"
    files = {p.name.lower(): p for p in folder.iterdir()}
    targets = sorted(
        n for n in files if n.startswith("target") and n.endswith(".txt") and "_" not in n
    )
    assert targets
    nodules = {}
    for t in targets:
        suffix = t[len("target") : -len(".txt")]
        name = f"nodule{suffix}.nii.gz"
        if name not in nodules:
            nodules[name] = VoxelSDF.from_mask(read_mask(files[name]))
        field = nodules[name]
        assert field.signed_distance(np.loadtxt(files[t])) <= field.error_bound_mm


@pytest.mark.realdata
@pytest.mark.slow
def test_liver_case_pairs_starts_with_targets(medrad_dir):
    case = load_medrad("liver", 2, medrad_dir)
    assert set(case.targets_mm) == {"target1", "target2"}
    assert [(s.name, s.target) for s in case.starts] == [
        ("target1_start1", "target1"),
        ("target1_start2", "target1"),
        ("target2_start1", "target2"),
    ]
    assert {s.name for s in case.scene.by_role("target")} == {"nodule1", "nodule2"}
    assert case.start(2).name == "target1_start2"
    with pytest.raises(InvalidInputError, match="start"):
        case.start(9)


def test_bad_arguments(tmp_path, monkeypatch):
    # a synthetic folder with one (empty) lung patient: no real data needed
    empty = tmp_path / "Lungs" / "TumorTargetEnvironments" / "Patient1"
    empty.mkdir(parents=True)
    with pytest.raises(InvalidInputError, match="organ"):
        load_medrad("brain", 1, tmp_path)
    with pytest.raises(InvalidInputError, match="patient"):
        load_medrad("lung", 42, tmp_path)
    with pytest.raises(InvalidInputError, match="root"):
        medrad_root(tmp_path / "nope")
    monkeypatch.setenv(MEDRAD_ENV, os.fspath(tmp_path / "missing"))
    with pytest.raises(InvalidInputError, match=MEDRAD_ENV):
        medrad_root()
    with pytest.raises(InvalidInputError, match="missing segmentation"):
        load_medrad("lung", 1, tmp_path)


def _world_points(mask):
    idx = np.argwhere(mask.data)
    return idx @ mask.affine[:3, :3].T + mask.affine[:3, 3]


@pytest.mark.parametrize("kind", ["shift", "resample"])
def test_masks_on_other_grids_are_aligned_through_their_affines(kind):
    from needlekit.io.medrad_prepare import _align
    from needlekit.io.volumes import Mask

    ref = Mask(np.zeros((40, 30, 20), bool), np.diag([0.5, 0.5, 0.7, 1.0]))
    data = np.zeros((25, 25, 25), bool)
    data[5:9, 10:12, 3:6] = True
    affine = np.diag([0.5, 0.5, 0.7, 1.0])
    affine[:3, 3] = [3.0, 2.5, 2.1]  # 6, 5 and 3 voxels away from the reference grid
    if kind == "resample":
        affine[:3, :3] = np.diag([-0.5, 0.5, 0.7])  # flipped x: not a plain shift
        affine[0, 3] = 15.0
    other = Mask(data, affine)
    got = _align(other, ref, "other")
    assert got.shape == ref.shape and np.array_equal(got.affine, ref.affine)
    # the same world points are set
    a = np.array(sorted(map(tuple, np.round(_world_points(other), 6))))
    b = np.array(sorted(map(tuple, np.round(_world_points(got), 6))))
    assert np.allclose(a, b)


@pytest.mark.realdata
@pytest.mark.slow
@pytest.mark.parametrize(
    ("organ", "patient"), [(o, p) for o in ("lung", "liver") for p in range(1, 6)]
)
def test_every_patient_loads_with_starts_targets_and_an_obstacle_field(medrad_dir, organ, patient):
    case = load_medrad(organ, patient, medrad_dir)
    assert case.starts and case.targets_mm
    field = case.scene.obstacle_field()
    starts = np.array([s.world_T_tip[:3, 3] for s in case.starts])
    targets = np.array(list(case.targets_mm.values()))
    # starts and targets lie inside the grid of the free space, near or in the free space
    d = field.signed_distance(np.vstack([starts, targets]))
    assert np.all(np.isfinite(d))
    assert np.all(d[len(starts) :] > -5.0)  # targets in nodules are clear of the obstacles
    for s in case.starts:
        assert s.target in case.targets_mm


@pytest.mark.realdata
@pytest.mark.slow
def test_lung1_starts_clear_the_exact_collision_test_only_with_the_start_exclusion(medrad_lung1):
    lung1 = medrad_lung1
    obs = lung1.voxel_obstacles(needle_diameter_mm=1.0)
    assert obs.min_distance_mm == pytest.approx(1.0236, abs=1e-4)
    for s in lung1.starts:
        p = s.world_T_tip[:3, 3]
        assert obs.collides(p)  # on the airway wall
        assert not obs.collides(p, exclude_near=p, exclusion_mm=3.0)
    target = lung1.targets_mm["target"]
    assert not obs.collides(target)  # the nodule is not an obstacle


@pytest.mark.realdata
@pytest.mark.slow
def test_a_lung_scene_is_boxed_and_drawn_without_building_its_structures(medrad_dir):
    """Drawing a patient (what `report` and `scene render` do) boxes every structure
    from its mask and meshes it from its preview: no structure's full field is built
    (lung 1: 15 s and 1.3 GB of cache entries before), and the box is the built field's."""
    from needlekit.anatomy.fields import LazyField
    from needlekit.report.scene3d import scene_figure

    case = load_medrad("lung", 1, medrad_dir)  # the session's cache (tests/conftest.py)
    lazy = [s.field for s in case.scene.structures if isinstance(s.field, LazyField)]
    assert len(lazy) == 5
    box = case.scene.bounds()
    fig = scene_figure(case.scene)
    assert len(fig.data) >= 5 and np.all(np.isfinite(box))
    assert not any(f.built for f in lazy)
    nodule = case.scene["nodule"].field
    unbuilt = nodule.bounds()
    nodule.get()
    assert nodule.built and np.array_equal(unbuilt, nodule.bounds())


def test_a_prepared_structure_is_boxed_without_building_it():
    """The loader's lazy field without the cache (io.medrad_prepare) boxes a structure
    as its built field does, bit for bit, without building it."""
    from needlekit.io.medrad_prepare import _lazy_sdf
    from needlekit.io.volumes import Mask

    m = np.zeros((40, 30, 20), bool)
    m[5:30, 8:12, 3:17] = True
    affine = np.array([[0.0, -0.7, 0.0, 12.0], [0.8, 0.0, 0.0, -30.0],
                       [0.0, 0.0, 1.25, 5.5], [0, 0, 0, 1]])  # fmt: skip
    field = _lazy_sdf(Mask(m, affine, None), "a plate")
    box = field.bounds()
    assert not field.built
    assert np.array_equal(box, VoxelSDF.from_mask(m, affine).bounds())
