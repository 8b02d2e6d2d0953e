"""Reachability figure: the lecture's condition, shortest arc-then-line paths, the torus."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import matplotlib
import numpy as np
from matplotlib.colors import ListedColormap
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Patch

from needlekit.geometry.arcs import arc_transform, sample_arcs
from needlekit.needle.reachability import (
    is_reachable,
    lecture_reachability_condition,
    shortest_arc_line,
    single_arc_to,
    tip_coordinates,
)
from needlekit.report._style import (
    _GREY,
    _INK,
    _PALETTE,
    _RHO,
    _SKY,
    _VERMILLION,
    _equal_3d,
    _heading_arrow,
    _new_figure,
    _style_3d,
)

#: Minimum radius of the reachability figure (mm).
R_MIN_REACH_MM = 50.0


@dataclass
class _ReachPath:
    rho_mm: float
    axial_mm: float
    reachable: bool
    single_arc: bool
    points: np.ndarray | None  # (k, 2) rho, axial of the shortest arc-then-line path
    single_arc_points: np.ndarray | None  # (k, 2) of the single arc, if allowed
    info: dict[str, Any]


@dataclass
class _ReachData:
    rho: np.ndarray  # (nr,) cell centres
    axial: np.ndarray  # (nz,)
    category: np.ndarray  # (nz, nr) 0 inside the r_min torus, 1 arc+line only, 2 single arc
    shortest: np.ndarray  # (nz, nr) length, nan where no arc-then-line path exists
    disagreements: int
    paths: list[_ReachPath]


# (rho_mm, axial_mm) of the example points, and where their labels go (offset points)
_REACH_POINTS = ((25.0, 120.0), (125.0, 70.0), (140.0, -45.0), (22.0, -62.0), (40.0, 20.0))
_REACH_LABEL_OFFSETS = ((8, 2), (10, -22), (-8, -24), (8, -14), (8, -3))


def _reach_data() -> _ReachData:
    r = R_MIN_REACH_MM
    eye = np.eye(4)
    rho = np.arange(0.5, 160.0, 1.0)
    axial = np.arange(-109.5, 160.0, 1.0)
    rr, zz = np.meshgrid(rho, axial)
    pts = np.stack([rr.ravel(), np.zeros(rr.size), zz.ravel()], axis=1)  # tip frame = world
    single = is_reachable(eye, pts, r)
    lecture = lecture_reachability_condition(pts, r)
    arcline = shortest_arc_line(eye, pts, r)
    cat = np.where(single, 2, np.where(arcline.reachable, 1, 0)).reshape(rr.shape)
    shortest = np.where(arcline.reachable, arcline.length_mm, np.nan).reshape(rr.shape)

    paths = []
    for rho_p, ax_p in _REACH_POINTS:
        p = np.array([rho_p, 0.0, ax_p])
        a, rad = tip_coordinates(eye, p)
        path = shortest_arc_line(eye, p, r)
        ok = bool(path.reachable[0])
        one = bool(is_reachable(eye, p, r))
        info: dict[str, Any] = {
            "rho_mm": float(rad),
            "axial_mm": float(a),
            "single_forward_arc": one,
            "arc_then_line_reachable": ok,
        }
        pts_path = pts_single = None
        if ok:
            spin, arc_len, line_len = (
                path.spin_rad[0],
                path.arc_length_mm[0],
                path.line_length_mm[0],
            )
            arc = sample_arcs(eye, spin, 1.0 / r, arc_len, 120)
            end = arc_transform(spin, 1.0 / r, arc_len)
            line = end[:3, 3] + np.outer(np.linspace(0.0, line_len, 30), end[:3, 2])
            xyz = np.vstack([arc, line])
            pts_path = np.stack([np.hypot(xyz[:, 0], xyz[:, 1]), xyz[:, 2]], axis=1)
            info.update(
                shortest_length_mm=float(path.length_mm[0]),
                arc_length_mm=float(arc_len),
                line_length_mm=float(line_len),
                turn_deg=float(np.degrees(path.turn_rad[0])),
                spin_deg=float(np.degrees(spin)),
                path_end_error_mm=float(np.linalg.norm(line[-1] - p)),
            )
        if one:
            sa = single_arc_to(eye, p)
            arc = sample_arcs(eye, path.spin_rad[0], 1.0 / sa.radius_mm[0], sa.length_mm[0], 120)
            pts_single = np.stack([np.hypot(arc[:, 0], arc[:, 1]), arc[:, 2]], axis=1)
            info.update(
                single_arc_radius_mm=float(sa.radius_mm[0]),
                single_arc_length_mm=float(sa.length_mm[0]),
                single_arc_end_error_mm=float(np.linalg.norm(arc[-1] - p)),
            )
        paths.append(_ReachPath(float(rad), float(a), ok, one, pts_path, pts_single, info))
    return _ReachData(rho, axial, cat, shortest, int(np.count_nonzero(single != lecture)), paths)


def _reach_torus(ax3, r: float) -> None:
    """Panel (c): the r_min disc revolved about the needle axis, a horn torus touching the
    tip (``r``: r_min in mm)."""
    # (c) the r_min disc revolved about the needle axis: a horn torus touching the tip
    _style_3d(ax3)
    uu, vv = np.meshgrid(np.linspace(0, 2 * np.pi, 60), np.linspace(0, 2 * np.pi, 60))
    rad = r + r * np.cos(uu)
    ax3.plot_surface(
        rad * np.cos(vv),
        rad * np.sin(vv),
        r * np.sin(uu),
        color=_SKY,
        alpha=0.35,
        linewidth=0.2,
        edgecolor="#3b7fa8",
        rstride=3,
        cstride=3,
    )
    ax3.plot([0, 0], [0, 0], [-110, 130], color=_INK, lw=1.0, ls=(0, (4, 3)))
    ax3.quiver(0, 0, 0, 0, 0, 35, color=_INK, linewidth=2.0, arrow_length_ratio=0.3)
    _equal_3d(ax3, np.array([[-2 * r, -2 * r, -1.2 * r], [2 * r, 2 * r, 1.2 * r]]), 0.0)
    ax3.view_init(elev=22, azim=-60)
    ax3.set_xlabel("x (mm)", labelpad=0)
    ax3.set_ylabel("y (mm)", labelpad=0)
    ax3.set_zlabel("z (mm)", labelpad=0)
    ax3.set_title("(c) In 3D: the disc swept about the\nneedle axis, a horn torus", loc="left")


def _plot_reach(d: _ReachData) -> Figure:
    r = R_MIN_REACH_MM
    fig = _new_figure(14.0, 6.6)
    gs = fig.add_gridspec(1, 3, width_ratios=(1.0, 1.15, 0.95))
    ax = fig.add_subplot(gs[0])
    ax2 = fig.add_subplot(gs[1])
    ax3 = fig.add_subplot(gs[2], projection="3d")
    extent = (0.0, d.rho[-1] + 0.5, d.axial[0] - 0.5, d.axial[-1] + 0.5)
    region_colours = ("#d9d9d9", "#fbe3c4", "#cde9dc")
    ax.imshow(
        d.category,
        origin="lower",
        extent=extent,
        cmap=ListedColormap(region_colours),
        vmin=-0.5,
        vmax=2.5,
        interpolation="nearest",
        aspect="equal",
    )
    u = np.linspace(0.0, 2.0 * np.pi, 400)
    circle = np.stack([r + r * np.cos(u), r * np.sin(u)], axis=1)
    ax.plot(*circle.T, color=_INK, lw=0.9, ls=(0, (4, 3)))
    rb = np.linspace(0.0, 2.0 * r, 300)
    boundary = np.sqrt(np.maximum(2.0 * r * rb - rb**2, 0.0))
    ax.plot(rb, boundary, color=_INK, lw=2.2)
    ax.plot([2 * r, extent[1]], [0, 0], color=_INK, lw=2.2)
    rho_note = 1.7 * r
    ax.annotate(
        "$P_z = \\sqrt{2 r_{min} \\rho - \\rho^2}$",
        (rho_note, np.sqrt(2 * r * rho_note - rho_note**2)),
        xytext=(2.55 * r, 0.74 * r),
        textcoords="data",
        fontsize=9.5,
        ha="center",
        arrowprops={"arrowstyle": "-", "color": _INK, "lw": 0.8},
        bbox={"boxstyle": "round,pad=0.25", "fc": "white", "ec": "#cccccc"},
    )
    for k, path in enumerate(d.paths):
        colour = _PALETTE[k % len(_PALETTE)]
        off = _REACH_LABEL_OFFSETS[k % len(_REACH_LABEL_OFFSETS)]
        ha = "left" if off[0] >= 0 else "right"
        if path.single_arc_points is not None:
            ax.plot(*path.single_arc_points.T, color=colour, lw=1.4, ls=(0, (3, 2)))
        if path.points is not None:
            ax.plot(*path.points.T, color=colour, lw=2.2)
            ax.plot(
                path.rho_mm, path.axial_mm, "o", ms=7, color=colour, mec=_INK, mew=0.8, zorder=6
            )
            text = f"{path.info['shortest_length_mm']:.0f} mm"
            if path.single_arc:
                text += f"\n(one arc {path.info['single_arc_length_mm']:.0f} mm)"
        else:
            ax.plot(
                path.rho_mm,
                path.axial_mm,
                "X",
                ms=9,
                color=_VERMILLION,
                mec=_INK,
                mew=0.6,
                zorder=6,
            )
            text = "no arc + line"
        ax.annotate(
            text,
            (path.rho_mm, path.axial_mm),
            xytext=off,
            textcoords="offset points",
            fontsize=8,
            ha=ha,
            va="center",
            color=_INK,
        )
    # the lecture's boundary on top of the paths that run along the r_min circle
    ax.plot(rb, boundary, color=_INK, lw=2.2, zorder=5)
    ax.plot(0, 0, "o", ms=7, color=_INK, zorder=7)
    _heading_arrow(ax, (0, 0), (0, 1), 16.0, _INK, lw=1.8)
    ax.set_xlim(extent[0], extent[1])
    ax.set_ylim(extent[2], extent[3])
    ax.set_xlabel(f"radial distance {_RHO} from the needle axis (mm)")
    ax.set_ylabel("axial distance $P_z$ along the insertion (mm)")
    ax.set_title(f"(a) Reachable set, r_min = {r:g} mm")
    fig.legend(
        [
            Patch(fc=region_colours[2], ec="#999999"),
            Patch(fc=region_colours[1], ec="#999999"),
            Patch(fc=region_colours[0], ec="#999999"),
            Line2D([], [], color=_INK, lw=2.2),
            Line2D([], [], color=_GREY, lw=2.2),
            Line2D([], [], color=_GREY, lw=1.4, ls=(0, (3, 2))),
        ],
        [
            "one forward arc (is_reachable)",
            "arc then straight line only",
            "inside the r_min circle: no arc + line",
            "lecture boundary",
            "shortest arc-then-line path (length)",
            "single arc (radius ≥ r_min)",
        ],
        loc="outside lower center",
        ncol=6,
        fontsize=8,
    )

    masked = np.ma.masked_invalid(d.shortest)
    cmap = matplotlib.colormaps["viridis"].with_extremes(bad="#d9d9d9")
    im = ax2.imshow(
        masked, origin="lower", extent=extent, cmap=cmap, aspect="equal", interpolation="bilinear"
    )
    levels = np.arange(50.0, 400.0, 50.0)
    cs = ax2.contour(d.rho, d.axial, masked, levels=levels, colors="white", linewidths=0.8)
    ax2.clabel(cs, fmt="%d mm", fontsize=7.5)
    ax2.plot(*circle.T, color="white", lw=1.2)
    for k, path in enumerate(d.paths):
        if path.points is not None:
            ax2.plot(*path.points.T, color=_PALETTE[k % len(_PALETTE)], lw=1.6)
    ax2.plot(0, 0, "o", ms=6, color="white", mec=_INK, zorder=7)
    cb = fig.colorbar(im, ax=ax2, shrink=0.85, pad=0.02)
    cb.set_label("shortest arc-then-line length (mm)")
    ax2.set_xlim(extent[0], extent[1])
    ax2.set_ylim(extent[2], extent[3])
    ax2.set_xlabel(f"radial distance {_RHO} (mm)")
    ax2.set_ylabel("axial distance $P_z$ (mm)")
    ax2.set_title("(b) Length of the shortest path (Dubins CS)")
    ax2.grid(False)

    _reach_torus(ax3, r)
    fig.suptitle(
        "Reachability from the tip: single arc (lecture condition) vs arc then straight line"
    )
    return fig


def _reach_json(d: _ReachData) -> dict[str, Any]:
    return {
        "r_min_mm": R_MIN_REACH_MM,
        "grid": {
            "rho_mm": [float(d.rho[0]), float(d.rho[-1]), len(d.rho)],
            "axial_mm": [float(d.axial[0]), float(d.axial[-1]), len(d.axial)],
        },
        "cells_single_forward_arc": int(np.count_nonzero(d.category == 2)),
        "cells_arc_then_line_only": int(np.count_nonzero(d.category == 1)),
        "cells_inside_r_min_torus": int(np.count_nonzero(d.category == 0)),
        "lecture_vs_frame_free_disagreements": d.disagreements,
        "paths": [p.info for p in d.paths],
    }
