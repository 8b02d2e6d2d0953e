"""Figures and page sections of a ``needlekit bench scale`` record (``scale.json``).

- :func:`planning_figure`: the planner's wall time against the straight start-goal
  distance and against the obstacle density around it, log-log, with the fitted power laws;
- :func:`sweep_figure`: the sweep's wall time against directions per executor, and the
  efficiency ``planner_s_sum / (workers x (wall - prep))``;
- :func:`study_figure`: the control study's wall time against trials per worker count,
  with the fitted line read at 100 trials;
- :func:`scale_sections`: all of it on a page (``needlekit report scale.json``), with the
  machine, the date and the load average of each series;
- :func:`scale_png`: the same figures in one matplotlib PNG (for the docs).
"""

from __future__ import annotations

import io

import numpy as np
from matplotlib import rc_context
from matplotlib.ticker import FuncFormatter

from needlekit.report._style import _PALETTE, DEFAULT_DPI, _new_figure, _style
from needlekit.report.html_page import FigureSection, TableSection, TextSection

__all__ = ["planning_figure", "scale_png", "scale_sections", "study_figure", "sweep_figure"]

_STATUS_SYMBOLS = {"solved": "circle", "approximate": "x", "infeasible": "square"}


def _label(p: dict) -> str:
    return "serial" if p["executor"] == "serial" else f"{p['executor']} x{p['workers']}"


def _load_text(load: dict | None) -> str:
    if not load:
        return "load average not recorded"
    a, b = load.get("start"), load.get("end")
    return f"load average (1, 5, 15 min) {a} at the start, {b} at the end"


def _power_line(fit: dict | None, xs) -> tuple[np.ndarray, np.ndarray] | None:
    xs = np.asarray([x for x in xs if x is not None and x > 0], float)
    if fit is None or len(xs) < 2:
        return None
    x = np.geomspace(xs.min(), xs.max(), 50)
    return x, fit["coefficient"] * x ** fit["exponent"]


def _fit_words(fit: dict | None, key: str = "exponent") -> str:
    if fit is None:
        return "no fit"
    return f"{key} {fit[key]:.2f}, R² {fit['r2']:.2f}, n {fit['n']}"


def planning_figure(planning: dict):
    """Planner wall time against straight distance and against obstacle density.

    Parameters
    ----------
    planning : dict
        A scale record's ``planning`` block.

    Returns
    -------
    plotly.graph_objects.Figure
    """
    import plotly.graph_objects as go
    from plotly.subplots import make_subplots

    fig = make_subplots(rows=1, cols=2, horizontal_spacing=0.1, subplot_titles=(
        "(a) planner time vs straight start-goal distance",
        f"(a) planner time vs obstacle density ({planning['capsule_radius_mm']:g} mm capsule)",
    ))  # fmt: skip
    rows = planning["rows"]
    for k, planner in enumerate(dict.fromkeys(r["planner"] for r in rows)):
        colour = _PALETTE[k % len(_PALETTE)]
        mine = [r for r in rows if r["planner"] == planner]
        fits = planning["fits"].get(planner, {})
        for col, key, fit in ((1, "straight_distance_mm", "time_vs_distance"),
                              (2, "obstacle_density", "time_vs_density")):  # fmt: skip
            text = [f"lung {r['patient']} {r['start']}: {r['status']}" for r in mine]
            fig.add_trace(
                go.Scatter(
                    x=[r[key] for r in mine], y=[r["planner_wall_s"] for r in mine],
                    mode="markers", name=planner, legendgroup=planner, showlegend=col == 1,
                    text=text, hovertemplate="%{text}<br>%{x:.3g}, %{y:.3g} s<extra></extra>",
                    marker={"color": colour, "size": 9,
                            "symbol": [_STATUS_SYMBOLS.get(r["status"], "diamond") for r in mine]},
                ), 1, col,
            )  # fmt: skip
            line = _power_line(fits.get(fit), [r[key] for r in mine])
            if line is not None:
                fig.add_trace(
                    go.Scatter(
                        x=line[0], y=line[1], mode="lines", legendgroup=planner,
                        name=f"{planner} fit: {_fit_words(fits[fit])}", showlegend=True,
                        line={"color": colour, "dash": "dash", "width": 1.5},
                    ), 1, col,
                )  # fmt: skip
    fig.update_xaxes(type="log", title_text="straight distance (mm)", row=1, col=1)
    fig.update_xaxes(type="log", title_text="obstacle voxels in the capsule (share)", row=1, col=2)
    fig.update_yaxes(type="log", title_text="planner wall time (s)")
    fig.update_layout(height=480, template="plotly_white", legend={"orientation": "h", "y": -0.2})
    return fig


def sweep_figure(sweep: dict):
    """Sweep wall time and efficiency against directions, per executor.

    Parameters
    ----------
    sweep : dict
        A scale record's ``sweep`` block.

    Returns
    -------
    plotly.graph_objects.Figure
    """
    import plotly.graph_objects as go
    from plotly.subplots import make_subplots

    fig = make_subplots(rows=1, cols=2, horizontal_spacing=0.1, subplot_titles=(
        "(b) sweep wall time vs directions", "(b) efficiency: planners / (workers x (wall - prep))",
    ))  # fmt: skip
    points = sweep["points"]
    for k, label in enumerate(dict.fromkeys(_label(p) for p in points)):
        mine = [p for p in points if _label(p) == label]
        name = label + (" (more workers than CPUs)" if mine[0]["oversubscribed"] else "")
        style = {"color": _PALETTE[k % len(_PALETTE)]}
        x = [p["directions"] for p in mine]
        fig.add_trace(go.Scatter(x=x, y=[p["wall_s"] for p in mine], name=name, legendgroup=label,
                                 mode="lines+markers", line=style), 1, 1)  # fmt: skip
        fig.add_trace(go.Scatter(x=x, y=[p["efficiency"] for p in mine], name=name,
                                 legendgroup=label, showlegend=False, mode="lines+markers",
                                 line=style), 1, 2)  # fmt: skip
    fig.add_hline(y=1.0, line={"color": "#444", "dash": "dot"}, row=1, col=2)
    fig.update_xaxes(type="log", title_text="candidate directions")
    fig.update_yaxes(type="log", title_text="wall time (s)", row=1, col=1)
    fig.update_yaxes(title_text="efficiency", rangemode="tozero", row=1, col=2)
    fig.update_layout(height=460, template="plotly_white", legend={"orientation": "h", "y": -0.2})
    return fig


def study_figure(study: dict):
    """Control-study wall time against trials, per worker count, with the fitted lines
    carried to the target size (dashed: an extrapolation beyond the largest size run).

    Parameters
    ----------
    study : dict
        A scale record's ``study`` block.

    Returns
    -------
    plotly.graph_objects.Figure
    """
    import plotly.graph_objects as go

    fig = go.Figure()
    target = study.get("target_trials", 100)
    for k, (w, fit) in enumerate(study["fits"].items()):
        mine = [p for p in study["points"] if str(p["workers"]) == w]
        colour = _PALETTE[k % len(_PALETTE)]
        name = f"{w} worker{'s' * (w != '1')}"
        fig.add_trace(go.Scatter(x=[p["trials"] for p in mine], y=[p["wall_s"] for p in mine],
                                 mode="markers", name=name + ": measured", legendgroup=w,
                                 marker={"color": colour, "size": 9}))  # fmt: skip
        if fit is not None:
            x = np.array([0.0, float(target)])
            fig.add_trace(go.Scatter(
                x=x, y=fit["intercept"] + fit["slope"] * x, mode="lines", legendgroup=w,
                name=f"{name}: {fit['intercept']:.1f} s + {fit['slope']:.2f} s x trials "
                f"(R² {fit['r2']:.3f}); {target} trials ~ {fit['predicted']:.0f} s",
                line={"color": colour, "dash": "dash", "width": 1.5},
            ))  # fmt: skip
    fig.update_xaxes(title_text="trials", rangemode="tozero")
    fig.update_yaxes(title_text="wall time of the trials (s)", rangemode="tozero")
    fig.update_layout(height=460, template="plotly_white", legend={"orientation": "h", "y": -0.2},
                      title="(c) control study wall time vs trials")  # fmt: skip
    return fig


def _machine_text(record: dict) -> str:
    m = record["machine"]
    run = record.get("load_average") or {}
    return (
        f"Measured {m.get('time_utc', '?')} on {m.get('cpu', '?')} ({m.get('cpu_count', '?')} "
        f"CPUs), Python {m.get('python', '?')}, needlekit "
        f"{(m.get('versions') or {}).get('needlekit', '?')}; the run took "
        f"{record.get('wall_s', float('nan')):.0f} s, {_load_text(run)}. Inputs: "
        + ", ".join(f"{k} {v}" for k, v in (record.get("inputs") or {}).items())
        + "."
    )


def scale_sections(record: dict) -> list:
    """The page of a scale record: machine and inputs, then each series run (figure,
    fits, table), each with its own load average.

    Parameters
    ----------
    record : dict
        ``scale.json``.

    Returns
    -------
    list of FigureSection, TableSection and TextSection
    """
    out: list = [TextSection(_machine_text(record), "Machine, date and inputs")]
    prep = record.get("preparation")
    if prep:
        row = {k: prep[k] for k in ("patient", "cold_s", "warm_s", "import_s", "peak_rss_mb")}
        out.append(TableSection(
            "Preparing one lung for a first plan", [row],
            "In a fresh process: cold into an empty prepared-anatomy cache, then warm from it; "
            f"Python's imports apart. {_load_text(prep.get('load_average'))}.",
        ))  # fmt: skip
    pl = record.get("planning")
    if pl:
        out.append(FigureSection(
            "(a) Planning time vs path length and obstacle density", planning_figure(pl),
            f"Every start of each lung to its target, r_min {pl['r_min_mm']:g} mm, iteration "
            "budget as in the inputs. Circles: solved; crosses: approximate (the budget ran "
            "out). Density: share of obstacle voxels with centres within "
            f"{pl['capsule_radius_mm']:g} mm of the start-goal segment. "
            f"{_load_text(pl.get('load_average'))}.",
        ))  # fmt: skip
        out.append(TableSection("(a) Fits (log-log)", [
            {"planner": k, "against": what.replace("time_vs_", ""),
             "exponent": None if f is None else f["exponent"],
             "r2": None if f is None else f["r2"], "n": None if f is None else f["n"]}
            for k, fits in pl["fits"].items() for what, f in fits.items()
        ]))  # fmt: skip
        out.append(TableSection("(a) Cases", pl["rows"]))
    sw = record.get("sweep")
    if sw:
        over = any(p["oversubscribed"] for p in sw["points"])
        out.append(FigureSection(
            "(b) Sweep time vs directions and workers", sweep_figure(sw),
            f"{sw.get('case', 'the sweep')}, {sw['max_iterations']} iterations per direction "
            f"(time cap {sw['time_limit_s']:g} s), a fresh executor per point. "
            + (f"Some executors have more workers than the {sw['cpu_count']} CPUs "
               "(oversubscribed): their workers share the cores. " if over else "")
            + "Points: " + "; ".join(
                f"{_label(p)} {p['directions']}: {_load_text(p['load_average'])}"
                for p in sw["points"]),
        ))  # fmt: skip
        out.append(TableSection("(b) Points", [
            {k: v for k, v in p.items() if k not in ("load_average", "prep_s_by_worker",
                                                     "tasks_by_worker")}
            for p in sw["points"]
        ], "efficiency = planner_s_sum / (workers x (wall_s - prep_s)); equal to serial: every "
           "direction's status, cost and iterations as in this process."))  # fmt: skip
    st = record.get("study")
    if st:
        out.append(FigureSection(
            "(c) Control study time vs trials", study_figure(st),
            "Tang's puncture study, no report page; a fresh executor per point. "
            + "; ".join(f"{p['trials']} trials on {p['workers']}: "
                        f"{_load_text(p['load_average'])}" for p in st["points"]),
        ))  # fmt: skip
        out.append(TableSection("(c) Points", [
            {k: v for k, v in p.items() if k != "load_average"} for p in st["points"]
        ]))  # fmt: skip
    return out


def _plain_log_ticks(ax) -> None:
    """Log axes labelled 40, 60, 2, 0.01 rather than 4 x 10^1."""

    def minor(v, _):  # 2 and 5 of each decade only
        lead = round(v / 10 ** np.floor(np.log10(v))) if v > 0 else 0
        return f"{v:g}" if lead in (2, 5) else ""

    for axis in (ax.xaxis, ax.yaxis):
        if axis.get_scale() == "log":
            axis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
            axis.set_minor_formatter(FuncFormatter(minor))


def scale_png(record: dict, *, dpi: int = DEFAULT_DPI) -> bytes:
    """The record's figures in one PNG (matplotlib): (a) time vs distance and vs density,
    (b) sweep wall vs directions, (c) study wall vs trials.

    Parameters
    ----------
    record : dict
    dpi : int

    Returns
    -------
    bytes
    """
    with rc_context(_style()):
        fig = _new_figure(12.0, 8.0)
        axes = fig.subplots(2, 2)
        pl, sw, st = record.get("planning"), record.get("sweep"), record.get("study")
        if pl:
            for ax, key, fit, xlabel in (
                (axes[0, 0], "straight_distance_mm", "time_vs_distance", "straight distance (mm)"),
                (axes[0, 1], "obstacle_density", "time_vs_density",
                 f"obstacle share in a {pl['capsule_radius_mm']:g} mm capsule"),
            ):  # fmt: skip
                for k, planner in enumerate(dict.fromkeys(r["planner"] for r in pl["rows"])):
                    mine = [r for r in pl["rows"] if r["planner"] == planner]
                    c = _PALETTE[k % len(_PALETTE)]
                    for solved in (True, False):
                        sel = [r for r in mine if (r["status"] == "solved") == solved]
                        ax.scatter([r[key] for r in sel], [r["planner_wall_s"] for r in sel],
                                   color=c, marker="o" if solved else "x", s=28,
                                   label=f"{planner} {'solved' if solved else 'not solved'}")  # fmt: skip
                    f = pl["fits"][planner][fit]
                    line = _power_line(f, [r[key] for r in mine])
                    if line is not None:
                        ax.plot(*line, "--", color=c, lw=1.2, label=f"fit: {_fit_words(f)}")
                ax.set(xscale="log", yscale="log", xlabel=xlabel, ylabel="planner time (s)")
                _plain_log_ticks(ax)
                ax.legend(fontsize=7.5)
            axes[0, 0].set_title("(a) planning time vs distance")
            axes[0, 1].set_title("(a) planning time vs obstacle density")
        ax = axes[1, 0]
        if sw:
            for k, label in enumerate(dict.fromkeys(_label(p) for p in sw["points"])):
                mine = [p for p in sw["points"] if _label(p) == label]
                over = " (oversubscribed)" if mine[0]["oversubscribed"] else ""
                ax.plot([p["directions"] for p in mine], [p["wall_s"] for p in mine], "o-",
                        color=_PALETTE[k % len(_PALETTE)], label=label + over)  # fmt: skip
            ax.set(xscale="log", yscale="log", xlabel="directions", ylabel="sweep wall time (s)")
            _plain_log_ticks(ax)
            ax.legend(fontsize=7.5)
        ax.set_title("(b) sweep time vs directions and workers")
        ax = axes[1, 1]
        if st:
            target = st.get("target_trials", 100)
            for k, (w, f) in enumerate(st["fits"].items()):
                c = _PALETTE[k % len(_PALETTE)]
                mine = [p for p in st["points"] if str(p["workers"]) == w]
                ax.plot([p["trials"] for p in mine], [p["wall_s"] for p in mine], "o", color=c,
                        label=f"{w} worker(s): measured")  # fmt: skip
                if f is not None:
                    ax.plot([0, target], [f["intercept"], f["predicted"]], "--", color=c, lw=1.2,
                            label=f"fit, {target} trials ~ {f['predicted']:.0f} s")  # fmt: skip
            ax.set(xlabel="trials", ylabel="study wall time (s)", xlim=(0, None), ylim=(0, None))
            ax.legend(fontsize=7.5)
        ax.set_title("(c) control study time vs trials")
        m = record["machine"]
        fig.suptitle(f"needlekit bench scale, {m.get('time_utc', '')}, {m.get('cpu_count')} CPUs, "
                     f"load {(record.get('load_average') or {}).get('start')} -> "
                     f"{(record.get('load_average') or {}).get('end')}")  # fmt: skip
        buf = io.BytesIO()
        fig.savefig(buf, format="png", dpi=dpi)
    return buf.getvalue()
