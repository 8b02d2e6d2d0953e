"""A whole case as one 3D Slicer scene: the anatomy, the target and entry points, the plan
and, optionally, what an execution did (``needlekit slicer``, docs/export.md).

- **anatomy**: one Model per structure of the scenario, its surface by marching cubes on
  the structure's field (a CT mask as Slicer's segmentation would make it), faces turned
  outward, coloured and named by structure (the colours of ``needlekit report``'s 3D
  views);
- **points**: a Point List ``target`` (the plan's goal, or each needle's target) and a
  Point List ``entry`` (the start of the path, or each needle's skin entry);
- **plan**: a steerable plan's tip path as a Curve ``plan`` (control points at most
  ``spacing_mm`` apart, the ends of every arc included, Slicer's spline through them), or
  one Line ``needle k`` per needle of a straight multi-needle plan;
- **execution** (an ``execute.json``): for the first ``trials`` trials, the tip path the
  closed loop and the open loop recorded, each a Curve (linear between its points,
  thinned to ``spacing_mm``), or, for a multi-needle plan, each needle as the robot
  placed it: a Line from its tip back along its axis by the planned length.

The scene is written by :func:`needlekit.io.slicer_scene.write_slicer_scene` (no VTK or
Slicer needed); Slicer's own classes read it back in the tests.
"""

from __future__ import annotations

import numpy as np

from needlekit._validation import as_points
from needlekit.anatomy.fields import LazyField
from needlekit.anatomy.summary import surface_mesh
from needlekit.errors import InvalidInputError
from needlekit.io.markups import markups_curve, markups_line
from needlekit.io.slicer_scene import SlicerMarkup, SlicerModel, fiducials_markup
from needlekit.planning.steerable.plan import plan_from_dict
from needlekit.report.scene3d import structure_style

__all__ = [
    "DEFAULT_TRIALS",
    "case_markups",
    "case_scene_parts",
    "execution_markups",
    "structure_models",
    "thin_path",
]

#: Trials of an execution drawn by default (two curves each: a scene stays light).
DEFAULT_TRIALS = 10

_TARGET_RGB = (0.906, 0.435, 0.318)
_ENTRY_RGB = (0.149, 0.275, 0.325)
_PLAN_RGB = (1.0, 0.84, 0.0)
_CLOSED_RGB = (0.18, 0.62, 0.27)
_OPEN_RGB = (0.85, 0.33, 0.1)
#: The plan drawn as a 1 mm tube with small control points; the trials thinner, their
#: control points smaller still and their names not shown in the views (a dozen labels
#: would hide the anatomy; the Data module lists them).
_PLAN_STYLE = {"line_diameter_mm": 1.0, "glyph_scale": 1.5}
_TRIAL_STYLE = {"line_diameter_mm": 0.5, "glyph_scale": 0.75,
                "extra": {"propertiesLabelVisibility": "false"}}  # fmt: skip


def _rgb(css: str) -> tuple[float, float, float]:
    from matplotlib.colors import to_rgb

    return tuple(float(c) for c in to_rgb(css))


def structure_models(scene, *, max_cells: int = 256) -> list[SlicerModel]:
    """One Model per structure of a scene: its zero level set by marching cubes.

    Parameters
    ----------
    scene : needlekit.anatomy.scene.Scene
    max_cells : int
        Largest number of samples along an axis (a voxel mask is subsampled to it; a CT of
        512 voxels across is meshed every second voxel at 256).

    Returns
    -------
    list of SlicerModel
        In the scene's order; a structure whose surface does not cross the box meshed
        (unbounded, or empty) is left out. Faces are turned to face out of the structure
        (along its field's gradient).
    """
    box = scene.bounds()
    models = []
    for s in scene.structures:
        field = s.field.get() if isinstance(s.field, LazyField) else s.field
        v, f = surface_mesh(
            field, max_cells=max_cells, bounds=box if np.all(np.isfinite(box)) else None
        )
        if len(f) == 0:
            continue
        centres = v[f].mean(axis=1)
        normals = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
        if float(np.einsum("ij,ij->", field.gradient(centres), normals)) < 0.0:
            f = f[:, ::-1]
        css, opacity = structure_style(s)
        models.append(SlicerModel(s.name, v, f, color=_rgb(s.color or css), opacity=opacity))
    return models


def thin_path(points_mm, spacing_mm: float) -> np.ndarray:
    """A recorded path's points at least ``spacing_mm`` apart along it, the first and the
    last kept (repeated points dropped).

    Parameters
    ----------
    points_mm : array_like, shape (n, 3)
    spacing_mm : float
        > 0.

    Returns
    -------
    ndarray, shape (m, 3)

    Examples
    --------
    >>> thin_path([[0, 0, 0], [0.5, 0, 0], [1, 0, 0], [2.5, 0, 0], [3, 0, 0]], 1.0)[:, 0].tolist()
    [0.0, 1.0, 2.5, 3.0]
    """
    p, _ = as_points(points_mm, "points_mm")
    keep = [0]
    for i in range(1, len(p)):
        if np.linalg.norm(p[i] - p[keep[-1]]) >= spacing_mm:
            keep.append(i)
    if keep[-1] != len(p) - 1 and np.any(p[-1] != p[keep[-1]]):
        keep.append(len(p) - 1)
    return p[keep]


def _needles(plan_data: dict, where: str) -> list[tuple[int, np.ndarray, np.ndarray]]:
    """``(order, entry, target)`` of each placed needle of a multi-needle plan."""
    needles = plan_data.get("needles")
    if not isinstance(needles, list):
        raise InvalidInputError(where, "needles: expected a list")
    out = []
    for i, n in enumerate(needles):
        if not isinstance(n, dict):
            raise InvalidInputError(where, f"needles[{i}]: expected an object")
        if n.get("entry_mm") is None:
            continue  # a needle with no feasible entry: nothing to draw
        pair, _ = as_points([n.get("entry_mm"), n.get("target_mm")], f"{where}: needles[{i}]")
        out.append((int(n.get("order", i + 1)), pair[0], pair[1]))
    if not out:
        raise InvalidInputError(where, "holds no placed needle: nothing to export")
    return out


def case_markups(plan_data: dict, where: str, *, spacing_mm: float = 2.0) -> list[SlicerMarkup]:
    """The target and entry points and the plan of a ``plan.json`` or ``multi.json``.

    Parameters
    ----------
    plan_data : dict
        The document (a steerable plan, or a straight multi-needle plan: ``needles``).
    where : str
        Names it in messages.
    spacing_mm : float
        Largest spacing of a curve's control points.

    Returns
    -------
    list of SlicerMarkup
        ``target``, ``entry``, then ``plan`` (a Curve) or ``needle 1``, ... (Lines).
    """
    if "needles" in plan_data:
        needles = _needles(plan_data, where)
        return [
            SlicerMarkup(fiducials_markup([t for _, _, t in needles],
                                          [f"target {k}" for k, _, _ in needles],
                                          name="target", color=_TARGET_RGB)),
            SlicerMarkup(fiducials_markup([e for _, e, _ in needles],
                                          [f"entry {k}" for k, _, _ in needles],
                                          name="entry", color=_ENTRY_RGB)),
            *(SlicerMarkup(markups_line(e, t, name=f"needle {k}", color=_PLAN_RGB,
                                        description=f"planned needle {k}"), **_PLAN_STYLE)
              for k, e, t in needles),
        ]  # fmt: skip
    plan, goal = plan_from_dict(plan_data, where)
    if plan is None:
        status = plan_data.get("status", "unknown")
        raise InvalidInputError(where, f"holds no path (status {status!r}): nothing to export")
    points = plan.points_mm(float(spacing_mm))
    desc = f"{plan_data.get('planner', 'planner')} plan ({plan_data.get('status')}), {plan.length_mm:.2f} mm"
    return [
        SlicerMarkup(fiducials_markup([goal], ["target"], name="target", color=_TARGET_RGB)),
        SlicerMarkup(fiducials_markup([points[0]], ["entry"], name="entry", color=_ENTRY_RGB)),
        SlicerMarkup(markups_curve(points, name="plan", color=_PLAN_RGB, description=desc),
                     **_PLAN_STYLE),
    ]  # fmt: skip


def _check_execution_matches(plan_data: dict, execution: dict, where: str) -> None:
    """The execution was made from this plan: same primitives, or same needles."""
    if "needles" in plan_data:
        ours = [(e, t) for _, e, t in _needles(plan_data, "plan")]
        theirs = execution.get("plan_needles")
        if not isinstance(theirs, list):
            raise InvalidInputError(
                where, "does not execute a multi-needle plan (no plan_needles); the plan is one"
            )
        pairs = [as_points([n.get("entry_mm"), n.get("target_mm")], where)[0] for n in theirs
                 if isinstance(n, dict) and n.get("entry_mm") is not None]  # fmt: skip
        same = len(pairs) == len(ours) and all(
            np.allclose(p, np.stack(q), atol=1e-3) for p, q in zip(pairs, ours, strict=True)
        )
    else:
        prims = [[p.get("rotation_rad"), p.get("curvature_per_mm"), p.get("length_mm")]
                 for p in plan_data.get("primitives") or [] if isinstance(p, dict)]  # fmt: skip
        theirs = execution.get("plan_primitives")
        if not isinstance(theirs, list):
            raise InvalidInputError(
                where, "does not execute a steerable plan (no plan_primitives); the plan is one"
            )
        try:
            same = np.shape(theirs) == np.shape(prims) and np.allclose(
                np.asarray(theirs, dtype=float), np.asarray(prims, dtype=float), atol=1e-9
            )
        except (TypeError, ValueError):
            same = False
    if not same:
        raise InvalidInputError(where, "was made from another plan (its plan differs from PLAN)")


def execution_markups(
    plan_data: dict,
    execution: dict,
    where: str,
    *,
    trials: int = DEFAULT_TRIALS,
    spacing_mm: float = 2.0,
) -> list[SlicerMarkup]:
    """What an execution did, for its first ``trials`` trials.

    Parameters
    ----------
    plan_data : dict
        The plan carried out (checked to be the execution's).
    execution : dict
        ``execute.json`` as ``needlekit execute`` writes it.
    where : str
        Names the execution in messages.
    trials : int
        How many trials to draw (the first ones).
    spacing_mm : float
        Largest spacing kept between a recorded path's points.

    Returns
    -------
    list of SlicerMarkup
        Per trial, ``trial k closed loop`` and ``trial k open loop`` (Curves), or per
        needle ``trial k needle j`` (Lines).
    """
    _check_execution_matches(plan_data, execution, where)
    runs = execution.get("trials")
    if not isinstance(runs, list):
        raise InvalidInputError(where, "trials: expected a list")
    out: list[SlicerMarkup] = []
    if "needles" in plan_data:
        lengths = {k: float(np.linalg.norm(t - e)) for k, e, t in _needles(plan_data, "plan")}
        for i, run in enumerate(runs[:trials]):
            for j, n in enumerate(run.get("needles") or [] if isinstance(run, dict) else []):
                k = int(n.get("order", j + 1))
                if n.get("tip_mm") is None or n.get("axis") is None or k not in lengths:
                    continue  # not inserted (the trial stopped before it)
                tip, axis = as_points(
                    [n["tip_mm"], n["axis"]], f"{where}: trials[{i}].needles[{j}]"
                )[0]
                axis = axis / np.linalg.norm(axis)
                out.append(SlicerMarkup(markups_line(
                    tip - lengths[k] * axis, tip, name=f"trial {i + 1} needle {k}",
                    color=_CLOSED_RGB, description=f"{n.get('status')}: {n.get('error_mm')} mm to the target",
                ), **_TRIAL_STYLE))  # fmt: skip
        return out
    for i, run in enumerate(runs[:trials]):
        if not isinstance(run, dict):
            raise InvalidInputError(where, f"trials[{i}]: expected an object")
        for loop, label, rgb in (("closed_loop", "closed loop", _CLOSED_RGB),
                                 ("open_loop", "open loop", _OPEN_RGB)):  # fmt: skip
            rec = run.get(loop)
            if not isinstance(rec, dict) or not rec.get("points_mm"):
                continue  # a crashed trial records no path
            pts = thin_path(rec["points_mm"], spacing_mm)
            if len(pts) < 2:
                continue
            err = rec.get("final_error_mm")
            desc = f"{label}, trial {i + 1}" + (
                f": {err:.3f} mm to the target" if isinstance(err, float) else ""
            )
            out.append(SlicerMarkup(markups_curve(pts, name=f"trial {i + 1} {label}", color=rgb,
                                                  description=desc),
                                    curve_type="linear", **_TRIAL_STYLE))  # fmt: skip
    return out


def case_scene_parts(
    scene,
    plan_data: dict,
    plan_where: str,
    *,
    execution: dict | None = None,
    execution_where: str = "execution",
    trials: int = DEFAULT_TRIALS,
    spacing_mm: float = 2.0,
    max_cells: int = 256,
) -> tuple[list[SlicerModel], list[SlicerMarkup]]:
    """Everything of a case, ready for :func:`~needlekit.io.slicer_scene.write_slicer_scene`.

    Parameters
    ----------
    scene : needlekit.anatomy.scene.Scene
    plan_data, plan_where : dict, str
        The plan document and its name (:func:`case_markups`).
    execution, execution_where : dict or None, str
        An ``execute.json`` of this plan (:func:`execution_markups`).
    trials, spacing_mm, max_cells
        As :func:`execution_markups` and :func:`structure_models` take them.

    Returns
    -------
    models : list of SlicerModel
    markups : list of SlicerMarkup
    """
    markups = case_markups(plan_data, plan_where, spacing_mm=spacing_mm)
    if execution is not None:
        markups += execution_markups(plan_data, execution, execution_where,
                                     trials=trials, spacing_mm=spacing_mm)  # fmt: skip
    return structure_models(scene, max_cells=max_cells), markups
