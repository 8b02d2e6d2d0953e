"""Interactive 3D views of scenes (plotly), self-contained HTML that opens offline.

Surfaces come from marching cubes on each structure's distance field
(:func:`needlekit.anatomy.summary.surface_mesh`); start poses are drawn as cones along
their insertion axis, targets as markers, paths as lines.
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
from needlekit.report.html_page import CANVAS_READBACK_HINT

__all__ = ["scene_figure", "write_scene_html", "write_scenes_html", "zoom_onto"]

_ROLE_STYLE = {
    Role.ALLOWED_REGION: ("#9ecae1", 0.12),
    Role.OBSTACLE: ("#d1495b", 0.75),
    Role.TARGET: ("#2a9d8f", 0.95),
    Role.ENTRY_SURFACE: ("#e9c46a", 0.35),
    Role.CONTEXT: ("#c98474", 0.25),
}


def scene_figure(
    scene: Scene,
    *,
    start_poses=None,
    targets_mm=None,
    paths_mm: Sequence[np.ndarray] = (),
    path_names: Sequence[str] = (),
    max_cells: int = 160,
    title: str | None = None,
):
    """A plotly figure of a scene.

    Parameters
    ----------
    scene : Scene
    start_poses : array_like, shape (k, 4, 4), optional
        Needle start poses (RAS mm), drawn as cones along their z axes.
    targets_mm : array_like, shape (m, 3), optional
    paths_mm : sequence of ndarray, shape (p_i, 3)
        Needle paths to draw as lines.
    path_names : sequence of str
        Legend entries of the paths.
    max_cells : int
        Resolution limit of the surfaces (samples per axis).
    title : str, optional

    Returns
    -------
    plotly.graph_objects.Figure
    """
    import plotly.graph_objects as go

    fig = go.Figure()
    box = scene.bounds()
    for s in scene.structures:
        colour, opacity = _ROLE_STYLE[s.role]
        verts, faces = surface_mesh(
            s.field, max_cells=max_cells, bounds=box if np.all(np.isfinite(box)) else None
        )
        if len(faces) == 0:
            continue
        verts = np.round(verts, 2)  # 0.01 mm: far below any voxel, a third of the file size
        fig.add_trace(
            go.Mesh3d(
                x=verts[:, 0],
                y=verts[:, 1],
                z=verts[:, 2],
                i=faces[:, 0],
                j=faces[:, 1],
                k=faces[:, 2],
                color=s.color or colour,
                opacity=opacity,
                name=f"{s.name} ({s.role.value})",
                showlegend=True,
                flatshading=False,
                lighting={"ambient": 0.55, "diffuse": 0.7, "specular": 0.15, "roughness": 0.8},
                hovertemplate=f"{s.name}<br>%{{x:.1f}}, %{{y:.1f}}, %{{z:.1f}} mm<extra></extra>",
            )
        )
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
        fig.add_trace(
            go.Scatter3d(
                x=p[:, 0], y=p[:, 1], z=p[:, 2], mode="lines", name=name, line={"width": 6}
            )
        )
    fig.update_layout(
        title=title if title is not None else (scene.name or "needlekit scene"),
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
    return fig


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


def write_scene_html(fig, path: str | os.PathLike) -> Path:
    """Write a plotly figure as one self-contained HTML file (plotly.js inlined, works
    offline), atomically.

    Parameters
    ----------
    fig : plotly.graph_objects.Figure
    path : path-like

    Returns
    -------
    Path
    """
    html = fig.to_html(include_plotlyjs=True, full_html=True)
    html = html.replace("<head>", f"<head>{CANVAS_READBACK_HINT}", 1)
    return atomic_write(path, lambda p: p.write_text(html, encoding="utf-8"))


def write_scenes_html(figures, path: str | os.PathLike, *, title: str = "needlekit scenes") -> Path:
    """Write several plotly figures into one self-contained HTML page (plotly.js inlined
    once, works offline), atomically.

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
    parts = []
    for i, (heading, fig) in enumerate(figures):
        body = fig.to_html(include_plotlyjs=(i == 0), full_html=False, default_height="720px")
        parts.append(f"<section><h2>{_html.escape(heading)}</h2>{body}</section>")
    page = (
        "<!DOCTYPE html><html><head><meta charset='utf-8'>"
        f"<title>{_html.escape(title)}</title>{CANVAS_READBACK_HINT}"
        "<style>body{font-family:system-ui,sans-serif;margin:1.5em;color:#222}"
        "h1{font-weight:600}h2{font-weight:500;margin-top:1.5em}</style></head><body>"
        f"<h1>{_html.escape(title)}</h1>{''.join(parts)}</body></html>"
    )
    return atomic_write(path, lambda p: p.write_text(page, encoding="utf-8"))
