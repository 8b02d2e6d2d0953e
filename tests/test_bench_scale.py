"""``needlekit bench scale``: the fits, the obstacle density, the
settings and their flags, the record's structure, serial = process results, the page.

No clock is asserted: only that times are recorded, finite and non-negative.
"""

import json
import math
from pathlib import Path

import numpy as np
import pytest

from needlekit.benchmarks.scale import (
    DEFAULTS,
    QUICK,
    run_scale_benchmark,
    scale_settings,
    summary_lines,
)
from needlekit.benchmarks.scale_math import capsule_obstacle_fraction, linear_fit, loglog_fit
from needlekit.cli import main
from needlekit.errors import InvalidInputError

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"

# -- fits and density -----------------------------------------------------------------------


def test_loglog_fit_recovers_a_known_exponent_under_noise():
    rng = np.random.default_rng(0)
    x = np.geomspace(10.0, 500.0, 40)
    y = 0.02 * x**1.7 * np.exp(rng.normal(0.0, 0.05, len(x)))
    f = loglog_fit(x, y)
    assert f["exponent"] == pytest.approx(1.7, abs=0.05)
    assert f["coefficient"] == pytest.approx(0.02, rel=0.2)
    assert 0.98 < f["r2"] <= 1.0 and f["n"] == 40 and f["left_out"] == 0


def test_fits_leave_out_what_they_cannot_use_and_refuse_a_single_size():
    f = loglog_fit([1.0, 2.0, 4.0, 0.0, -1.0, np.nan], [2.0, 4.0, 8.0, 1.0, 1.0, 1.0])
    assert f["exponent"] == pytest.approx(1.0) and f["n"] == 3 and f["left_out"] == 3
    assert loglog_fit([3.0, 3.0], [1.0, 2.0]) is None
    assert linear_fit([5], [1.0]) is None
    g = linear_fit([1, 2, 5, 10], [4.0, 6.5, 14.0, 26.5], at=100)
    assert (g["slope"], g["intercept"]) == pytest.approx((2.5, 1.5))
    assert g["predicted"] == pytest.approx(251.5) and g["r2"] == pytest.approx(1.0)


def test_capsule_density_on_a_half_filled_grid_under_any_affine():
    occ = np.zeros((60, 60, 60), dtype=bool)
    occ[30:] = True  # i >= 30 is obstacle
    aff = np.diag([0.5, 0.5, 0.7, 1.0])
    aff[:3, 3] = [-10.0, 4.0, 2.0]
    x = -10.0 + 0.5 * 29.5  # halfway between the planes i = 29 and i = 30
    d = capsule_obstacle_fraction(occ, aff, [x, 19.0, 10.0], [x, 19.0, 30.0], 5.0)
    assert d["fraction"] == pytest.approx(0.5) and d["voxels"] > 1000
    inside = capsule_obstacle_fraction(occ, aff, [x + 8, 19.0, 10.0], [x + 8, 19.0, 30.0], 5.0)
    assert inside["fraction"] == 1.0
    far = capsule_obstacle_fraction(occ, aff, [500.0, 0, 0], [600.0, 0, 0], 5.0)
    assert far["fraction"] is None and far["voxels"] == 0


# -- settings and flags ---------------------------------------------------------------------


def test_settings_quick_and_given_values_win():
    s = scale_settings(quick=True, patients=[0], directions=[0], trials=[3, 1, 3])
    assert s["trials"] == (1, 3) and s["patients"] == () and s["directions"] == ()
    assert s["study_workers"] == QUICK["study_workers"] and s["medrad"] is None
    s = scale_settings(patients=[0], directions=[0], workers=[2, 1])
    assert s["workers"] == s["study_workers"] == (1, 2)
    assert s["trials"] == DEFAULTS["trials"] and s["max_iterations"] == DEFAULTS["max_iterations"]


@pytest.mark.parametrize(
    ("kw", "flag"),
    [
        ({"trials": [-1]}, "--trials"),
        ({"workers": [0]}, "--workers"),
        ({"dask_workers": [1.5]}, "--dask-workers"),
        ({"planners": ["nope"]}, "--planners"),
        ({"planners": ["liu_cfrw"]}, "--planners"),
        ({"max_iterations": 0}, "--max-iterations"),
        ({"time_limit_s": float("inf")}, "--time-limit-s"),
    ],
)
def test_settings_refuse_bad_values_naming_the_flag(kw, flag):
    base = {"patients": [0], "directions": [0]}
    with pytest.raises(InvalidInputError, match=flag):
        scale_settings(**(base | kw))


def test_settings_need_the_med_rad_lungs(tmp_path):
    with pytest.raises(InvalidInputError, match="--medrad"):
        scale_settings(patients=[1], directions=[0], medrad_dir=tmp_path)
    with pytest.raises(InvalidInputError, match="--medrad"):
        scale_settings(patients=[0], directions=[34], medrad_dir=tmp_path)


def _exit_status(argv) -> int:
    """``main``'s status, whether returned or raised by argparse (a bad value of a flag)."""
    try:
        return main(argv)
    except SystemExit as exc:
        return exc.code


@pytest.mark.parametrize(
    ("argv", "said"),
    [
        (["--workers", "0"], "--workers"),
        (["--trials", "x"], "--trials"),
        (["--planners", "nope", "--patients", "0", "--directions", "0"], "--planners"),
        (["--patients", "0", "--directions", "0", "--max-iterations", "-3"], "--max-iterations"),
        (["--medrad", "/no/such/folder"], "--medrad"),
    ],
)
def test_the_command_refuses_bad_flags_before_any_work(argv, said, capsys, monkeypatch):
    import needlekit.benchmarks.scale as scale

    def no_work(*a, **k):
        raise AssertionError("work started")

    monkeypatch.setattr(scale, "run_scale_benchmark", no_work)
    assert _exit_status(["bench", "scale", *argv]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith("error:") and said in err
    assert "Traceback" not in err


def test_the_output_path_is_checked_first(tmp_path, capsys, monkeypatch):
    import needlekit.benchmarks.scale as scale

    monkeypatch.setattr(scale, "scale_settings", lambda **k: pytest.fail("settings read"))
    assert main(["bench", "scale", "--out", str(tmp_path)]) == 2  # a folder, not a file
    assert "--out" in capsys.readouterr().err


# -- the record -----------------------------------------------------------------------------


def _toy_settings(**kw):
    from needlekit.scenario.problems import ScenarioSource

    s = scale_settings(patients=[0], directions=[8, 24], trials=[0], dask_workers=[0],
                       max_iterations=30, **kw)  # fmt: skip
    return s | {"sweep_source": ScenarioSource.of(EXAMPLES / "toy.yaml"), "sweep_case": "toy"}


def _finite_non_negative(value) -> bool:
    return value is not None and math.isfinite(value) and value >= 0.0


def test_the_record_of_a_serial_sweep_on_the_toy_scene(tmp_path):
    from needlekit.io.files import write_json
    from needlekit.io.results import ResultKind
    from needlekit.report.result_report import write_result_report
    from needlekit.scenario.results import read_result

    record = run_scale_benchmark(_toy_settings(workers=[1]))
    assert record["benchmark"] == "scale" and record["planning"] is None
    assert record["study"] is None and record["preparation"] is None
    assert len(record["machine"]["load_average"]) == 3
    assert set(record["load_average"]) == {"start", "end"}
    assert "sweep_source" not in record["inputs"]
    sw = record["sweep"]
    assert [p["directions"] for p in sw["points"]] == [8, 24] and sw["case"] == "toy"
    for p in sw["points"]:
        assert p["executor"] == "serial" and p["workers"] == 1 and p["equal_to_serial"]
        for key in ("wall_s", "planner_s_sum", "setup_s_sum", "prep_s", "start_s"):
            assert _finite_non_negative(p[key]), key
        assert p["efficiency"] is None or _finite_non_negative(p["efficiency"])
        assert 0 <= p["solved"] <= p["effective"] <= p["directions"]
    fit = sw["fits"]["serial"]["wall_vs_directions"]
    assert fit["n"] == 2 and all(math.isfinite(fit[k]) for k in ("slope", "intercept", "r2"))
    assert [r["name"] for r in record["results"]] == ["sweep serial"]
    assert summary_lines(record) == record["results"]
    path = write_json(tmp_path / "scale.json", record)
    rf = read_result(path)
    assert rf.kind is ResultKind.SCALE and rf.scenario is None
    page = write_result_report(tmp_path / "scale.html", [rf]).path
    assert "(b) Sweep time vs directions and workers" in page.read_text()


@pytest.mark.slow
def test_serial_and_process_sweeps_give_the_same_results():
    record = run_scale_benchmark(_toy_settings(workers=[1, 2]))
    points = record["sweep"]["points"]
    pool = [p for p in points if p["executor"] == "process"]
    assert len(pool) == 2 and all(p["workers"] == 2 for p in pool)
    assert all(p["equal_to_serial"] is True for p in points)
    for p in pool:  # each worker that ran a task prepared the scene once
        assert 1 <= len(p["prep_s_by_worker"]) <= 2
        assert all(_finite_non_negative(v) for v in p["prep_s_by_worker"].values())
    serial = {p["directions"]: p for p in points if p["executor"] == "serial"}
    for p in pool:
        same = serial[p["directions"]]
        assert (p["effective"], p["searched"], p["solved"]) == (
            same["effective"], same["searched"], same["solved"])  # fmt: skip


@pytest.mark.slow
def test_the_study_series_fits_a_line_through_its_points():
    from needlekit.benchmarks.scale_series import study_series

    st = study_series([1], workers=[1])
    (p,) = st["points"]
    assert p["trials"] == 1 and p["completed"] <= 1 and _finite_non_negative(p["wall_s"])
    assert p["equal_to_serial"] is True and st["fits"] == {"1": None}  # one size: no line


@pytest.mark.realdata
@pytest.mark.slow
def test_planning_series_on_med_rad_lung_1(medrad_dir):
    from needlekit.benchmarks.scale_series import planning_series

    pl = planning_series([1], ["rcs_star"], max_iterations=40, medrad_dir=medrad_dir)
    rows = pl["rows"]
    assert [r["start"] for r in rows] == [f"start{i}" for i in range(1, 6)]
    for r in rows:
        assert 0.0 < r["obstacle_density"] < 1.0 and r["capsule_voxels"] > 1000
        assert 20.0 < r["straight_distance_mm"] < 150.0
        assert (r["path_length_mm"] is not None) == (r["status"] == "solved")
        if r["path_length_mm"] is not None:  # a path is never shorter than the chord
            assert r["path_length_mm"] >= r["straight_distance_mm"] - 1.0
    assert any(r["status"] == "solved" for r in rows)
    fits = pl["fits"]["rcs_star"]
    assert fits["time_vs_distance"]["n"] == 5 and math.isfinite(fits["time_vs_density"]["r2"])


# -- the page -------------------------------------------------------------------------------


def small_record() -> dict:
    """A scale record with every series, as ``bench scale`` writes it (made-up numbers)."""
    load = {"start": [0.5, 0.6, 0.7], "end": [0.6, 0.6, 0.7]}
    rows = [
        {"patient": 1, "start": f"start{i}", "planner": "rcs_star",
         "status": "solved" if i != 2 else "approximate", "certified": i != 2,
         "straight_distance_mm": 40.0 + 5 * i, "path_length_mm": None if i == 2 else 41.0 + 5 * i,
         "planner_wall_s": 0.01 * i**2, "time_s": 0.01 * i**2, "setup_s": 0.1,
         "iterations": 5 * i, "obstacle_density": 0.1 * i, "capsule_voxels": 40000}
        for i in range(1, 6)
    ]  # fmt: skip
    points = [
        {"executor": kind, "workers": w, "oversubscribed": w > 2, "directions": n,
         "effective": n // 3, "searched": n // 10, "solved": 2, "wall_s": n * 0.05 / w + w,
         "start_s": 0.1 * w, "planner_s_sum": n * 0.05, "setup_s_sum": 0.2,
         "prep_s_by_worker": {f"h:{k}": 0.5 for k in range(w)}, "prep_s": 0.5 * (w > 1),
         "tasks_by_worker": {}, "efficiency": 0.9, "equal_to_serial": True,
         "load_average": load}
        for kind, w in (("serial", 1), ("process", 2), ("dask", 4)) for n in (34, 68)
    ]  # fmt: skip
    study = [{"workers": 1, "trials": n, "completed": n, "wall_s": 3.0 * n + 0.5,
              "total_s": 3.0 * n + 0.6, "equal_to_serial": True, "load_average": load}
             for n in (1, 2)]  # fmt: skip
    record = {
        "benchmark": "scale",
        "machine": {"time_utc": "2026-12-03T10:00:00+00:00", "cpu": "test", "cpu_count": 2,
                    "python": "3.11", "versions": {"needlekit": "0"}, "load_average": [0.6] * 3},
        "load_average": load, "inputs": {"patients": [1]}, "wall_s": 60.0,
        "preparation": {"patient": 1, "cold_s": 6.0, "warm_s": 0.3, "import_s": 0.5,
                        "peak_rss_mb": 1300.0, "load_average": load},
        "planning": {"rows": rows, "load_s": {"1": 0.3}, "capsule_radius_mm": 10.0,
                     "r_min_mm": 50.0, "load_average": load, "fits": {"rcs_star": {
                         "time_vs_distance": loglog_fit([r["straight_distance_mm"] for r in rows],
                                                        [r["planner_wall_s"] for r in rows]),
                         "time_vs_density": loglog_fit([r["obstacle_density"] for r in rows],
                                                       [r["planner_wall_s"] for r in rows]),
                         "time_vs_path_length": None}}},
        "sweep": {"points": points, "planner": "rcs_star", "max_iterations": 1000,
                  "time_limit_s": 30.0, "main_prep_s": 0.5, "cpu_count": 2, "case": "made up",
                  "fits": {lab: {"wall_vs_directions": linear_fit([34, 68], [1.0, 2.0])}
                           for lab in ("serial", "process x2", "dask x4")}},
        "study": {"points": study, "target_trials": 100, "seed": 0,
                  "fits": {"1": linear_fit([1, 2], [3.5, 6.5], at=100)}},
    }  # fmt: skip
    return record | {"results": summary_lines(record)}


def test_needlekit_report_draws_a_scale_record(tmp_path, capsys):
    path = tmp_path / "scale.json"
    path.write_text(json.dumps(small_record()))
    page = tmp_path / "scale.html"
    assert main(["report", str(path), "--out", str(page)]) == 0
    assert f"{path}: scale: scaling curves: planning, sweep, study" in capsys.readouterr().out
    html = page.read_text()
    for heading in ("(a) Planning time vs path length", "(b) Sweep time vs directions",
                    "(c) Control study time vs trials", "oversubscribed"):  # fmt: skip
        assert heading in html
    assert html.count("js-plotly-plot") >= 3 or html.count("plotly-graph-div") >= 3


def test_a_scale_record_without_its_series_is_refused(tmp_path, capsys):
    bad = small_record()
    del bad["sweep"]["points"][0]["wall_s"]
    path = tmp_path / "scale.json"
    path.write_text(json.dumps(bad))
    assert main(["report", str(path), "--out", str(tmp_path / "p.html")]) == 2
    assert "sweep.points[0]: wall_s" in capsys.readouterr().err


def test_the_docs_figure_is_a_png():
    from needlekit.report.scale_figures import scale_png

    assert scale_png(small_record(), dpi=40).startswith(b"\x89PNG\r\n\x1a\n")
