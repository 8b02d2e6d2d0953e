"""Interactive 3D views of scenes (plotly), HTML pages that open offline.

Surfaces come from marching cubes on each structure's distance field
(:func:`needlekit.anatomy.summary.surface_mesh`); start poses are drawn as cones along
their insertion axis, targets as markers, paths as lines.

A view of a path (``focus_mm``: a plan, an executed path, with its start and target) is
framed on it, not on the whole anatomy:

- the axes span a cube around the path and the target (:data:`FOCUS_MARGIN_MM` beyond
  them), and only that cube's part of each surface is meshed, at the resolution the cube
  allows (plotly clips the rest anyway);
- the structures that enclose the workspace (:func:`encloses`: the allowed region such as
  the pleura, the entry surface or skin, context organs such as the liver, and obstacles
  named like a fissure, pleura, capsule or skin) are drawn see-through; the other
  obstacles, those the path threads between, solid;
- the camera looks at the cube's centre from the direction, among :data:`CAMERA_CANDIDATES`
  around the sphere, along which the fewest points of the path and target are hidden
  behind a solid obstacle (:func:`view_direction`), preferring views across the path;
- the first path is drawn in :data:`PATH_COLOUR`, a colour no surface has.

Every surface is decimated to a face budget (:data:`FACE_BUDGET` faces per figure, shared
by the structures by their size; :func:`decimate`) and its coordinates stored as 32-bit
floats rounded to 0.01 mm: a page of one plan weighs about 1 MB besides plotly.js.
"""

from __future__ import annotations

import html as _html
import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from needlekit.anatomy.scene import Role, Scene
from needlekit.anatomy.summary import surface_mesh
from needlekit.io.files import atomic_write
from needlekit.report.html_page import CANVAS_READBACK_HINT, DRAWN_SCRIPT, drawn_note
from needlekit.report.plotly_js import plotly_script

__all__ = [
    "FACE_BUDGET",
    "PATH_COLOUR",
    "decimate",
    "encloses",
    "focus_box",
    "scene_figure",
    "view_direction",
    "structure_style",
    "write_scene_html",
    "write_scenes_html",
    "zoom_onto",
]

#: (colour, opacity) of each role's surfaces. Enclosing structures (:func:`encloses`) are
#: drawn with :data:`SEE_THROUGH` instead.
_ROLE_STYLE = {
    Role.ALLOWED_REGION: ("#9ecae1", 0.08),
    Role.OBSTACLE: ("#d1495b", 1.0),
    Role.TARGET: ("#2a9d8f", 0.6),
    Role.ENTRY_SURFACE: ("#e9c46a", 0.1),
    Role.CONTEXT: ("#c98474", 0.12),
}
#: Opacity of an obstacle that encloses the workspace (a fissure): seen, and seen through.
SEE_THROUGH: float = 0.18
#: Roles whose structures enclose the workspace.
ENCLOSING_ROLES = (Role.ALLOWED_REGION, Role.ENTRY_SURFACE, Role.CONTEXT)
#: Name parts of obstacles that enclose the workspace (sheets and shells around it).
ENCLOSING_NAMES = ("fissure", "pleura", "capsule", "skin")
#: The first path's colour (magenta): no surface, marker nor other line has it, so the
#: path's pixels can be told from everything else in a screenshot.
PATH_COLOUR = "#ff00ff"
#: Colours of the other paths.
_PATH_COLOURS = ("#0072b2", "#e69f00", "#009e73", "#56b4e9", "#f0e442", "#d55e00")
#: Faces of all the surfaces of one figure, at most.
FACE_BUDGET: int = 24_000
#: An enclosing structure's share of the face budget, per face, beside a solid one's.
ENCLOSED_WEIGHT: float = 0.3
#: Faces a structure keeps at least (below it, the budget goes unshared).
MIN_FACES: int = 400
#: The view's cube extends this far beyond the path and target (mm).
FOCUS_MARGIN_MM: float = 15.0
#: Directions the camera may look from (points on the sphere, a Fibonacci lattice).
CAMERA_CANDIDATES: int = 96
#: What looking along the path (|cos| of the angle between the view and the path's main
#: axis, 0 to 1) costs beside the fraction of its points hidden: a path seen end-on reads
#: badly even when nothing hides it.
ACROSS_WEIGHT: float = 0.25
#: Height of a 3D view (px).
VIEW_HEIGHT_PX: int = 760
#: Distance of the camera from the cube's centre, in plotly's units (the cube spans 1).
_EYE = 1.7


def structure_style(structure) -> tuple[str, float]:
    """The colour and opacity a structure's surface is drawn with, in every 3D view and in
    the Slicer scene: its role's, and :data:`SEE_THROUGH` for an obstacle that encloses
    the workspace (:func:`encloses`).

    Parameters
    ----------
    structure : Structure

    Returns
    -------
    tuple of (str, float)
        A CSS colour (``#rrggbb``; the role's, not the structure's own) and an opacity.
    """
    colour, opacity = _ROLE_STYLE[structure.role]
    if structure.role is Role.OBSTACLE and encloses(structure):
        opacity = SEE_THROUGH
    return colour, opacity


def encloses(structure) -> bool:
    """Whether a structure encloses the workspace (drawn see-through, never blocking the
    view): the allowed region (a pleura), the entry surface (skin), context organs (a
    liver), and obstacles named like a fissure, pleura, capsule or skin.

    Parameters
    ----------
    structure : Structure

    Returns
    -------
    bool
    """
    if structure.role in ENCLOSING_ROLES:
        return True
    name = (structure.name or "").lower()
    return structure.role is Role.OBSTACLE and any(w in name for w in ENCLOSING_NAMES)


def _cluster(verts: np.ndarray, faces: np.ndarray, h: float):
    """Vertex clustering on a grid of cell ``h``: each cell's vertices merge into their
    mean; faces that lose a corner, and repeated faces, go."""
    cells = np.floor((verts - verts.min(axis=0)) / h).astype(np.int64)
    n = cells.max(axis=0) + 1
    key = (cells[:, 0] * n[1] + cells[:, 1]) * n[2] + cells[:, 2]
    uniq, inv = np.unique(key, return_inverse=True)
    inv = inv.reshape(-1)
    count = np.bincount(inv, minlength=len(uniq)).astype(float)
    merged = np.stack(
        [np.bincount(inv, weights=verts[:, a], minlength=len(uniq)) / count for a in range(3)],
        axis=1,
    )
    f = inv[faces]
    f = f[(f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 0] != f[:, 2])]
    if len(f):
        # one copy of each face (the same three corners in any order)
        order = np.sort(f, axis=1)
        _, first = np.unique(order, axis=0, return_index=True)
        f = f[np.sort(first)]
    used = np.unique(f)
    remap = np.full(len(merged), -1, dtype=np.int64)
    remap[used] = np.arange(len(used))
    return merged[used], remap[f]


def decimate(verts, faces, max_faces: int):
    """A mesh with at most ``max_faces`` faces, by vertex clustering: the vertices of each
    cell of a grid merge into their mean, the cell grown until the faces fit.

    Parameters
    ----------
    verts : array_like, shape (v, 3)
    faces : array_like of int, shape (f, 3)
    max_faces : int

    Returns
    -------
    verts : ndarray, shape (v', 3)
        Each within half a cell's diagonal of the vertices it replaces.
    faces : ndarray of int, shape (f', 3)
        ``f' <= max_faces``; the mesh unchanged when it already fits.
    """
    verts = np.asarray(verts, dtype=float).reshape(-1, 3)
    faces = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    if len(faces) <= max_faces:
        return verts, faces
    if max_faces < 1:
        return np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64)
    a, b, c = verts[faces[:, 0]], verts[faces[:, 1]], verts[faces[:, 2]]
    area = 0.5 * float(np.linalg.norm(np.cross(b - a, c - a), axis=1).sum())
    # a cell of side h leaves about 2 area / h^2 faces on a smooth surface
    h = max(np.sqrt(2.0 * area / max_faces) * 0.8, 1e-6)
    while True:
        v, f = _cluster(verts, faces, h)
        if len(f) <= max_faces:
            return v, f
        h *= 1.2


def _budgets(counts: list[int], weights: list[float], total: int) -> list[int]:
    """Each structure's share of ``total`` faces, by its size times its weight (at least
    :data:`MIN_FACES`, at most its own faces)."""
    if sum(counts) <= total:
        return list(counts)
    whole = sum(c * w for c, w in zip(counts, weights, strict=True))
    return [
        min(c, max(MIN_FACES, int(total * c * w / whole)))
        for c, w in zip(counts, weights, strict=True)
    ]


def _sphere(n: int) -> np.ndarray:
    """``n`` directions spread evenly over the sphere (a Fibonacci lattice)."""
    k = np.arange(n) + 0.5
    z = 1.0 - 2.0 * k / n
    r = np.sqrt(1.0 - z * z)
    phi = np.pi * (1.0 + 5**0.5) * k
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


def view_direction(solid_fields, points_mm, box, axis=None, *, candidates: int = CAMERA_CANDIDATES):
    """The direction to look from (a unit vector from the view's centre to the eye): the
    one, among ``candidates`` directions over the sphere, along which the fewest of
    ``points_mm`` are hidden, a point being hidden when the segment from it towards the
    eye, within ``box``, passes inside a solid structure; a view along ``axis`` (the
    path's main direction) costs :data:`ACROSS_WEIGHT` times the cosine more, and views
    from 30 degrees above win ties.

    Parameters
    ----------
    solid_fields : sequence of DistanceField
        What hides (negative inside).
    points_mm : array_like, shape (n, 3)
        What should be seen (points along the path, the target).
    box : array_like, shape (2, 3)
        The view's cube; rays end where they leave it (plotly draws nothing beyond).
    axis : array_like, shape (3,), optional

    Returns
    -------
    direction : ndarray, shape (3,)
    hidden : float
        The fraction of the points hidden from it.
    """
    pts = np.asarray(points_mm, dtype=float).reshape(-1, 3)
    box = np.asarray(box, dtype=float).reshape(2, 3)
    dirs = _sphere(int(candidates))
    step = max(float(np.max(box[1] - box[0])) / 120.0, 0.25)
    t = np.arange(1.0, float(np.linalg.norm(box[1] - box[0])) + step, step)
    hidden = np.zeros(len(dirs))
    for i, d in enumerate(dirs):
        samples = pts[:, None, :] + t[None, :, None] * d  # (n, m, 3)
        inside = np.all((samples >= box[0]) & (samples <= box[1]), axis=2)
        blocked = np.zeros(inside.shape, dtype=bool)
        flat = samples[inside]
        if len(flat):
            hit = np.zeros(len(flat), dtype=bool)
            for f in solid_fields:
                hit |= np.asarray(f.signed_distance(flat)) < 0.0
            blocked[inside] = hit
        hidden[i] = float(blocked.any(axis=1).mean())
    across = 0.0 if axis is None else np.abs(dirs @ _unit(axis))
    score = hidden + ACROSS_WEIGHT * across + 0.1 * np.abs(dirs[:, 2] - 0.5)
    best = int(np.argmin(score))
    return dirs[best], float(hidden[best])


def _unit(v) -> np.ndarray:
    v = np.asarray(v, dtype=float).reshape(3)
    n = float(np.linalg.norm(v))
    return v / n if n > 0 else np.array([0.0, 0.0, 1.0])


def focus_box(points_mm, margin_mm: float = FOCUS_MARGIN_MM) -> np.ndarray:
    """The cube a view of ``points_mm`` spans: around their box, ``margin_mm`` wider than
    their largest side on every side.

    Parameters
    ----------
    points_mm : array_like, shape (n, 3)
    margin_mm : float

    Returns
    -------
    ndarray, shape (2, 3)
    """
    pts = np.asarray(points_mm, dtype=float).reshape(-1, 3)
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    half = 0.5 * float(np.max(hi - lo)) + float(margin_mm)
    c = 0.5 * (lo + hi)
    return np.array([c - half, c + half])


def _mesh_trace(go, s, verts, faces, colour, opacity, visible=True):
    verts = np.round(verts, 2).astype(np.float32)  # 0.01 mm, far below any voxel
    return go.Mesh3d(
        x=verts[:, 0], y=verts[:, 1], z=verts[:, 2],
        i=faces[:, 0].astype(np.int32), j=faces[:, 1].astype(np.int32),
        k=faces[:, 2].astype(np.int32),
        color=s.color or colour, opacity=opacity, visible=visible,
        name=f"{s.name} ({s.role.value})", showlegend=True, flatshading=False,
        lighting={"ambient": 0.55, "diffuse": 0.7, "specular": 0.15, "roughness": 0.8},
        hovertemplate=f"{s.name}<br>%{{x:.1f}}, %{{y:.1f}}, %{{z:.1f}} mm<extra></extra>",
    )  # fmt: skip


def scene_figure(
    scene: Scene,
    *,
    start_poses=None,
    targets_mm=None,
    paths_mm: Sequence[np.ndarray] = (),
    path_names: Sequence[str] = (),
    max_cells: int = 160,
    title: str | None = None,
    focus_mm=None,
    focus_margin_mm: float = FOCUS_MARGIN_MM,
    face_budget: int | None = None,
    see_through: bool = True,
):
    """A plotly figure of a scene, framed on a path when ``focus_mm`` is given (see the
    module's notes).

    Parameters
    ----------
    scene : Scene
    start_poses : array_like, shape (k, 4, 4), optional
        Needle start poses (RAS mm), drawn as cones along their z axes.
    targets_mm : array_like, shape (m, 3), optional
    paths_mm : sequence of ndarray, shape (p_i, 3)
        Needle paths to draw as lines (the first in :data:`PATH_COLOUR`).
    path_names : sequence of str
        Legend entries of the paths.
    max_cells : int
        Resolution limit of the surfaces (samples per axis, over the view's cube when
        focused, else over each structure).
    title : str, optional
    focus_mm : array_like, shape (n, 3), optional
        What the view frames (the path, its start, the target): the axes span the cube
        around them (:func:`focus_box`), the surfaces are meshed there only, and the
        camera looks from where the fewest of them are hidden (:func:`view_direction`).
        Without it, the whole scene, from plotly's default camera.
    focus_margin_mm : float
        How far the view's cube extends beyond ``focus_mm``.
    face_budget : int, optional
        Faces of all the surfaces together, at most (:func:`decimate`); default
        :data:`FACE_BUDGET`.
    see_through : bool
        Draw the enclosing structures see-through (:func:`encloses`); False draws every
        obstacle solid and every surface at its role's opacity, as needlekit did before
        (kept for comparison).

    Returns
    -------
    plotly.graph_objects.Figure
    """
    import plotly.graph_objects as go

    fig = go.Figure()
    box = scene.bounds()
    crop = None if focus_mm is None else focus_box(focus_mm, focus_margin_mm)
    meshes = []
    for s in scene.structures:
        colour, opacity = structure_style(s)
        if not see_through:
            opacity = {Role.ALLOWED_REGION: 0.12, Role.OBSTACLE: 0.75, Role.TARGET: 0.95, Role.ENTRY_SURFACE: 0.35,
                       Role.CONTEXT: 0.25}.get(s.role, opacity)  # fmt: skip
        verts, faces = surface_mesh(
            s.field,
            max_cells=max_cells,
            bounds=box if np.all(np.isfinite(box)) else None,
            crop=crop,
        )
        if len(faces):
            meshes.append((s, verts, faces, colour, opacity))
    # see-through surfaces are context: a third of the detail of the solid ones
    weights = [ENCLOSED_WEIGHT if encloses(m[0]) else 1.0 for m in meshes]
    total = FACE_BUDGET if face_budget is None else int(face_budget)
    budgets = _budgets([len(m[2]) for m in meshes], weights, total)
    for (s, verts, faces, colour, opacity), budget in zip(meshes, budgets, strict=True):
        verts, faces = decimate(verts, faces, budget)
        fig.add_trace(_mesh_trace(go, s, verts, faces, colour, opacity))
    if start_poses is not None:
        g = np.asarray(start_poses, dtype=float).reshape(-1, 4, 4)
        fig.add_trace(
            go.Cone(
                x=g[:, 0, 3],
                y=g[:, 1, 3],
                z=g[:, 2, 3],
                u=g[:, 0, 2],
                v=g[:, 1, 2],
                w=g[:, 2, 2],
                sizemode="absolute",
                sizeref=6.0,
                anchor="tail",
                colorscale=[[0, "#264653"], [1, "#264653"]],
                showscale=False,
                name="start poses",
                showlegend=True,
                hovertemplate="start<br>%{x:.1f}, %{y:.1f}, %{z:.1f} mm<extra></extra>",
            )
        )
    if targets_mm is not None:
        t = np.asarray(targets_mm, dtype=float).reshape(-1, 3)
        fig.add_trace(
            go.Scatter3d(
                x=t[:, 0], y=t[:, 1], z=t[:, 2], mode="markers", name="targets",
                marker={"size": 5, "color": "#e76f51", "symbol": "diamond"},
            )
        )  # fmt: skip
    for i, p in enumerate(paths_mm):
        p = np.asarray(p, dtype=float)
        name = path_names[i] if i < len(path_names) else f"path {i + 1}"
        colour = PATH_COLOUR if i == 0 else _PATH_COLOURS[(i - 1) % len(_PATH_COLOURS)]
        fig.add_trace(
            go.Scatter3d(
                x=p[:, 0], y=p[:, 1], z=p[:, 2], mode="lines", name=name,
                line={"width": 7, "color": colour},
            )
        )  # fmt: skip
    fig.update_layout(
        title=title if title is not None else (scene.name or "needlekit scene"),
        height=VIEW_HEIGHT_PX,
        scene={
            "aspectmode": "data",
            "xaxis_title": "x (R) mm",
            "yaxis_title": "y (A) mm",
            "zaxis_title": "z (S) mm",
        },
        legend={"itemsizing": "constant"},
        margin={"l": 0, "r": 0, "t": 40, "b": 0},
        template="plotly_white",
    )
    if focus_mm is not None:
        pts = np.asarray(focus_mm, dtype=float).reshape(-1, 3)
        axis = _principal_axis(pts)
        solid = [] if not see_through else _solid_fields(scene, crop)
        if see_through:
            direction, _ = view_direction(solid, _thin(pts, 48), crop, axis)
        else:
            direction = np.ones(3) / np.sqrt(3.0)  # plotly's default camera
        _frame(fig, crop, direction)
    return fig


def _solid_fields(scene: Scene, box) -> list:
    """The fields of the structures drawn solid, near the view's cube."""
    out = []
    for s in scene.structures:
        if s.role is not Role.OBSTACLE or encloses(s):
            continue
        f = s.field.near_box(box, 1.0)
        if f is not None:
            out.append(f)
    return out


def _principal_axis(points: np.ndarray) -> np.ndarray | None:
    """The direction the points spread most along (None for a single point)."""
    centred = points - points.mean(axis=0)
    if len(points) < 2 or not np.any(centred):
        return None
    return np.linalg.svd(centred, full_matrices=False)[2][0]


def _thin(points: np.ndarray, n: int) -> np.ndarray:
    """At most ``n`` of the points, evenly spread along the array (first and last kept)."""
    if len(points) <= n:
        return points
    return points[np.unique(np.linspace(0, len(points) - 1, n).round().astype(int))]


def _frame(fig, box, direction) -> None:
    """Axes spanning the cube ``box``, the camera looking at its centre from ``direction``."""
    d = _unit(direction)
    up = np.array([0.0, 0.0, 1.0]) if abs(d[2]) < 0.9 else np.array([0.0, 1.0, 0.0])
    ranges = {f"{a}axis_range": [float(box[0][k]), float(box[1][k])] for k, a in enumerate("xyz")}
    fig.update_scenes(
        aspectmode="cube",
        camera={
            "eye": dict(zip("xyz", (_EYE * d).tolist(), strict=True)),
            "up": dict(zip("xyz", up.tolist(), strict=True)),
            "center": {"x": 0.0, "y": 0.0, "z": 0.0},
        },
        **ranges,
    )


def zoom_onto(fig, points_mm, margin_mm: float = 15.0) -> None:
    """Zoom a scene figure onto points (e.g. needle paths, small beside the whole scene): a
    cube around them, ``margin_mm`` wider than their largest side on every side.

    Parameters
    ----------
    fig : plotly.graph_objects.Figure
    points_mm : array_like, shape (n, 3)
    margin_mm : float

    Returns
    -------
    None
    """
    pts = np.asarray(points_mm, dtype=float).reshape(-1, 3)
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    half = 0.5 * float(np.max(hi - lo)) + float(margin_mm)
    ranges = {
        f"{a}axis_range": [c - half, c + half] for a, c in zip("xyz", (lo + hi) / 2, strict=True)
    }
    fig.update_scenes(aspectmode="cube", **ranges)


def _figure_div(fig, height: str | None = None) -> str:
    config = {"displaylogo": False, "responsive": True}
    kw = {} if height is None else {"default_height": height}
    return fig.to_html(
        full_html=False,
        include_plotlyjs=False,
        config=config,
        post_script=DRAWN_SCRIPT,
        auto_play=False,  # an animation waits for its play button
        **kw,
    )


def _page(path, title: str, body: str, figures: int) -> str:
    return (
        "<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'>"
        f"<title>{_html.escape(title)}</title>{CANVAS_READBACK_HINT}{drawn_note(figures)}"
        f"{plotly_script(path)}"
        "<style>body{font-family:system-ui,sans-serif;margin:1.5em;color:#222}"
        "h1{font-weight:600}h2{font-weight:500;margin-top:1.5em}</style></head><body>"
        f"{body}</body></html>\n"
    )


def write_scene_html(fig, path: str | os.PathLike) -> Path:
    """Write a plotly figure as an HTML page, atomically: plotly.js inlined (the page
    opens offline on its own) or shared beside it, as ``--plotly`` says
    (:mod:`needlekit.report.plotly_js`).

    Parameters
    ----------
    fig : plotly.graph_objects.Figure
    path : path-like

    Returns
    -------
    Path
    """
    title = fig.layout.title.text or "needlekit scene"
    page = _page(path, title, _figure_div(fig), 1)
    return atomic_write(path, lambda p: p.write_text(page, encoding="utf-8"))


def write_scenes_html(figures, path: str | os.PathLike, *, title: str = "needlekit scenes") -> Path:
    """Write several plotly figures into one HTML page (plotly.js loaded once, inlined or
    shared as for :func:`write_scene_html`), atomically.

    Parameters
    ----------
    figures : sequence of (str, plotly.graph_objects.Figure)
        Section headings and figures, in order.
    path : path-like
    title : str

    Returns
    -------
    Path
    """
    parts = [
        f"<section><h2>{_html.escape(heading)}</h2>{_figure_div(fig, '720px')}</section>"
        for heading, fig in figures
    ]
    body = f"<h1>{_html.escape(title)}</h1>{''.join(parts)}"
    page = _page(path, title, body, len(parts))
    return atomic_write(path, lambda p: p.write_text(page, encoding="utf-8"))
