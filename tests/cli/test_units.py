"""Units and plausibility the same on every path: a length outside the
range insertions use is named in one warning line whether a flag or a scenario field gave
it; range errors come before the anatomy is loaded; a mask that lies outside the anatomy it
belongs to is an error naming its file."""

from __future__ import annotations

import logging
from pathlib import Path

import nibabel as nib
import numpy as np
import pytest

from needlekit.cli import main
from needlekit.errors import InvalidInputError
from needlekit.plausibility import QUANTITIES, document_warnings, flag_warnings, implausible

ROOT = Path(__file__).resolve().parents[2]
EXAMPLES = ROOT / "examples"
TOY = EXAMPLES / "toy.yaml"
MULTI = EXAMPLES / "liver_phantom_multi.yaml"


def _warnings(caplog) -> list[str]:
    return [r.getMessage() for r in caplog.records if r.name == "needlekit.units"]


def _edit(src: Path, tmp_path: Path, old: str, new: str, name: str = "case.yaml") -> Path:
    text = src.read_text()
    assert old in text, old
    path = tmp_path / name
    path.write_text(text.replace(old, new, 1))
    return path


@pytest.fixture
def no_anatomy(monkeypatch):
    """Loading any anatomy fails the test: the errors must come before it."""

    def refuse(*args, **kwargs):
        raise AssertionError("the anatomy was loaded before the range error")

    import needlekit.anatomy.phantoms as phantoms
    import needlekit.io.medrad as medrad

    monkeypatch.setattr(phantoms, "make_phantom", refuse)
    monkeypatch.setattr(medrad, "load_medrad", refuse)


def test_flags_in_metres_are_named(tmp_path, capsys, caplog):
    caplog.set_level(logging.WARNING)
    out = tmp_path / "plan.json"
    code = main(["plan", str(TOY), "--r-min-mm", "0.03", "--needle-diameter-mm", "0.001",
                 "--max-iterations", "1", "--out", str(out)])  # fmt: skip
    assert code in (0, 1) and out.is_file()  # it plans (the values are valid): it warns
    assert sorted(_warnings(caplog)) == [
        "--needle-diameter-mm is 0.001 mm, below the 0.1 mm insertions use: lengths are "
        "millimetres (was it written in metres or centimetres?)",
        "--r-min-mm is 0.03 mm, below the 1 mm insertions use: lengths are millimetres "
        "(was it written in metres or centimetres?)",
    ]


@pytest.mark.parametrize(
    ("old", "new", "field", "value", "side"),
    [
        ("diameter_mm: 1.0", "diameter_mm: 0.002", "needle.diameter_mm", "0.002", "below the 0.1"),
        ("r_min_mm: 50", "r_min_mm: 0.05", "needle.r_min_mm", "0.05", "below the 1"),
        ("tolerance_mm: 1.0", "tolerance_mm: 1000", "goal.tolerance_mm", "1000", "above the 50"),
    ],
)
def test_scenario_lengths_in_other_units_are_named(tmp_path, capsys, caplog, old, new, field,
                                                    value, side):  # fmt: skip
    caplog.set_level(logging.WARNING)
    path = _edit(TOY, tmp_path, old, new)
    main(["plan", str(path), "--max-iterations", "1", "--out", str(tmp_path / "p.json")])
    assert [w for w in _warnings(caplog) if field in w] == [
        f"case.yaml: {field} is {value} mm, {side} mm insertions use: lengths are millimetres "
        + (
            "(was it written in metres or centimetres?)"
            if side.startswith("below")
            else "(was it written in micrometres, or mistyped?)"
        )
    ]


def test_gamma_in_metres_is_named_in_the_file_and_on_the_flag(tmp_path, capsys, caplog,
                                                              no_anatomy):  # fmt: skip
    caplog.set_level(logging.WARNING)
    path = _edit(MULTI, tmp_path, "gamma_mm: 1.5", "gamma_mm: 0.0015")
    with pytest.raises(AssertionError, match="anatomy was loaded"):  # warned before it
        main(["multi", str(path), "--out", str(tmp_path / "m.json")])
    assert _warnings(caplog) == [
        "case.yaml: straight.gamma_mm is 0.0015 mm, below the 0.01 mm insertions use: "
        "lengths are millimetres (was it written in metres or centimetres?)"
    ]
    assert flag_warnings({"gamma": [1.5, 0.003]}) == [
        "--gamma is 0.003 mm, below the 0.01 mm insertions use: lengths are millimetres "
        "(was it written in metres or centimetres?)"
    ]


def test_the_shipped_scenarios_draw_no_units_warning(caplog):
    from needlekit.io.scenario_schema import read_scenario_document

    caplog.set_level(logging.WARNING)
    paths = sorted(EXAMPLES.glob("*.yaml")) + sorted((ROOT / "src/needlekit/data").glob("*.yaml"))
    assert len(paths) >= 10
    for p in paths:
        read_scenario_document(p)
    assert _warnings(caplog) == []


def test_each_quantity_warns_outside_its_range_only():
    for q in QUANTITIES:
        inside = [v for v in (q.low, q.high) if v is not None]
        for v in inside:  # the ends are plausible
            assert implausible("x", v, q) is None
        assert implausible("x", 0, q) is None  # a zero the field allows is a choice
        assert implausible("x", "7", q) is None  # text is the schema's business
        if q.low is not None:
            assert "below" in implausible("x", q.low * 0.99, q)
        if q.high is not None:
            assert "above" in implausible("x", q.high * 1.01, q)
    # a structure's own name places a mesh's voxel size
    doc = {"structures": [{"name": "liver", "mesh": {"path": "l.stl", "voxel_size_mm": 50}}]}
    assert document_warnings(doc) == [
        "structures.liver.mesh.voxel_size_mm is 50 mm, above the 20 mm insertions use: "
        "lengths are millimetres (was it written in micrometres, or mistyped?)"
    ]


RANGE_CASES = [
    # (scenario, command, text added under straight: or replaced, expected error line end)
    (MULTI, "multi", "  max_normal_angle_deg: 200\n",
     "straight.max_normal_angle_deg: expected a number <= 90, got 200"),
    (MULTI, "cfrw", "  approach_cone_deg: 500\n",
     "straight.approach_cone_deg: expected a number <= 180, got 500"),
    (MULTI, "multi", "  up: [0, 0, 0]\n", "straight.up: expected a non-zero vector, got [0, 0, 0]"),
    (MULTI, "multi", "  order: [7, 8]\n",
     "straight.order: expected a permutation of 0..2 (the targets), got [7, 8]"),
    (MULTI, "multi", "  order: [0, 0, 1]\n", "straight.order: [0, 0, 1] has non-unique elements"),
]  # fmt: skip


@pytest.mark.parametrize(("scenario", "command", "added", "expected"), RANGE_CASES)
def test_range_errors_come_before_the_anatomy(tmp_path, capsys, no_anatomy, scenario, command,
                                              added, expected):  # fmt: skip
    path = tmp_path / "case.yaml"
    path.write_text(scenario.read_text() + added)
    code = main([command, str(path), "--out", str(tmp_path / "out.json")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and err == [f"error: case.yaml: {expected}"]


def test_steerable_range_errors_come_before_the_anatomy(tmp_path, capsys, no_anatomy):
    base = "version: 1\nbase: {phantom: {name: lung}}\ngoal: {case_target: 1}\n"
    for block, expected in [
        ("start: {point_mm: [0, 0, 0], direction: [0, 0, 0]}",
         "start.direction: expected a non-zero vector, got [0, 0, 0]"),
        ("start: {case_start: 1}\nneedle: {min_puncture_angle_deg: 95}",
         "needle.min_puncture_angle_deg: expected a number < 90, got 95"),
    ]:  # fmt: skip
        path = tmp_path / "case.yaml"
        path.write_text(base + block + "\n")
        code = main(["plan", str(path), "--out", str(tmp_path / "out.json")])
        err = capsys.readouterr().err.strip().splitlines()
        assert code == 2 and err == [f"error: case.yaml: {expected}"], err


def _nifti(path: Path, mask: np.ndarray, origin) -> Path:
    affine = np.diag([1.0, 1.0, 1.0, 1.0])
    affine[:3, 3] = origin
    nib.save(nib.Nifti1Image(mask.astype(np.uint8), affine), str(path))
    return path


def test_a_mask_outside_the_anatomy_is_an_error_naming_its_file(tmp_path, capsys):
    m = np.zeros((30, 30, 30), bool)
    m[10:20, 10:20, 10:20] = True
    _nifti(tmp_path / "vessel.nii.gz", m, [-15, -15, -15])
    far = _nifti(tmp_path / "far.nii.gz", m, [985, -15, -15])  # a metre off: another volume
    body = (
        "version: 1\nstructures:\n"
        "  - {name: body, role: allowed_region, sphere: {center_mm: [0, 0, 0], radius_mm: 60}}\n"
        "  - {name: vessel, role: obstacle, mask: {path: vessel.nii.gz}}\n"
    )
    ok = tmp_path / "ok.yaml"
    ok.write_text(body)
    bad = tmp_path / "bad.yaml"
    bad.write_text(body + "  - {name: far, role: obstacle, mask: {path: far.nii.gz}}\n")
    code = main(["scene", "info", str(ok)])
    assert code == 0, capsys.readouterr().err
    capsys.readouterr()
    code = main(["scene", "info", str(bad)])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1
    assert err[0].startswith(
        f"error: bad.yaml: structures[2].mask.path: {far}: its set voxels span"
    )
    assert "outside the anatomy the other structures span" in err[0]


def test_a_medrad_mask_off_the_reference_grid_is_an_error_naming_its_file(tmp_path):
    from needlekit.io.medrad_prepare import _align
    from needlekit.io.volumes import Mask

    ref = Mask(np.ones((8, 8, 8), bool), np.eye(4), tmp_path / "lung.nii.gz")
    shifted = np.eye(4)
    shifted[:3, 3] = [100.0, 0.0, 0.0]  # whole voxels, beyond the grid
    with pytest.raises(InvalidInputError) as exc:
        _align(Mask(np.ones((4, 4, 4), bool), shifted, tmp_path / "vessels.nii.gz"), ref, "vessels")
    assert exc.value.field == str(tmp_path / "vessels.nii.gz")
    assert "none of its 64 set voxels lies in the volume of" in str(exc.value)
    half = np.eye(4)
    half[:3, 3] = [6.0, 0.0, 0.0]  # half of it inside: kept, the rest dropped with a warning
    out = _align(Mask(np.ones((4, 4, 4), bool), half, tmp_path / "v.nii.gz"), ref, "v")
    assert int(out.data.sum()) == 2 * 4 * 4
