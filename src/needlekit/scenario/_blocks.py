"""The blocks of a scenario document turned into objects: structures and their
primitives, the base (a phantom, a Med-RAD case) and the structures it drops, the case's
starts and targets picked by number or name, moving blocks, the straight block with its
coverage and deformation; and the context that names the file and field in every error.

Used by :mod:`needlekit.scenario.loading` (which assembles the
:class:`~needlekit.scenario.loading.Scenario`); the document was checked against the schema
before any of this runs.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from needlekit._validation import as_poses
from needlekit.anatomy import primitives as P
from needlekit.anatomy.fields import ComplementField, DistanceField, TransformedField, union
from needlekit.anatomy.scene import Role, Scene, Structure
from needlekit.batch import worker_cached
from needlekit.errors import InvalidInputError
from needlekit.io.medrad_paths import patient_folder
from needlekit.io.scenario_schema import SOURCE_KINDS
from needlekit.planning.steerable.moving_obstacles import Motion
from needlekit.planning.straight.coverage import AblationZone

#: RAS <- LPS (and back): a rotation by pi about z.
_LPS_TO_RAS = np.diag([-1.0, -1.0, 1.0, 1.0])


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
        try:
            sdf = voxelize_mesh_sdf(mesh, voxel, **kw)
        except InvalidInputError as exc:
            if exc.field == "voxel_size_mm":  # a grid too big for memory: name the field
                raise ctx.error(f"{sub}.voxel_size_mm", exc.reason) from None
            if exc.field == "mesh":  # the mesh itself (not closed): name its file
                raise ctx.error(f"{sub}.path", f"{path}: mesh {exc.reason}") from None
            raise
        field_ = ctx.placed(sdf)
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

    return worker_cached(key, lambda: load_medrad(m["organ"], m["patient"], root, **cache))


def _medrad_key(organ, patient, root, cache: dict) -> tuple | None:
    """What identifies a loaded Med-RAD case in this process: organ, patient, the patient's
    folder and its files (names, sizes, times), the cache settings; None when the folder is
    not there (loading then says why)."""
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
    # the coverage package (its planners) only when a scenario has a coverage block
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


def _combined(base_scene: Scene, extra: list[Structure]) -> DistanceField | None:
    """The base's combined obstacle field extended by extra obstacles and regions."""
    try:
        base_field = base_scene.obstacle_field()
    except InvalidInputError:
        return None
    parts = [s.field for s in extra if s.role is Role.OBSTACLE]
    parts += [ComplementField(s.field) for s in extra if s.role is Role.ALLOWED_REGION]
    return union(base_field, *parts)
