"""Tests of needlekit.report.straight_report and straight_figures: the CFRW layers (Liu's
Fig. 11), the accessibility map, the 3D scene and the self-contained page.

A small analytic scene (a skin sphere, a short vessel straight above the first target that
cuts a hole in its CFRW, a long vessel across) and two targets, planned at 5 degrees: the
figures must carry exactly the planner's data.
"""

from __future__ import annotations

import html
import re

import numpy as np
import plotly.graph_objects as go
import pytest
from plotly.offline import get_plotlyjs

from needlekit.anatomy.needle_body import LIU_HEAD
from needlekit.anatomy.primitives import Capsule, Sphere
from needlekit.anatomy.scene import Role, Scene, Structure
from needlekit.constants import RECORD_ROUNDING_ALLOWANCE_MM
from needlekit.errors import InvalidInputError
from needlekit.planning.straight.cfrw import Blocked, inside_polylines
from needlekit.planning.straight.coverage import AblationZone
from needlekit.planning.straight.entry import best_on_map
from needlekit.planning.straight.problem import StraightNeedle, StraightProblem
from needlekit.planning.straight.sequence import plan_needles
from needlekit.report.straight_report import (
    accessibility_map_figure,
    blocking_table,
    cfrw_layers_figure,
    needle_table,
    plan_maps,
    scene_figure,
    write_straight_report,
)

RES_DEG = 5.0
TARGETS = np.array([[0.0, 0.0, 0.0], [-15.0, 10.0, 0.0]])
H = (50.0, 60.0, 70.0)


def _scene() -> Scene:
    return Scene(
        [
            Structure("skin", Role.ENTRY_SURFACE, Sphere([0, 0, 0], 100.0)),
            Structure("short vessel", Role.OBSTACLE, Capsule([-3, 0, 45], [3, 0, 45], 4.0)),
            Structure("long vessel", Role.OBSTACLE, Capsule([30, -60, 60], [30, 60, 60], 3.0)),
        ],
        name="analytic",
    )


@pytest.fixture(scope="module")
def planned():
    pr = StraightProblem(
        _scene(), TARGETS[0], "skin", StraightNeedle(1.0, 150.0), theta_range_deg=(0, 60)
    )
    plan = plan_needles(pr, TARGETS, resolution_deg=RES_DEG)
    maps = plan_maps(pr, plan, resolution_deg=RES_DEG)
    return pr, plan, maps


#: How far the plan record's rounded points (RECORD_DECIMALS) may lie from the map's
#: choice (mm), and the angle that moves an entry tens of mm out by (deg).
ROUNDED_MM = RECORD_ROUNDING_ALLOWANCE_MM
ROUNDED_DEG = 1e-6


def _record(plan, target_index):
    return next(r for r in plan.needles if r.target_index == target_index)


def _named(fig, name):
    return [t for t in fig.data if t.name == name]


def test_the_maps_are_the_ones_the_planner_chose_on(planned):
    _, plan, maps = planned
    assert plan.solved and len(maps) == 2
    for r, m in zip(plan.needles, maps, strict=True):
        assert m.problem.target_mm == pytest.approx(r.target_mm)
        assert m.counts() == r.blocked
        # the record holds its points rounded (RECORD_DECIMALS): the map's choice is the
        # record's entry up to that rounding
        assert best_on_map(m).entry_mm == pytest.approx(r.entry.entry_mm, abs=ROUNDED_MM)
    # the second map has the first needle as an obstacle: fewer free directions than alone
    assert len(maps[1].problem.extra_obstacles) == 1


# ---------------------------------------------------------------------------------------
# Fig. 11: layers


@pytest.fixture(scope="module")
def first_layers(planned):
    _, plan, maps = planned
    m = maps[[r.target_index for r in plan.needles].index(0)]
    fig = cfrw_layers_figure(m, H, [_record(plan, 0)])
    return m, fig, m.layer(H[0])


def test_the_layer_polylines_are_the_maps_boundary(first_layers):
    m, fig, polys = first_layers
    lines = _named(fig, f"boundary z = {H[0]:g} mm")
    assert len(lines) == len(polys) >= 2  # the outer boundary and the short vessel's hole
    for t, p in zip(lines, polys, strict=True):
        assert np.array_equal(np.column_stack([t.x, t.y]), p)
    # one filled shape of every polyline, by the even-odd rule: the hole stays empty
    (shape,) = fig.layout.shapes
    assert shape.fillrule == "evenodd" and shape.path.count("M ") == len(polys)
    assert shape.xref == "x" and shape.yref == "y"
    assert not inside_polylines([[0.0, 0.0]], polys)[0]  # straight up meets the vessel
    assert m.blocked[0, 0] == Blocked.CLEARANCE


def test_the_stacked_layers_are_the_maps_layers_at_each_height(first_layers):
    m, fig, polys = first_layers
    for h in H:
        (t,) = _named(fig, f"z = {h:g} mm")
        assert t.scene == "scene"
        xyz = np.column_stack([t.x, t.y, t.z])
        breaks = np.flatnonzero([x is None for x in t.x])
        parts = np.split(xyz, breaks)
        parts = [p[1:] if i else p for i, p in enumerate(parts)][: len(polys)]
        # one plane computed, the others scaled: as the map's own layer there (checked
        # at the top one, to stay fast)
        exact = m.layer(h) if h == H[-1] else [p * (h / H[0]) for p in polys]
        assert len(breaks) == len(exact)
        for p, q in zip(parts, exact, strict=True):
            assert np.allclose(p[:, :2].astype(float), q, atol=1e-9)
            assert np.all(p[:, 2] == h)


def test_the_trajectory_crosses_the_plane_where_its_angles_say(planned, first_layers):
    _, plan, _ = planned
    m, fig, polys = first_layers
    r = _record(plan, 0)
    (cross,) = [t for t in _named(fig, f"needle {r.order}") if t.type == "scatter"]
    th, ph = r.entry.theta_rad, r.entry.phi_rad
    expected = H[0] * np.tan(th) * np.array([np.cos(ph), np.sin(ph)])
    # the angles are the rounded record's (RECORD_DECIMALS), the figure the map's
    assert np.array([cross.x[0], cross.y[0]]) == pytest.approx(expected, abs=ROUNDED_MM)
    assert inside_polylines([expected], polys)[0]  # the chosen trajectory is in the CFRW
    (entry,) = _named(fig, f"needle {r.order} entry")
    g = m.problem.world_T_sigma
    local = (r.entry.entry_mm - g[:3, 3]) @ g[:3, :3]
    assert [entry.x[0], entry.y[0], entry.z[0]] == pytest.approx(local, abs=1e-9)
    assert "mm" in fig.layout.xaxis.title.text and "mm" in fig.layout.scene.zaxis.title.text


def test_a_given_layer_is_drawn_as_given(first_layers):
    m, _, _ = first_layers
    square = [np.array([[0, 0], [10, 0], [10, 10], [0, 10], [0, 0]], float)]
    fig = cfrw_layers_figure(m, (20.0, 40.0), layers={20.0: square})
    (t,) = _named(fig, "boundary z = 20 mm")
    assert list(t.x) == [0, 10, 10, 0, 0]
    (top,) = _named(fig, "z = 40 mm")
    assert max(x for x in top.x if x is not None) == 20.0  # scaled by 40 / 20


# ---------------------------------------------------------------------------------------
# the accessibility map


def test_the_accessibility_map_shows_every_direction_and_the_choice(planned):
    _, plan, maps = planned
    r, m = plan.needles[1], maps[1]
    fig = accessibility_map_figure(m, [r])
    (free,) = _named(fig, "in the CFRW")
    ok = m.feasible
    assert np.allclose(np.column_stack([free.x, free.y, free.z]), m.entry_mm[ok])
    assert np.allclose(free.marker.color, m.clearance_mm[ok])
    assert free.marker.cmin == m.problem.gamma_mm
    points = [t for t in fig.data if t.type == "scatter3d"]
    names = {t.name for t in points} - {"target", "chosen entries"}
    # needle 2's directions: free, or blocked by the anatomy, or by needle 1 (told apart)
    assert names == {
        "in the CFRW",
        "closer than \N{GREEK SMALL LETTER GAMMA} to the anatomy",
        "closer than \N{GREEK SMALL LETTER GAMMA} to a placed needle",
    }
    n_drawn = sum(len(t.x) for t in points if t.name in names)
    assert n_drawn == np.count_nonzero(np.all(np.isfinite(m.entry_mm), axis=2))
    (chosen,) = _named(fig, "chosen entries")
    assert [chosen.x[0], chosen.y[0], chosen.z[0]] == pytest.approx(r.entry.entry_mm)
    (heat,) = [t for t in fig.data if isinstance(t, go.Heatmap)]
    assert np.array_equal(np.asarray(heat.z), m.blocked)
    assert np.allclose(heat.x, np.degrees(m.phi_rad)) and np.allclose(
        heat.y, np.degrees(m.theta_rad)
    )
    (star,) = _named(fig, "chosen")
    # the star is the map's direction, the record's angles those of its rounded points:
    # an entry ~100 mm out moved by ROUNDED_MM turns by ~1e-8 rad
    assert star.y[0] == pytest.approx(np.degrees(r.entry.theta_rad), abs=ROUNDED_DEG)
    dphi = (star.x[0] - np.degrees(r.entry.phi_rad)) % 360.0
    assert min(dphi, 360.0 - dphi) < ROUNDED_DEG or r.entry.theta_rad == 0.0
    assert heat.colorbar.ticktext[Blocked.CLEARANCE].startswith("closer than")


# ---------------------------------------------------------------------------------------
# the scene


def test_the_scene_draws_needles_heads_and_zones(planned):
    _, plan, _ = planned
    zone = AblationZone.ellipsoid(30.0, 20.0, tip_offset_mm=2.0)
    fig = scene_figure(_scene(), plan, zone, max_cells=40)
    assert {"skin (entry_surface)", "short vessel (obstacle)"} <= {t.name for t in fig.data}
    for r in plan.needles:
        (line,) = _named(fig, f"needle {r.order}")
        seg = np.column_stack([line.x, line.y, line.z])
        assert np.allclose(seg, [r.entry.entry_mm, r.entry.target_mm])
        (label,) = _named(fig, f"label {r.order}")
        assert label.text == (str(r.order),)
        (head,) = _named(fig, f"head {r.order}")
        v = np.column_stack([head.x, head.y, head.z])
        axis = (r.entry.entry_mm - r.entry.target_mm) / r.entry.length_mm
        along = (v - r.entry.entry_mm) @ axis
        assert along.min() == pytest.approx(0.0, abs=1e-9)
        assert along.max() == pytest.approx(LIU_HEAD.length_mm)
        across = np.linalg.norm((v - r.entry.entry_mm) - along[:, None] * axis, axis=1)
        assert across.max() == pytest.approx(LIU_HEAD.diameter_mm / 2)
        # the zone's mesh lies on the zone's own surface, around this needle's axis
        (mesh,) = _named(fig, f"ablation zone {r.order}")
        v = np.column_stack([mesh.x, mesh.y, mesh.z])
        w = r.entry.target_mm - r.entry.entry_mm
        sd = zone.signed_distance(v, r.entry.target_mm, w)
        assert np.abs(sd).max() < 1e-6
        assert mesh.opacity < 1
    bare = scene_figure(_scene(), plan, head=False, max_cells=40)
    assert not [t for t in bare.data if (t.name or "").startswith(("head", "ablation"))]
    explicit = scene_figure(_scene(), plan, [([0, 0, 0], [0, 0, 1], AblationZone.sphere(5.0))])
    (ball,) = _named(explicit, "ablation zone 1")
    r_ball = np.linalg.norm(np.column_stack([ball.x, ball.y, ball.z]), axis=1)
    assert np.allclose(r_ball, 5.0)


# ---------------------------------------------------------------------------------------
# the page


PLOTLY_JS_HEAD = get_plotlyjs()[:60]


@pytest.fixture(scope="module")
def page(planned, tmp_path_factory):
    _, plan, maps = planned
    path = tmp_path_factory.mktemp("straight") / "sub" / "multi.html"
    out = write_straight_report(
        path, plan=plan, maps=maps, scene=_scene(), zones=AblationZone.sphere(8.0),
        title="Two <needles>", heights_mm=H, max_cells=40,
    )  # fmt: skip
    return out, path.read_text(encoding="utf-8")


@pytest.mark.slow  # the page: ~7 s
def test_the_page_is_self_contained(page):
    out, text = page
    assert out.is_file() and [p.name for p in out.parent.iterdir()] == ["multi.html"]
    assert text.count(PLOTLY_JS_HEAD) == 1
    assert not re.search(r"<script[^>]+src=", text)
    rest = text.replace(get_plotlyjs(), "")
    assert "https://" not in rest and "cdn.plot.ly" not in rest
    assert "<title>Two &lt;needles&gt;</title>" in text


@pytest.mark.slow  # the page: ~7 s
def test_the_page_has_the_needle_table_and_a_figure_per_needle(planned, page):
    _, plan, _ = planned
    _, text = page
    # 2 layer figures, 2 accessibility maps, the scene
    assert text.count('class="plotly-graph-div"') == 2 * len(plan.needles) + 1
    for r in plan.needles:
        assert f"<h2>CFRW of needle {r.order}</h2>" in text
        assert f"<h2>Accessibility map of needle {r.order}</h2>" in text
    assert "<h2>3D scene</h2>" in text and "<h2>Needles</h2>" in text
    assert "As the paper&#x27;s Fig. 11." in text
    table = text[text.index("<h2>Needles</h2>") : text.index("</table>")]
    for r in plan.needles:
        e = r.entry
        cells = [f">{v:.3f}<" for v in (e.length_mm, e.clearance_mm, np.degrees(e.theta_rad))]
        cells.append(">(" + ", ".join(f"{v:.3f}" for v in e.entry_mm) + ")<")
        for cell in cells:
            assert cell.replace("-", "\N{MINUS SIGN}") in html.unescape(table)
    second = plan.needles[1]
    assert f"{second.needle_clearance_mm:.3f}" in table
    assert "clearance to needles (mm)" in table and "clearance to anatomy (mm)" in table


def test_table_rows(planned):
    _, plan, _ = planned
    rows = needle_table(plan)
    assert [r["order"] for r in rows] == [1, 2]
    assert rows[0]["clearance_to_needles_mm"] is None
    assert rows[1]["clearance_to_needles_mm"] == plan.needles[1].needle_clearance_mm
    assert "planned_target_mm" not in rows[0]  # no deformation: the targets did not move
    counts = blocking_table(plan)
    for row, r in zip(counts, plan.needles, strict=True):
        assert row["free"] == r.blocked["free"] and row["directions"] == sum(r.blocked.values())


@pytest.mark.slow  # the page: ~7 s
def test_bad_input_names_the_argument_and_leaves_the_page(planned, page):
    _, plan, maps = planned
    out, before = page
    with pytest.raises(InvalidInputError, match="maps"):
        write_straight_report(out, plan=plan, maps=maps[:1], scene=_scene())
    with pytest.raises(InvalidInputError, match=r"maps\[1\]"):
        write_straight_report(out, plan=plan, maps=[maps[0], "map"], scene=_scene())
    assert out.read_text(encoding="utf-8") == before
    with pytest.raises(InvalidInputError, match=r"trajectories\[0\]"):
        cfrw_layers_figure(maps[0], H, ["entry"])
    with pytest.raises(InvalidInputError, match="heights_mm"):
        cfrw_layers_figure(maps[0], (0.0,))
    with pytest.raises(InvalidInputError, match="cfrw"):
        accessibility_map_figure(plan)
    with pytest.raises(InvalidInputError, match=r"zones\[0\]"):
        scene_figure(_scene(), plan, [("centre", [0, 0, 1])])
