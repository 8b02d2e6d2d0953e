"""``needlekit slicer`` without Slicer: the scene's files as written (the layout of the
bundle, the scene file's nodes and their references, the LPS model file), and bad input
refused in one line, exit 2, before the anatomy loads and with nothing written. Slicer's
own classes read the scenes back in tests/report/test_slicer_oracle.py."""

from __future__ import annotations

import json
import xml.etree.ElementTree as ET
import zipfile
from pathlib import Path

import numpy as np
import pytest

from needlekit.cli import main
from needlekit.io.slicer_scene import SlicerModel, model_vtk_bytes, scene_files
from needlekit.report.slicer_case import thin_path

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
TOY = EXAMPLES / "toy.yaml"

#: A plan on the toy lung (the start pose of examples/toy.yaml, an arc then a line).
PLAN = {
    "status": "solved",
    "planner": "rcs_star",
    "cost_mm": 62.86,
    "goal_mm": [20.0, 30.0, 40.0],
    "start_pose": [[0.0, 1.0, 0.0, 0.0], [-0.28734788556634544, 0.0, 0.9578262852211513, -12.0],
                   [0.9578262852211514, 0.0, 0.2873478855663454, 0.0], [0.0, 0.0, 0.0, 1.0]],
    "primitives": [
        {"rotation_rad": 2.2219751641433416, "curvature_per_mm": 0.02,
         "length_mm": 42.31310479758358},
        {"rotation_rad": 0.0, "curvature_per_mm": 0.0, "length_mm": 20.548724558891504},
    ],
}  # fmt: skip


@pytest.fixture
def files(tmp_path):
    (tmp_path / "plan.json").write_text(json.dumps(PLAN))
    return tmp_path


def _run(argv, capsys):
    try:
        code = main([str(a) for a in argv])
    except SystemExit as exc:  # the parser's own refusals
        code = exc.code
    return code, capsys.readouterr()


def test_the_bundle_holds_one_scene_and_its_files_each_referenced_once(files, capsys):
    out = files / "case.mrb"
    code, cap = _run(["slicer", TOY, files / "plan.json", "--max-cells", 24, "--out", out], capsys)
    assert code == 0, cap.err
    assert cap.out.splitlines()[:2] == [
        "4 models (lung, vessel, airway, nodule)",
        "3 markups (target, entry, plan)",
    ]
    with zipfile.ZipFile(out) as z:
        names = sorted(z.namelist())
        root = ET.fromstring(z.read("case/case.mrml"))
    assert names == sorted(
        ["case/case.mrml"]
        + [f"case/Data/{s}.vtk" for s in ("lung", "vessel", "airway", "nodule")]
        + [f"case/Data/{s}.mrk.json" for s in ("target", "entry", "plan")]
    )
    ids = {e.get("id"): e for e in root}
    assert len(ids) == len(root) == 3 * 7  # node, display, storage of each
    files_named = []
    for e in root:
        refs = e.get("references")
        if refs is None:
            continue
        kinds = dict(r.split(":") for r in refs.strip(";").split(";"))
        assert set(kinds) == {"display", "storage"}
        storage = ids[kinds["storage"]]
        assert storage.get("coordinateSystem") == "LPS"
        files_named.append("case/" + storage.get("fileName"))
        assert kinds["display"] in ids
    assert sorted(files_named) == [n for n in names if "/Data/" in n]


def test_a_model_file_is_lps_binary_vtk_with_outward_normals():
    v = np.array([[10.0, 20.0, 30.0], [20, 20, 30], [10, 30, 30], [10, 20, 40]])
    f = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])  # outward
    raw = model_vtk_bytes(v, f)
    head, rest = raw.split(b"POINTS 4 float\n", 1)
    assert head.decode().splitlines() == [
        "# vtk DataFile Version 4.2", "needlekit surface. SPACE=LPS", "BINARY",
        "DATASET POLYDATA",
    ]  # fmt: skip
    pts = np.frombuffer(rest[:48], dtype=">f4").reshape(4, 3)
    assert pts.tolist() == [[-10, -20, 30], [-20, -20, 30], [-10, -30, 30], [-10, -20, 40]]
    polys = rest[48:].split(b"\n", 2)
    assert polys[1] == b"POLYGONS 4 16"
    cells = np.frombuffer(polys[2][:64], dtype=">i4").reshape(4, 4)
    assert cells.tolist() == [[3, *t] for t in f.tolist()]
    normals = np.frombuffer(raw[-49:-1], dtype=">f4").reshape(4, 3)
    # vertex 0, the corner: outward is (-1, -1, -1)/sqrt(3) in RAS, (1, 1, -1)/sqrt(3) in LPS
    assert normals[0] == pytest.approx(np.array([1, 1, -1]) / np.sqrt(3), abs=1e-6)


def test_a_structure_thinner_than_a_cell_is_named(files, capsys):
    out = files / "case.mrb"
    code, cap = _run(["slicer", TOY, files / "plan.json", "--max-cells", 16, "--out", out], capsys)
    assert code == 0
    assert cap.out.splitlines()[:2] == [
        "3 models (lung, airway, nodule)",
        "no surface at --max-cells 16 (thinner than a cell?): vessel",
    ]


def test_node_names_become_safe_unique_file_names():
    a = SlicerModel("liver / tumour", [[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]])
    b = SlicerModel("liver: tumour", [[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]])
    assert list(scene_files([a, b], [], name="s")) == [
        "s.mrml", "Data/liver_tumour.vtk", "Data/liver_tumour_2.vtk",
    ]  # fmt: skip


def test_thin_path_keeps_the_ends_and_drops_repeats():
    p = [[0, 0, 0], [0, 0, 0], [0.4, 0, 0], [1.2, 0, 0], [1.3, 0, 0], [1.3, 0, 0]]
    assert thin_path(p, 1.0)[:, 0].tolist() == [0.0, 1.2, 1.3]
    assert thin_path([[0, 0, 0], [5, 0, 0]], 1.0)[:, 0].tolist() == [0.0, 5.0]


def _execution(primitives):
    pts = [[0.0, -12.0 + s, 0.3 * s] for s in range(30)]
    return {"plan_primitives": primitives,
            "trials": [{"closed_loop": {"points_mm": pts}, "open_loop": {"points_mm": pts}}]}  # fmt: skip


@pytest.mark.parametrize(
    ("extra", "line"),
    [
        (["--out", "{T}/case.zip"], "error: --out: {T}/case.zip: expected a name ending in .mrb"),
        (["--execution", "{T}/other.json", "--out", "{T}/c.mrb"],
         "error: {T}/other.json: was made from another plan (its plan differs from PLAN)"),
        (["--execution", "{T}/plan.json", "--out", "{T}/c.mrb"],
         "error: {T}/plan.json: does not execute a steerable plan (no plan_primitives); the plan is one"),
        (["--out-dir", "{T}/plan.json"], "error: --out-dir: {T}/plan.json: is a file, expected a folder"),
        (["--max-cells", "4", "--out", "{T}/c.mrb"],
         "error: argument --max-cells: expected a whole number in [8, 1024], got '4'"),
        ([], "error: one of the arguments --out --out-dir is required"),
    ],
)  # fmt: skip
def test_bad_input_is_one_line_and_nothing_is_written(files, capsys, monkeypatch, extra, line):
    import needlekit.scenario.loading as loading

    def no_anatomy(*a, **k):
        raise AssertionError("the scenario was loaded before the input was checked")

    monkeypatch.setattr(loading, "load_scenario", no_anatomy)
    other = [[p["rotation_rad"], p["curvature_per_mm"], 2 * p["length_mm"]]
             for p in PLAN["primitives"]]  # fmt: skip
    (files / "other.json").write_text(json.dumps(_execution(other)))
    before = sorted(p.name for p in files.iterdir())
    argv = ["slicer", TOY, files / "plan.json", *[a.replace("{T}", str(files)) for a in extra]]
    code, cap = _run(argv, capsys)
    assert code == 2
    assert cap.err.splitlines() == [line.replace("{T}", str(files))]
    assert sorted(p.name for p in files.iterdir()) == before


def test_a_plan_without_a_path_or_of_another_kind_is_refused(tmp_path, capsys):
    (tmp_path / "t.json").write_text(json.dumps({**PLAN, "status": "timeout", "primitives": []}))
    code, cap = _run(["slicer", TOY, tmp_path / "t.json", "--out", tmp_path / "c.mrb"], capsys)
    assert (code, cap.err) == (
        2, f"error: {tmp_path}/t.json: holds no path (status 'timeout'): nothing to export\n"
    )  # fmt: skip
    sweep = {"planners": [], "summary": {}, "directions": [], "best_plans": {}}
    (tmp_path / "s.json").write_text(json.dumps(sweep))
    code, cap = _run(["slicer", TOY, tmp_path / "s.json", "--out", tmp_path / "c.mrb"], capsys)
    assert code == 2
    assert cap.err == (
        f"error: {tmp_path}/s.json: is a start-direction sweep (needlekit sweep); expected a "
        "plan.json (needlekit plan) or multi.json (needlekit multi)\n"
    )
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s.json", "t.json"]
