"""The puncture study's report: figures like Tang et al.'s Fig. 4 (the puncture of example
trials against the guide cylinder and cone) and Fig. 5 (the adaptation of the base and
needle estimates), the distribution of the final errors, and the comparison with the paper.
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np

from needlekit.report._style import _PALETTE
from needlekit.report.html_page import (
    FigureSection,
    TableSection,
    TextSection,
    write_report_html,
)

__all__ = [
    "adaptation_figure",
    "error_histograms_figure",
    "neck_figure",
    "puncture_figure",
    "puncture_sections",
    "start_and_angle_figure",
    "write_puncture_report",
]

_OCTANTS = ("+x +y", "-x +y", "-x -y", "+x -y")
#: The report page's title.
TITLE = "Robotic needle puncture: simulation study (Tang et al., Section III)"
_PAPER_TRIALS = 100  # Tang et al., Section III-B: the simulation was run 100 times
_REASON_WORDS = {
    "inside_patient_cylinder": "start point inside the patient cylinder",
    "wrist_too_close": "wrist too close to the shoulder",
    "wrist_too_far": "wrist beyond the arm's reach",
}


def _series(log: dict, key: str) -> np.ndarray:
    return np.array([np.nan if v is None else v for v in log[key]], dtype=float)


def _examples(trials: list[dict]) -> list[dict]:
    return [t for t in trials if "log" in t and "puncture" in t["phase_times_s"]]


def _label(t: dict) -> str:
    return f"trial {t['trial']} (octant {_OCTANTS[t['octant']]})"


def puncture_figure(trials: list[dict], *, guide_radius_mm: float = 1.5, cone_deg: float = 0.5):
    """Fig. 4: distance to the target, distance from the guide line and needle angle during
    the puncture of the example trials (real: lines; measured by the needle sensor: dots).

    Parameters
    ----------
    trials : list of dict
        Trial outcomes; those with a ``log`` are drawn.
    guide_radius_mm, cone_deg : float
        The bounds drawn as dashed lines.

    Returns
    -------
    plotly.graph_objects.Figure
    """
    import plotly.graph_objects as go
    from plotly.subplots import make_subplots

    fig = make_subplots(
        rows=3,
        cols=1,
        shared_xaxes=True,
        vertical_spacing=0.06,
        subplot_titles=(
            "(A) tip to target (mm): real, and the quintic (dashed)",
            "(B) tip to guide line (mm): real, and measured (dots)",
            "(C) needle to guide line (deg): real, and measured (dots)",
        ),
    )
    for k, t in enumerate(_examples(trials)):
        log, colour = t["log"], _PALETTE[k % len(_PALETTE)]
        t0 = t["phase_times_s"]["puncture"]
        ts = np.asarray(log["t_s"], float)
        on = ts >= t0
        x = ts[on] - t0
        name = _label(t)
        common = {"legendgroup": name, "line": {"color": colour, "width": 2}}
        fig.add_trace(
            go.Scatter(x=x, y=_series(log, "to_target_mm")[on], name=name, **common), 1, 1
        )
        fig.add_trace(
            go.Scatter(
                x=x,
                y=_series(log, "desired_to_target_mm")[on],
                showlegend=False,
                legendgroup=name,
                line={"color": colour, "width": 1, "dash": "dash"},
            ),
            1,
            1,
        )
        for row, real, meas in (
            (2, "to_line_mm", "measured_to_line_mm"),
            (3, "angle_deg", "measured_angle_deg"),
        ):
            fig.add_trace(
                go.Scatter(
                    x=x[::5],
                    y=_series(log, meas)[on][::5],
                    mode="markers",
                    showlegend=False,
                    legendgroup=name,
                    marker={"color": colour, "size": 3, "opacity": 0.35},
                ),
                row,
                1,
            )
            fig.add_trace(
                go.Scatter(x=x, y=_series(log, real)[on], showlegend=False, **common), row, 1
            )
    fig.add_hline(y=guide_radius_mm, line={"color": "#444", "dash": "dot"}, row=2, col=1)
    fig.add_hline(y=cone_deg, line={"color": "#444", "dash": "dot"}, row=3, col=1)
    fig.update_yaxes(rangemode="tozero")
    fig.update_yaxes(range=[0, 3 * guide_radius_mm], row=2, col=1)
    fig.update_yaxes(range=[0, 3 * cone_deg], row=3, col=1)
    fig.update_xaxes(title_text="time since the puncture began (s)", row=3, col=1)
    fig.update_layout(height=820, template="plotly_white", legend={"orientation": "h", "y": -0.08})
    return fig


def adaptation_figure(trials: list[dict]):
    """Fig. 5 (A, B): errors of the estimated base and needle poses over whole example
    trials.

    Parameters
    ----------
    trials : list of dict

    Returns
    -------
    plotly.graph_objects.Figure
    """
    import plotly.graph_objects as go
    from plotly.subplots import make_subplots

    panels = (  # lettered as Tang et al.'s Fig. 5: (A) the base pose, (B) the needle tip's
        ("base_error_mm", "(A) base position error (mm)"),
        ("base_rotation_error_deg", "(A) base rotation error (deg)"),
        ("needle_error_mm", "(B) needle-tip position error (mm)"),
        ("needle_rotation_error_deg", "(B) needle-tip rotation error (deg)"),
        ("tip_estimate_error_mm", "estimated minus real tip (mm)"),
    )
    fig = make_subplots(
        rows=3, cols=2, subplot_titles=[p[1] for p in panels], vertical_spacing=0.09
    )
    for k, t in enumerate(_examples(trials)):
        log, colour, name = t["log"], _PALETTE[k % len(_PALETTE)], _label(t)
        ts = np.asarray(log["t_s"], float)
        for j, (key, _) in enumerate(panels):
            fig.add_trace(
                go.Scatter(
                    x=ts,
                    y=_series(log, key),
                    name=name,
                    legendgroup=name,
                    showlegend=j == 0,
                    line={"color": colour, "width": 1.6},
                ),
                j // 2 + 1,
                j % 2 + 1,
            )
            start = t["phase_times_s"].get("puncture")
            if start is not None:
                fig.add_vline(
                    x=start, line={"color": colour, "dash": "dot", "width": 1},
                    row=j // 2 + 1, col=j % 2 + 1,
                )  # fmt: skip
    fig.update_yaxes(type="log")
    fig.update_xaxes(title_text="time (s); dotted: the puncture begins")
    fig.update_layout(height=900, template="plotly_white", legend={"orientation": "h", "y": -0.06})
    return fig


def _to_start(t: dict, start_distance_mm: float) -> np.ndarray:
    """The real tip's distance from the real start point; computed from the logged tip for
    files written before ``to_start_mm`` was logged."""
    log = t["log"]
    if "to_start_mm" in log:
        return _series(log, "to_start_mm")
    start = np.asarray(t["target_mm"], float) + start_distance_mm * np.asarray(
        t["guide_direction"], float
    )
    return np.linalg.norm(np.asarray(log["tip_mm"], float) - start, axis=1)


def start_and_angle_figure(
    trials: list[dict], *, start_distance_mm: float = 300.0, cone_deg: float = 0.5
):
    """Fig. 5 (C, D): the real tip's distance from the real start point and the real
    needle's angle to the real guide line over whole example trials, with the cone's bound
    from the puncture's first step on.

    Parameters
    ----------
    trials : list of dict
        Trial outcomes; those with a ``log`` that reached the puncture are drawn.
    start_distance_mm : float
        The start point's distance out along the guide line.
    cone_deg : float
        The cone's half-angle, drawn (dotted, in each trial's colour) from the time the
        trial's puncture began to its end.

    Returns
    -------
    plotly.graph_objects.Figure
    """
    import plotly.graph_objects as go
    from plotly.subplots import make_subplots

    fig = make_subplots(
        rows=2,
        cols=1,
        shared_xaxes=True,
        vertical_spacing=0.08,
        subplot_titles=(
            "(C) real tip to the real start point (mm)",
            "(D) real needle to the real guide line (deg); dotted: the cone's bound",
        ),
    )
    for k, t in enumerate(_examples(trials)):
        log, colour, name = t["log"], _PALETTE[k % len(_PALETTE)], _label(t)
        ts = np.asarray(log["t_s"], float)
        start = t["phase_times_s"]["puncture"]
        for row, y in ((1, _to_start(t, start_distance_mm)), (2, _series(log, "angle_deg"))):
            fig.add_trace(
                go.Scatter(
                    x=ts,
                    y=y,
                    name=name,
                    legendgroup=name,
                    showlegend=row == 1,
                    line={"color": colour, "width": 1.6},
                ),
                row,
                1,
            )
            fig.add_vline(
                x=start, line={"color": colour, "dash": "dot", "width": 1}, row=row, col=1
            )
        fig.add_trace(
            go.Scatter(
                x=[start, ts[-1]],
                y=[cone_deg, cone_deg],
                mode="lines",
                showlegend=False,
                legendgroup=name,
                hoverinfo="skip",
                line={"color": colour, "dash": "dot", "width": 2},
            ),
            2,
            1,
        )
    fig.update_yaxes(type="log")
    fig.update_xaxes(
        title_text="time (s); dotted vertical lines: the puncture begins", row=2, col=1
    )
    fig.update_layout(height=720, template="plotly_white", legend={"orientation": "h", "y": -0.1})
    return fig


def error_histograms_figure(trials: list[dict], paper: dict):
    """Distributions of the final position and angle errors, with the paper's mean +- sd.

    Parameters
    ----------
    trials : list of dict
    paper : dict
        ``PAPER_RESULTS``.

    Returns
    -------
    plotly.graph_objects.Figure
    """
    import plotly.graph_objects as go
    from plotly.subplots import make_subplots

    done = [t for t in trials if t["status"] == "completed"]
    keys = (("position_error_mm", "final tip-to-target error (mm)"),
            ("angle_error_deg", "final needle-to-guide-line angle (deg)"))  # fmt: skip
    fig = make_subplots(rows=1, cols=2, subplot_titles=[k[1] for k in keys])
    for j, (key, _) in enumerate(keys):
        fig.add_trace(
            go.Histogram(
                x=[t[key] for t in done],
                nbinsx=25,
                name="needlekit" if j == 0 else None,
                showlegend=j == 0,
                marker={"color": _PALETTE[0]},
            ),
            1,
            j + 1,
        )
        p = paper[key]
        fig.add_vrect(
            x0=p["mean"] - p["sd"], x1=p["mean"] + p["sd"], fillcolor=_PALETTE[1],
            opacity=0.15, line_width=0, row=1, col=j + 1,
        )  # fmt: skip
        fig.add_vline(x=p["mean"], line={"color": _PALETTE[1], "dash": "dash"}, row=1, col=j + 1)
    fig.update_yaxes(title_text="trials", col=1)
    fig.update_layout(
        height=420,
        template="plotly_white",
        title_text="shaded: the paper's mean +- sd (dashed: mean)",
    )
    return fig


def _rotation_onto(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The smallest rotation taking unit vector ``a`` onto unit vector ``b``."""
    from needlekit.geometry.so3 import so3_exp

    axis = np.cross(a, b)
    s, c = np.linalg.norm(axis), float(a @ b)
    if s < 1e-12:
        if c > 0:
            return np.eye(3)
        perp = np.cross(a, [1.0, 0.0, 0.0] if abs(a[0]) < 0.9 else [0.0, 1.0, 0.0])
        return so3_exp(np.pi * perp / np.linalg.norm(perp))
    return so3_exp(axis / s * np.arctan2(s, c))


def neck_figure(trials: list[dict], phantom=None, *, outside_mm: float = 60.0):
    """The example trials' needle-tip paths in the neck phantom (3D).

    Each trial's real tip positions during the puncture are carried rigidly onto the
    phantom's guide line (its target onto the phantom's target, its ``l_g`` onto the
    phantom's outward guide direction): the paths show how far off the line the real tip
    went, in the anatomy the puncture is for.

    Parameters
    ----------
    trials : list of dict
    phantom : Phantom, optional
        Default: the built-in neck phantom (seed 0).
    outside_mm : float
        How far out from the skin the paths are drawn.

    Returns
    -------
    plotly.graph_objects.Figure
    """
    from needlekit.anatomy.phantoms import neck_phantom
    from needlekit.geometry.se3 import pose_from_direction
    from needlekit.report.scene3d import scene_figure

    ph = phantom or neck_phantom(0)
    gl = ph.info["guide_line"]
    target = np.asarray(gl["target_mm"], float)
    inward = np.asarray(gl["direction"], float)
    depth = float(gl["length_mm"]) + outside_mm
    paths, names = [], []
    for t in _examples(trials):
        log = t["log"]
        ts = np.asarray(log["t_s"], float)
        tips = np.asarray(log["tip_mm"], float)
        on = ts >= t["phase_times_s"]["puncture"]
        rel = tips[on] - np.asarray(t["target_mm"], float)
        lg = np.asarray(t["guide_direction"], float)
        r = _rotation_onto(lg, -inward)
        mapped = rel @ r.T + target
        keep = (mapped - target) @ -inward <= depth
        paths.append(mapped[keep])
        names.append(_label(t))
    start = pose_from_direction(target - depth * inward, inward)
    return scene_figure(
        ph.scene,
        start_poses=start[None],
        targets_mm=target[None],
        paths_mm=paths,
        path_names=names,
        title="needle-tip paths of the example trials, carried onto the neck phantom's guide line",
    )


def _comparison_rows(summary: dict) -> list[dict]:
    rows = []
    for key, what in (("position_error_mm", "position error"), ("angle_error_deg", "angle")):
        unit = "mm" if key.endswith("mm") else "deg"
        for source, st in (("needlekit", summary[key]), ("Tang et al.", summary["paper"][key])):
            rows.append(
                {
                    "quantity": what,
                    "source": source,
                    f"mean_{unit}": st["mean"],
                    f"sd_{unit}": st["sd"],
                    f"min_{unit}": st["min"],
                    f"max_{unit}": st["max"],
                }
            )
    return rows


def _min_sample_sd(lo: float, hi: float, n: int) -> float:
    """The smallest sample SD (ddof 1) of ``n`` values with minimum ``lo`` and maximum
    ``hi``: two at the ends and the others at the midpoint."""
    return (hi - lo) / 2.0 * math.sqrt(2.0 / (n - 1))


def _angle_sd_note(paper: dict) -> str:
    a = paper["angle_error_deg"]
    least = _min_sample_sd(a["min"], a["max"], _PAPER_TRIALS)
    return (
        f"Tang et al.'s figures are shown as printed, but their angle SD ({a['sd']} deg) "
        f"cannot go with their range ({a['min']}-{a['max']} deg): {_PAPER_TRIALS} values "
        f"spanning {a['max'] - a['min']:.2f} deg have a sample SD of at least {least:.4f} deg "
        f"(two at the ends, the others at the midpoint), so the SD or the range is misprinted."
    )


def _reasons(by_reason: dict) -> str:
    return ", ".join(f"{n} {r}" for r, n in by_reason.items()) or "none"


def _redraw_sections(summary: dict) -> list:
    """The guide-line filter: its rule, what it did in this run (and, without redraws, the
    trials that kept a refused line), and its refusal rate on its own."""
    from needlekit.control.controller import ControllerSettings

    g, f = summary.get("guide_redraws"), summary.get("redraw_filter")
    if g is None or f is None:  # written before the filter was reported
        return []
    sc = summary["scenario"]
    rule = (
        f"Not in the paper: the study draws a trial's guide line again while its start point "
        f"{sc['start_distance_mm']:g} mm out lies inside the patient cylinder (radius "
        f"{ControllerSettings().patient_radius_mm:g} mm about the patient axis through the "
        f"target), or puts the arm's wrist closer than {sc['min_wrist_reach_mm']:g} mm to its "
        f"shoulder or farther than {sc['max_wrist_reach_mm']:g} mm (checked in that order; a "
        f"refused line counts under the first that holds)."
    )
    r, first = g["refused_draws"], g["first_line_refused"]
    counts = ", ".join(f"{r[k]} {w}" for k, w in _REASON_WORDS.items())
    if g["enabled"]:
        run = (
            f" In this run {g['trials_redrawn']} of {g['trials']} trials needed redraws: "
            f"{g['draws']} lines drawn, {r['total']} refused ({counts})."
        )
    else:
        kept, ok = g["kept_refused_line"], g["acceptable_first_line"]
        first_counts = ", ".join(f"{first[k]} {w}" for k, w in _REASON_WORDS.items())
        run = (
            f" This run did not redraw (--no-redraw): {kept['count']} of {g['trials']} trials "
            f"kept a first line the filter refuses ({first_counts}), and "
            f"{kept['aborted']['count']} of them aborted ({_reasons(kept['aborted']['by_reason'])}"
            f"); of the {ok['count']} trials with an acceptable line, {ok['aborted']['count']} "
            f"aborted ({_reasons(ok['aborted']['by_reason'])})."
        )
    a = f["all"]
    alone = (
        f" The filter on its own ({f['draws_per_octant']} random lines per octant, targets in "
        f"the target cube, seed {f['seed']}, no simulation) refuses {a['refusal_rate']:.1%} "
        f"of lines ({a['inside_patient_cylinder'] / a['draws']:.1%} inside the cylinder, "
        f"{a['wrist_too_close'] / a['draws']:.1%} wrist too close, "
        f"{a['wrist_too_far'] / a['draws']:.1%} wrist too far): without redraws that share "
        f"of trials keeps a refused line, and with them a trial takes "
        f"{a['expected_draws_per_trial']:.1f} draws on average."
    )
    octants = [
        {
            "octant": o["octant"],
            "refused_%": 100.0 * o["refusal_rate"],
            "inside_cylinder_%": 100.0 * o["inside_patient_cylinder"] / o["draws"],
            "wrist_too_close_%": 100.0 * o["wrist_too_close"] / o["draws"],
            "wrist_too_far_%": 100.0 * o["wrist_too_far"] / o["draws"],
            "draws_per_trial": o["expected_draws_per_trial"],
        }
        for o in f["octants"]
    ]
    octant_caption = "Octants in trial order (trial i takes octant i mod 4)."
    exact = f.get("inside_patient_cylinder_exact_share")
    if exact is not None:
        octant_caption += (
            f" Exactly {exact:.1%} of lines in every octant put the start point inside the "
            f"patient cylinder (the share depends on the line's direction alone)."
        )
    outcomes = [
        {
            "first line": "acceptable" if v == "acceptable" else f"refused: {_REASON_WORDS[v]}",
            "trials": o["count"],
            "completed": o["completed"],
            "aborted": o["aborted"]["count"],
            "abort reasons": _reasons(o["aborted"]["by_reason"]),
        }
        for v, o in g["by_first_line"].items()
        if o["count"]
    ]
    return [
        TextSection(rule + run + alone, heading="Guide-line redraws"),
        TableSection(
            "The guide-line filter on its own, per octant",
            octants,
            octant_caption,
        ),
        TableSection(
            "Outcomes by the verdict on each trial's first guide line",
            outcomes,
            (
                "The refused first lines were redrawn: those trials ran with an acceptable one."
                if g["enabled"]
                else "Without redraws each trial ran with its first line."
            ),
        ),
    ]


def _start_and_angle_caption(trials: list[dict], summary: dict) -> str:
    starts = "; ".join(
        f"trial {t['trial']} at {t['phase_times_s']['puncture']:.1f} s" for t in _examples(trials)
    )
    d = summary["scenario"]["start_distance_mm"]
    return (
        f"The same example trials as Fig. 5 (A, B), from the start: the arm stands still while "
        f"the estimate adapts, turns the needle onto the guide line, brings the tip to the start "
        f"point {d:g} mm out, waits there until the estimate agrees with the needle sensor, and "
        f"punctures (dotted vertical lines; (C) then climbs to {d:g} mm). The 0.5 deg bound "
        f"applies from the puncture's first step: needlekit's controller adds the cone VFI in "
        f"the puncture step only (Phase.PUNCTURE of control.procedure, step_vfis in "
        f"control.controller), as Tang et al. constrain the needle in their step 3. Their "
        f"Fig. 5 applies it from 15 s; here each trial reaches the puncture at its own time "
        f"({starts}). The controller steers its estimate of the tip and needle towards the "
        f"guide line it measured (one noisy bronchoscope sample), while these curves are the "
        f"real tip and needle against the real line: (C) settles at the estimation and "
        f"measurement errors rather than at zero, and (D) may pass the bound by them."
    )


def puncture_sections(summary: dict, trials: list[dict]) -> list:
    """The report's sections (figures, tables, text).

    Parameters
    ----------
    summary : dict
        The study summary (``puncture.json`` without ``per_trial``).
    trials : list of dict

    Returns
    -------
    list
    """
    v = summary["constraint_violations"]
    opts = summary["options"]
    text = (
        f"{summary['trials']} trials (seed {summary['seed']}): {summary['completed']} completed, "
        f"{summary['aborted']['count']} aborted; {v['total']} constraint violations beyond "
        f"the measurement noise ({v['tolerance']['position_mm']} mm, "
        f"{v['tolerance']['angle_deg']} deg). Sensors "
        f"{'exact' if opts['exact_sensors'] else 'noisy (1 mm, 0.2 deg, 100 Hz)'}, "
        f"stability radius {opts['stability_radius_mm']} mm, "
        f"{opts['history_keyframes']} measurement keyframes, guide line from "
        f"{opts['guide_samples'] or 'all'} bronchoscope sample"
        f"{'' if opts['guide_samples'] == 1 else 's'}. Constraints are checked on the real tip "
        f"and needle from the start of the puncture."
    )
    reached = summary.get("reached_target")
    if reached is not None:
        text += (
            f" Target reached (within the target tolerance): {reached['estimated']} by the "
            f"robot's estimate, {reached['real']} by the real tip."
        )
    viol = [
        {
            "constraint": k,
            "violations": v[k]["count"],
            "trials": ", ".join(map(str, v[k]["trials"])),
        }
        for k in ("guide_cylinder", "cone", "plane", "patient_cylinder")
    ]
    sections = [
        TextSection(text),
        TableSection(
            "Final errors beside Tang et al. (Section III-B)",
            _comparison_rows(summary),
            _angle_sd_note(summary["paper"]),
        ),
        FigureSection(
            "Final errors",
            error_histograms_figure(trials, summary["paper"]),
            "The angle's shaded band is the paper's mean +- SD as printed (see the note on "
            "its SD under the table above).",
        ),
        FigureSection(
            "The puncture (like Fig. 4)",
            puncture_figure(trials),
            "Example trials, one per octant of guide directions. Dotted lines: the guide "
            "cylinder's radius and the cone's half-angle. The VFIs act on the estimate; the "
            "curves are the real robot's.",
        ),
        FigureSection(
            "The adaptation (like Fig. 5 A and B)",
            adaptation_figure(trials),
            "Errors of the estimated base (transmitter to base) and needle tip (flange to tip) "
            "against the truth, over whole trials.",
        ),
    ]
    if _examples(trials):
        sections.append(
            FigureSection(
                "The start point and the needle angle (like Fig. 5 C and D)",
                start_and_angle_figure(
                    trials, start_distance_mm=summary["scenario"]["start_distance_mm"]
                ),
                _start_and_angle_caption(trials, summary),
            )
        )
    if any("tip_mm" in t.get("log", {}) for t in trials):
        sections.append(
            FigureSection(
                "The punctures in the neck phantom",
                neck_figure(trials),
                "The real tip paths of the example trials, each carried rigidly onto the "
                "phantom's guide line (between two tracheal rings below the thyroid isthmus, "
                "to the middle of the trachea).",
            )
        )
    sections.append(TableSection("Constraint violations beyond the measurement noise", viol))
    sections += _redraw_sections(summary)
    if summary["aborted"]["count"]:
        sections.append(TableSection("Aborted trials", summary["aborted"]["trials"]))
    return sections


def write_puncture_report(path: str | os.PathLike, summary: dict, trials: list[dict]) -> Path:
    """Write the study's report page atomically.

    Parameters
    ----------
    path : path-like
    summary : dict
    trials : list of dict

    Returns
    -------
    Path
    """
    return write_report_html(path, title=TITLE, sections=puncture_sections(summary, trials))
