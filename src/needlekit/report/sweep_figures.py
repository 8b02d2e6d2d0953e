"""Plotly figures of start-direction sweeps (Feng et al. 2023): the direction sphere of
their Fig. 8, the cost per effective direction of their Fig. 9, and the best and valid
paths in the anatomy (Fig. 7). :mod:`needlekit.report.sweep_report` puts them on a page
(and re-exports them).

A direction counts as solved when its planner returned ``PlanStatus.SOLVED`` with a finite
cost, as in the sweep's own statistics.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from needlekit.errors import InvalidInputError
from needlekit.planning.steerable.sweep import SweepResult
from needlekit.report._style import _GREEN, _ORANGE, _PALETTE, _PURPLE, _SKY
from needlekit.report.scene3d import scene_figure

__all__ = [
    "FIG9_OFFSET",
    "best_paths_figure",
    "cost_per_direction_figure",
    "direction_sphere_figure",
    "valid_paths_figure",
]


_GREY, _YELLOW, _RED, _INK = "#b8b8b8", "#f5c400", "#d62728", "#222222"

# Solved directions: dark (cheap) to light (costly) blue, Feng's "valid path" colour; no
# yellow or red end, which mean "no plan" and "best" here.
_COST_SCALE = [[0.0, "#08306b"], [0.4, "#2171b5"], [0.75, "#6baed6"], [1.0, "#c6dbef"]]

_PLANNER_COLOURS = {"rcs": _PALETTE[0], "rcs_star": _PALETTE[1], "rrt": _GREEN}

_SPARE_COLOURS = (_PURPLE, _ORANGE, _SKY)

_PLANNER_LABELS = {"rcs": "RCS", "rcs_star": "RCS*", "rrt": "RRT"}

_SYMBOLS = ("circle", "diamond", "square", "triangle-up", "x")

#: Horizontal distance between the planners' series in Fig. 9 (a direction's position).
FIG9_OFFSET: float = 0.2


def _check_sweeps(sweeps) -> dict[str, SweepResult]:
    """A non-empty mapping of sweeps over one set of directions and one effective region."""
    if not isinstance(sweeps, Mapping) or len(sweeps) == 0:
        raise InvalidInputError("sweeps", "expected a non-empty mapping planner -> SweepResult")
    out: dict[str, SweepResult] = {}
    for name, sw in sweeps.items():
        field = f"sweeps[{name!r}]"
        if not isinstance(sw, SweepResult):
            raise InvalidInputError(field, f"expected a SweepResult, got {type(sw).__name__}")
        d = np.asarray(sw.directions, dtype=float)
        if d.ndim != 2 or d.shape[1] != 3 or not len(d) == len(sw.effective) == len(sw.results):
            raise InvalidInputError(field, "directions (n, 3), effective (n,), results (n) differ")
        if out:
            ref_name, ref = next(iter(out.items()))
            ref_d = np.asarray(ref.directions, dtype=float)
            if d.shape != ref_d.shape or not np.allclose(d, ref_d, atol=1e-9):
                msg = f"swept other directions than sweeps[{ref_name!r}]; expected the same set"
                raise InvalidInputError(field, msg)
            if not np.array_equal(np.asarray(sw.effective, bool), np.asarray(ref.effective, bool)):
                msg = f"effective region differs from sweeps[{ref_name!r}] (other normal or alpha)"
                raise InvalidInputError(field, msg)
        out[str(name)] = sw
    return out


def _costs(sw: SweepResult) -> np.ndarray:
    """Cost (mm) per direction, NaN where there is no solved plan; shape (n,)."""
    c = sw.costs_mm
    return np.where(np.isfinite(c), c, np.nan)


def _label(planner: str) -> str:
    return _PLANNER_LABELS.get(planner, planner)


def _xyz(p) -> dict:
    """``x``, ``y``, ``z`` keyword arguments from an array of shape (3, ...)."""
    return {"x": p[0], "y": p[1], "z": p[2]}


def direction_sphere_figure(sweeps: Mapping[str, SweepResult], *, normal=None, title=None):
    """Feng's Fig. 8: the candidate directions on the unit sphere, one 3D view per planner.

    Non-effective directions are small grey dots, effective ones without a plan yellow,
    solved ones coloured by cost on one colour scale shared by all views (one colour bar),
    the best direction a large red diamond. Hovering shows index, direction and cost.

    Parameters
    ----------
    sweeps : mapping of str to SweepResult
        Planner name -> sweep, all over the same directions and effective region.
    normal : array_like, shape (3,), optional
        Outward normal of the entry surface (RAS), drawn as an arrow; the views look along
        it onto the effective region (without it, along the region's mean direction).
    title : str, optional

    Returns
    -------
    plotly.graph_objects.Figure
        Traces named ``"not effective"``, ``"effective, no plan"``, ``"solved"``,
        ``"best"`` (and ``"surface normal"``) in the scenes ``scene``, ``scene2``, ...;
        the solved markers use the layout's ``coloraxis``, whose ``cmin`` and ``cmax``
        span the costs of all planners.
    """
    import plotly.graph_objects as go
    from plotly.subplots import make_subplots

    sweeps = _check_sweeps(sweeps)
    if normal is not None:
        normal = np.asarray(normal, dtype=float).reshape(-1)
        if normal.shape != (3,) or not np.all(np.isfinite(normal)) or not normal.any():
            raise InvalidInputError("normal", "expected a finite non-zero 3-vector")
        normal = normal / np.linalg.norm(normal)
    costs = {k: _costs(sw) for k, sw in sweeps.items()}
    titles = [
        f"{_label(k)}: {int(np.isfinite(c).sum())} of {int(np.sum(sweeps[k].effective))} solved"
        for k, c in costs.items()
    ]
    n = len(sweeps)
    fig = make_subplots(1, n, specs=[[{"type": "scene"}] * n], subplot_titles=titles)
    u, v = np.mgrid[0 : np.pi : 25j, 0 : 2 * np.pi : 49j]
    ball = 0.985 * np.array([np.sin(u) * np.cos(v), np.sin(u) * np.sin(v), np.cos(u)])
    hover = "#%{customdata[0]}  (%{x:.3f}, %{y:.3f}, %{z:.3f})<br>%{customdata[1]}<extra></extra>"
    for col, (name, sw) in enumerate(sweeps.items(), start=1):
        d, c = np.asarray(sw.directions, dtype=float), costs[name]
        eff, solved = np.asarray(sw.effective, dtype=bool), np.isfinite(costs[name])
        best = np.zeros(len(d), dtype=bool)
        if sw.stats.get("best_index") is not None:
            best[sw.stats["best_index"]] = True
        text = ["not effective" if r is None else f"no plan ({r.status.value})" for r in sw.results]
        text = [f"cost {c[i]:.3f} mm" if solved[i] else t for i, t in enumerate(text)]
        traces = [
            go.Surface(
                **_xyz(ball),
                surfacecolor=0 * ball[0],
                colorscale=[[0, "#e6e6e6"], [1, "#e6e6e6"]],
                opacity=0.18,
                showscale=False,
                hoverinfo="skip",
                showlegend=False,
                name="sphere",
            )
        ]
        categories = (
            ("not effective", ~eff, {"size": 2, "color": _GREY}),
            ("effective, no plan", eff & ~solved, {"size": 4, "color": _YELLOW}),
            ("solved", solved, {"size": 5, "color": c[solved], "coloraxis": "coloraxis"}),
            ("best", best, {"size": 10, "color": _RED, "symbol": "diamond"}),
        )
        for label, mask, marker in categories:
            idx = np.flatnonzero(mask)
            if len(idx):
                custom = [[int(i), text[i]] for i in idx]
                traces.append(
                    go.Scatter3d(
                        **_xyz(d[idx].T),
                        mode="markers",
                        name=label,
                        marker=marker,
                        customdata=custom,
                        hovertemplate=hover,
                        legendgroup=label,
                        showlegend=col == 1,
                    )
                )
        if normal is not None:
            style = {"name": "surface normal", "legendgroup": "normal", "hoverinfo": "skip"}
            line = go.Scatter3d(
                **_xyz(np.outer(normal, [0.0, 1.35])),
                mode="lines",
                line={"width": 5, "color": _INK},
                showlegend=col == 1,
                **style,
            )
            head = go.Cone(
                **_xyz(1.35 * normal[:, None]),
                u=normal[:1],
                v=normal[1:2],
                w=normal[2:],
                sizemode="absolute",
                sizeref=0.18,
                anchor="tip",
                showscale=False,
                colorscale=[[0, _INK], [1, _INK]],
                showlegend=False,
                **style,
            )
            traces += [line, head]
        fig.add_traces(traces, rows=1, cols=col)
    # look at the effective cap from 25 deg beside its axis, so that the arrow shows
    look = normal if normal is not None else d[eff].sum(axis=0)
    look = look / np.linalg.norm(look) if np.linalg.norm(look) > 1e-9 else np.array([1.0, 0, 0])
    side = np.cross([0.0, 0.0, 1.0], look)
    side = side / np.linalg.norm(side) if np.linalg.norm(side) > 1e-6 else np.array([1.0, 0, 0])
    eye = 1.15 * (np.cos(0.45) * look + np.sin(0.45) * side) + [0.0, 0.0, 0.35]
    axis = {"range": [-1.4, 1.4], "showbackground": False, "gridcolor": "#eeeeee"}
    axis |= {"zerolinecolor": "#cccccc", "tickvals": [-1, 0, 1]}
    fig.update_scenes(
        xaxis={**axis, "title": "x (R)"},
        yaxis={**axis, "title": "y (A)"},
        zaxis={**axis, "title": "z (S)"},
        aspectmode="cube",
        camera={"eye": dict(zip("xyz", eye.tolist(), strict=True))},
    )
    finite = np.concatenate([c[np.isfinite(c)] for c in costs.values()])
    if finite.size:
        lo, hi = float(finite.min()), float(finite.max())
        bar = {"title": {"text": "cost (mm)"}, "thickness": 14, "len": 0.75}
        scale = {"colorscale": _COST_SCALE, "cmin": lo, "cmax": max(hi, lo + 1e-6)}
        fig.update_layout(coloraxis={**scale, "colorbar": bar})
    fig.update_layout(
        title=title,
        height=520,
        template="plotly_white",
        margin={"l": 0, "r": 0, "t": 60, "b": 0},
        legend={"orientation": "h", "y": -0.02, "x": 0.0, "itemsizing": "constant"},
    )
    return fig


def cost_per_direction_figure(sweeps: Mapping[str, SweepResult], *, title=None):
    """Feng's Fig. 9: cost of each effective direction, in sweep order, per planner.

    Parameters
    ----------
    sweeps : mapping of str to SweepResult
        Planner name -> sweep, all over the same directions and effective region.
    title : str, optional

    Returns
    -------
    plotly.graph_objects.Figure
        Per planner a line with markers named after it (RCS, RCS*, RRT; x: 1-based position
        among the effective directions, y: cost in mm, ``None`` (a gap) where there is no
        plan), a marker ``"<name> best"`` and a dashed line ``"<name> mean"``.
    """
    import plotly.graph_objects as go

    sweeps = _check_sweeps(sweeps)
    fig = go.Figure()
    spare = iter(_SPARE_COLOURS * len(sweeps))
    n = len(sweeps)
    for j, (name, sw) in enumerate(sweeps.items()):
        idx = np.flatnonzero(np.asarray(sw.effective, dtype=bool))
        # planners often find the same cost: each series sits a little to the side of the
        # direction's position (FIG9_OFFSET apart) and has its own marker size, so that
        # one never hides another
        shift = (j - (n - 1) / 2) * FIG9_OFFSET
        c, x = _costs(sw)[idx], np.arange(1, len(idx) + 1) + shift
        colour, label = _PLANNER_COLOURS.get(name) or next(spare), _label(name)
        custom = np.column_stack([idx, np.asarray(sw.directions, dtype=float)[idx]])
        hover = f"{label}<br>effective #%{{x}} (direction #%{{customdata[0]}})<br>"
        hover += "(%{customdata[1]:.3f}, %{customdata[2]:.3f}, %{customdata[3]:.3f})<br>"
        group = {"legendgroup": name, "hovertemplate": hover + "cost %{y:.3f} mm<extra></extra>"}
        y = [None if np.isnan(val) else float(val) for val in c]
        fig.add_scatter(
            x=x,
            y=y,
            mode="lines+markers",
            name=label,
            line={"color": colour, "width": 2},
            marker={
                "size": max(5, 11 - 3 * j),
                "symbol": _SYMBOLS[j % len(_SYMBOLS)],
                "opacity": 0.85,
                "line": {"width": 1, "color": colour},
            },
            connectgaps=False,
            customdata=custom,
            **group,
        )
        best = sw.stats.get("best_index")
        if best is not None and best in idx:
            k = int(np.flatnonzero(idx == best)[0])
            star = {
                "size": 16,
                "symbol": "star",
                "color": colour,
                "line": {"width": 1, "color": _INK},
            }
            fig.add_scatter(
                x=[k + 1 + shift],
                y=[float(c[k])],
                mode="markers",
                name=f"{label} best",
                marker=star,
                showlegend=False,
                customdata=custom[k : k + 1],
                **group,
            )
        mean = sw.stats.get("mean_cost_mm")
        if mean is not None and len(idx):
            fig.add_scatter(
                x=[0.5, len(idx) + 0.5],
                y=[mean, mean],
                mode="lines",
                name=f"{label} mean",
                line={"color": colour, "dash": "dash", "width": 1.2},
                showlegend=False,
                legendgroup=name,
                hovertemplate=f"{label} mean %{{y:.3f}} mm<extra></extra>",
            )
    fig.update_layout(
        title=title,
        height=440,
        template="plotly_white",
        hovermode="closest",
        xaxis={"title": "effective direction (sweep order)", "rangemode": "tozero"},
        yaxis={"title": "cost: path length (mm)"},
        margin={"l": 60, "r": 20, "t": 60, "b": 50},
        legend={"orientation": "h", "yanchor": "bottom", "y": 1.02, "x": 0.0},
    )
    return fig


def best_paths_figure(scene, sweeps: Mapping[str, SweepResult], *, max_cells: int = 96):
    """The best plan of every planner in its scene (Feng's Fig. 7), drawn with
    :func:`needlekit.report.scene3d.scene_figure`, the view zoomed onto the paths.

    Parameters
    ----------
    scene : needlekit.anatomy.scene.Scene
    sweeps : mapping of str to SweepResult
    max_cells : int
        Resolution limit of the surfaces (samples per axis).

    Returns
    -------
    plotly.graph_objects.Figure
    """
    sweeps = _check_sweeps(sweeps)
    best = {
        k: sw.best for k, sw in sweeps.items() if sw.best is not None and sw.best.plan is not None
    }
    starts = [r.start_pose for r in best.values() if r.start_pose is not None]
    goals = [r.goal_mm for sw in sweeps.values() for r in sw.results if r is not None][:1]
    paths = [r.plan.points_mm(0.5) for r in best.values()]
    fig = scene_figure(
        scene,
        start_poses=np.array(starts) if starts else None,
        targets_mm=np.array(goals) if goals else None,
        paths_mm=paths,
        path_names=[f"{_label(k)} best ({r.cost_mm:.2f} mm)" for k, r in best.items()],
        max_cells=max_cells,
        title="",
        # framed on the paths (they are small beside the whole scene), looked at across them
        focus_mm=np.vstack([*paths, *goals]) if paths else None,
    )
    return fig


def valid_paths_figure(scene, sweep: SweepResult, *, max_cells: int = 96):
    """Feng's Fig. 7: every valid path of one planner's sweep (one per solved direction),
    coloured by cost from the cheapest (dark) to the costliest (light), the best in red.

    Parameters
    ----------
    scene : needlekit.anatomy.scene.Scene
    sweep : SweepResult
    max_cells : int
        Resolution limit of the surfaces (samples per axis).

    Returns
    -------
    plotly.graph_objects.Figure
    """
    import plotly.graph_objects as go
    from plotly.colors import sample_colorscale

    solved = [
        (i, r) for i, r in enumerate(sweep.results)
        if r is not None and r.plan is not None and r.status.value == "solved"
    ]  # fmt: skip
    goals = [r.goal_mm for _, r in solved][:1]
    every = [r.plan.points_mm(0.5) for _, r in solved]
    fig = scene_figure(
        scene,
        targets_mm=np.array(goals) if goals else None,
        max_cells=max_cells,
        title="",
        focus_mm=np.vstack([*every, *goals]) if every else None,
    )
    if not solved:
        return fig
    costs = np.array([r.cost_mm for _, r in solved])
    lo, hi = float(costs.min()), float(costs.max())
    t = (costs - lo) / (hi - lo) if hi > lo else np.zeros_like(costs)
    colours = sample_colorscale(_COST_SCALE, t.tolist())
    best = sweep.stats.get("best_index")
    for (i, r), colour in zip(solved, colours, strict=True):
        p = r.plan.points_mm(0.5)
        is_best = i == best
        fig.add_trace(
            go.Scatter3d(
                x=p[:, 0], y=p[:, 1], z=p[:, 2], mode="lines",
                name=f"direction #{i}: {r.cost_mm:.2f} mm" + (" (best)" if is_best else ""),
                line={"width": 7 if is_best else 3, "color": _RED if is_best else colour},
                legendgroup="best" if is_best else "paths", showlegend=is_best,
                hovertemplate=f"direction #{i}<br>cost {r.cost_mm:.3f} mm<extra></extra>",
            )
        )  # fmt: skip
    return fig
