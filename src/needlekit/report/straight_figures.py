"""Figures of straight-needle CFRW maps (Liu et al. 2016): layers and accessibility.

- :func:`cfrw_layers_figure`: the CFRW boundary in layered planes ``z = h`` of Liu's frame
  Sigma at the target, (a) one plane with the CFRW filled (even-odd, so holes show) and the
  trajectories' crossing points, (b) the planes stacked in 3D with the trajectories (the
  paper's Fig. 11, 14/15 and 17);
- :func:`accessibility_map_figure`: every direction of a CFRW map, (a) as its entry point
  on the entry surface coloured by certified clearance (or by what blocks it), (b) as a
  map over ``(phi, theta)`` with the blocking reasons as categories.

The page that gathers them is :mod:`needlekit.report.straight_report`.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from needlekit.errors import InvalidInputError
from needlekit.planning.straight.cfrw import CLEARANCE_CAP_ABOVE_GAMMA_MM, Blocked, CFRWMap
from needlekit.planning.straight.entry import Entry
from needlekit.planning.straight.problem import angles_of
from needlekit.planning.straight.sequence import NeedleRecord
from needlekit.report._style import _GREEN, _PALETTE, _VERMILLION

__all__ = ["LIU_HEIGHTS_MM", "accessibility_map_figure", "cfrw_layers_figure"]


#: Heights (mm above the target along Sigma's z) of the paper's layers (Fig. 11b).
LIU_HEIGHTS_MM: tuple[float, ...] = (150.0, 160.0, 170.0)

_SIGMA = "\N{GREEK CAPITAL LETTER SIGMA}"
_THETA, _PHI = "\N{GREEK SMALL LETTER THETA}", "\N{GREEK SMALL LETTER PHI}"
_GAMMA = "\N{GREEK SMALL LETTER GAMMA}"
_INK, _FILL = "#222222", "rgba(0, 158, 115, 0.28)"
#: Colour of each blocking reason (index: the :class:`Blocked` code).
_REASON_COLOURS = ("#009E73", "#c7c7c7", "#7f7f7f", "#E69F00", "#CC79A7", "#D55E00", "#0072B2")
_REASON_LABELS = (
    "in the CFRW",
    "outside the angle limits",
    "no entry within reach",
    "too long",
    "too oblique to the surface",
    f"closer than {_GAMMA} to the anatomy",
    f"closer than {_GAMMA} to a placed needle",
)


# ---------------------------------------------------------------------------------------
# inputs


def _trajectories(items, name: str = "trajectories") -> list[tuple[str, np.ndarray, np.ndarray]]:
    """``(label, target_mm, entry_mm)`` of NeedleRecords (with an entry), Entries, or
    ``(target, entry)`` / ``(label, target, entry)`` tuples."""
    if items is None:
        return []
    if isinstance(items, (NeedleRecord, Entry)):
        items = [items]
    out = []
    for i, t in enumerate(items):
        if isinstance(t, NeedleRecord):
            if t.entry is not None:
                out.append((f"needle {t.order}", t.entry.target_mm, t.entry.entry_mm))
            continue
        if isinstance(t, Entry):
            label, target, entry = f"trajectory {i + 1}", t.target_mm, t.entry_mm
        elif isinstance(t, (tuple, list)) and len(t) in (2, 3):
            label = str(t[0]) if len(t) == 3 else f"trajectory {i + 1}"
            target, entry = t[-2], t[-1]
        else:
            msg = "expected a NeedleRecord, an Entry or (target_mm, entry_mm)"
            raise InvalidInputError(f"{name}[{i}]", f"{msg}, got {type(t).__name__}")
        target = np.asarray(target, dtype=float).reshape(-1)
        entry = np.asarray(entry, dtype=float).reshape(-1)
        if target.shape != (3,) or entry.shape != (3,) or not np.all(np.isfinite([target, entry])):
            raise InvalidInputError(f"{name}[{i}]", "expected finite points of shape (3,)")
        out.append((label, target, entry))
    return out


def _check_map(cfrw, name: str = "cfrw") -> CFRWMap:
    if not isinstance(cfrw, CFRWMap):
        raise InvalidInputError(name, f"expected a CFRWMap, got {type(cfrw).__name__}")
    return cfrw


def _to_sigma(cfrw: CFRWMap, points_mm) -> np.ndarray:
    """World points (n, 3) in the map's Sigma frame (mm)."""
    g = cfrw.problem.world_T_sigma
    return (np.asarray(points_mm, dtype=float).reshape(-1, 3) - g[:3, 3]) @ g[:3, :3]


def _crossing(tip_s: np.ndarray, entry_s: np.ndarray, h_mm: float) -> np.ndarray | None:
    """Where the line from the tip through the entry (Sigma) meets the plane z = h, going
    out from the tip (None if it never does)."""
    dz = entry_s[2] - tip_s[2]
    if abs(dz) < 1e-12:
        return None
    s = (h_mm - tip_s[2]) / dz
    return tip_s + s * (entry_s - tip_s) if s >= 0 else None


def _heights(heights_mm) -> list[float]:
    h = np.asarray(heights_mm, dtype=float).reshape(-1)
    if h.size == 0 or not np.all(np.isfinite(h)) or np.any(h <= 0):
        raise InvalidInputError("heights_mm", f"expected one or more heights > 0, got {heights_mm}")
    return [float(v) for v in h]


def _wrap_phi_deg(cfrw: CFRWMap, phi_deg: np.ndarray) -> np.ndarray:
    """Angles into the map's phi range (the grid starts at its lower limit)."""
    lo = float(np.degrees(cfrw.phi_rad[0]))
    return lo + np.mod(phi_deg - lo, 360.0)


# ---------------------------------------------------------------------------------------
# figures


def _path(polylines) -> str:
    """One SVG path of closed polylines (filled by the even-odd rule)."""
    parts = []
    for p in polylines:
        pts = " L ".join(f"{x:.4f},{y:.4f}" for x, y in p)
        parts.append(f"M {pts} Z")
    return " ".join(parts)


def _plane_panel(fig, cfrw: CFRWMap, plane: float, plane_polys: list, lines: list) -> list:
    """Panel (a) of :func:`cfrw_layers_figure`: the CFRW in one plane and where the
    trajectories cross it; returns each trajectory in Sigma as (label, tip, entry, colour)."""
    import plotly.graph_objects as go

    # (a) one plane, filled by the even-odd rule
    if plane_polys:
        fig.add_shape(
            type="path", path=_path(plane_polys), fillcolor=_FILL, fillrule="evenodd",
            line={"width": 0}, xref="x", yref="y", layer="below",
        )  # fmt: skip
    for i, p in enumerate(plane_polys):
        fig.add_trace(
            go.Scatter(
                x=p[:, 0], y=p[:, 1], mode="lines", name=f"boundary z = {plane:g} mm",
                line={"color": _GREEN, "width": 1.8}, legendgroup="boundary",
                showlegend=i == 0, hovertemplate="(%{x:.2f}, %{y:.2f}) mm<extra></extra>",
            ),
            row=1, col=1,
        )  # fmt: skip
    if not plane_polys:
        fig.add_annotation(
            text="no CFRW in this plane", x=0, y=0, xref="x", yref="y", showarrow=False
        )
    fig.add_trace(
        go.Scatter(
            x=[0.0], y=[0.0], mode="markers", name=f"{_SIGMA} z axis (above the target)",
            marker={"symbol": "cross-thin", "size": 10, "line": {"width": 2, "color": _INK}},
        ),
        row=1, col=1,
    )  # fmt: skip
    sigma_lines = []
    for k, (label, target, entry) in enumerate(lines):
        tip_s, entry_s = _to_sigma(cfrw, [target, entry])
        colour = _PALETTE[(k + 1) % len(_PALETTE)]
        sigma_lines.append((label, tip_s, entry_s, colour))
        c = _crossing(tip_s, entry_s, plane)
        if c is not None:
            fig.add_trace(
                go.Scatter(
                    x=[c[0]], y=[c[1]], mode="markers+text", name=label, text=[label],
                    textposition="top center", legendgroup=label,
                    marker={"size": 10, "color": colour, "symbol": "circle",
                            "line": {"width": 1.5, "color": "white"}},
                    hovertemplate=f"{label}<br>(%{{x:.2f}}, %{{y:.2f}}) mm<extra></extra>",
                ),
                row=1, col=1,
            )  # fmt: skip
    return sigma_lines


def _stacked_panel(fig, hs: list, polys: dict, sigma_lines: list) -> None:
    """Panel (b) of :func:`cfrw_layers_figure`: the layers stacked in 3D, the target, and
    each trajectory from the target past the top layer with its entry point."""
    import plotly.graph_objects as go

    # (b) the layers stacked in 3D
    for j, h in enumerate(hs):
        xs, ys = [], []
        for p in polys[h]:
            xs += [*p[:, 0], None]
            ys += [*p[:, 1], None]
        fig.add_trace(
            go.Scatter3d(
                x=xs, y=ys, z=[h if x is not None else None for x in xs], mode="lines",
                name=f"z = {h:g} mm", line={"width": 4, "color": _PALETTE[j % len(_PALETTE)]},
                hovertemplate="(%{x:.2f}, %{y:.2f}, %{z:.0f}) mm<extra></extra>",
            ),
            row=1, col=2,
        )  # fmt: skip
    fig.add_trace(
        go.Scatter3d(
            x=[0.0], y=[0.0], z=[0.0], mode="markers", name="target",
            marker={"size": 5, "color": _VERMILLION, "symbol": "diamond"},
        ),
        row=1, col=2,
    )  # fmt: skip
    top = max(hs)
    for label, tip_s, entry_s, colour in sigma_lines:
        end = _crossing(tip_s, entry_s, top)
        if end is None or np.linalg.norm(end - tip_s) < np.linalg.norm(entry_s - tip_s):
            end = entry_s
        seg = np.array([tip_s, end])
        fig.add_trace(
            go.Scatter3d(
                x=seg[:, 0], y=seg[:, 1], z=seg[:, 2], mode="lines", name=f"{label} (line)",
                line={"width": 5, "color": colour}, legendgroup=label, showlegend=False,
                hoverinfo="skip",
            ),
            row=1, col=2,
        )  # fmt: skip
        fig.add_trace(
            go.Scatter3d(
                x=[entry_s[0]], y=[entry_s[1]], z=[entry_s[2]], mode="markers",
                name=f"{label} entry", legendgroup=label,
                marker={"size": 4, "color": colour, "symbol": "circle"},
                hovertemplate=f"{label} entry<br>(%{{x:.2f}}, %{{y:.2f}}, %{{z:.2f}}) mm"
                "<extra></extra>",
            ),
            row=1, col=2,
        )  # fmt: skip


def cfrw_layers_figure(
    cfrw: CFRWMap,
    heights_mm=LIU_HEIGHTS_MM,
    trajectories=(),
    *,
    plane_mm: float | None = None,
    layers: Mapping[float, list] | None = None,
    title: str | None = None,
):
    """The CFRW's boundaries in layered planes ``z = h`` of Sigma (Liu's Fig. 11).

    Parameters
    ----------
    cfrw : CFRWMap
    heights_mm : sequence of float
        Heights (mm above the target along Sigma's z, each > 0) of the stacked layers of
        panel (b); default the paper's 150, 160, 170 mm.
    trajectories : sequence of NeedleRecord, Entry or (target_mm, entry_mm)
        Lines to draw (world RAS mm): their crossing points with the plane in panel (a),
        the lines themselves and their entry points in panel (b).
    plane_mm : float, optional
        Height of panel (a)'s plane (default the first of ``heights_mm``).
    layers : mapping of float to list of ndarray, optional
        ``cfrw.layer(h)`` already computed, by height. Missing ones: the plane's is
        ``cfrw.layer(plane_mm)``, the others are it scaled by ``h / plane_mm`` (the CFRW
        is a set of directions from the target, so its layers are central projections of
        one curve; ``cfrw.layer`` samples and refines in angles, so it gives the same
        scaled copy to rounding).
    title : str, optional

    Returns
    -------
    plotly.graph_objects.Figure
        Panel (a) (``xaxis``/``yaxis``, Sigma mm, equal scales): the CFRW as one layout
        shape (an SVG path of every polyline, ``fillrule="evenodd"``), one line trace per
        polyline named ``"boundary z = <h> mm"`` with the vertices of ``cfrw.layer(h)``,
        a marker trace per crossing trajectory named by its label. Panel (b) (``scene``):
        one line trace per height named ``"z = <h> mm"`` (the polylines separated by
        None), the target, each trajectory as a line from the target past the top layer
        and its entry point.
    """
    from plotly.subplots import make_subplots

    cfrw = _check_map(cfrw)
    hs = _heights(heights_mm)
    plane = hs[0] if plane_mm is None else _heights([plane_mm])[0]
    polys = dict(layers or {})
    if plane not in polys:
        polys[plane] = cfrw.layer(plane)
    for h in hs:  # the CFRW is a cone of directions: its layers are scaled copies
        if h not in polys:
            polys[h] = [p * (h / plane) for p in polys[plane]]
    lines = _trajectories(trajectories)
    fig = make_subplots(
        1,
        2,
        specs=[[{"type": "xy"}, {"type": "scene"}]],
        column_widths=[0.45, 0.55],
        subplot_titles=(
            f"(a) CFRW in the plane z = {plane:g} mm",
            f"(b) CFRW boundaries at z = {', '.join(f'{h:g}' for h in hs)} mm",
        ),
    )
    sigma_lines = _plane_panel(fig, cfrw, plane, polys[plane], lines)
    _stacked_panel(fig, hs, polys, sigma_lines)
    fig.update_xaxes(title_text=f"x in {_SIGMA} (mm)", row=1, col=1)
    fig.update_yaxes(title_text=f"y in {_SIGMA} (mm)", scaleanchor="x", scaleratio=1, row=1, col=1)
    fig.update_layout(
        title=title if title is not None else "Collision-free reachable workspace (CFRW)",
        scene={
            "xaxis_title": f"x in {_SIGMA} (mm)",
            "yaxis_title": f"y in {_SIGMA} (mm)",
            "zaxis_title": "z = h (mm)",
            "aspectmode": "data",
        },
        template="plotly_white",
        height=560,
        margin={"l": 40, "r": 10, "t": 70, "b": 40},
        legend={"itemsizing": "constant"},
    )
    return fig


def accessibility_map_figure(cfrw: CFRWMap, entries=(), *, title: str | None = None):
    """Every direction of a CFRW map: its entry point and what (if anything) blocks it.

    Parameters
    ----------
    cfrw : CFRWMap
    entries : sequence of NeedleRecord, Entry or (target_mm, entry_mm)
        Chosen trajectories to mark (world RAS mm).
    title : str, optional

    Returns
    -------
    plotly.graph_objects.Figure
        Panel (a) (``scene``): the entry points on the entry surface (RAS mm), those in
        the CFRW in a trace ``"in the CFRW"`` coloured by certified clearance (mm; the top
        of the scale, gamma plus the map's cap, means "at least"), the blocked ones with an
        entry in one trace per reason (named as :data:`_REASON_LABELS`), the target, and
        the chosen entries in a trace ``"chosen entries"``. Panel (b) (``xaxis``/``yaxis``,
        degrees): a heat map over ``phi`` (x) and ``theta`` (y) of the :class:`Blocked`
        codes, one colour per reason, and the chosen directions as a trace ``"chosen"``.
    """
    import plotly.graph_objects as go
    from plotly.subplots import make_subplots

    cfrw = _check_map(cfrw)
    chosen = _trajectories(entries, "entries")
    pr = cfrw.problem
    fig = make_subplots(
        1,
        2,
        specs=[[{"type": "scene"}, {"type": "xy"}]],
        column_widths=[0.55, 0.45],
        subplot_titles=("(a) entry points on the entry surface", "(b) directions in Sigma"),
    )
    th_deg, ph_deg = np.degrees(cfrw.theta_rad), np.degrees(cfrw.phi_rad)
    T, P = np.meshgrid(th_deg, ph_deg, indexing="ij")
    e = cfrw.entry_mm.reshape(-1, 3)
    code = cfrw.blocked.reshape(-1)
    clear, length = cfrw.clearance_mm.reshape(-1), cfrw.length_mm.reshape(-1)
    has = np.all(np.isfinite(e), axis=1)
    custom = np.column_stack([T.reshape(-1), P.reshape(-1), clear, length])
    hover = (
        f"{_THETA} %{{customdata[0]:.1f}}°, {_PHI} %{{customdata[1]:.1f}}°<br>"
        "clearance %{customdata[2]:.2f} mm, length %{customdata[3]:.1f} mm<extra>%{fullData.name}"
        "</extra>"
    )
    cmax = pr.gamma_mm + CLEARANCE_CAP_ABOVE_GAMMA_MM
    for b in Blocked:
        idx = np.flatnonzero(has & (code == b))
        if not idx.size:
            continue
        if b == Blocked.FREE:
            marker = {
                "size": 3.5, "color": clear[idx], "colorscale": "Viridis", "cmin": pr.gamma_mm,
                "cmax": cmax, "colorbar": {"title": {"text": "clearance (mm)"}, "x": 0.5,
                                           "len": 0.8},
            }  # fmt: skip
        else:
            marker = {"size": 2.5, "color": _REASON_COLOURS[b]}
        fig.add_trace(
            go.Scatter3d(
                x=e[idx, 0], y=e[idx, 1], z=e[idx, 2], mode="markers",
                name=_REASON_LABELS[b], marker=marker, customdata=custom[idx],
                hovertemplate=hover,
            ),
            row=1, col=1,
        )  # fmt: skip
    fig.add_trace(
        go.Scatter3d(
            x=pr.target_mm[:1], y=pr.target_mm[1:2], z=pr.target_mm[2:], mode="markers",
            name="target", marker={"size": 5, "color": _INK, "symbol": "diamond"},
        ),
        row=1, col=1,
    )  # fmt: skip
    if chosen:
        pts = np.array([c[2] for c in chosen])
        fig.add_trace(
            go.Scatter3d(
                x=pts[:, 0], y=pts[:, 1], z=pts[:, 2], mode="markers+text",
                text=[c[0] for c in chosen], name="chosen entries",
                marker={"size": 7, "color": _VERMILLION, "symbol": "diamond"},
                hovertemplate="%{text}<br>(%{x:.2f}, %{y:.2f}, %{z:.2f}) mm<extra></extra>",
            ),
            row=1, col=1,
        )  # fmt: skip
    n = len(Blocked)
    scale = []
    for i, c in enumerate(_REASON_COLOURS[:n]):
        scale += [[i / n, c], [(i + 1) / n, c]]
    text = np.array(_REASON_LABELS)[cfrw.blocked]
    fig.add_trace(
        go.Heatmap(
            x=ph_deg, y=th_deg, z=cfrw.blocked, zmin=-0.5, zmax=n - 0.5, colorscale=scale,
            name="blocking reason", text=text,
            customdata=np.stack([cfrw.clearance_mm, cfrw.length_mm], axis=-1),
            hovertemplate=f"{_PHI} %{{x:.1f}}°, {_THETA} %{{y:.1f}}°<br>%{{text}}<br>"
            "clearance %{customdata[0]:.2f} mm, length %{customdata[1]:.1f} mm<extra></extra>",
            colorbar={"tickvals": list(range(n)), "ticktext": list(_REASON_LABELS), "x": 1.02,
                      "len": 0.8},
        ),
        row=1, col=2,
    )  # fmt: skip
    if chosen:
        d = np.array([c[2] - c[1] for c in chosen])
        theta, phi = angles_of(d, pr.world_T_sigma)
        fig.add_trace(
            go.Scatter(
                x=_wrap_phi_deg(cfrw, np.degrees(phi)), y=np.degrees(theta), mode="markers+text",
                text=[c[0] for c in chosen], textposition="top center", name="chosen",
                marker={"size": 11, "color": "white", "symbol": "star",
                        "line": {"width": 1.5, "color": _INK}},
                textfont={"color": _INK},
            ),
            row=1, col=2,
        )  # fmt: skip
    fig.update_xaxes(title_text=f"{_PHI} (°)", row=1, col=2)
    fig.update_yaxes(title_text=f"{_THETA} (°)", row=1, col=2)
    fig.update_layout(
        title=title if title is not None else "Accessibility map",
        scene={"xaxis_title": "x (R) mm", "yaxis_title": "y (A) mm", "zaxis_title": "z (S) mm",
               "aspectmode": "data"},
        template="plotly_white", height=560, margin={"l": 10, "r": 10, "t": 70, "b": 40},
        legend={"itemsizing": "constant", "x": 0.0, "y": -0.05, "orientation": "h"},
    )  # fmt: skip
    return fig
