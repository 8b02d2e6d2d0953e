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

from needlekit._validation import as_poses
from needlekit.anatomy.fields import (
    ComplementField,
    DistanceField,
    LazyField,
    TransformedField,
    union,
)
from needlekit.anatomy.scene import Role, Scene, Structure
from needlekit.constants import (
    DEFAULT_GOAL_TOLERANCE_MM,
    DEFAULT_MAX_HEADING_CHANGE_DEG,
    DEFAULT_MAX_LENGTH_MM,
    DEFAULT_NEEDLE_DIAMETER_MM,
    DEFAULT_R_MIN_MM,
    DEFAULT_START_EXCLUSION_MM,
    MM_WARNING_MIN_EXTENT_MM,
    MM_WARNING_MIN_R_MIN_MM,
)
from needlekit.errors import InvalidInputError
from needlekit.io.scenario_schema import (
    SOURCE_KINDS,
    checked_document,
    read_scenario_document,
)
from needlekit.planning.steerable.moving import Motion
from needlekit.planning.straight.coverage import AblationZone

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

#: RAS <- LPS (and back): a rotation by pi about z.
_LPS_TO_RAS = np.diag([-1.0, -1.0, 1.0, 1.0])


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


class _Ctx:
    def __init__(self, source: str, base_dir: Path, frame: str) -> None:
        self.source = source
        self.base_dir = base_dir
        self.lps = frame == "LPS"

    def error(self, where: str, msg: str) -> InvalidInputError:
        return InvalidInputError(f"{self.source}: {where}", msg)

    def file(self, rel: str, where: str) -> Path:
        p = Path(rel)
        p = p if p.is_absolute() else self.base_dir / p
        if not p.is_file():
            raise self.error(where, f"file {p} not found")
        return p

    def point(self, v) -> np.ndarray:
        p = np.asarray(v, dtype=np.float64)
        return _LPS_TO_RAS[:3, :3] @ p if self.lps else p

    def raw_pose(self, m, where: str) -> np.ndarray:
        """A 4x4 rigid pose as written in the file's frame."""
        try:
            g, _ = as_poses(np.asarray(m, dtype=np.float64), where)
        except InvalidInputError as exc:
            raise self.error(where, exc.reason) from None
        return g[0]

    def pose(self, m, where: str) -> np.ndarray:
        """A 4x4 rigid pose in RAS."""
        g = self.raw_pose(m, where)
        return _LPS_TO_RAS @ g if self.lps else g

    def placed(self, f: DistanceField) -> DistanceField:
        return TransformedField(f, _LPS_TO_RAS) if self.lps else f


def _primitive(kind: str, spec: dict, ctx: _Ctx, where: str) -> DistanceField:
    from needlekit.anatomy import primitives as P

    # parameters and pose stay in the file's frame; placed() moves the shape to RAS
    pose = ctx.raw_pose(spec["pose"], f"{where}.pose") if "pose" in spec else None
    try:
        if kind == "sphere":
            f = P.Sphere(spec["center_mm"], spec["radius_mm"])
        elif kind == "ellipsoid":
            f = P.Ellipsoid(spec["semi_axes_mm"], pose)
        elif kind == "capsule":
            f = P.Capsule(spec["p0_mm"], spec["p1_mm"], spec["radius_mm"])
        elif kind == "cylinder":
            f = P.Cylinder(spec["p0_mm"], spec["p1_mm"], spec["radius_mm"])
        elif kind == "box":
            f = P.Box(spec["half_extents_mm"], pose)
        elif kind == "half_space":
            f = P.HalfSpace(spec["point_mm"], spec["normal_mm"])
        else:
            f = P.Superquadric(spec["semi_axes_mm"], spec["exponents"], pose)
    except InvalidInputError as exc:
        raise ctx.error(f"{where}.{exc.field}", exc.reason) from None
    return ctx.placed(f)


def _structure(i: int, spec: dict, ctx: _Ctx, names: set[str]) -> Structure:
    where = f"structures[{i}]"
    kinds = [k for k in SOURCE_KINDS if k in spec]
    if len(kinds) != 1:
        got = ", ".join(kinds) if kinds else "none"
        raise ctx.error(where, f"needs exactly one source ({', '.join(SOURCE_KINDS)}); got {got}")
    kind = kinds[0]
    name = spec["name"]
    if name in names:
        raise ctx.error(f"{where}.name", f"duplicate structure name {name!r}")
    names.add(name)
    src = spec[kind]
    sub = f"{where}.{kind}"
    if kind == "mask":
        from needlekit.anatomy.voxel import VoxelSDF
        from needlekit.io.volumes import Mask, read_mask

        path = ctx.file(src["path"], f"{sub}.path")
        mask = read_mask(path, allow_empty="label" in src)
        if "label" in src:
            raise ctx.error(f"{sub}.label", "label maps are not supported yet; give a binary mask")
        field_ = VoxelSDF.from_mask(Mask(mask.data, mask.affine, path))
        source = str(path)
    elif kind == "mesh":
        from needlekit.anatomy.mesh import default_voxel_size_mm, voxelize_mesh_sdf
        from needlekit.io.meshes import read_mesh

        path = ctx.file(src["path"], f"{sub}.path")
        mesh = read_mesh(path)
        kw = {k: src[k] for k in ("padding_mm",) if k in src}
        voxel = src.get("voxel_size_mm", default_voxel_size_mm(mesh))
        field_ = ctx.placed(voxelize_mesh_sdf(mesh, voxel, **kw))
        source = str(path)
    else:
        field_ = _primitive(kind, src, ctx, sub)
        source = f"{kind} {src}"
    return Structure(
        name, Role.parse(spec["role"], f"{where}.role"), field_, spec.get("color"), source
    )


def _base(spec: dict, ctx: _Ctx, cache: dict | None = None, share: bool = False):
    if "phantom" in spec:
        from needlekit.anatomy.phantoms import make_phantom

        p = spec["phantom"]
        kw = {"voxel_size_mm": p["voxel_size_mm"]} if "voxel_size_mm" in p else {}
        return make_phantom(p["name"], p.get("seed", 0), **kw)
    from needlekit.io.medrad import load_medrad

    m = spec["medrad"]
    root = (
        ctx.base_dir / m["root"]
        if "root" in m and not Path(m["root"]).is_absolute()
        else m.get("root")
    )
    cache = dict(cache or {})
    key = _medrad_key(m["organ"], m["patient"], root, cache) if share else None
    if key is None:
        return load_medrad(m["organ"], m["patient"], root, **cache)
    from needlekit.batch import worker_cached

    return worker_cached(key, lambda: load_medrad(m["organ"], m["patient"], root, **cache))


def _medrad_key(organ, patient, root, cache: dict) -> tuple | None:
    """What identifies a loaded Med-RAD case in this process: organ, patient, the patient's
    folder and its files (names, sizes, times), the cache settings; None when the folder is
    not there (loading then says why)."""
    from needlekit.io.medrad_paths import patient_folder

    try:
        folder = patient_folder(organ, patient, root)
    except InvalidInputError:
        return None
    files = tuple(
        (str(f), st.st_size, st.st_mtime_ns) for f in sorted(folder.iterdir()) for st in (f.stat(),)
    )
    cache_dir = cache.get("cache_dir")
    cache_dir = None if cache_dir is None else str(Path(cache_dir).expanduser().resolve())
    return (
        "MedradCase", str(organ).lower(), int(patient), str(folder), files,
        cache_dir, bool(cache.get("use_cache", True)),
    )  # fmt: skip


def _dropped(scene: Scene, spec: dict, ctx: _Ctx) -> Scene:
    """The base scene without the structures ``phantom.drop`` names (its combined
    obstacle field rebuilt from the rest)."""
    drop = spec.get("phantom", {}).get("drop", [])
    if not drop:
        return scene
    for i, n in enumerate(drop):
        if n not in scene.names:
            have = ", ".join(scene.names)
            raise ctx.error(f"base.phantom.drop[{i}]", f"no structure named {n!r} (have {have})")
    kept = [s for s in scene.structures if s.name not in drop]
    return Scene(kept, name=scene.name)


def _case_starts(base) -> list[tuple[str, np.ndarray]]:
    if base is None:
        return []
    if hasattr(base, "starts"):  # Med-RAD case
        return [(s.name, s.world_T_tip) for s in base.starts]
    return [(f"start{i + 1}", g) for i, g in enumerate(base.start_poses)]


def _case_targets(base) -> list[tuple[str, np.ndarray]]:
    if base is None:
        return []
    if hasattr(base, "targets_mm") and isinstance(base.targets_mm, dict):
        return sorted(base.targets_mm.items())
    return [(f"target{i + 1}", p) for i, p in enumerate(np.atleast_2d(base.targets_mm))]


def _pick(items: list[tuple[str, np.ndarray]], key, what: str, ctx: _Ctx, where: str):
    if not items:
        raise ctx.error(where, f"{what} needs a base (phantom or medrad) that defines them")
    names = [n for n, _ in items]
    if isinstance(key, int) and not isinstance(key, bool):
        if not 1 <= key <= len(items):
            raise ctx.error(where, f"expected 1 to {len(items)}, got {key}")
        return items[key - 1]
    for n, v in items:
        if n == key:
            return n, v
    raise ctx.error(where, f"no {what} named {key!r} (have {', '.join(names)})")


def _straight(spec, ctx: _Ctx, base, goal, structures=()) -> dict:
    """The straight block with its targets as points and file paths made absolute."""
    if spec is None:
        return {}
    out = dict(spec)
    if spec.get("targets") == "coverage":
        out["coverage"] = _coverage(spec.get("coverage") or {}, ctx, base, structures)
        if "up" in spec:
            out["up"] = ctx.point(spec["up"])
        return _straight_deformation(out, spec, ctx)
    if "coverage" in spec:
        raise ctx.error("straight.coverage", "only goes with targets: coverage")
    targets = []
    for i, t in enumerate(spec.get("targets", [])):
        if isinstance(t, list):
            targets.append(ctx.point(t))
        else:
            targets.append(
                np.array(_pick(_case_targets(base), t, "target", ctx, f"straight.targets[{i}]")[1])
            )
    if not targets:
        if goal is None:
            raise ctx.error("straight.targets", "give targets, or a goal")
        targets = [goal.point_mm]
    out["targets"] = np.array(targets, dtype=float)
    if "up" in spec:
        out["up"] = ctx.point(spec["up"])  # a direction: LPS files turn it as points
    return _straight_deformation(out, spec, ctx)


def _straight_deformation(out: dict, spec: dict, ctx: _Ctx) -> dict:
    deformation = spec.get("deformation")
    if isinstance(deformation, dict):
        out["deformation"] = {
            "grid": str(ctx.file(deformation["grid"], "straight.deformation.grid"))
        }
    return out


def _coverage(spec: dict, ctx: _Ctx, base, structures) -> dict:
    """The coverage block with its defaults, the zone checked and the tumour named."""

    z = dict(spec.get("zone") or {"kind": "ellipsoid"})
    kind = z["kind"]
    where = "straight.coverage.zone"
    if kind == "sphere":
        wrong = [k for k in ("length_mm", "diameter_mm") if k in z]
        if wrong or "radius_mm" not in z:
            raise ctx.error(where, "a sphere takes radius_mm (not length_mm, diameter_mm)")
        lengths = (2.0 * z["radius_mm"], 2.0 * z["radius_mm"])
    else:
        if "radius_mm" in z:
            raise ctx.error(f"{where}.radius_mm", "only for kind: sphere")
        lengths = (z.get("length_mm", 30.0), z.get("diameter_mm", 20.0))
        if lengths[0] < lengths[1]:
            raise ctx.error(
                f"{where}.length_mm",
                f"the zone is longest along the needle: length_mm {lengths[0]:g} < "
                f"diameter_mm {lengths[1]:g}",
            )
    zone = AblationZone(kind, *lengths, z.get("tip_offset_mm", 0.0))
    targets = [s.name for s in structures if s.role is Role.TARGET]
    name = spec.get("structure")
    if name is None:
        if not targets:
            raise ctx.error("straight.coverage.structure", "the scene has no target structure")
        name = targets[0]
    elif name not in {s.name for s in structures}:
        raise ctx.error(
            "straight.coverage.structure",
            f"no structure named {name!r} (targets: {', '.join(targets) or 'none'})",
        )
    return {
        "zone": zone,
        "margin_mm": float(spec.get("margin_mm", 5.0)),
        "max_needles": int(spec.get("max_needles", 6)),
        "coverage_goal": float(spec.get("coverage_goal", 1.0)),
        "structure": name,
        "voxel_mm": float(spec.get("voxel_mm", 1.0)),
        "clip_to_body": bool(spec.get("clip_to_body", True)),
    }


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
        from needlekit.io.poses import read_pose_txt

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
    from needlekit.geometry.se3 import pose_from_direction

    d = ctx.point(spec["direction"])
    big = float(np.max(np.abs(d)))
    if not big > 1e-12:
        raise ctx.error("start.direction", "must be a non-zero vector")
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
        from needlekit.io.poses import read_point_txt

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
    base = _base(data["base"], ctx, cache, share_base) if "base" in data else None
    names: set[str] = set()
    extra = [_structure(i, s, ctx, names) for i, s in enumerate(data.get("structures", []))]
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
    _warn_if_not_mm(scene, needle, source)
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
        _straight(data.get("straight"), ctx, base, goal, structures),
        moving,
        dict(data.get("dynamic", {})),
        static_scene,
        dict(data.get("collision_options", {})),
    )


def _moving(specs: list, ctx: _Ctx) -> dict:
    """The structures' ``moving`` blocks, checked, in RAS (by name)."""

    out = {}
    for i, spec in enumerate(specs):
        if "moving" not in spec:
            continue
        where = f"structures[{i}].moving"
        if spec["role"] != "obstacle":
            raise ctx.error(where, f"only obstacles move; this structure is a {spec['role']}")
        m = spec["moving"]
        kw = {k: ctx.point(m[k]) for k in ("velocity_mm_s", "amplitude_mm") if k in m}
        kw.update({k: m[k] for k in ("period_s", "phase_deg") if k in m})
        if "period_s" in m and "amplitude_mm" not in m:
            raise ctx.error(f"{where}.period_s", "a period needs amplitude_mm")
        try:
            Motion(**kw)
        except InvalidInputError as exc:
            raise ctx.error(f"{where}.{exc.field}", exc.reason) from None
        out[spec["name"]] = kw
    return out


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


def _warn_if_not_mm(scene: Scene, needle: NeedleSpec, source: str) -> None:
    """Log a warning when the sizes look like centimetres or metres, not millimetres."""
    extent = _cheap_extent_mm(scene)
    if extent is not None and extent < MM_WARNING_MIN_EXTENT_MM:
        _log.warning(
            "%s: the anatomy is only %.3g mm across; lengths in scenario files are "
            "millimetres (was it written in cm or m?)",
            source,
            extent,
        )
    if needle.r_min_mm < MM_WARNING_MIN_R_MIN_MM:
        _log.warning(
            "%s: needle.r_min_mm is %.3g mm; lengths in scenario files are millimetres "
            "(was it written in cm or m?)",
            source,
            needle.r_min_mm,
        )


def _combined(base_scene: Scene, extra: list[Structure]) -> DistanceField | None:
    """The base's combined obstacle field extended by extra obstacles and regions."""
    try:
        base_field = base_scene.obstacle_field()
    except InvalidInputError:
        return None
    parts = [s.field for s in extra if s.role is Role.OBSTACLE]
    parts += [ComplementField(s.field) for s in extra if s.role is Role.ALLOWED_REGION]
    return union(base_field, *parts)


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
