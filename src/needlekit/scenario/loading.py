"""Scenario files: anatomy, needle, start, goal and planner settings in one YAML file.

The format is described in ``docs/scenarios.md`` and by the JSON Schema in
:mod:`needlekit.io.scenario_schema` (``needlekit schema`` prints it; that module reads
and checks the file, this one builds the scenario). A minimal file::

    version: 1
    base: {phantom: {name: lung, seed: 0}}
    start: {case_start: 1}
    goal: {case_target: 1, tolerance_mm: 1.0}

Every error names the file, the field (``structures[2].sphere.radius_mm``) and what was
expected, in one line; nothing but :class:`~needlekit.errors.NeedlekitError` comes out of
:func:`load_scenario` for a bad file.
"""

from __future__ import annotations

import logging
import os
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from needlekit.anatomy.fields import (
    LazyField,
)
from needlekit.anatomy.scene import Scene
from needlekit.constants import (
    DEFAULT_GOAL_TOLERANCE_MM,
    DEFAULT_MAX_HEADING_CHANGE_DEG,
    DEFAULT_MAX_LENGTH_MM,
    DEFAULT_NEEDLE_DIAMETER_MM,
    DEFAULT_R_MIN_MM,
    DEFAULT_START_EXCLUSION_MM,
    MM_WARNING_MIN_EXTENT_MM,
)
from needlekit.errors import InvalidInputError
from needlekit.geometry.se3 import pose_from_direction
from needlekit.io.poses import read_point_txt, read_pose_txt
from needlekit.io.scenario_schema import (
    checked_document,
    read_scenario_document,
)
from needlekit.scenario._blocks import (  # the document's blocks
    _LPS_TO_RAS,
    _base,
    _case_starts,
    _case_targets,
    _combined,
    _Ctx,
    _dropped,
    _moving,
    _pick,
    _straight,
    _structure,
)
from needlekit.scenario.extent import anatomy_box, check_inside_anatomy

_log = logging.getLogger(__name__)

__all__ = [
    "GoalSpec",
    "NeedleSpec",
    "Scenario",
    "StartSpec",
    "load_scenario",
    "parse_scenario",
    "read_scenario_document",
]


@dataclass(frozen=True)
class NeedleSpec:
    """The needle and its limits (defaults as in the schema).

    Attributes
    ----------
    diameter_mm, r_min_mm, max_length_mm, safety_margin_mm : float
    max_heading_change_deg : float
        Largest change of direction along the path.
    min_puncture_angle_deg : float
        Smallest angle between the needle and the entry surface (Feng's alpha).
    start_exclusion_mm : float
        Obstacles within this distance of the start are ignored (the needle leaves the
        airway through its wall).
    """

    diameter_mm: float = DEFAULT_NEEDLE_DIAMETER_MM
    r_min_mm: float = DEFAULT_R_MIN_MM
    max_length_mm: float = DEFAULT_MAX_LENGTH_MM
    safety_margin_mm: float = 0.0
    max_heading_change_deg: float = DEFAULT_MAX_HEADING_CHANGE_DEG
    min_puncture_angle_deg: float = 0.0
    start_exclusion_mm: float = DEFAULT_START_EXCLUSION_MM

    @property
    def clearance_margin_mm(self) -> float:
        """Needle radius plus safety margin: the clearance a path must keep (mm)."""
        return 0.5 * self.diameter_mm + self.safety_margin_mm


@dataclass(frozen=True)
class StartSpec:
    """Where the needle starts.

    Attributes
    ----------
    point_mm : ndarray, shape (3,)
        Start point (RAS mm).
    world_T_tip : ndarray, shape (4, 4) or None
        Full start pose when the direction is fixed; None for a start point only (the
        planner sweeps directions).
    name : str
        Where it came from (``"start2"``, a file name, ``"pose"``).
    """

    point_mm: np.ndarray
    world_T_tip: np.ndarray | None
    name: str = ""


@dataclass(frozen=True)
class GoalSpec:
    """Target point (RAS mm) and tolerance (mm)."""

    point_mm: np.ndarray
    tolerance_mm: float = DEFAULT_GOAL_TOLERANCE_MM
    name: str = ""


@dataclass(frozen=True)
class Scenario:
    """A loaded scenario.

    Attributes
    ----------
    name, description : str
    scene : Scene
    needle : NeedleSpec
    start : StartSpec or None
    goal : GoalSpec or None
    planner : dict
        ``name``, ``time_limit_s``, ``seed``, ``options`` as given (validated by the
        schema; interpreted by the planners).
    path : Path or None
        The file it was read from.
    base : object or None
        The phantom or Med-RAD case the scene was built from.
    collision_model : str
        A registered collision checker's name: ``"field"``, ``"voxel_centres"`` or a
        user's own (:mod:`needlekit.anatomy.collision_registry`).
    collision_options : dict
        The checker's own settings (``collision_options``).
    straight : dict
        The ``straight`` block (straight multi-needle planning), its ``targets`` resolved to
        points (mm, RAS) and its ``deformation`` grid path made absolute.
    moving : dict
        Per moving obstacle's name, its ``moving`` block in RAS (``velocity_mm_s``,
        ``amplitude_mm``, ``period_s``, ``phase_deg``; ``Motion`` arguments).
    dynamic : dict
        The ``dynamic`` block as given (``plan --dynamic``).
    static_scene : Scene or None
        With moving obstacles, the scene without them (the anatomy that stays put).
    """

    name: str
    description: str
    scene: Scene
    needle: NeedleSpec
    start: StartSpec | None
    goal: GoalSpec | None
    planner: dict = field(default_factory=dict)
    path: Path | None = None
    base: Any = None
    collision_model: str = "field"
    straight: dict = field(default_factory=dict)
    moving: dict = field(default_factory=dict)
    dynamic: dict = field(default_factory=dict)
    static_scene: Scene | None = None
    collision_options: dict = field(default_factory=dict)


# ----------------------------------------------------------------------------------------
# building


def _start(spec: dict, ctx: _Ctx, base) -> StartSpec:
    given = [k for k in ("pose", "pose_file", "case_start", "point_mm") if k in spec]
    if len(given) != 1:
        raise ctx.error("start", "give exactly one of pose, pose_file, case_start, point_mm")
    if "direction" in spec and given[0] != "point_mm":
        raise ctx.error("start.direction", "only goes with start.point_mm")
    k = given[0]
    if k == "pose":
        g = ctx.pose(spec["pose"], "start.pose")
        return StartSpec(g[:3, 3].copy(), g, "pose")
    if k == "pose_file":
        path = ctx.file(spec["pose_file"], "start.pose_file")
        g = read_pose_txt(path)
        g = _LPS_TO_RAS @ g if ctx.lps else g
        return StartSpec(g[:3, 3].copy(), g, path.name)
    if k == "case_start":
        name, g = _pick(_case_starts(base), spec["case_start"], "start", ctx, "start.case_start")
        return StartSpec(g[:3, 3].copy(), np.array(g), name)
    point = ctx.point(spec["point_mm"])
    if "direction" not in spec:
        return StartSpec(point, None, "point")

    d = ctx.point(spec["direction"])
    big = float(np.max(np.abs(d)))  # > 1e-12: the document's check refused less
    # scaled first: the norm of a huge vector would overflow; the frame is the one sweeps
    # give the same direction
    g = pose_from_direction(point, d / big)
    return StartSpec(point, g, "point+direction")


def _goal(spec: dict, ctx: _Ctx, base) -> GoalSpec:
    given = [k for k in ("point_mm", "point_file", "case_target") if k in spec]
    if len(given) != 1:
        raise ctx.error("goal", "give exactly one of point_mm, point_file, case_target")
    tol = float(spec.get("tolerance_mm", DEFAULT_GOAL_TOLERANCE_MM))
    k = given[0]
    if k == "point_mm":
        return GoalSpec(ctx.point(spec["point_mm"]), tol, "point")
    if k == "point_file":
        path = ctx.file(spec["point_file"], "goal.point_file")
        return GoalSpec(ctx.point(read_point_txt(path)), tol, path.name)
    name, p = _pick(_case_targets(base), spec["case_target"], "target", ctx, "goal.case_target")
    return GoalSpec(np.array(p, dtype=float), tol, name)


def parse_scenario(
    data: Any,
    *,
    base_dir: str | os.PathLike = ".",
    source: str = "scenario",
    cache_dir: str | os.PathLike | None = None,
    use_cache: bool = True,
    share_base: bool = False,
) -> Scenario:
    """Validate and build a scenario from already-parsed YAML/JSON data.

    Parameters
    ----------
    data : dict
        The document.
    base_dir : path-like
        Folder that relative file paths are resolved against.
    source : str
        Name used in error messages (usually the file name).
    cache_dir : path-like, optional
        Root of the prepared-anatomy cache of a Med-RAD base (default: the user cache).
    use_cache : bool
        Use that cache (see :func:`needlekit.io.medrad.load_medrad`).
    share_base : bool
        Load a Med-RAD base once per process (:func:`needlekit.batch.worker_cached`) and
        share it, with the fields built on it, between the scenarios of that patient (a
        batch worker running several targets of one patient prepares it once).

    Returns
    -------
    Scenario

    Raises
    ------
    InvalidInputError
        ``"<source>: <field>: <what was expected>"``.
    """
    data = checked_document(data, source)  # a document checked already is not checked again
    ctx = _Ctx(source, Path(base_dir), data.get("frame", "RAS"))
    cache = {"cache_dir": cache_dir, "use_cache": use_cache}
    names: set[str] = set()
    # the file's own structures first: a bad one is named before a patient is loaded
    extra = [_structure(i, s, ctx, names) for i, s in enumerate(data.get("structures", []))]
    base = _base(data["base"], ctx, cache, share_base) if "base" in data else None
    if base is not None:
        base_scene = _dropped(base.scene, data["base"], ctx)
        clash = names & set(base_scene.names)
        if clash:
            raise ctx.error(
                "structures", f"names already in the base scene: {', '.join(sorted(clash))}"
            )
        structures = list(base_scene.structures) + extra
        obstacle = _combined(base_scene, extra)
    else:
        structures, obstacle = extra, None
    if not structures:
        raise ctx.error("structures", "the scenario has no structures (add some or a base)")
    _check_masks_overlap(data.get("structures", []), extra, structures, ctx)
    scene_name = base.scene.name if base is not None else data.get("name", "")
    scene = Scene(structures, name=scene_name, obstacle_field=obstacle)
    moving = _moving(data.get("structures", []), ctx)
    static_scene = None
    if moving:  # the anatomy that stays put: the scene without the moving obstacles
        kept = [s for s in extra if s.name not in moving]
        static_scene = Scene(
            [s for s in structures if s.name not in moving],
            name=scene_name,
            obstacle_field=None if base is None else _combined(base_scene, kept),
        )
    needle = NeedleSpec(**data.get("needle", {}))
    start = _start(data["start"], ctx, base) if "start" in data else None
    goal = _goal(data["goal"], ctx, base) if "goal" in data else None
    _warn_if_not_mm(scene, source)
    straight = _straight(data.get("straight"), ctx, base, goal, structures)
    _check_points_inside(scene, data, start, goal, straight, ctx)
    return Scenario(
        data.get("name", ""),
        data.get("description", ""),
        scene,
        needle,
        start,
        goal,
        dict(data.get("planner", {})),
        None,
        base,
        data.get("collision_model", "field"),
        straight,
        moving,
        dict(data.get("dynamic", {})),
        static_scene,
        dict(data.get("collision_options", {})),
    )


def _check_points_inside(scene: Scene, data: dict, start, goal, straight: dict, ctx) -> None:
    """The start, the goal and the straight block's targets lie where the anatomy is
    (:func:`needlekit.scenario.extent.check_inside_anatomy`), each named by its field."""
    box = anatomy_box(scene)
    if box is None:
        return
    points = []
    if start is not None:
        given = [k for k in ("pose", "pose_file", "case_start", "point_mm") if k in data["start"]]
        points.append((start.point_mm, "start." + given[0]))
    if goal is not None:
        given = [k for k in ("point_mm", "point_file", "case_target") if k in data["goal"]]
        points.append((goal.point_mm, "goal." + given[0]))
    targets = straight.get("targets")
    if isinstance(targets, np.ndarray) and "targets" in (data.get("straight") or {}):
        points += [(t, f"straight.targets[{i}]") for i, t in enumerate(targets)]
    for point, where in points:
        try:
            check_inside_anatomy(point, box, where)
        except InvalidInputError as exc:
            raise ctx.error(where, exc.reason) from None


def _cheap_extent_mm(scene: Scene) -> float | None:
    """Largest side (mm) of the box around the bounded structures, from the bounds that
    are known without building a field (lazy fields not built yet are left out); None
    when no structure is bounded and known."""
    boxes = []
    for s in scene.structures:
        if isinstance(s.field, LazyField) and not s.field.built:
            continue
        b = np.asarray(s.field.bounds(), dtype=float)
        if np.all(np.isfinite(b)):
            boxes.append(b)
    if not boxes:
        return None
    b = np.stack(boxes)
    return float(np.max(b[:, 1].max(axis=0) - b[:, 0].min(axis=0)))


def _check_masks_overlap(specs: list, extra: list, structures: list, ctx) -> None:
    """Each mask the file adds lies where the rest of the anatomy is: its set voxels' box
    meets the box of the other structures (the base's and the file's own bounded ones). A
    mask whose affine places it elsewhere (another volume's mask, a wrong origin, LPS read
    as RAS) is an error naming its file, not an obstacle planned around far away."""
    for i, (spec, st) in enumerate(zip(specs, extra, strict=True)):
        if "mask" not in spec:
            continue
        others = [
            b
            for b in (o.field.bounds() for o in structures if o is not st)
            if np.all(np.isfinite(b))
        ]
        if not others:
            continue
        lo = np.min([b[0] for b in others], axis=0)
        hi = np.max([b[1] for b in others], axis=0)
        box = st.field.bounds()
        if np.all(box[0] <= hi) and np.all(box[1] >= lo):
            continue
        raise ctx.error(
            f"structures[{i}].mask.path",
            f"{st.source}: its set voxels span {np.round(box, 1).tolist()} mm, outside the "
            f"anatomy the other structures span {np.round([lo, hi], 1).tolist()} mm (a mask "
            "of another volume, or a wrong affine?)",
        )


def _warn_if_not_mm(scene: Scene, source: str) -> None:
    """Log a warning when the anatomy's size looks like centimetres or metres, not
    millimetres (each length field is held to its range when the document is checked:
    :mod:`needlekit.plausibility`)."""
    extent = _cheap_extent_mm(scene)
    if extent is not None and extent < MM_WARNING_MIN_EXTENT_MM:
        _log.warning(
            "%s: the anatomy is only %.3g mm across; lengths in scenario files are "
            "millimetres (was it written in cm or m?)",
            source,
            extent,
        )


def load_scenario(
    path: str | os.PathLike,
    *,
    cache_dir: str | os.PathLike | None = None,
    use_cache: bool = True,
    document: dict | None = None,
    share_base: bool = False,
) -> Scenario:
    """Read a scenario file (YAML or JSON).

    Parameters
    ----------
    path : path-like
    cache_dir : path-like, optional
        Root of the prepared-anatomy cache of a Med-RAD base (default: the user cache).
    use_cache : bool
        Use that cache (see :func:`needlekit.io.medrad.load_medrad`).
    document : dict, optional
        The file's document as :func:`read_scenario_document` returned it (read and
        checked already, e.g. by the command line before importing the anatomy); default:
        read the file.
    share_base : bool
        Load a Med-RAD base once per process for every scenario of that patient
        (:func:`parse_scenario`; batch workers).

    Returns
    -------
    Scenario

    Raises
    ------
    InvalidInputError
        Missing or unreadable file, bad YAML, or any field not as the schema says; the
        message names the file and the field.
    """
    p = Path(path)
    data = read_scenario_document(p) if document is None else document
    sc = parse_scenario(
        data,
        base_dir=p.parent,
        source=p.name,
        cache_dir=cache_dir,
        use_cache=use_cache,
        share_base=share_base,
    )
    return replace(sc, path=p)
