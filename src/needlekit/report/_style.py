"""Shared look of needlekit's figures: palette, matplotlib style and small drawing helpers."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from cycler import cycler
from matplotlib.figure import Figure

#: Resolution of the PNG files (dots per inch); the figures are 11 to 14 inches wide.
DEFAULT_DPI = 150

# Okabe-Ito colours: distinguishable with the common colour-vision deficiencies.
_BLUE, _VERMILLION, _GREEN, _PURPLE = "#0072B2", "#D55E00", "#009E73", "#CC79A7"
_ORANGE, _SKY, _YELLOW, _INK = "#E69F00", "#56B4E9", "#F0E442", "#222222"
_PALETTE = (_BLUE, _VERMILLION, _GREEN, _PURPLE, _ORANGE, _SKY)
_GREY = "#8a8a8a"
# Letters ruff would take for Latin look-alikes (RUF001), spelled by name.
_MINUS = "\N{MINUS SIGN}"
_ALPHA = "\N{GREEK SMALL LETTER ALPHA}"
_RHO = "\N{GREEK SMALL LETTER RHO}"
_AXIS_COLOURS = ("#d62728", "#2ca02c", "#1f5fbf")  # tip frame x, y, z (RGB convention)


# ---------------------------------------------------------------------------------------
# style


def _style() -> dict[str, Any]:
    """rcParams shared by every kinematics figure (applied with ``rc_context``)."""
    return {
        "font.family": "DejaVu Sans",
        "font.size": 9.5,
        "axes.titlesize": 10.5,
        "axes.titleweight": "bold",
        "axes.titlelocation": "left",
        "axes.labelsize": 9.5,
        "axes.edgecolor": "#555555",
        "axes.linewidth": 0.8,
        "axes.grid": True,
        "axes.axisbelow": True,
        "axes.spines.top": False,
        "axes.spines.right": False,
        "axes.prop_cycle": cycler(color=list(_PALETTE)),
        "grid.color": "#dddddd",
        "grid.linewidth": 0.6,
        "xtick.color": "#444444",
        "ytick.color": "#444444",
        "xtick.labelsize": 8.5,
        "ytick.labelsize": 8.5,
        "legend.fontsize": 8.5,
        "legend.frameon": True,
        "legend.framealpha": 0.92,
        "legend.edgecolor": "#cccccc",
        "legend.fancybox": False,
        "lines.linewidth": 2.0,
        "lines.solid_capstyle": "round",
        "figure.facecolor": "white",
        "figure.titlesize": 12.5,
        "figure.titleweight": "bold",
        "savefig.facecolor": "white",
        "image.cmap": "viridis",
        "mathtext.fontset": "dejavusans",
    }


def _new_figure(width_in: float, height_in: float) -> Figure:
    return Figure(figsize=(width_in, height_in), layout="constrained")


def _style_3d(ax) -> None:
    for axis in (ax.xaxis, ax.yaxis, ax.zaxis):
        axis.set_pane_color((0.97, 0.97, 0.97, 1.0))
    ax.tick_params(labelsize=8, pad=0)


def _equal_3d(ax, points: np.ndarray, margin_mm: float = 5.0) -> None:
    """Equal scaling on the three axes, limits fitted to ``points`` (n, 3)."""
    lo = points.min(axis=0) - margin_mm
    hi = points.max(axis=0) + margin_mm
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_zlim(lo[2], hi[2])
    ax.set_box_aspect(tuple(hi - lo))


def _heading_arrow(ax, start, direction, length, colour, lw=1.6) -> None:
    start = np.asarray(start, dtype=float)
    end = start + length * np.asarray(direction, dtype=float)
    ax.annotate(
        "",
        xy=end,
        xytext=start,
        arrowprops={"arrowstyle": "-|>", "color": colour, "lw": lw, "mutation_scale": 11},
        annotation_clip=False,
        zorder=5,
    )


def _arrows_3d(ax, points: np.ndarray, directions: np.ndarray, length: float, colour) -> None:
    """Arrows of one length from points (n, 3) along unit directions (n, 3) in a 3D axes."""
    d = directions * length
    ax.quiver(
        points[:, 0],
        points[:, 1],
        points[:, 2],
        d[:, 0],
        d[:, 1],
        d[:, 2],
        color=colour,
        linewidth=1.4,
        arrow_length_ratio=0.28,
        normalize=False,
    )


def _frame_arrows(ax, poses: np.ndarray, length: float) -> None:
    """Tip frames (x, y, z columns of R in red, green, blue) in a 3D axes; poses (n, 4, 4)."""
    for k in range(3):
        _arrows_3d(ax, poses[:, :3, 3], poses[:, :3, k], length, _AXIS_COLOURS[k])


def _deg(value: float, fmt: str, *, sign: bool = False) -> str:
    """Degrees for figure text, with a true minus sign and no "-0"."""
    text = format(float(value) + 0.0, ("+" if sign else "") + fmt)
    if float(text) == 0.0:
        text = format(0.0, fmt)
    return text.replace("-", _MINUS) + "°"


def _f(x) -> float | None:
    """JSON-safe float (None for inf/nan, which JSON cannot hold)."""
    x = float(x)
    return x if math.isfinite(x) else None


# ---------------------------------------------------------------------------------------
# 1. planar forward steering
