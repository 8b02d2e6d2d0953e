"""The 3D views of a path: framed on it, enclosing surfaces see-through, the camera where
the path is seen, surfaces decimated to a face budget, plotly.js inlined or shared."""

from __future__ import annotations

import re

import numpy as np
import pytest

from needlekit.anatomy.primitives import Capsule, Sphere
from needlekit.anatomy.scene import Role, Scene, Structure
from needlekit.report.html_page import FigureSection, write_report_html
from needlekit.report.plotly_js import PLOTLY_FILE, plotly_mode
from needlekit.report.scene3d import (
    ACROSS_WEIGHT,
    FACE_BUDGET,
    PATH_COLOUR,
    VIEW_HEIGHT_PX,
    decimate,
    encloses,
    focus_box,
    scene_figure,
    view_direction,
    write_scene_html,
)


def _sphere_mesh(radius: float, cells: int = 60):
    from skimage.measure import marching_cubes

    h = 2.4 * radius / cells
    g = np.linspace(-1.2 * radius, 1.2 * radius, cells + 1)
    x, y, z = np.meshgrid(g, g, g, indexing="ij")
    v, f, _, _ = marching_cubes(np.sqrt(x * x + y * y + z * z) - radius, level=0.0)
    return v * h - 1.2 * radius, f


def test_decimation_keeps_the_budget_and_the_surface():
    verts, faces = _sphere_mesh(20.0)
    assert len(faces) > 20_000
    v, f = decimate(verts, faces, 2_000)
    assert 500 < len(f) <= 2_000
    # every vertex a mean of vertices on the sphere within one cell: close to it
    r = np.linalg.norm(v, axis=1)
    assert np.all(np.abs(r - 20.0) < 2.0)
    assert f.min() >= 0 and f.max() < len(v)
    assert len(np.unique(f)) == len(v)  # no vertex left unused
    assert np.all((f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 0] != f[:, 2]))


def test_a_mesh_within_the_budget_is_unchanged():
    verts, faces = _sphere_mesh(5.0, cells=12)
    v, f = decimate(verts, faces, len(faces))
    assert np.array_equal(v, verts) and np.array_equal(f, faces)


def test_enclosing_structures_by_role_and_name():
    ball = Sphere([0, 0, 0], 1.0)
    assert encloses(Structure("pleura", Role.ALLOWED_REGION, ball))
    assert encloses(Structure("skin", Role.ENTRY_SURFACE, ball))
    assert encloses(Structure("liver", Role.CONTEXT, ball))
    assert encloses(Structure("fissures", Role.OBSTACLE, ball))
    assert encloses(Structure("liverCapsule", Role.OBSTACLE, ball))
    assert not encloses(Structure("vessels", Role.OBSTACLE, ball))
    assert not encloses(Structure("nodule", Role.TARGET, ball))


class _Slab:
    """A solid slab ``z0 <= z <= z1`` (signed distance, negative inside)."""

    def __init__(self, z0: float, z1: float):
        self.z0, self.z1 = z0, z1

    def signed_distance(self, p):
        z = np.asarray(p, dtype=float)[..., 2]
        return np.maximum(self.z0 - z, z - self.z1)


def _hidden(slab, points, box, d) -> float:
    """Brute force: the fraction of points whose ray towards ``d`` meets the slab in the box."""
    t = np.linspace(0.0, 200.0, 40_001)[1:]
    out = []
    for p in points:
        s = p + t[:, None] * d
        inside = np.all((s >= box[0]) & (s <= box[1]), axis=1)
        out.append(bool(np.any(slab.signed_distance(s[inside]) < 0)))
    return float(np.mean(out))


def test_the_camera_looks_from_where_the_path_is_not_hidden():
    path = np.stack([np.linspace(-20, 20, 21), np.zeros(21), np.zeros(21)], axis=1)
    box = focus_box(path)  # a cube of side 70 mm around the path
    slab = _Slab(5.0, 8.0)  # above the path, across the whole box
    d, hidden = view_direction([slab], path, box, axis=[1.0, 0.0, 0.0])
    assert hidden == 0.0 and _hidden(slab, path, box, d) == 0.0
    assert abs(d[0]) < 0.35  # across the path, not along it
    default = np.ones(3) / np.sqrt(3.0)  # plotly's camera: every point behind the slab
    assert _hidden(slab, path, box, default) == 1.0
    # nothing in the way: across the path, from about 30 degrees above
    d_free, hidden_free = view_direction([], path, box, axis=[1.0, 0.0, 0.0])
    assert hidden_free == 0.0 and abs(d_free[0]) < 0.2 and 0.35 < d_free[2] < 0.65
    assert ACROSS_WEIGHT > 0.01


def _scene() -> Scene:
    return Scene(
        [
            Structure("pleura", Role.ALLOWED_REGION, Sphere([0, 0, 0], 50.0)),
            Structure("fissure", Role.OBSTACLE, Capsule([-60, 0, 12], [60, 0, 12], 1.0)),
            Structure("vessel", Role.OBSTACLE, Capsule([0, -60, -15], [0, 60, -15], 4.0)),
            Structure("far vessel", Role.OBSTACLE, Capsule([70, -5, 0], [70, 5, 0], 3.0)),
            Structure("nodule", Role.TARGET, Sphere([25, 0, 0], 4.0)),
        ],
        name="analytic",
    )


def test_a_path_view_is_framed_on_the_path_with_see_through_enclosures():
    path = np.stack([np.linspace(-25, 25, 51), np.zeros(51), np.zeros(51)], axis=1)
    fig = scene_figure(
        _scene(), targets_mm=path[-1:], paths_mm=[path], path_names=["plan"], max_cells=64,
        focus_mm=path,
    )  # fmt: skip
    box = focus_box(path)
    sc = fig.layout.scene
    assert sc.xaxis.range == pytest.approx(box[:, 0]) and sc.zaxis.range == pytest.approx(box[:, 2])
    assert fig.layout.height == VIEW_HEIGHT_PX >= 700
    meshes = {t.name.split(" (")[0]: t for t in fig.data if t.type == "mesh3d"}
    assert "far vessel" not in meshes  # outside the view's cube: not meshed
    assert meshes["pleura"].opacity <= 0.15 and meshes["fissure"].opacity <= 0.25
    assert meshes["vessel"].opacity == 1.0
    faces = sum(len(t.i) for t in meshes.values())
    assert faces <= FACE_BUDGET
    for t in meshes.values():  # what is drawn lies in the cube (one cell of slack)
        xyz = np.stack([t.x, t.y, t.z], axis=1)
        assert np.all(xyz >= box[0] - 3.0) and np.all(xyz <= box[1] + 3.0)
    line = next(t for t in fig.data if t.type == "scatter3d" and t.mode == "lines")
    assert line.line.color == PATH_COLOUR
    # the fissure (see-through) above and the vessel (solid) below: seen from the side
    eye = np.array([sc.camera.eye.x, sc.camera.eye.y, sc.camera.eye.z])
    assert abs(eye[0]) / np.linalg.norm(eye) < 0.35 and abs(eye[2]) / np.linalg.norm(eye) < 0.5


def test_a_face_budget_bounds_every_surface():
    fig = scene_figure(_scene(), max_cells=96, face_budget=3_000)
    faces = [len(t.i) for t in fig.data if t.type == "mesh3d"]
    assert sum(faces) <= 3_000 + 400 * len(faces) and max(faces) <= 3_000


def test_plotly_js_is_inlined_or_shared_by_the_folder(tmp_path):
    import plotly.graph_objects as go

    fig = go.Figure(go.Scatter3d(x=[0, 1], y=[0, 1], z=[0, 1]))
    inline = write_report_html(tmp_path / "a" / "page.html", title="t", sections=[FigureSection("f", fig)])
    assert inline.stat().st_size > 4_000_000 and not (tmp_path / "a" / PLOTLY_FILE).exists()
    with plotly_mode("shared"):
        one = write_report_html(tmp_path / "b" / "one.html", title="t", sections=[FigureSection("f", fig)])
        two = write_scene_html(fig, tmp_path / "b" / "two.html")
    js = tmp_path / "b" / PLOTLY_FILE
    assert js.stat().st_size > 4_000_000
    for page in (one, two):
        text = page.read_text()
        assert page.stat().st_size < 100_000
        assert f'src="{PLOTLY_FILE}"' in text and "window.needlekitDrawn" in text
    # the page counts its figures, and each notes when it drew
    assert re.search(r"needlekitDrawn=\{figures:1,", one.read_text())
