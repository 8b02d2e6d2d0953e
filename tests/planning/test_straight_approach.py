"""The approach analysis on a skin mesh: Slicer's PercutaneousApproachAnalysis (PAA), exactly,
and needlekit's criteria beside it: everything PAA does, and what it cannot."""

import json
from pathlib import Path

import numpy as np
import pytest
import trimesh

from needlekit.anatomy.mesh import ExactMeshDistance
from needlekit.cli import main
from needlekit.errors import InvalidInputError
from needlekit.planning.straight.approach import (
    ApproachAnalysis,
    approach_analysis,
    approach_scores,
)

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"

R = 60.0


def _brute_hits(p0, p1, mesh):
    """The oracle: every segment against every triangle (Moller-Trumbore, closed)."""
    tri = np.asarray(mesh.triangles)
    a, b, c = tri[:, 0], tri[:, 1], tri[:, 2]
    e1, e2 = b - a, c - a
    out = np.zeros(len(p0), dtype=bool)
    for i in range(len(p0)):
        d = p1[i] - p0[i]
        h = np.cross(d, e2)
        det = np.einsum("ij,ij->i", e1, h)
        ok = det != 0.0
        inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
        s = p0[i] - a
        u = inv * np.einsum("ij,ij->i", s, h)
        q = np.cross(s, e1)
        v = inv * (q @ d)
        t = inv * np.einsum("ij,ij->i", e2, q)
        out[i] = np.any(ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (t >= 0) & (t <= 1))
    return out


def _scene():
    skin = trimesh.creation.icosphere(subdivisions=3, radius=R)
    plate = trimesh.creation.box([30.0, 30.0, 2.0])
    plate.apply_translation([5.0, 0.0, 25.0])
    vessel = trimesh.creation.cylinder(radius=3.0, height=80.0)
    vessel.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [0, 1, 0]))
    vessel.apply_translation([0.0, 15.0, -20.0])
    return skin, [plate, vessel]


def test_the_line_test_is_paa_s_answer_exactly():
    skin, obstacles = _scene()
    target = np.array([0.0, 0.0, 0.0])
    a = approach_analysis(target, skin, obstacles)
    both = trimesh.util.concatenate(obstacles)
    want = _brute_hits(a.centres_mm, np.broadcast_to(target, a.centres_mm.shape), both)
    assert np.array_equal(a.hit, want)
    assert 0 < want.sum() < len(want)
    # no length limit given: null in the record, which JSON can hold
    rec = json.loads(json.dumps(a.to_dict(), allow_nan=False))
    assert rec["settings"]["max_length_mm"] is None
    # PAA's score: the accessible skin area over all of it; its shortest accessible line
    areas = np.asarray(skin.area_faces)
    assert a.score_paa == pytest.approx(areas[~want].sum() / areas.sum(), rel=1e-12)
    lengths = np.linalg.norm(np.asarray(skin.triangles_center) - target, axis=1)
    best = a.shortest(paa=True)
    assert best["length_mm"] == pytest.approx(lengths[~want].min())
    # label-wise: the score of each target point
    pts = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 10.0], [0.0, -20.0, 5.0]])
    scores = approach_scores(pts, skin, obstacles)
    assert scores[0] == pytest.approx(a.score_paa, rel=1e-12)
    for p, s in zip(pts, scores, strict=True):
        h = _brute_hits(a.centres_mm, np.broadcast_to(p, a.centres_mm.shape), both)
        assert s == pytest.approx(areas[~h].sum() / areas.sum(), rel=1e-12)


def test_needle_thickness_and_gamma_only_take_triangles_away():
    skin, obstacles = _scene()
    field = ExactMeshDistance(trimesh.util.concatenate(obstacles))
    target = [0.0, 0.0, 0.0]
    thin = approach_analysis(target, skin, obstacles, field=field)
    thick = approach_analysis(
        target, skin, obstacles, field=field, needle_radius_mm=1.0, gamma_mm=3.0
    )
    assert np.all(thick.accessible <= thin.accessible)
    assert np.all(thin.accessible <= thin.accessible_paa)
    assert thick.score < thin.score <= thin.score_paa
    # the clearance is certified: never above the exact distance along the line
    ok = np.flatnonzero(thick.accessible)[:40]
    t = np.linspace(0.0, 1.0, 2001)[:, None]
    for i in ok:
        pts = np.asarray(target) + t * (thick.centres_mm[i] - np.asarray(target))
        exact = field.signed_distance(pts).min() - 1.0
        assert thick.clearance_mm[i] <= exact + 1e-9
        assert thick.clearance_mm[i] >= 3.0


def test_the_record_reads_back_to_the_analysis_it_was_written_from():
    """approach.json -> ApproachAnalysis.from_dict -> to_dict gives the record's
    per-triangle answers again (rounded as the record keeps them) and its chosen line; a record
    without them (--summary-only) or with a column of another length is named."""
    skin, obstacles = _scene()
    field = ExactMeshDistance(trimesh.util.concatenate(obstacles))
    a = approach_analysis([0.0, 0.0, 0.0], skin, obstacles, field=field, needle_radius_mm=1.0,
                          gamma_mm=3.0, max_normal_angle_deg=60.0)  # fmt: skip
    rec = json.loads(json.dumps(a.to_dict(), allow_nan=False))
    back = ApproachAnalysis.from_dict(rec, "approach.json")
    again = json.loads(json.dumps(back.to_dict(), allow_nan=False))
    for key in ("target_mm", "faces", "settings", "per_face"):
        assert again[key] == rec[key], key
    assert again["needlekit"]["shortest"] == rec["needlekit"]["shortest"]
    # the sums over the rounded areas: to their rounding
    assert again["skin_area_mm2"] == pytest.approx(rec["skin_area_mm2"], abs=1280 * 5e-7)
    assert np.array_equal(back.hit, a.hit) and np.array_equal(back.accessible, a.accessible)
    assert np.array_equal(back.leaves_body, a.leaves_body)
    assert back.score == pytest.approx(a.score, abs=1e-6) and back.shortest() == a.shortest()
    assert np.isnan(back.clearance_mm[a.hit]).all()  # no clearance where the line is blocked
    assert back.settings["max_length_mm"] == np.inf
    with pytest.raises(InvalidInputError, match="per_face: missing: the record keeps no"):
        ApproachAnalysis.from_dict(a.to_dict(per_face=False), "approach.json")
    rec["per_face"]["accessible"] = rec["per_face"]["accessible"][:-1]
    with pytest.raises(InvalidInputError, match=r"per_face.accessible: expected 1280 numbers"):
        ApproachAnalysis.from_dict(rec, "approach.json")


def test_lines_that_leave_the_body_are_refused_by_needlekit_only():
    ring = trimesh.creation.torus(40.0, 12.0)  # a tube around the z axis
    target = np.array([40.0, 0.0, 0.0])  # inside the tube
    far = trimesh.creation.box([1.0, 1.0, 1.0])
    far.apply_translation([0.0, 0.0, 200.0])  # an obstacle out of the way
    a = approach_analysis(target, ring, [far])
    assert not a.hit.any() and a.score_paa == pytest.approx(1.0)
    # the far side of the ring is reached only through the hole: out of the body and in
    far_side = a.centres_mm[:, 0] < -30.0
    assert np.all(a.leaves_body[far_side])
    near_outer = a.centres_mm[:, 0] > 51.0
    assert not np.any(a.leaves_body[near_outer])
    assert 0.0 < a.score < 1.0


def test_bad_inputs_name_the_field():
    skin, obstacles = _scene()
    with pytest.raises(InvalidInputError, match="target_mm"):
        approach_analysis([0.0, np.nan, 0.0], skin, obstacles)
    with pytest.raises(InvalidInputError, match="gamma_mm"):
        approach_analysis([0.0, 0.0, 0.0], skin, obstacles, gamma_mm=-1.0)
    with pytest.raises(InvalidInputError, match="skin"):
        approach_analysis([0.0, 0.0, 0.0], (np.zeros((3, 3)), np.zeros((0, 3))), obstacles)


SCENARIO = """\
version: 1
name: a mesh skin and a mesh vessel
structures:
  - {{name: skin, role: entry_surface, mesh: {{path: {skin}, voxel_size_mm: 1.0}}}}
  - {{name: vessel, role: obstacle, mesh: {{path: {vessel}, voxel_size_mm: 0.5}}}}
needle: {{diameter_mm: 2.0, max_length_mm: 100}}
straight:
  entry_surface: skin
  targets: [[0, 0, 0]]
  gamma_mm: 1.5
"""


def test_the_command_writes_the_analysis_and_its_view(tmp_path, capsys):
    skin_mesh, (plate, _) = _scene()
    skin = tmp_path / "skin.stl"
    skin_mesh.export(skin)
    vessel = tmp_path / "plate.stl"
    plate.export(vessel)
    path = tmp_path / "case.yaml"
    path.write_text(SCENARIO.format(skin=skin, vessel=vessel))
    out, report = tmp_path / "approach.json", tmp_path / "approach.html"
    assert main(["approach", str(path), "--out", str(out), "--report", str(report)]) == 0
    text = capsys.readouterr().out
    assert "PAA (line, no thickness): score" in text and "needlekit: score" in text
    rec = json.loads(out.read_text())
    assert rec["faces"] == len(skin_mesh.faces) == rec["skin"]["faces"]
    assert rec["obstacles"] == {"vessel": len(plate.faces)}
    assert 0 < rec["needlekit"]["score"] < rec["paa"]["score"] < 1
    assert rec["settings"] == {
        "needle_radius_mm": 1.0, "gamma_mm": 1.5, "max_length_mm": 100.0,
        "max_normal_angle_deg": 90.0,
    }  # fmt: skip
    face = rec["per_face"]
    assert len(face["accessible"]) == rec["faces"]
    # the mesh files are read as they are: PAA's answer on them, exactly
    a = approach_analysis([0.0, 0.0, 0.0], skin_mesh, [plate])
    assert face["accessible_paa"] == (~a.hit).astype(int).tolist()
    html = report.read_text()
    assert "Skin map" in html and "shortest (PAA)" in html
    code = main(["approach", str(path), "--target", "2", "--out", str(tmp_path / "x.json")])
    err = capsys.readouterr().err
    assert code == 2 and err == "error: --target: expected 1 to 1, got 2\n"


@pytest.mark.realdata
@pytest.mark.slow
def test_bench_approach_runs_on_liver_4_and_says_why_the_reference_is_missing(
    medrad_dir, monkeypatch
):
    import sys

    from needlekit.benchmarks.approach import run_approach_benchmark

    monkeypatch.setitem(sys.modules, "vtk", None)  # as on a machine without the [paa] extra
    rec = run_approach_benchmark(repeat=1, medrad_dir=medrad_dir)
    (case,) = rec["cases"]
    assert case["reference"] == {"skipped": "vtk not installed (pip install 'needlekit[paa]')"}
    assert case["skin_faces"] > 100_000 and case["obstacle_faces"] > 10_000
    # the liver capsule from the case's target: PAA's line test lets more through than
    # needlekit's needle of 1 mm radius with gamma 1.5 mm inside the body
    assert 0.0 < case["needlekit_full"]["score"] < case["needlekit_lines"]["score"] < 1.0
    assert case["label_wise"]["voxels"] == 16
    assert [r["name"] for r in rec["results"]] == [
        "medrad_liver4 lines", "medrad_liver4 needlekit", "medrad_liver4 label-wise",
    ]  # fmt: skip


def test_bench_approach_without_the_data_says_so(tmp_path):
    from needlekit.benchmarks.approach import run_approach_benchmark

    rec = run_approach_benchmark(repeat=1, medrad_dir=tmp_path)
    (case,) = rec["cases"]
    assert case["name"] == "medrad_liver4" and "no Med-RAD liver 4" in case["skipped"]
    assert rec["results"][0]["summary"].startswith("skipped: no Med-RAD liver 4")


# ---------------------------------------------------------------------------------------
# the shipped examples: the figures docs/straight.md shows, pinned


@pytest.mark.realdata
@pytest.mark.slow
def test_the_liver_4_example_keeps_the_figures_the_docs_show(medrad_dir, tmp_path, capsys,
                                                            monkeypatch):  # fmt: skip
    """``needlekit approach examples/medrad_liver4.yaml`` on the vessels' own surfaces.
    These are the figures docs/straight.md shows, and VTK's BSP tree (PAA's procedure,
    ``bench approach``) gave the same answer on all but 17 of the 249830 triangles
    (2026-12-05, VTK 9.7.2). The meshes once came from the lazy fields' coarse previews,
    whose pooled voxels grow the vessels: 121644 lines blocked and a score of 0.5102,
    which VTK agreed with on those wrong meshes; here the count is held to the real one."""
    monkeypatch.setenv("NEEDLEKIT_MEDRAD", str(medrad_dir))
    out = tmp_path / "approach.json"
    argv = ["approach", str(EXAMPLES / "medrad_liver4.yaml"), "--summary-only", "--out", str(out)]
    assert main(argv) == 0
    rec = json.loads(out.read_text())
    assert rec["skin"] == {"structure": "liver", "faces": 249830}
    assert rec["obstacles"] == {"hepaticArtery": 28048, "hepaticVein": 11038, "portalVein": 8322}
    assert rec["blocked"] == {
        "obstacle_on_line": 82182, "leaves_body": 118185, "clearance_below_gamma": 106352,
        "too_long": 0, "too_oblique": 37950,
    }  # fmt: skip
    assert round(rec["paa"]["score"], 4) == 0.6665
    assert round(rec["needlekit"]["score"], 4) == 0.1925
    assert round(rec["paa"]["shortest"]["length_mm"], 2) == 19.53
    assert round(rec["needlekit"]["shortest"]["length_mm"], 2) == 21.39
    said = capsys.readouterr().out
    assert (
        "PAA (line, no thickness): score 0.6665; shortest 19.53 mm from (42.90, 8.37, -265.55)"
        in said
    )


@pytest.mark.realdata
@pytest.mark.slow
def test_the_liver_4_line_test_is_vtk_s_answer(medrad_dir, monkeypatch):
    """Against the reference itself, where VTK is installed (the ``paa`` extra): PAA's
    BSP-tree procedure and needlekit's exact line test on the example's meshes differ on
    at most 20 of 249830 triangles (17 measured, each a line within VTK's tolerance of a
    vessel's surface)."""
    pytest.importorskip("vtk", reason="the paa extra (VTK) is not installed")
    from needlekit.benchmarks.approach import _paa_lines
    from needlekit.planning.straight.approach import reach_box, structure_mesh
    from needlekit.scenario.loading import load_scenario
    from needlekit.scenario.straight import multi_problem_from_scenario

    monkeypatch.setenv("NEEDLEKIT_MEDRAD", str(medrad_dir))
    sc = load_scenario(EXAMPLES / "medrad_liver4.yaml")
    multi, _ = multi_problem_from_scenario(sc)
    pr = multi.problem
    target = np.asarray(multi.targets_mm[0], dtype=float)
    box = reach_box(target, pr.needle.max_length_mm)
    skin = structure_mesh(pr.scene[pr.entry_surface], bounds=box)
    from needlekit.anatomy.scene import Role

    obstacles = [structure_mesh(s, bounds=box) for s in pr.scene.by_role(Role.OBSTACLE)]
    ours = approach_analysis(target, skin, obstacles)
    theirs = _paa_lines(np.asarray(skin.triangles_center), target, obstacles)
    assert len(theirs) == 249830
    assert int(np.sum(ours.hit != theirs)) <= 20


@pytest.mark.slow
def test_the_phantom_example_is_analysed(tmp_path, capsys):
    """``examples/liver_phantom_multi.yaml``: the phantom's skin, an unbounded elliptic
    cylinder, used to fail ("could not be meshed"); it is meshed within the needle's reach
    of the target (``reach_box``), faces turned outward by its field."""
    out = tmp_path / "approach.json"
    argv = ["approach", str(EXAMPLES / "liver_phantom_multi.yaml"), "--summary-only",
            "--out", str(out)]  # fmt: skip
    assert main(argv) == 0
    rec = json.loads(out.read_text())
    assert rec["skin"]["faces"] == 204828
    assert rec["blocked"]["obstacle_on_line"] == 104934
    assert rec["blocked"]["leaves_body"] == 0  # the outward faces: lines start on the skin
    assert round(rec["paa"]["score"], 4) == 0.4867
    assert round(rec["needlekit"]["score"], 4) == 0.1347
    # every skin vertex lies within the box the needle can come from
    assert "PAA (line, no thickness): score 0.4867" in capsys.readouterr().out
