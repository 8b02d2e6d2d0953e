"""Tests of needlekit.report.sweep_report and html_page: Feng's Fig. 8, Fig. 9, Table 4 and
the self-contained HTML page.

A real sweep of the three planners over 136 directions on the lung phantom (iteration
budgets, a second or two) checks the figures against the sweep's own statistics; small
hand-made sweeps check the edge cases and the input validation.
"""

from __future__ import annotations

import importlib
import inspect
import re
from pathlib import Path

import numpy as np
import plotly.graph_objects as go
import pytest
from plotly.offline import get_plotlyjs

from needlekit.errors import InvalidInputError
from needlekit.planning.result import PlanStatus
from needlekit.planning.steerable.result import PlanResult
from needlekit.planning.steerable.sweep import SweepResult, sphere_directions, sweep_stats
from needlekit.report.sweep_report import (
    FIG9_OFFSET,
    FigureSection,
    TableSection,
    TextSection,
    cost_per_direction_figure,
    direction_sphere_figure,
    direction_table,
    goal_connection_rule,
    sweep_sections,
    sweep_table,
    write_report_html,
)

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
PLANNERS = ("rcs_star", "rcs", "rrt")


@pytest.fixture(scope="module")
def lung():
    from needlekit.planning.steerable.sweep import sweep
    from needlekit.scenario.loading import load_scenario
    from needlekit.scenario.problems import problem_from_scenario

    sc = load_scenario(EXAMPLES / "lung_phantom.yaml")
    p = problem_from_scenario(sc)
    dirs = sphere_directions(136)
    runs = {
        pl: sweep(p, pl, directions=dirs, time_limit_s=30.0, max_iterations=200) for pl in PLANNERS
    }
    normal = p.scene.normal(p.start_point_mm, p.entry_surface)
    return sc, runs, normal


def test_every_plan_of_the_lung_sweep_clears_the_exact_anatomy(lung, exact_clearance):
    # iteration budgets end each search: the same plans on any machine, each re-checked
    # against the phantom's exact structures (not the voxel grids the planners used)
    from needlekit.scenario.problems import problem_from_scenario

    sc, runs, _ = lung
    p = problem_from_scenario(sc)
    for pl in PLANNERS:
        stats = runs[pl].stats
        assert (stats["n_effective"], stats["n_solved"]) == (42, 5)
        plans = [r for r in runs[pl].results if r is not None and r.plan is not None]
        assert [r.status for r in plans] == [PlanStatus.SOLVED] * 5
        for r in plans:
            exact_clearance(sc.base, p, r.plan, r.stats["certified_clearance_mm"])


def _fake_sweep(directions, effective, costs, planner="rcs", statuses=None) -> SweepResult:
    """A SweepResult from per-direction costs (None: not effective; inf: no plan), with the
    statistics computed as :func:`sweep` does."""
    results = []
    for i, (eff, c) in enumerate(zip(effective, costs, strict=True)):
        status = (statuses or {}).get(
            i, PlanStatus.SOLVED if np.isfinite(c) else PlanStatus.TIMEOUT
        )
        results.append(
            PlanResult(status, planner, None, float(c), 0.01, np.zeros(3)) if eff else None
        )
    stats = sweep_stats(directions, effective, results, 0.5)
    return SweepResult(np.asarray(directions), np.asarray(effective), results, planner, stats)


def _traces(fig, name, scene=None):
    return [t for t in fig.data if t.name == name and (scene is None or t.scene == scene)]


def _costs(sw) -> np.ndarray:
    return np.array(
        [
            r.cost_mm if r is not None and r.status is PlanStatus.SOLVED else np.nan
            for r in sw.results
        ]
    )


# ---------------------------------------------------------------------------------------
# Fig. 8: the direction spheres


def test_sphere_markers_per_category_match_the_sweep(lung):
    _, runs, normal = lung
    fig = direction_sphere_figure(runs, normal=normal)
    assert runs["rcs"].stats["n_solved"] > 1  # the fixture exercises every category
    for k, sw in enumerate(runs.values()):
        scene = "scene" if k == 0 else f"scene{k + 1}"
        count = {
            label: sum(len(t.x) for t in _traces(fig, label, scene))
            for label in ("not effective", "effective, no plan", "solved", "best")
        }
        s = sw.stats
        assert count == {
            "not effective": s["n_directions"] - s["n_effective"],
            "effective, no plan": s["n_effective"] - s["n_solved"],
            "solved": s["n_solved"],
            "best": 1,
        }
        (best,) = _traces(fig, "best", scene)
        np.testing.assert_allclose([best.x[0], best.y[0], best.z[0]], s["best_direction"])
        assert best.marker.color == "#d62728" and best.marker.size > 5
        (solved,) = _traces(fig, "solved", scene)
        idx = [int(c[0]) for c in solved.customdata]
        costs = _costs(sw)
        assert idx == list(np.flatnonzero(np.isfinite(costs)))
        np.testing.assert_allclose(
            np.column_stack([solved.x, solved.y, solved.z]), sw.directions[idx]
        )
        np.testing.assert_allclose(solved.marker.color, costs[idx])
        (grey,) = _traces(fig, "not effective", scene)
        assert not np.any(sw.effective[[int(c[0]) for c in grey.customdata]])
        assert "cost" in solved.hovertemplate or "customdata[1]" in solved.hovertemplate
        assert solved.customdata[0][1] == f"cost {costs[idx[0]]:.3f} mm"
    # one normal arrow per view, pointing along the given normal
    lines = _traces(fig, "surface normal")
    assert len([t for t in lines if isinstance(t, go.Scatter3d)]) == len(runs)
    arrow = next(t for t in lines if isinstance(t, go.Scatter3d))
    tip = np.array([arrow.x[1], arrow.y[1], arrow.z[1]])
    np.testing.assert_allclose(tip / np.linalg.norm(tip), normal / np.linalg.norm(normal))


def test_sphere_colour_scale_is_shared_across_planners(lung):
    _, runs, _ = lung
    fig = direction_sphere_figure(runs)
    all_costs = np.concatenate([_costs(sw) for sw in runs.values()])
    ax = fig.layout.coloraxis
    assert ax.cmin == pytest.approx(np.nanmin(all_costs))
    assert ax.cmax == pytest.approx(np.nanmax(all_costs))
    assert ax.colorbar.title.text == "cost (mm)"
    solved = _traces(fig, "solved")
    assert len(solved) == len(runs) and all(t.marker.coloraxis == "coloraxis" for t in solved)
    # exactly one colour bar: the shared axis; no trace draws its own
    assert not any(getattr(t, "showscale", None) for t in fig.data)
    assert not _traces(fig, "surface normal")  # no normal given, no arrow


def test_sphere_of_a_sweep_without_any_plan_has_no_colour_axis():
    d = sphere_directions(10)
    eff = d[:, 2] > 0
    sw = _fake_sweep(d, eff, [np.inf] * 10)
    fig = direction_sphere_figure({"rrt": sw})
    assert sum(len(t.x) for t in _traces(fig, "effective, no plan")) == int(eff.sum())
    assert not _traces(fig, "solved") and not _traces(fig, "best")
    assert fig.layout.coloraxis.cmin is None


def test_approximate_results_count_as_no_plan():
    d = sphere_directions(6)
    eff = np.ones(6, dtype=bool)
    sw = _fake_sweep(
        d, eff, [5.0, 4.0, 3.0, np.inf, 6.0, 7.0], statuses={2: PlanStatus.APPROXIMATE}
    )
    assert sw.stats["n_solved"] == 4 and sw.stats["best_index"] == 1
    fig = direction_sphere_figure({"rcs": sw})
    assert len(_traces(fig, "solved")[0].x) == 4
    texts = [c[1] for c in _traces(fig, "effective, no plan")[0].customdata]
    assert texts == ["no plan (approximate)", "no plan (timeout)"]


# ---------------------------------------------------------------------------------------
# Fig. 9: cost per effective direction


def test_cost_lines_follow_the_effective_directions_in_sweep_order(lung):
    _, runs, _ = lung
    fig = cost_per_direction_figure(runs)
    labels = {"rcs_star": "RCS*", "rcs": "RCS", "rrt": "RRT"}
    n = len(runs)
    sizes = []
    for j, (name, sw) in enumerate(runs.items()):
        label = labels[name]
        (line,) = _traces(fig, label)
        idx = np.flatnonzero(sw.effective)
        costs = _costs(sw)[idx]
        # each planner a little to the side of the direction's position, so equal costs
        # never hide one series behind another
        shift = (j - (n - 1) / 2) * FIG9_OFFSET
        assert list(line.x) == pytest.approx([i + shift for i in range(1, len(idx) + 1)])
        sizes.append(line.marker.size)
        assert [None if np.isnan(c) else c for c in costs] == list(line.y)  # gaps, no zeros
        assert line.connectgaps is False and line.mode == "lines+markers"
        assert [int(c[0]) for c in line.customdata] == list(idx)
        (best,) = _traces(fig, f"{label} best")
        k = list(idx).index(sw.stats["best_index"])
        assert best.x[0] == pytest.approx(k + 1 + shift)
        assert best.y[0] == pytest.approx(sw.stats["best_cost_mm"])
        assert best.y[0] == pytest.approx(np.nanmin(costs))
        (mean,) = _traces(fig, f"{label} mean")
        assert mean.line.dash == "dash" and mean.line.color == line.line.color
        assert list(mean.y) == [pytest.approx(sw.stats["mean_cost_mm"])] * 2
        assert mean.y[0] == pytest.approx(np.nanmean(costs))
    colours = {_traces(fig, labels[n])[0].line.color for n in runs}
    assert len(colours) == len(runs)
    assert len(set(sizes)) == len(runs)  # and marker sizes apart


def test_tables_2_3_and_the_goal_connections(lung):
    _, runs, _ = lung
    rows = direction_table(runs)
    solved = {i for sw in runs.values() for i in np.flatnonzero(np.isfinite(_costs(sw)))}
    assert len(rows) == len(solved) > 0
    row = rows[0]
    assert list(row) == ["effective #", "direction", "RCS* cost (mm)", "RCS cost (mm)",
                         "RRT cost (mm)"]  # fmt: skip
    assert goal_connection_rule("rcs_star").startswith("turn at r_min, then straight")
    assert goal_connection_rule("rcs") == "one arc to the target itself"
    assert "one arc" in goal_connection_rule("rrt", {"connection": "arc"})
    assert "into the tau-ball" in goal_connection_rule("rrt", {})
    assert goal_connection_rule("mine").startswith("its own")


# ---------------------------------------------------------------------------------------
# Table 4


def test_table_rows_are_the_sweep_statistics(lung):
    _, runs, _ = lung
    rows = sweep_table(runs)
    assert [r["planner"] for r in rows] == list(runs)
    keys = ["n_effective", "n_solved", "best_cost_mm", "best_direction", "mean_cost_mm"]
    keys += ["cost_before_lowest_mm", "time_s"]
    for row, sw in zip(rows, runs.values(), strict=True):
        assert list(row) == ["planner", *keys]
        assert row == {"planner": sw.planner, **{k: sw.stats[k] for k in keys}}


def test_cost_before_lowest_is_fengs_sum_up_to_the_best():
    d = sphere_directions(5)
    sw = _fake_sweep(d, np.ones(5, bool), [7.0, np.inf, 5.0, 3.0, 4.0])
    (row,) = sweep_table({"rrt": sw})
    assert row["best_cost_mm"] == 3.0 and row["cost_before_lowest_mm"] == pytest.approx(15.0)
    assert row["mean_cost_mm"] == pytest.approx(19.0 / 4)


# ---------------------------------------------------------------------------------------
# input validation


def test_bad_sweeps_are_refused_with_a_clear_error():
    d = sphere_directions(8)
    eff = d[:, 0] > 0
    a = _fake_sweep(d, eff, [3.0] * 8)
    for fn in (direction_sphere_figure, cost_per_direction_figure, sweep_table, sweep_sections):
        with pytest.raises(InvalidInputError, match="sweeps: expected a non-empty mapping"):
            fn({})
        with pytest.raises(InvalidInputError, match="sweeps: expected a non-empty mapping"):
            fn([a])
        with pytest.raises(InvalidInputError, match=r"sweeps\['rcs'\]: expected a SweepResult"):
            fn({"rcs": {"directions": d}})
        other = _fake_sweep(sphere_directions(9), np.ones(9, bool), [3.0] * 9, "rrt")
        with pytest.raises(InvalidInputError, match=r"sweeps\['rrt'\]: swept other directions"):
            fn({"rcs": a, "rrt": other})
        rotated = _fake_sweep(d[::-1], eff[::-1], [3.0] * 8, "rrt")
        with pytest.raises(InvalidInputError, match="swept other directions"):
            fn({"rcs": a, "rrt": rotated})
        shifted = _fake_sweep(d, ~eff, [3.0] * 8, "rrt")
        with pytest.raises(InvalidInputError, match=r"sweeps\['rrt'\]: effective region differs"):
            fn({"rcs": a, "rrt": shifted})
    with pytest.raises(InvalidInputError, match="normal"):
        direction_sphere_figure({"rcs": a}, normal=[0.0, 0.0, 0.0])
    with pytest.raises(InvalidInputError, match="normal"):
        direction_sphere_figure({"rcs": a}, normal=[1.0, np.nan, 0.0])


# ---------------------------------------------------------------------------------------
# the HTML page


PLOTLY_JS_HEAD = get_plotlyjs()[:60]  # the licence header that opens every copy of plotly.js


@pytest.fixture(scope="module")
def report(lung, tmp_path_factory):
    sc, runs, normal = lung
    sections = [
        *sweep_sections(runs, normal=normal, scene=sc.scene),
        TextSection("Plans within <1 mm & more", heading="Notes <on> the run"),
        "a bare string is a paragraph",
    ]
    path = tmp_path_factory.mktemp("report") / "sub" / "sweep.html"  # directory made on write
    out = write_report_html(path, title="Sweep <b>lung</b> & co", sections=sections)
    return out, path.read_text(encoding="utf-8"), sections


def test_html_is_one_self_contained_page(report):
    out, page, sections = report
    assert out.is_file() and out.suffix == ".html"
    assert page.startswith("<!DOCTYPE html>") and page.rstrip().endswith("</html>")
    assert page.count(PLOTLY_JS_HEAD) == 1  # plotly.js inlined exactly once
    n_figures = sum(isinstance(s, FigureSection) for s in sections)
    assert n_figures == 4  # Fig. 8, Fig. 9, Fig. 7 and the best paths
    assert page.count('class="plotly-graph-div"') == n_figures
    assert page.index(PLOTLY_JS_HEAD) < page.index('class="plotly-graph-div"')
    assert not re.search(r"<script[^>]+src=", page)  # nothing fetched: opens offline
    # plotly.js itself names a CDN (the default topojson URL of geo maps, unused here)
    rest = page.replace(get_plotlyjs(), "")
    assert len(rest) < len(page) - 1_000_000  # the library was inlined verbatim
    assert "cdn.plot.ly" not in rest and "https://" not in rest
    assert [p.name for p in out.parent.iterdir()] == ["sweep.html"]  # no temporary file left


def test_html_has_every_heading_and_escapes_text(report):
    _, page, sections = report
    for s in sections:
        if getattr(s, "heading", None):
            assert f"<h2>{s.heading.replace('<', '&lt;').replace('>', '&gt;')}</h2>" in page
    assert "<title>Sweep &lt;b&gt;lung&lt;/b&gt; &amp; co</title>" in page
    assert "<h1>Sweep &lt;b&gt;lung&lt;/b&gt; &amp; co</h1>" in page
    assert "<b>lung" not in page and "<on>" not in page
    assert "<p>Plans within &lt;1 mm &amp; more</p>" in page
    assert "<p>a bare string is a paragraph</p>" in page


def test_html_table_formats_numbers(lung, tmp_path):
    _, runs, _ = lung
    rows = [
        {
            "planner": "rcs",
            "n_solved": 3,
            "best_cost_mm": 61.12345678,
            "best_direction": [0.5, -0.25, 1.0],
        },
        {"planner": "rrt", "n_solved": 0, "best_cost_mm": None, "time_s": float("nan"), "ok": True},
    ]
    path = write_report_html(tmp_path / "t.html", title="t", sections=[TableSection("T", rows)])
    page = path.read_text(encoding="utf-8")
    heads = re.findall(r"<th>(.*?)</th>", page)
    assert heads == ["planner", "n solved", "best cost (mm)", "best direction", "time (s)", "ok"]
    cells = re.findall(r"<td[^>]*>(.*?)</td>", page)
    assert cells == [
        "rcs",
        "3",
        "61.123",
        "(0.500, \N{MINUS SIGN}0.250, 1.000)",
        "\N{EN DASH}",
        "\N{EN DASH}",
        "rrt",
        "0",
        "\N{EN DASH}",
        "\N{EN DASH}",
        "\N{EN DASH}",
        "yes",
    ]
    assert PLOTLY_JS_HEAD not in page  # no figure, no plotly.js
    # the sweep table itself renders one row per planner
    page = write_report_html(
        tmp_path / "s.html", title="s", sections=[TableSection("S", sweep_table(runs))]
    ).read_text()
    assert page.count("<tr>") == 1 + len(runs)


class _BrokenFigure(go.Figure):
    def to_html(self, *args, **kwargs):
        raise RuntimeError("renderer failed")


@pytest.mark.parametrize(
    ("section", "error", "match"),
    [
        (42, InvalidInputError, r"sections\[2\]: expected a FigureSection"),
        (FigureSection("f", {"data": []}), InvalidInputError, r"sections\[2\].figure"),
        (TableSection("t", {"a": 1}), InvalidInputError, r"sections\[2\].rows"),
        (TableSection("t", [1, 2]), InvalidInputError, r"sections\[2\].rows"),
        (TextSection(3.0), InvalidInputError, r"sections\[2\].text"),
        (FigureSection("f", _BrokenFigure()), RuntimeError, "renderer failed"),  # mid-write
    ],
)
def test_a_failed_write_leaves_the_old_file_intact(tmp_path, section, error, match):
    path = tmp_path / "report.html"
    path.write_text("old report", encoding="utf-8")
    good = [TextSection("first"), FigureSection("a figure", go.Figure(go.Scatter(y=[1, 2])))]
    with pytest.raises(error, match=match):
        write_report_html(path, title="t", sections=[*good, section])
    assert path.read_text(encoding="utf-8") == "old report"
    assert [p.name for p in tmp_path.iterdir()] == ["report.html"]


def test_bad_title_or_sections_container_are_refused(tmp_path):
    with pytest.raises(InvalidInputError, match="title"):
        write_report_html(tmp_path / "x.html", title=None, sections=[])
    with pytest.raises(InvalidInputError, match="sections"):
        write_report_html(tmp_path / "x.html", title="x", sections="text")
    assert not list(tmp_path.iterdir())


# ---------------------------------------------------------------------------------------
# documentation (stricter than tests/test_docstrings.py, which walks every module)


@pytest.mark.parametrize("module", ["needlekit.report.sweep_report", "needlekit.report.html_page"])
def test_public_functions_have_numpydoc_sections(module):
    mod = importlib.import_module(module)
    for name in mod.__all__:
        fn = getattr(mod, name)
        assert fn.__doc__, f"{name}: no docstring"
        if inspect.isfunction(fn):
            doc = inspect.getdoc(fn)
            assert "Returns\n-------" in doc and "Parameters\n----------" in doc, name
            if "ndarray" in doc or "array_like" in doc:
                assert "shape" in doc, name


def test_best_paths_figure_draws_each_planners_best_plan(lung, report):
    _, runs, _ = lung
    _, _, sections = report
    (fig,) = [s.figure for s in sections if getattr(s, "heading", "") == "Best path per planner"]
    labels = {"rcs_star": "RCS*", "rcs": "RCS", "rrt": "RRT"}
    for name, sw in runs.items():
        (line,) = [t for t in fig.data if t.name.startswith(f"{labels[name]} best (")]
        assert line.name == f"{labels[name]} best ({sw.stats['best_cost_mm']:.2f} mm)"
        pts = np.column_stack([line.x, line.y, line.z])
        np.testing.assert_allclose(pts[0], sw.best.start_pose[:3, 3], atol=1e-9)
        assert np.linalg.norm(pts[-1] - sw.best.goal_mm) <= 1.0 + 1e-6  # goal tolerance
        # the view is zoomed onto the paths
        for axis in ("xaxis", "yaxis", "zaxis"):
            lo, hi = fig.layout.scene[axis].range
            k = "xyz".index(axis[0])
            assert lo <= pts[:, k].min() and pts[:, k].max() <= hi


def test_fig7_draws_every_valid_path_of_the_first_planner(lung):
    from needlekit.report.sweep_report import valid_paths_figure

    sc, runs, _ = lung
    sw = runs["rcs_star"]
    fig = valid_paths_figure(sc.scene, sw)
    lines = [t for t in fig.data if t.type == "scatter3d" and t.name.startswith("direction #")]
    solved = [r for r in sw.results if r is not None and r.status.value == "solved"]
    assert len(lines) == len(solved) == sw.stats["n_solved"]
    (best,) = [t for t in lines if t.name.endswith("(best)")]
    assert best.name.startswith(f"direction #{sw.stats['best_index']}:")
    assert best.line.color == "#d62728" and best.showlegend
