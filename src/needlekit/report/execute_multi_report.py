"""The page of ``needlekit execute SCENARIO multi.json --report PAGE``: the straight needles
as planned and as the robot placed them, per-needle errors beside Liu et al.'s in-vitro
figure, the gaps between needles, the constraints and the coverage."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from needlekit.report.html_page import FigureSection, TableSection, TextSection, write_report_html

__all__ = ["TITLE", "multi_execute_sections", "placed_figure", "write_multi_execute_report"]

_PLANNED, _PLACED = "#1f77b4", "#d62728"


#: The page's title.
TITLE = "needlekit execute: the straight plan, inserted by the robot"


def _needle_rows(s: dict) -> list[dict]:
    rows = []
    for order, r in s["by_needle"].items():
        e, sh = r["error_mm"], r["target_shift_mm"]
        rows.append({"needle": order, "error_mean_mm": e.get("mean"), "error_sd_mm": e.get("sd"),
                     "error_max_mm": e.get("max"), "target_shift_mm": sh.get("mean")})  # fmt: skip
    e = s["error_mm"]
    rows.append({"needle": "all", "error_mean_mm": e.get("mean"), "error_sd_mm": e.get("sd"),
                 "error_max_mm": e.get("max"), "target_shift_mm": None})  # fmt: skip
    for lit in s["literature"]:
        rows.append({"needle": f"{lit['source']} ({lit['setting']})",
                     "error_mean_mm": lit["mean_mm"], "error_sd_mm": lit["sd_mm"],
                     "error_max_mm": None, "target_shift_mm": None})  # fmt: skip
    return rows


def placed_figure(scene, record: dict, trial: dict):
    """The anatomy with the planned lines and one trial's needles as placed.

    Parameters
    ----------
    scene : Scene
    record : dict
        The ``multi.json`` document.
    trial : dict
        One trial of ``execute.json`` (with ``needles``; tips and axes in the anatomy's
        frame).

    Returns
    -------
    plotly.graph_objects.Figure
    """
    from needlekit.report.scene3d import scene_figure

    planned = {n["order"]: n for n in record["needles"] if n.get("entry_mm")}
    paths, names = [], []
    for n in trial["needles"]:
        p = planned[n["order"]]
        entry, aimed = np.asarray(p["entry_mm"], float), np.asarray(p["target_mm"], float)
        depth = float(np.linalg.norm(entry - aimed))
        tip = np.asarray(n["tip_mm"], float)
        paths += [np.array([entry, aimed]), np.array([tip - depth * np.asarray(n["axis"]), tip])]
        names += [f"needle {n['order']} planned", f"needle {n['order']} placed"]
    targets = np.array([n["target_mm"] for n in trial["needles"]], float)
    fig = scene_figure(scene, targets_mm=targets, paths_mm=paths, path_names=names, max_cells=96,
                       focus_mm=np.vstack([*paths, targets]))  # fmt: skip
    for i, tr in enumerate(fig.data[-len(paths) :]):
        tr.line.color = _PLANNED if i % 2 == 0 else _PLACED
        tr.line.width = 5 if i % 2 == 0 else 7
    return fig


def _error_histogram(trials: list[dict], literature: list[dict]):
    import plotly.graph_objects as go

    err = [n["error_mm"] for t in trials for n in t.get("needles", [])]
    fig = go.Figure(go.Histogram(x=err, nbinsx=30, name="needles", marker={"color": _PLACED}))
    for lit in literature:
        lo, hi = lit["mean_mm"] - lit["sd_mm"], lit["mean_mm"] + lit["sd_mm"]
        fig.add_vrect(x0=lo, x1=hi, fillcolor="#999", opacity=0.2, line_width=0)
        fig.add_vline(x=lit["mean_mm"], line={"dash": "dot", "color": "#555"},
                      annotation_text=f"{lit['source']}: {lit['mean_mm']:g} +- {lit['sd_mm']:g} mm")  # fmt: skip
    fig.update_layout(height=380, xaxis_title="tip to real target (mm)", yaxis_title="needles")
    return fig


def multi_execute_sections(doc: dict, scene, record: dict) -> list:
    """The page's sections for a multi ``execute.json`` document.

    Parameters
    ----------
    doc : dict
    scene : Scene
        The scenario's anatomy (RAS).
    record : dict
        The ``multi.json`` document carried out.

    Returns
    -------
    list
    """
    s = doc["summary"]
    reg = doc["registration_sd_mm"]
    sections = [TextSection(
        f"{s['trials']} trials of the plan's {len(record['needles'])} needles on "
        f"{doc['scenario'] or 'the scenario'} (seed {doc['seed']}), each needle inserted by the "
        "simulated Panda under Tang et al.'s adaptive controller in the planned order, the "
        "needles already placed kept off by VFIs, the remaining targets moved by the plan's "
        f"deformation model ({doc['deformation'] or 'none'}). The registration is "
        + ("exact." if not reg else f"off by one random offset per trial, SD {reg:g} mm per axis.")
        + " Errors are from the real tip to the real (moved) target.")]  # fmt: skip
    sections.append(TableSection("Per-needle error beside Liu et al.", _needle_rows(s)))
    gap = s["min_needle_gap_mm"]
    c = s["constraints"]
    sections.append(TableSection("Needles and constraints", [{
        "needles": s["needles"], "touched a placed needle": len(s["touched"]),
        "smallest gap (mm)": gap, "left the guide cylinder": c["guide_cylinder"]["count"],
        "left the cone": c["cone"]["count"], "passed the target plane": c["plane"]["count"],
        "statuses": ", ".join(f"{k} {v}" for k, v in s["statuses"].items()),
    }], caption="Touch: the shafts' surfaces meet (gap below 0). Constraints by Tang et al.'s "
        "criterion, beyond the sensor noise, as needlekit puncture counts them."))  # fmt: skip
    if "coverage" in s:
        cov = s["coverage"]
        sections.append(TableSection("Ablation coverage", [{
            "planned": (cov["planned"] or {}).get("coverage"),
            "executed mean": cov["coverage"].get("mean"), "executed min": cov["coverage"].get("min"),
            "tumour min": cov["tumour_coverage"].get("min"),
            "trials fully covered": f"{cov['fully_covered']} of {cov['coverage']['n']}",
        }], caption="Zones at the executed tips along the executed axes, in the tissue at rest."))  # fmt: skip
    shown = next((t for t in doc["trials"] if "needles" in t), None)
    if shown is not None:
        sections.append(FigureSection(
            f"Trial {shown['trial']}: the needles as planned and as placed",
            placed_figure(scene, record, shown),
            caption="Blue: the planned lines (entry to aimed target); red: the needles as the "
            "robot placed them (to the planned depth along the placed axis).",
        ))  # fmt: skip
        sections.append(FigureSection("Errors", _error_histogram(doc["trials"], s["literature"]),
                                      caption="Grey band: Liu et al.'s mean +- SD."))  # fmt: skip
    if s["crashed"]:
        sections.append(TableSection("Trials that crashed", s["crashed"]))
    return sections


def write_multi_execute_report(path: str | os.PathLike, doc: dict, scene, record: dict) -> Path:
    """Write the page (atomically).

    Parameters
    ----------
    path : path-like
    doc : dict
        The multi ``execute.json`` document.
    scene : Scene
    record : dict
        The ``multi.json`` document.

    Returns
    -------
    Path
    """
    return write_report_html(
        path, title=TITLE,
        sections=multi_execute_sections(doc, scene, record),
    )  # fmt: skip
