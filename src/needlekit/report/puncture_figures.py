"""Plotly figures of the simulated robotic punctures (Tang et al., Section III): the
example trials' errors over time, the adaptation of the uncertain parameters, the start
points and angles, the error histograms and the neck in 3D.
:mod:`needlekit.report.puncture_report` puts them on a page (and re-exports them).
"""

from __future__ import annotations

import numpy as np

from needlekit.records import trial_solved
from needlekit.report._style import _PALETTE

__all__ = [
    "adaptation_figure",
    "error_histograms_figure",
    "neck_figure",
    "puncture_figure",
    "start_and_angle_figure",
]


_OCTANTS = ("+x +y", "-x +y", "-x -y", "+x -y")


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

    done = [t for t in trials if trial_solved(t["status"])]
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
        focus_mm=np.vstack([*paths, start[None, :3, 3], target[None]]),
        title="needle-tip paths of the example trials, carried onto the neck phantom's guide line",
    )
