"""The approach analysis drawn: the skin coloured by who can come from where.

One self-contained HTML page (:func:`write_approach_report`): a table of the scores and
shortest lines (PAA's criterion and needlekit's), and a 3D view of the skin mesh whose
triangles are coloured by certified clearance where a needle can come from them, grey
where only PAA's line test lets it through, and dark where an obstacle lies on the line,
with the obstacles, the target and both shortest lines.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from needlekit.report.html_page import FigureSection, TableSection, write_report_html

__all__ = ["approach_figure", "approach_sections", "approach_title", "write_approach_report"]

_BLOCKED = "#4d4d4d"  # an obstacle on the line
_PAA_ONLY = "#c7c7c7"  # PAA lets it through, needlekit does not
_OBSTACLE = "#D55E00"


def _clearance_colours(values: np.ndarray, lo: float, hi: float) -> list[str]:
    from plotly.colors import sample_colorscale

    t = np.clip((values - lo) / max(hi - lo, 1e-9), 0.0, 1.0)
    return sample_colorscale("Viridis", t.tolist())


def approach_figure(analysis, skin, obstacles: dict, *, title: str = "Approach analysis"):
    """The skin mesh by accessibility, the obstacles, the target and the shortest lines.

    Parameters
    ----------
    analysis : ApproachAnalysis
    skin : trimesh.Trimesh
        The mesh the analysis ran on.
    obstacles : dict of str to trimesh.Trimesh
    title : str

    Returns
    -------
    plotly.graph_objects.Figure
    """
    import plotly.graph_objects as go

    a = analysis
    colours = np.full(len(a.areas_mm2), _BLOCKED, dtype=object)
    colours[a.accessible_paa & ~a.accessible] = _PAA_ONLY
    ok = np.flatnonzero(a.accessible)
    if ok.size:
        values = (
            a.clearance_mm[ok]
            if a.clearance_mm is not None
            else np.full(ok.size, a.settings["gamma_mm"])
        )
        g = a.settings["gamma_mm"]
        colours[ok] = _clearance_colours(values, g, g + 10.0)
    v = np.asarray(skin.vertices)
    f = np.asarray(skin.faces)
    fig = go.Figure()
    fig.add_trace(
        go.Mesh3d(
            x=v[:, 0], y=v[:, 1], z=v[:, 2], i=f[:, 0], j=f[:, 1], k=f[:, 2],
            facecolor=colours.tolist(), name="skin", opacity=1.0, flatshading=True,
            hoverinfo="skip", showlegend=True,
        )
    )  # fmt: skip
    for name, m in obstacles.items():
        ov, of = np.asarray(m.vertices), np.asarray(m.faces)
        fig.add_trace(
            go.Mesh3d(
                x=ov[:, 0], y=ov[:, 1], z=ov[:, 2], i=of[:, 0], j=of[:, 1], k=of[:, 2],
                color=_OBSTACLE, opacity=0.6, name=name, hoverinfo="name", showlegend=True,
            )
        )  # fmt: skip
    t = a.target_mm
    fig.add_trace(
        go.Scatter3d(
            x=[t[0]], y=[t[1]], z=[t[2]], mode="markers", name="target",
            marker={"size": 5, "color": "#000000"},
        )
    )  # fmt: skip
    for label, paa, colour in (("shortest (PAA)", True, "#E69F00"), ("shortest", False, "#0072B2")):
        best = a.shortest(paa=paa)
        if best is None:
            continue
        e = best["entry_mm"]
        fig.add_trace(
            go.Scatter3d(
                x=[e[0], t[0]], y=[e[1], t[1]], z=[e[2], t[2]], mode="lines",
                name=f"{label}: {best['length_mm']:.1f} mm", line={"width": 6, "color": colour},
            )
        )  # fmt: skip
    fig.update_layout(
        title={"text": title},
        scene={"aspectmode": "data", "xaxis_title": "R (mm)", "yaxis_title": "A (mm)",
               "zaxis_title": "S (mm)"},
        margin={"l": 0, "r": 0, "t": 40, "b": 0},
    )  # fmt: skip
    return fig


def approach_title(scenario, path: str | os.PathLike) -> str:
    """The page's title: the scenario's name, else its file's name (the same whether
    ``needlekit approach`` or ``needlekit report approach.json`` draws it).

    Parameters
    ----------
    scenario : Scenario
        Its ``name`` (may be empty).
    path : path-like
        The scenario file.

    Returns
    -------
    str
    """
    return f"Approach analysis: {scenario.name or Path(path).name}"


def write_approach_report(
    path: str | os.PathLike, analysis, skin, obstacles: dict, *, title: str = "Approach analysis"
) -> Path:
    """Write the approach analysis as one self-contained HTML page, atomically.

    Parameters
    ----------
    path : path-like
    analysis : ApproachAnalysis
    skin : trimesh.Trimesh
    obstacles : dict of str to trimesh.Trimesh
    title : str

    Returns
    -------
    Path
    """
    sections = approach_sections(analysis, skin, obstacles, title=title)
    return write_report_html(path, title=title, sections=sections)


def approach_sections(analysis, skin, obstacles: dict, *, title: str = "Approach analysis") -> list:
    """The page's sections: the scores and shortest lines by both criteria, and the skin
    map (:func:`approach_figure`).

    Parameters
    ----------
    analysis : ApproachAnalysis
    skin : trimesh.Trimesh
    obstacles : dict of str to trimesh.Trimesh
    title : str
        The figure's title.

    Returns
    -------
    list
        For :func:`~needlekit.report.html_page.write_report_html`.
    """
    a = analysis
    s = a.settings
    rows = []
    for label, paa, score in (
        ("PAA: the line, no thickness", True, a.score_paa),
        (
            f"needlekit: needle radius {s['needle_radius_mm']:g} mm, gamma {s['gamma_mm']:g} mm, "
            "inside the body, length and angle limits",
            False,
            a.score,
        ),
    ):
        best = a.shortest(paa=paa)
        rows.append(
            {
                "criterion": label,
                "accessible skin area": f"{score:.4f}",
                "shortest line (mm)": "-" if best is None else f"{best['length_mm']:.2f}",
                "its skin point (RAS mm)": "-"
                if best is None
                else ", ".join(f"{c:.2f}" for c in best["entry_mm"]),
            }
        )
    caption = (
        f"{len(a.areas_mm2)} skin triangles, one line each from its centre to the target "
        f"({', '.join(f'{c:.2f}' for c in a.target_mm)}). Accessible skin area: the fraction "
        "of the skin's area (PAA's approach score)."
    )
    sections = [
        TableSection("Scores", rows, caption),
        FigureSection(
            "Skin map",
            approach_figure(a, skin, obstacles, title=title),
            "Skin triangles a needle can come from, coloured by certified clearance (gamma to "
            "gamma + 10 mm); light grey: the line is free but needlekit's criteria refuse "
            "it (clearance below gamma, leaves the body, too long or too oblique); dark grey: "
            "an obstacle lies on the line.",
        ),
    ]
    return sections
