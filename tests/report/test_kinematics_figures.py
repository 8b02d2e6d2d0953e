"""Tests of needlekit.report.kinematics: the files it writes and the numbers it reports.

The figures are rendered once per module (a few seconds); the checks read them back as
PNG images, parse ``demo.json`` and recompute its numbers with the library. A failure in
the middle of the run must leave only whole files behind.
"""

from __future__ import annotations

import json
from pathlib import Path

import matplotlib.image
import numpy as np
import pytest
from matplotlib.figure import Figure

from needlekit.errors import InvalidInputError
from needlekit.needle.planar import planar_steer_waypoints
from needlekit.needle.reachability import is_reachable, shortest_arc_line, single_arc_to
from needlekit.needle.transform_method import tm_inverse
from needlekit.report.kinematics import FIGURE_NAMES, write_kinematics_figures

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


@pytest.fixture(scope="module")
def written(tmp_path_factory) -> tuple[Path, list[Path]]:
    out = tmp_path_factory.mktemp("kinematics") / "figs"  # does not exist yet
    return out, write_kinematics_figures(out)


@pytest.fixture(scope="module")
def demo(written) -> dict:
    out, _ = written
    return json.loads((out / "demo.json").read_text(encoding="utf-8"))


def test_returns_the_figures_in_the_fixed_order(written):
    out, paths = written
    assert [p.name for p in paths] == list(FIGURE_NAMES)
    assert all(p.parent == out for p in paths)
    assert sorted(f.name for f in out.iterdir()) == sorted([*FIGURE_NAMES, "demo.json"])


@pytest.mark.parametrize("index", range(len(FIGURE_NAMES)))
def test_every_figure_is_a_sensible_png(written, index):
    _, paths = written
    path = paths[index]
    data = path.read_bytes()
    assert data[:8] == PNG_MAGIC
    assert len(data) > 30_000  # a drawn figure, not an empty canvas
    img = matplotlib.image.imread(path, format="png")
    h, w = img.shape[:2]
    assert 600 <= w <= 2400 and 500 <= h <= 1600
    assert 1.0 <= w / h <= 2.6  # landscape, not a sliver
    # not blank: a fair share of pixels differs from the white background
    assert np.mean(np.any(img[..., :3] < 0.9, axis=-1)) > 0.02


def test_demo_json_lists_the_figures(demo):
    assert demo["figures"] == list(FIGURE_NAMES)
    assert demo["dpi"] == 150


def test_inverse_solutions_match_the_library(demo):
    inv = demo["inverse"]
    g = np.array(inv["world_T_tip"])
    targets = np.array([t["target_mm"] for t in inv["targets"]])
    sol = tm_inverse(targets, g, r_min_mm=inv["r_min_mm"])
    for i, rec in enumerate(inv["targets"]):
        assert rec["alpha_rad"] == pytest.approx(sol.alpha_rad[i], abs=1e-12)
        assert rec["radius_mm"] == pytest.approx(sol.radius_mm[i], rel=1e-12)
        assert rec["phi_rad"] == pytest.approx(sol.phi_rad[i], abs=1e-12)
        assert rec["length_mm"] == pytest.approx(sol.length_mm[i], rel=1e-12)
        assert rec["phi_deg"] == pytest.approx(np.degrees(rec["phi_rad"]))
        # the lecture's closed form: phi = pi - 2 atan(z / k), r = k/2 + z^2 / (2k)
        local = g[:3, :3].T @ (targets[i] - g[:3, 3])
        k = np.hypot(local[0], local[1])
        assert rec["phi_rad"] == pytest.approx(np.pi - 2 * np.arctan(local[2] / k), abs=1e-12)
        assert rec["radius_mm"] == pytest.approx(k / 2 + local[2] ** 2 / (2 * k), rel=1e-12)
    # the seeded targets are spread and all reachable with r >= r_min
    assert len(inv["targets"]) == 5
    assert bool(np.all(is_reachable(g, targets, inv["r_min_mm"])))
    assert inv["end_point_error_mm"] < 1e-9
    assert inv["twist_model_position_error_mm"] < 1e-9
    assert inv["twist_model_rotation_error"] < 1e-12


def test_planar_waypoint_steps_match_the_library(demo):
    pw = demo["inverse"]["planar_waypoints"]
    steps, _ = planar_steer_waypoints(pw["waypoints_zy_mm"], sampling_time_s=pw["sampling_time_s"])
    assert len(steps) == len(pw["steps"])
    for s, rec in zip(steps, pw["steps"], strict=True):
        assert rec["radius_mm"] == pytest.approx(s.radius_mm, rel=1e-12)
        assert rec["length_mm"] == pytest.approx(s.length_mm, rel=1e-12)
        assert rec["bevel"] == s.bevel
    assert pw["forward_check_error_mm"] < 1e-9
    # the lecture slide's radius (no factor 2) is the diameter and misses the way-point
    z, y = pw["waypoints_zy_mm"][0]
    assert pw["lecture_slide_radius_w1_mm"] == pytest.approx(2 * pw["steps"][0]["radius_mm"])
    assert pw["lecture_slide_radius_w1_mm"] == pytest.approx((y * y + z * z) / abs(y))
    assert pw["lecture_slide_miss_w1_mm"] > 1.0


def test_forward_examples_are_consistent(demo):
    fp = demo["forward_planar"]
    plus, minus, s_curve = fp["cases"]
    assert plus["final_y_mm"] > 0 > minus["final_y_mm"]  # lambda = +1 bends toward +y
    assert plus["final_y_mm"] == pytest.approx(-minus["final_y_mm"])
    assert plus["final_theta_deg"] == pytest.approx(np.degrees(fp["kappa_per_mm"] * 100.0))
    assert s_curve["final_theta_deg"] == pytest.approx(0.0, abs=1e-9)
    assert fp["closed_form_error_mm"] < 1e-9

    f3 = demo["forward_3d"]
    arc = np.array(f3["cases"][0]["final_pose"])
    assert arc[1, 3] < 0  # no spin: bends toward the tip's -y axis
    assert arc[1, 3] == pytest.approx(-plus["final_y_mm"])
    assert arc[2, 3] == pytest.approx(plus["final_z_mm"])
    h = f3["helix"]
    w2 = f3["kappa_per_mm"] ** 2 + h["spin_per_mm_rad"] ** 2
    assert h["radius_mm"] == pytest.approx(f3["kappa_per_mm"] / w2)
    assert h["pitch_check_error_mm"] < 1e-9
    assert f3["planar_vs_3d_s_curve_error_mm"] < 1e-9
    assert f3["sampled_vs_exact_end_error"] < 1e-9


def test_reachability_numbers_match_the_library(demo):
    re = demo["reachability"]
    r_min = re["r_min_mm"]
    assert re["lecture_vs_frame_free_disagreements"] == 0
    n_rho, n_ax = re["grid"]["rho_mm"][2], re["grid"]["axial_mm"][2]
    total = (
        re["cells_single_forward_arc"]
        + re["cells_arc_then_line_only"]
        + re["cells_inside_r_min_torus"]
    )
    assert total == n_rho * n_ax
    # the cells without an arc-then-line path fill the r_min disc: area pi r^2
    assert re["cells_inside_r_min_torus"] == pytest.approx(np.pi * r_min**2, rel=0.03)
    kinds = set()
    for rec in re["paths"]:
        p = np.array([rec["rho_mm"], 0.0, rec["axial_mm"]])
        path = shortest_arc_line(np.eye(4), p, r_min)
        assert rec["arc_then_line_reachable"] == bool(path.reachable[0])
        kinds.add((rec["single_forward_arc"], rec["arc_then_line_reachable"]))
        if not rec["arc_then_line_reachable"]:
            continue
        assert rec["shortest_length_mm"] == pytest.approx(path.length_mm[0], rel=1e-12)
        assert rec["path_end_error_mm"] < 1e-9
        # Dubins CS length: r_min * turn + tangent length from the circle's centre
        d = np.hypot(rec["rho_mm"] - r_min, rec["axial_mm"])
        expected = r_min * np.radians(rec["turn_deg"]) + np.sqrt(d * d - r_min * r_min)
        assert rec["shortest_length_mm"] == pytest.approx(expected, rel=1e-9)
        if rec["single_forward_arc"]:
            one = single_arc_to(np.eye(4), p)
            assert rec["single_arc_radius_mm"] == pytest.approx(one.radius_mm[0])
            assert rec["single_arc_radius_mm"] >= r_min
            assert rec["shortest_length_mm"] <= rec["single_arc_length_mm"] + 1e-9
            assert rec["single_arc_end_error_mm"] < 1e-9
    # examples of each kind: single arc, arc-then-line only, inside the torus
    assert kinds == {(True, True), (False, True), (False, False)}


def test_output_is_deterministic(written, tmp_path, monkeypatch):
    out, _ = written

    # the second run's numbers and names are compared, not its pictures: its figures are
    # built as in the first run but not rendered (a rendered PNG's bytes are not looked at)
    def unrendered(self, fname, *args, **kwargs):
        fname.write(PNG_MAGIC)

    monkeypatch.setattr(Figure, "savefig", unrendered)
    again = write_kinematics_figures(tmp_path)
    assert (tmp_path / "demo.json").read_text() == (out / "demo.json").read_text()
    assert [p.name for p in again] == list(FIGURE_NAMES)


def test_failure_mid_write_leaves_no_partial_file(tmp_path, monkeypatch):
    calls = {"n": 0}
    real_write_bytes = Path.write_bytes

    def failing_write_bytes(self, data):
        calls["n"] += 1
        if calls["n"] == 2:
            real_write_bytes(self, data[:20])  # a half-written file...
            raise OSError("disk full")  # ...then the failure
        return real_write_bytes(self, data)

    monkeypatch.setattr(Path, "write_bytes", failing_write_bytes)
    with pytest.raises(OSError, match="disk full"):
        write_kinematics_figures(tmp_path, dpi=30)  # the smallest pictures: size is not the point
    names = sorted(p.name for p in tmp_path.iterdir())
    assert names == [FIGURE_NAMES[0]]  # the first figure whole; no .tmp, no second, no json
    assert (tmp_path / FIGURE_NAMES[0]).read_bytes()[:8] == PNG_MAGIC


def test_a_figure_that_fails_to_draw_writes_nothing(tmp_path, monkeypatch):
    calls = {"n": 0}
    real_savefig = Figure.savefig

    def failing_savefig(self, fname, *args, **kwargs):
        calls["n"] += 1
        if calls["n"] == 2:
            raise RuntimeError("renderer crashed")
        return real_savefig(self, fname, *args, **kwargs)

    monkeypatch.setattr(Figure, "savefig", failing_savefig)
    with pytest.raises(RuntimeError, match="renderer crashed"):
        write_kinematics_figures(tmp_path, dpi=30)
    assert list(tmp_path.iterdir()) == []  # every figure is drawn before any is written


def test_failure_keeps_the_previous_file(tmp_path, monkeypatch):
    old = tmp_path / FIGURE_NAMES[0]
    old.write_bytes(b"previous run")

    def failing_savefig(self, fname, *args, **kwargs):
        raise RuntimeError("renderer crashed")

    monkeypatch.setattr(Figure, "savefig", failing_savefig)
    with pytest.raises(RuntimeError, match="renderer crashed"):
        write_kinematics_figures(tmp_path)
    assert old.read_bytes() == b"previous run"
    assert sorted(p.name for p in tmp_path.iterdir()) == [FIGURE_NAMES[0]]


@pytest.mark.parametrize("dpi", [0, 10, 5000, 150.0, True, "150"])
def test_bad_dpi_is_refused(tmp_path, dpi):
    with pytest.raises(InvalidInputError, match=r"^dpi: "):
        write_kinematics_figures(tmp_path, dpi=dpi)
