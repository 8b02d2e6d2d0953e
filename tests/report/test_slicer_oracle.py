"""``needlekit slicer`` read back by 3D Slicer's own classes (the ``slicer-core`` wheel,
``needlekit[slicer]``, which the ``test`` extra installs): the bundle opened as Slicer
opens a dropped ``.mrb`` (``vtkMRMLApplicationLogic.OpenSlicerDataBundle``: unzip, find
the ``.mrml``, ``vtkMRMLScene.Connect``, every storage node's ``ReadData``), the folder
through ``vtkMRMLScene.Connect``, and every node compared with what needlekit wrote, in
RAS, to 1e-3 mm: each model's points (and its faces and outward normals), each markup's
control points, no transform anywhere.

The frame is pinned by analytic shapes: the toy lung's nodule is the sphere of radius 7 mm
about RAS (20, 30, 40); read by Slicer, its model's points lie on that sphere (with x, y
flipped they would lie about (-20, -30, 40)), and its normals point away from the centre.
"""

from __future__ import annotations

import json
import math
import zipfile
from pathlib import Path

import numpy as np
import pytest

slicer = pytest.importorskip(
    "slicer",
    reason="slicer-core is not installed (pip install 'needlekit[slicer]'): "
    "Slicer's MRML classes are the oracle of these tests",
)
from vtkmodules.util.numpy_support import vtk_to_numpy  # noqa: E402  (vtk comes with it)
from vtkmodules.vtkCommonMath import vtkMatrix4x4  # noqa: E402

from needlekit.anatomy.summary import surface_mesh  # noqa: E402
from needlekit.cli import main  # noqa: E402
from needlekit.planning.steerable.plan import plan_from_dict  # noqa: E402
from needlekit.report.slicer_case import thin_path  # noqa: E402
from needlekit.scenario.loading import load_scenario  # noqa: E402

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
TOY = EXAMPLES / "toy.yaml"
TOL_MM = 1e-3
CELLS = 64

#: The toy lung's plan as `needlekit plan examples/toy.yaml` wrote it (rcs_star, seed 0):
#: the scenario's start pose, an arc of radius 50 mm then a line.
TOY_PLAN = {
    "status": "solved",
    "planner": "rcs_star",
    "cost_mm": 62.861829356475084,
    "length_mm": 62.861829356475084,
    "goal_mm": [20.0, 30.0, 40.0],
    "start_pose": [
        [0.0, 0.9999999999999999, 0.0, 0.0],
        [-0.28734788556634544, 0.0, 0.9578262852211513, -12.0],
        [0.9578262852211514, -0.0, 0.2873478855663454, 0.0],
        [0.0, 0.0, 0.0, 1.0],
    ],
    "primitives": [
        {"rotation_rad": 2.2219751641433416, "curvature_per_mm": 0.02,
         "length_mm": 42.31310479758358},
        {"rotation_rad": 0.0, "curvature_per_mm": 0.0, "length_mm": 20.548724558891504},
    ],
}  # fmt: skip


def _helix(k: int) -> list[list[float]]:
    """A recorded tip path of trial k: 0.25 mm steps along a gentle helix from the start."""
    s = np.arange(0.0, 60.0, 0.25)
    pts = np.stack([0.1 * k * np.sin(s / 10), -12.0 + s, 0.3 * s + 0.05 * k * np.cos(s / 7)], 1)
    return np.round(pts, 4).tolist()


#: An execution of TOY_PLAN in the layout `needlekit execute` writes (the fields read).
TOY_EXECUTION = {
    "plan_primitives": [[p["rotation_rad"], p["curvature_per_mm"], p["length_mm"]]
                        for p in TOY_PLAN["primitives"]],
    "trials": [
        {"trial": k,
         "closed_loop": {"points_mm": _helix(k), "final_error_mm": 0.1 * (k + 1)},
         "open_loop": {"points_mm": _helix(k + 5), "final_error_mm": 1.0 + k}}
        for k in range(3)
    ],
}  # fmt: skip

#: Three straight needles on the toy lung (entries on its surface, targets in the nodule),
#: in the layout `needlekit multi` writes (the fields read).
TOY_MULTI = {
    "status": "solved",
    "gamma_mm": 1.5,
    "order": [1, 2, 3],
    "needles": [
        {"order": 1, "entry_mm": [0.0, -60.0, 0.0], "target_mm": [18.0, 30.0, 40.0]},
        {"order": 2, "entry_mm": [80.0, 0.0, 0.0], "target_mm": [22.0, 30.0, 40.0]},
        {"order": 3, "entry_mm": [0.0, 0.0, 100.0], "target_mm": [20.0, 32.0, 40.0]},
    ],
}
TOY_MULTI_EXECUTION = {
    "kind": "multi",
    "plan_needles": TOY_MULTI["needles"],
    "trials": [
        {"trial": k, "needles": [
            {"order": n["order"], "status": "solved", "error_mm": 0.3,
             "tip_mm": (np.array(n["target_mm"]) + [0.1 * k, -0.2, 0.3]).tolist(),
             "axis": (np.subtract(n["target_mm"], n["entry_mm"])
                      / np.linalg.norm(np.subtract(n["target_mm"], n["entry_mm"]))).tolist()}
            for n in TOY_MULTI["needles"]]}
        for k in range(2)
    ],
}  # fmt: skip


class SlicerScene:
    """A scene read by Slicer's classes: every displayable node by name."""

    def __init__(self, path: Path, tmp: Path) -> None:
        self.scene = slicer.vtkMRMLScene()
        # what the application sets up before it loads anything: the selection and
        # interaction singletons, and the markups node classes registered
        self.app = slicer.vtkMRMLApplicationLogic()
        self.app.SetMRMLScene(self.scene)
        self.markups_logic = slicer.vtkSlicerMarkupsLogic()
        self.markups_logic.SetMRMLScene(self.scene)
        if path.suffix == ".mrb":
            tmp.mkdir(parents=True, exist_ok=True)  # Slicer unpacks into a folder that exists
            assert self.app.OpenSlicerDataBundle(str(path), str(tmp))
        else:
            self.scene.SetURL(str(path))
            assert self.scene.Connect() == 1
        self.nodes = {}
        for cls in ("vtkMRMLModelNode", "vtkMRMLMarkupsNode"):
            for i in range(self.scene.GetNumberOfNodesByClass(cls)):
                node = self.scene.GetNthNodeByClass(i, cls)
                assert node.GetName() not in self.nodes
                self.nodes[node.GetName()] = node

    def model_points(self, name: str) -> np.ndarray:
        node = self.nodes[name]
        assert node.GetParentTransformNode() is None  # no transform: world RAS
        storage = node.GetStorageNode()
        assert storage.GetCoordinateSystem() == slicer.vtkMRMLStorageNode.CoordinateSystemLPS
        return vtk_to_numpy(node.GetPolyData().GetPoints().GetData()).astype(float)

    def model_normals(self, name: str) -> np.ndarray:
        return vtk_to_numpy(self.nodes[name].GetPolyData().GetPointData().GetNormals())

    def model_faces(self, name: str) -> np.ndarray:
        polys = self.nodes[name].GetPolyData().GetPolys()
        assert vtk_to_numpy(polys.GetOffsetsArray()).tolist() == list(
            range(0, 3 * polys.GetNumberOfCells() + 1, 3)
        )  # triangles only
        return vtk_to_numpy(polys.GetConnectivityArray()).reshape(-1, 3)

    def control_points(self, name: str) -> np.ndarray:
        node = self.nodes[name]
        assert node.GetParentTransformNode() is None
        n = node.GetNumberOfControlPoints()
        local = np.array([node.GetNthControlPointPosition(i) for i in range(n)])
        world = np.array([node.GetNthControlPointPositionWorld(i) for i in range(n)])
        assert np.array_equal(local, world)
        return world

    def labels(self, name: str) -> list[str]:
        node = self.nodes[name]
        return [node.GetNthControlPointLabel(i) for i in range(node.GetNumberOfControlPoints())]


@pytest.fixture(scope="module")
def toy(tmp_path_factory):
    """The toy lung's plan and a 3-trial execution, exported as a bundle and as a folder."""
    d = tmp_path_factory.mktemp("slicer")
    (d / "plan.json").write_text(json.dumps(TOY_PLAN))
    (d / "execute.json").write_text(json.dumps(TOY_EXECUTION))
    common = [str(TOY), str(d / "plan.json"), "--execution", str(d / "execute.json"),
              "--max-cells", str(CELLS)]  # fmt: skip
    assert main(["slicer", *common, "--out", str(d / "toy.mrb")]) == 0
    assert main(["slicer", *common, "--out-dir", str(d / "toy")]) == 0
    return d


def _expected_surfaces(scenario_path: Path) -> dict[str, np.ndarray]:
    """Each structure's surface points as marching cubes gives them (RAS)."""
    scene = load_scenario(scenario_path).scene
    box = scene.bounds()
    return {s.name: surface_mesh(s.field, max_cells=CELLS, bounds=box)[0] for s in scene.structures}


@pytest.mark.parametrize("where", ["toy.mrb", "toy/case.mrml"])
def test_slicer_reads_back_every_model_point_in_ras(toy, tmp_path, where):
    sc = SlicerScene(toy / where, tmp_path)
    expected = _expected_surfaces(TOY)
    assert set(expected) <= set(sc.nodes)
    for name, verts in expected.items():
        got = sc.model_points(name)
        assert got.shape == verts.shape
        assert np.max(np.abs(got - verts)) < TOL_MM, name
        faces = sc.model_faces(name)
        assert faces.min() == 0 and faces.max() == len(verts) - 1
    # the frame, pinned by the nodule: the sphere of radius 7 about RAS (20, 30, 40)
    nodule = sc.model_points("nodule")
    r = np.linalg.norm(nodule - [20.0, 30.0, 40.0], axis=1)
    cell = 14.0 / (CELLS - 1) * 2  # marching cubes within a cell of the surface
    assert np.all(np.abs(r - 7.0) < cell)
    # its normals point out of it (the faces were turned outward)
    normals = sc.model_normals("nodule")
    radial = (nodule - [20.0, 30.0, 40.0]) / r[:, None]
    assert np.all(np.einsum("ij,ij->i", normals, radial) > 0.9)
    # the colours and opacities of the roles (report's 3D views)
    display = sc.nodes["vessel"].GetDisplayNode()
    assert display.GetColor() == pytest.approx((0xD1 / 255, 0x49 / 255, 0x5B / 255), abs=1e-6)
    assert display.GetOpacity() == pytest.approx(1.0)  # an obstacle: solid
    lung = sc.nodes["lung"].GetDisplayNode()  # the allowed region: see-through
    assert lung.GetOpacity() == pytest.approx(0.08)


@pytest.mark.parametrize("where", ["toy.mrb", "toy/case.mrml"])
def test_slicer_reads_back_the_points_the_plan_and_each_trial(toy, tmp_path, where):
    sc = SlicerScene(toy / where, tmp_path)
    plan, goal = plan_from_dict(TOY_PLAN, "plan")
    assert np.max(np.abs(sc.control_points("target") - [goal])) < TOL_MM
    assert sc.labels("target") == ["target"]
    assert np.max(np.abs(sc.control_points("entry") - [[0.0, -12.0, 0.0]])) < TOL_MM
    curve = sc.control_points("plan")
    assert np.max(np.abs(curve - plan.points_mm(2.0))) < TOL_MM
    assert sc.nodes["plan"].GetClassName() == "vtkMRMLMarkupsCurveNode"
    for k in range(3):
        for label, pts in (("closed loop", _helix(k)), ("open loop", _helix(k + 5))):
            node = f"trial {k + 1} {label}"
            assert sc.nodes[node].GetCurveTypeAsString(sc.nodes[node].GetCurveType()) == "linear"
            got = sc.control_points(node)
            assert np.max(np.abs(got - thin_path(pts, 2.0))) < TOL_MM
            assert got[0] == pytest.approx(pts[0], abs=TOL_MM)
            assert got[-1] == pytest.approx(pts[-1], abs=TOL_MM)
    assert len(sc.nodes) == 4 + 3 + 6  # models, target/entry/plan, two curves a trial
    # how they are drawn: the plan a 1 mm tube, a trial 0.5 mm without its name in the views
    plan_display = sc.nodes["plan"].GetDisplayNode()
    assert plan_display.GetCurveLineSizeMode() == plan_display.UseLineDiameter
    assert plan_display.GetLineDiameter() == 1.0
    assert plan_display.GetSelectedColor() == pytest.approx((1.0, 0.84, 0.0), abs=1e-6)
    trial_display = sc.nodes["trial 1 open loop"].GetDisplayNode()
    assert trial_display.GetLineDiameter() == 0.5
    assert not trial_display.GetPropertiesLabelVisibility()
    assert sc.nodes["target"].GetDisplayNode().GetPointLabelsVisibility()


def test_the_files_are_lps_and_slicer_turns_them_to_ras(toy):
    """What the files hold (LPS: x and y negated) against what Slicer made of them."""
    with zipfile.ZipFile(toy / "toy.mrb") as z:
        assert sorted(n.split("/", 1)[0] for n in z.namelist()) == ["toy"] * len(z.namelist())
        target = json.loads(z.read("toy/Data/target.mrk.json"))["markups"][0]
        vtk = z.read("toy/Data/nodule.vtk")
    assert target["coordinateSystem"] == "LPS"
    assert target["controlPoints"][0]["position"] == [-20.0, -30.0, 40.0]
    head = vtk.split(b"\n", 5)
    assert head[:4] == [b"# vtk DataFile Version 4.2", b"needlekit surface. SPACE=LPS",
                        b"BINARY", b"DATASET POLYDATA"]  # fmt: skip
    n = int(head[4].split()[1])
    raw = np.frombuffer(head[5][: 12 * n], dtype=">f4").reshape(n, 3)
    verts = _expected_surfaces(TOY)["nodule"]
    assert np.max(np.abs(raw - verts * [-1, -1, 1])) < TOL_MM


def test_a_multi_needle_plan_is_one_line_per_needle_and_its_execution_too(tmp_path):
    (tmp_path / "multi.json").write_text(json.dumps(TOY_MULTI))
    (tmp_path / "execute.json").write_text(json.dumps(TOY_MULTI_EXECUTION))
    out = tmp_path / "multi.mrb"
    argv = ["slicer", str(TOY), str(tmp_path / "multi.json"), "--execution",
            str(tmp_path / "execute.json"), "--max-cells", "24", "--out", str(out)]  # fmt: skip
    assert main(argv) == 0
    sc = SlicerScene(out, tmp_path / "unpacked")
    needles = TOY_MULTI["needles"]
    targets = [n["target_mm"] for n in needles]
    assert np.max(np.abs(sc.control_points("target") - targets)) < TOL_MM
    assert sc.labels("target") == ["target 1", "target 2", "target 3"]
    assert np.max(np.abs(sc.control_points("entry") - [n["entry_mm"] for n in needles])) < TOL_MM
    for n in needles:
        line = sc.nodes[f"needle {n['order']}"]
        assert line.GetClassName() == "vtkMRMLMarkupsLineNode"
        want = [n["entry_mm"], n["target_mm"]]
        assert np.max(np.abs(sc.control_points(f"needle {n['order']}") - want)) < TOL_MM
        length = math.dist(*want)
        for k in range(2):
            tip = np.array(n["target_mm"]) + [0.1 * k, -0.2, 0.3]
            axis = np.subtract(n["target_mm"], n["entry_mm"]) / length
            got = sc.control_points(f"trial {k + 1} needle {n['order']}")
            assert np.max(np.abs(got - [tip - length * axis, tip])) < TOL_MM
    assert len(sc.nodes) == 4 + 2 + 3 + 6


@pytest.mark.slow
def test_a_real_plan_and_execution_of_the_toy_lung(toy_execution, tmp_path):
    """`needlekit plan` then `needlekit execute` (2 trials; tests/conftest.py's
    ``toy_execution``, both exiting 0), the scene against both files."""
    plan_path, ex = toy_execution / "plan.json", toy_execution / "ex"
    out = tmp_path / "case.mrb"
    assert main(["slicer", str(TOY), str(plan_path), "--execution", str(ex / "execute.json"),
                 "--max-cells", "32", "--spacing-mm", "1", "--out", str(out)]) == 0  # fmt: skip
    sc = SlicerScene(out, tmp_path / "unpacked")
    data = json.loads(plan_path.read_text())
    plan, goal = plan_from_dict(data, "plan")
    assert np.max(np.abs(sc.control_points("plan") - plan.points_mm(1.0))) < TOL_MM
    assert np.max(np.abs(sc.control_points("target") - [goal])) < TOL_MM
    runs = json.loads((ex / "execute.json").read_text())["trials"]
    for k, run in enumerate(runs):
        for loop in ("closed_loop", "open_loop"):
            got = sc.control_points(f"trial {k + 1} {loop.replace('_', ' ')}")
            assert np.max(np.abs(got - thin_path(run[loop]["points_mm"], 1.0))) < TOL_MM


@pytest.mark.slow
def test_the_liver_phantoms_three_needles_planned_and_inserted(tmp_path, liver_phantom_drag_run):
    """`needlekit multi` on examples/liver_phantom_multi.yaml with the needle-drag
    deformation, `execute` (2 trials): the session's run (tests/conftest.py) that
    tests/execute/test_execute_multi.py checks."""
    d = liver_phantom_drag_run
    scenario, plan_path, ex = d / "drag.yaml", d / "multi.json", d / "two"
    out = tmp_path / "liver.mrb"
    assert main(["slicer", str(scenario), str(plan_path), "--execution", str(ex / "execute.json"),
                 "--max-cells", "48", "--out", str(out)]) == 0  # fmt: skip
    sc = SlicerScene(out, tmp_path / "unpacked")
    needles = json.loads(plan_path.read_text())["needles"]
    for n in needles:
        want = [n["entry_mm"], n["target_mm"]]
        assert np.max(np.abs(sc.control_points(f"needle {n['order']}") - want)) < TOL_MM
    runs = json.loads((ex / "execute.json").read_text())["trials"]
    assert len(runs) == 2
    for k, run in enumerate(runs):
        for n in run["needles"]:
            got = sc.control_points(f"trial {k + 1} needle {n['order']}")
            assert np.max(np.abs(got[1] - n["tip_mm"])) < TOL_MM
    scene = load_scenario(scenario).scene
    assert {s.name for s in scene.structures} <= set(sc.nodes)


@pytest.mark.realdata
@pytest.mark.slow
def test_med_rad_lung_1s_models_lie_on_its_masks_as_slicer_loads_them(medrad_dir, tmp_path):
    """The scene over the CT's own masks: each model of Med-RAD lung 1, read back by
    Slicer, lies on the boundary of its NIfTI mask as Slicer's volume reader places it
    (every vertex between a voxel inside and one outside), so nothing needs registering.
    The plan is a 10 mm straight insertion from the scenario's start pose (no planning)."""
    scenario = EXAMPLES / "medrad_lung1.yaml"
    sc = load_scenario(scenario)
    pose = sc.start.world_T_tip
    plan = {"status": "solved", "planner": "test", "cost_mm": 10.0,
            "goal_mm": (pose[:3, 3] + 10 * pose[:3, 2]).tolist(), "start_pose": pose.tolist(),
            "primitives": [{"rotation_rad": 0.0, "curvature_per_mm": 0.0, "length_mm": 10.0}]}  # fmt: skip
    (tmp_path / "plan.json").write_text(json.dumps(plan))
    out = tmp_path / "lung1.mrb"
    assert main(["slicer", str(scenario), str(tmp_path / "plan.json"), "--out", str(out)]) == 0
    slc = SlicerScene(out, tmp_path / "unpacked")
    assert np.max(np.abs(slc.control_points("entry") - pose[:3, 3])) < TOL_MM
    for s in sc.scene.structures:
        if s.name == "pleuralBoundary":
            continue  # a surface of 10^5 points: the smaller ones make the point
        pts = slc.model_points(s.name)
        mask = slc.scene.AddNewNodeByClass("vtkMRMLLabelMapVolumeNode", f"{s.name} mask")
        storage = slc.scene.AddNewNodeByClass("vtkMRMLVolumeArchetypeStorageNode")
        storage.SetFileName(str(s.source))
        mask.SetAndObserveStorageNodeID(storage.GetID())
        assert storage.ReadData(mask) == 1
        m = vtkMatrix4x4()
        mask.GetRASToIJKMatrix(m)
        ras_to_ijk = np.array([[m.GetElement(i, j) for j in range(4)] for i in range(4)])
        image = mask.GetImageData()
        dims = image.GetDimensions()
        labels = vtk_to_numpy(image.GetPointData().GetScalars()).reshape(dims[::-1]) > 0
        labels = np.pad(labels, 2)  # outside the image is outside the mask
        ijk = (np.c_[pts, np.ones(len(pts))] @ ras_to_ijk.T)[:, :3] + 2
        lo = np.floor(ijk).astype(int)
        assert np.all(lo >= 1) and np.all(lo + 2 < np.array(dims) + 4)
        # the surface is meshed every `step` voxels: look within the 4x4x4 voxels about it
        corners = np.array([labels[lo[:, 2] + k, lo[:, 1] + j, lo[:, 0] + i]
                            for k in range(-1, 3) for j in range(-1, 3) for i in range(-1, 3)])  # fmt: skip
        on_boundary = corners.any(axis=0) & ~corners.all(axis=0)
        assert on_boundary.all(), s.name
        # the same points with x and y negated (LPS taken for RAS) leave the image
        flipped = (np.c_[pts * [-1, -1, 1], np.ones(len(pts))] @ ras_to_ijk.T)[:, :3]
        assert not np.any(np.all((flipped >= 0) & (flipped < dims), axis=1)), s.name
