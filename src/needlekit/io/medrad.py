"""Reader for the Med-RAD anatomical dataset (lungs and livers) into needlekit scenes.

Med-RAD (UNC Robotics; CC BY-NC-SA 4.0) holds binary segmentations (``.nii.gz``, RAS
affines), start poses (4x4 text files, RAS mm, z axis = insertion direction) and target
points (RAS mm). needlekit never copies it: it is read from ``root``, the environment
variable ``NEEDLEKIT_MEDRAD``, or ``../shared/data/med-rad`` beside the working directory
or the source tree, in that order.

Lungs (``Lungs/TumorTargetEnvironments/PatientN``)
    ``pleuralBoundary`` (allowed region), ``bronchialTree``, ``vessels``, ``fissures``
    (obstacles), ``nodule`` (target), ``start1..5.txt``, ``target.txt``. The starts lie on
    the airway wall: a transbronchial needle leaves the airway through its wall.
Livers (``Liver/PatientN``)
    ``liver`` (allowed region), hepatic artery, hepatic vein and portal vein (obstacles),
    one or more nodules (targets), targets and starts in any of the patients' naming
    schemes (``target.txt``/``start1.txt``, ``target2.txt``/``target2_start1.txt``,
    ``nodule2_start1.txt``); file names are matched case-insensitively.

Distance fields are built for what planning needs first: one signed distance transform of
the *free space* (allowed region and nodules, minus all obstacles), whose complement is the
scene's combined obstacle field. The nodules belong to it because Med-RAD's liver masks
leave them out: a target must never count as an obstacle. Each structure's own field is built lazily on first use.

Prepared once: by default what loading builds (the masks on one grid, the free space, its
signed distance field and the obstacle voxels) is stored in the prepared-anatomy cache
(:mod:`needlekit.io.anatomy_cache`) under a key made of the mask files' *content* and the
settings, and every structure's own field joins the entry the first time it is built; the
next load maps them from disk (read-only memory maps) instead of reading and transforming
the masks again, with the same arrays bit for bit. ``use_cache=False`` skips it.
"""

from __future__ import annotations

import logging
import os
import re
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from needlekit.anatomy.fields import ComplementField, LazyField
from needlekit.anatomy.scene import Role, Scene, Structure
from needlekit.anatomy.voxel import DEFAULT_MASK_PADDING_MM, MASK_OFFSET_MAX_FRACTION, VoxelSDF
from needlekit.anatomy.voxel_local import local_mask_sdf, preview_mask_sdf
from needlekit.errors import InvalidInputError
from needlekit.io import anatomy_cache
from needlekit.io.medrad_paths import (  # noqa: F401 - re-exported
    _ORGANS,
    MEDRAD_ENV,
    _organ,
    _repo_candidates,
    list_patients,
    medrad_root,
    patient_folder,
)
from needlekit.io.poses import read_point_txt, read_pose_txt
from needlekit.io.volumes import Mask, read_mask

__all__ = [
    "MEDRAD_ENV",
    "MedradCase",
    "StartPose",
    "list_patients",
    "load_medrad",
    "medrad_root",
]

# (file stem, lower case) -> (structure name, role, display colour)
_LUNG = {
    "pleuralboundary": ("pleuralBoundary", Role.ALLOWED_REGION, "#9ecae1"),
    "bronchialtree": ("bronchialTree", Role.OBSTACLE, "#f2c14e"),
    "vessels": ("vessels", Role.OBSTACLE, "#d1495b"),
    "fissures": ("fissures", Role.OBSTACLE, "#8d99ae"),
}
_LIVER = {
    "liver": ("liver", Role.ALLOWED_REGION, "#c98474"),
    "hepaticartery": ("hepaticArtery", Role.OBSTACLE, "#d1495b"),
    "hepaticvein": ("hepaticVein", Role.OBSTACLE, "#3d5a80"),
    "portalvein": ("portalVein", Role.OBSTACLE, "#8e7dbe"),
}
_TARGET_COLOUR = "#2a9d8f"

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class StartPose:
    """A start pose of a Med-RAD case.

    Attributes
    ----------
    name : str
        File stem, e.g. ``"start3"`` or ``"target2_start1"``.
    world_T_tip : ndarray, shape (4, 4)
        RAS mm; z axis = insertion direction.
    target : str
        Name of the target this start is meant for (a key of ``MedradCase.targets_mm``).
    """

    name: str
    world_T_tip: np.ndarray
    target: str


@dataclass(frozen=True)
class MedradCase:
    """One Med-RAD patient as a needlekit scene with its start poses and targets.

    Attributes
    ----------
    organ : str
        ``"lung"`` or ``"liver"``.
    patient : int
    scene : Scene
    starts : tuple of StartPose
    targets_mm : dict of str to ndarray, shape (3,)
        Target points (RAS mm) by name (``"target"``, ``"target1"``, ...).
    folder : Path
    timings_s : dict of str to float
        When they were built: ``read_s`` (reading the masks), ``align_s`` (onto one
        grid), ``free_space_s`` (the free-space mask), ``free_field_s`` (its transform),
        and the sums ``load_s`` (read and align) and ``obstacle_field_s`` (free space and
        field). Through the cache also ``hash_s`` (hashing the mask files) and
        ``cache_write_s`` (storing a new entry) or ``cache_load_s`` (opening an entry).
    free_space : Mask or None
        The free-space mask (allowed region and nodules, minus the obstacles) on the
        allowed region's grid; its complement gives the exact voxel-centre collision test
        of :class:`needlekit.anatomy.occupancy.VoxelObstacles`.
    occupancy : ndarray of bool or None
        That complement (the obstacle voxels) when it came from the cache (read-only
        memory map), else None (computed when needed).
    cache_entry : Path or None
        The prepared-anatomy cache entry the case was loaded from or stored in.
    """

    organ: str
    patient: int
    scene: Scene
    starts: tuple[StartPose, ...]
    targets_mm: dict[str, np.ndarray]
    folder: Path
    timings_s: dict[str, float] = field(default_factory=dict)
    free_space: Mask | None = None
    occupancy: np.ndarray | None = None
    cache_entry: Path | None = None

    def voxel_obstacles(self, needle_diameter_mm: float, safety_margin_mm: float = 0.0):
        """Exact voxel-centre collision test over this case's obstacle voxels (everything
        that is not free space, as the reference planner counts them).

        Parameters
        ----------
        needle_diameter_mm : float
        safety_margin_mm : float

        Returns
        -------
        needlekit.anatomy.occupancy.VoxelObstacles
        """
        from needlekit.anatomy.occupancy import VoxelObstacles

        if self.free_space is None:
            raise InvalidInputError("free_space", "this case was built without its free-space mask")
        occupancy = ~self.free_space.data if self.occupancy is None else self.occupancy
        return VoxelObstacles(
            occupancy,
            self.free_space.affine,
            needle_diameter_mm=needle_diameter_mm,
            safety_margin_mm=safety_margin_mm,
        )

    def start(self, name_or_index: str | int) -> StartPose:
        """A start by name (``"start2"``) or 1-based number (``2``).

        Parameters
        ----------
        name_or_index : str or int

        Returns
        -------
        StartPose
        """
        if isinstance(name_or_index, (int, np.integer)) and not isinstance(name_or_index, bool):
            i = int(name_or_index)
            if not 1 <= i <= len(self.starts):
                raise InvalidInputError(
                    "start", f"expected 1 to {len(self.starts)} for this case, got {i}"
                )
            return self.starts[i - 1]
        for s in self.starts:
            if s.name == name_or_index:
                return s
        names = ", ".join(s.name for s in self.starts)
        raise InvalidInputError("start", f"no start named {name_or_index!r}; the case has {names}")


def _files(folder: Path) -> dict[str, Path]:
    """Lower-case stem (without .nii.gz / .txt) -> path."""
    out = {}
    for p in folder.iterdir():
        name = p.name.lower()
        for ext in (".nii.gz", ".nii", ".txt"):
            if name.endswith(ext):
                out[name[: -len(ext)]] = p
                break
    return out


def _target_key(stem: str) -> str | None:
    m = re.fullmatch(r"(?:target|nodule)(\d*)", stem)
    return None if m is None else f"target{m.group(1)}"


def _starts_and_targets(files: dict[str, Path], folder: Path):
    targets = {}
    for stem, path in files.items():
        if path.name.lower().endswith(".txt") and re.fullmatch(r"target\d*", stem):
            targets[stem] = read_point_txt(path)
    if not targets:
        raise InvalidInputError(str(folder), "no target*.txt file")
    starts = []
    for stem, path in files.items():
        if not path.name.lower().endswith(".txt"):
            continue
        m = re.fullmatch(r"(?:(target|nodule)(\d*)_)?start(\d+)", stem)
        if m is None:
            continue
        target = f"target{m.group(2)}" if m.group(1) else None
        if target is None:
            if len(targets) != 1:
                raise InvalidInputError(
                    str(path), "a plain start file needs exactly one target in the folder"
                )
            target = next(iter(targets))
        if target not in targets:
            raise InvalidInputError(str(path), f"refers to {target}.txt, which is missing")
        starts.append(StartPose(path.name[: -len(".txt")], read_pose_txt(path), target))
    if not starts:
        raise InvalidInputError(str(folder), "no start pose file (start*.txt)")
    starts.sort(key=lambda s: (s.target, [int(t) for t in re.findall(r"\d+", s.name)]))
    return tuple(starts), targets


def _read_all(paths: dict[str, Path]) -> dict[str, Mask]:
    # Sequential on purpose: reading is inflate + numpy passes under the GIL, and threads
    # measured slower (4.5 s vs 3.3 s for a lung's five masks on 2 cores).
    return {name: read_mask(path) for name, path in paths.items()}


def _align(mask: Mask, ref: Mask, name: str) -> Mask:
    """``mask`` on ``ref``'s voxel grid, through their affines.

    Med-RAD masks of one patient share a grid except for a few (Patient 4's fissures sit on
    an offset grid with the same spacing): for those the voxels are shifted by the whole
    number of voxels between the grids, exactly. Other grids are resampled by nearest
    neighbour. Set voxels that fall outside the reference grid are reported.
    """
    if mask.shape == ref.shape and np.allclose(mask.affine, ref.affine, atol=1e-4):
        return mask
    ref_to_mask = np.linalg.inv(mask.affine) @ ref.affine  # ref index -> mask index
    shift = ref_to_mask[:3, 3]
    if np.allclose(ref_to_mask[:3, :3], np.eye(3), atol=1e-6) and np.allclose(
        shift, np.round(shift), atol=1e-3
    ):
        off = np.round(shift).astype(np.int64)
        src_shape, dst_shape = np.array(mask.shape), np.array(ref.shape)
        lo = np.maximum(0, -off)
        hi = np.minimum(dst_shape, src_shape - off)
        out = np.zeros(ref.shape, dtype=bool)
        if np.all(hi > lo):
            out[lo[0] : hi[0], lo[1] : hi[1], lo[2] : hi[2]] = mask.data[
                lo[0] + off[0] : hi[0] + off[0],
                lo[1] + off[1] : hi[1] + off[1],
                lo[2] + off[2] : hi[2] + off[2],
            ]
    else:
        from scipy.ndimage import map_coordinates

        out = np.zeros(ref.shape, dtype=bool)
        ii = np.arange(ref.shape[0])
        for k0 in range(0, ref.shape[2], 32):  # slabs keep the index arrays small
            kk = np.arange(k0, min(k0 + 32, ref.shape[2]))
            grid = np.stack(
                np.meshgrid(ii, np.arange(ref.shape[1]), kk, indexing="ij"), axis=0
            ).reshape(3, -1)
            idx = ref_to_mask[:3, :3] @ grid + ref_to_mask[:3, 3:4]
            vals = map_coordinates(
                mask.data.astype(np.uint8), idx, order=0, mode="constant", cval=0
            )
            out[:, :, kk] = vals.reshape(ref.shape[0], ref.shape[1], len(kk)).astype(bool)
    lost = int(mask.data.sum()) - int(out.sum())
    if lost > 0:
        log.warning("%s: %d set voxels lie outside the common grid and were dropped", name, lost)
    return Mask(out, ref.affine, mask.path)


def _on_one_grid(masks: dict[str, Mask], reference: str) -> dict[str, Mask]:
    ref = masks[reference]
    return {name: _align(m, ref, name) for name, m in masks.items()}


#: Margin (mm) of the free space's grid beyond its own voxels: none beyond the few unset
#: layers :meth:`VoxelSDF.from_mask` always keeps. A wider grid would change no value on
#: this one (every free voxel lies in both, and each one's nearest obstacle voxel lies in the
#: first unset layer), only answer points farther outside the free space from the grid
#: instead of from its extrapolation, which is positive there too: "in an obstacle" either
#: way. The default 10 mm made the grid larger than the image (lung 1: 95 M voxels, 77 M now).
FREE_SPACE_PADDING_MM: float = 0.0


def _lazy_sdf(mask: Mask, name: str) -> LazyField:
    return LazyField(
        lambda: VoxelSDF.from_mask(mask),
        f"signed distance to {name}",
        local=lambda p, r, h=None: local_mask_sdf(mask.data, mask.affine, p, r, h),
        preview=lambda cells: preview_mask_sdf(mask.data, mask.affine, cells),
    )


@dataclass
class _Prepared:
    """What loading builds from the masks: the free space, its field, the structures'
    (lazy) fields, and where it came from."""

    free_space: Mask
    free_field: VoxelSDF
    fields: dict[str, LazyField]
    timings_s: dict[str, float]
    occupancy: np.ndarray | None = None
    cache_entry: Path | None = None
    masks: dict[str, Mask] | None = None


# (structure name, role, colour, metadata, description of its field)
_Spec = tuple[str, Role, str, dict, str]


def _prepare(paths: dict[str, Path], specs: list[_Spec], region: str, n_threads: int,
             folder: Path) -> _Prepared:  # fmt: skip
    """Read the masks onto one grid and build the free space's field (no cache)."""
    t0 = time.perf_counter()
    read = _read_all(paths)
    t1 = time.perf_counter()
    masks = _on_one_grid(read, region)
    t2 = time.perf_counter()
    free = masks[region].data.copy()
    for name, role, *_ in specs:  # targets are never obstacles (liver masks leave nodules out)
        if role is Role.TARGET:
            free |= masks[name].data
    for name, role, *_ in specs:
        if role is Role.OBSTACLE:  # free &= ~obstacle, without an 86 MB temporary each
            np.greater(free, masks[name].data, out=free)
    if not free.any():
        raise InvalidInputError(str(folder), "no free space: the obstacles fill the allowed region")
    t3 = time.perf_counter()
    free_field = VoxelSDF.from_mask(
        free, masks[region].affine, padding_mm=FREE_SPACE_PADDING_MM, n_threads=n_threads
    )
    t4 = time.perf_counter()
    timings = {
        "read_s": t1 - t0,
        "align_s": t2 - t1,
        "free_space_s": t3 - t2,
        "free_field_s": t4 - t3,
        "load_s": t2 - t0,  # reading and aligning
        "obstacle_field_s": t4 - t2,  # the free space and its field
    }
    fields = {name: _lazy_sdf(masks[name], what) for name, _, _, _, what in specs}
    return _Prepared(
        Mask(free, masks[region].affine, None),
        free_field,
        fields,
        timings,
        masks=masks,
    )


# -- through the prepared-anatomy cache ------------------------------------------------------


def _cache_inputs(organ: str, paths: dict[str, Path], specs: list[_Spec], region: str) -> dict:
    """Everything that changes the stored arrays: the masks' content and roles, and the
    settings of the transforms (the EDT library's version among them)."""
    import edt

    return {
        "kind": "medrad",
        "organ": organ,
        "region": region,
        "structures": [
            [name, role.value, anatomy_cache.file_digest(paths[name])] for name, role, *_ in specs
        ],
        "settings": {
            "mask_padding_mm": DEFAULT_MASK_PADDING_MM,
            "free_space_padding_mm": FREE_SPACE_PADDING_MM,
            "mask_offset_max_fraction": MASK_OFFSET_MAX_FRACTION,
            "edt": getattr(edt, "__version__", "unknown"),
        },
    }


def _grid_meta(mask: Mask) -> dict:
    return {"affine": np.asarray(mask.affine).tolist()}


def _cropped(mask: Mask) -> tuple[np.ndarray, dict]:
    """A mask cut to its set voxels (most of a structure's grid is empty), and how to put
    it back."""
    d = mask.data
    lo, hi = [0, 0, 0], [1, 1, 1]
    for axis in range(3):
        idx = np.flatnonzero(d.any(axis=tuple(a for a in range(3) if a != axis)))
        if idx.size:
            lo[axis], hi[axis] = int(idx[0]), int(idx[-1]) + 1
    part = d[lo[0] : hi[0], lo[1] : hi[1], lo[2] : hi[2]]
    meta = {**_grid_meta(mask), "shape": list(d.shape), "offset": lo}
    return part, meta


def _uncropped(stored: anatomy_cache.CachedArray) -> Mask:
    meta = stored.meta
    full = np.zeros(tuple(meta["shape"]), dtype=bool)
    lo = meta["offset"]
    s = stored.values.shape
    full[lo[0] : lo[0] + s[0], lo[1] : lo[1] + s[1], lo[2] : lo[2] + s[2]] = stored.values
    full.flags.writeable = False
    return Mask(full, np.array(meta["affine"], dtype=np.float64), None)


def _restored_sdf(stored: anatomy_cache.CachedArray) -> VoxelSDF:
    return VoxelSDF.from_prepared_state(stored.values, stored.meta)


def _cached_sdf(entry: anatomy_cache.CacheEntry, name: str) -> VoxelSDF:
    """A structure's field from the entry; built from the stored mask and added to the
    entry the first time."""
    stored = entry.get(f"sdf_{name}")
    if stored is not None:
        return _restored_sdf(stored)
    sdf = VoxelSDF.from_mask(_uncropped(entry[f"mask_{name}"]))
    stored = entry.put(f"sdf_{name}", sdf.values, sdf.prepared_state())
    return sdf if stored is None else _restored_sdf(stored)


def _local_cached_sdf(entry: anatomy_cache.CacheEntry, name: str, point, radius: float,
                      half=None):  # fmt: skip
    """A structure's field near one point (or box), from a window of its stored (cropped)
    mask."""
    stored = entry[f"mask_{name}"]
    affine = np.array(stored.meta["affine"], dtype=np.float64)
    affine[:3, 3] = affine[:3, :3] @ np.asarray(stored.meta["offset"], float) + affine[:3, 3]
    return local_mask_sdf(stored.values, affine, point, radius, half)


def _preview_cached_sdf(entry: anatomy_cache.CacheEntry, name: str, max_cells: int):
    """A structure's coarse field for drawing it, from its stored (cropped) mask."""
    stored = entry[f"mask_{name}"]
    affine = np.array(stored.meta["affine"], dtype=np.float64)
    affine[:3, 3] = affine[:3, :3] @ np.asarray(stored.meta["offset"], float) + affine[:3, 3]
    return preview_mask_sdf(stored.values, affine, max_cells)


def _lazy_cached_sdf(entry: anatomy_cache.CacheEntry, name: str, what: str) -> LazyField:
    return LazyField(
        lambda: _cached_sdf(entry, name),
        f"signed distance to {what}",
        local=lambda p, r, h=None: _local_cached_sdf(entry, name, p, r, h),
        preview=lambda cells: _preview_cached_sdf(entry, name, cells),
    )


def _entry_arrays(prep: _Prepared) -> dict[str, tuple[np.ndarray, dict]]:
    free = prep.free_space
    arrays = {
        "free_space": (free.data, _grid_meta(free)),
        "occupancy": (~free.data, _grid_meta(free)),
        "sdf_free_space": (prep.free_field.values, prep.free_field.prepared_state()),
    }
    for name, mask in (prep.masks or {}).items():
        arrays[f"mask_{name}"] = _cropped(mask)
    return arrays


def _from_entry(entry: anatomy_cache.CacheEntry, specs: list[_Spec],
                timings: dict[str, float]) -> _Prepared:  # fmt: skip
    free = entry["free_space"]
    affine = np.array(free.meta["affine"], dtype=np.float64)
    affine.flags.writeable = False
    return _Prepared(
        Mask(free.values, affine, None),
        _restored_sdf(entry["sdf_free_space"]),
        {name: _lazy_cached_sdf(entry, name, what) for name, _, _, _, what in specs},
        timings,
        occupancy=entry["occupancy"].values,
        cache_entry=entry.path,
    )


def _prepare_cached(organ: str, patient: int, paths: dict[str, Path], specs: list[_Spec],
                    region: str, n_threads: int, folder: Path, cache_dir) -> _Prepared:  # fmt: skip
    """:func:`_prepare` through the cache: open the entry of the masks' content, or build
    and store it."""
    t0 = time.perf_counter()
    inputs = _cache_inputs(organ, paths, specs, region)
    key = anatomy_cache.entry_key(inputs)
    label = f"medrad-{organ}{patient}"
    timings = {"hash_s": time.perf_counter() - t0}
    t0 = time.perf_counter()
    entry = anatomy_cache.open_entry(cache_dir, label, key)
    if entry is not None:
        timings["cache_load_s"] = time.perf_counter() - t0
        log.debug("prepared anatomy from the cache: %s", entry.path)
        return _from_entry(entry, specs, timings)
    prep = _prepare(paths, specs, region, n_threads, folder)
    timings.update(prep.timings_s)
    t0 = time.perf_counter()
    try:
        entry = anatomy_cache.write_entry(cache_dir, label, key, inputs, _entry_arrays(prep))
    except OSError as exc:
        log.warning("prepared-anatomy cache unavailable (%s); going on without it", exc)
        prep.timings_s = timings
        return prep
    timings["cache_write_s"] = time.perf_counter() - t0
    log.debug("prepared anatomy stored in the cache: %s", entry.path)
    return _from_entry(entry, specs, timings)


def load_medrad(
    organ: str,
    patient: int,
    root: str | os.PathLike | None = None,
    *,
    threads: int | None = None,
    cache_dir: str | os.PathLike | None = None,
    use_cache: bool = True,
) -> MedradCase:
    """Load a Med-RAD patient into a :class:`MedradCase`.

    Parameters
    ----------
    organ : {"lung", "liver"}
    patient : int
        Patient number (1 to 5 in the shipped subset).
    root : path-like, optional
        Med-RAD folder (default: see :func:`medrad_root`).
    threads : int, optional
        Threads of the distance transforms (default: all CPUs).
    cache_dir : path-like, optional
        Root of the prepared-anatomy cache (default
        :func:`needlekit.io.anatomy_cache.default_cache_dir`: ``$NEEDLEKIT_CACHE_DIR``,
        ``$XDG_CACHE_HOME/needlekit`` or ``~/.cache/needlekit``).
    use_cache : bool
        Load the prepared anatomy from the cache, or build and store it there (default);
        False builds it in memory only. A corrupt entry is rebuilt and an unwritable cache
        skipped, each with a logged warning.

    Returns
    -------
    MedradCase
        Its scene has the combined obstacle field built; per-structure fields are built on
        first use (and, through the cache, stored then and loaded on later runs).

    Raises
    ------
    InvalidInputError
        Unknown organ or patient, missing or malformed files (the message names the file),
        or no free space left. Masks on different grids are aligned to the allowed
        region's grid through their affines.
    """
    key = _organ(organ)
    if isinstance(patient, bool) or not isinstance(patient, (int, np.integer)):
        raise InvalidInputError("patient", f"expected a patient number, got {patient!r}")
    base = medrad_root(root) / _ORGANS[key]
    try:
        folder = patient_folder(key, patient, root, flag="patient")
    except InvalidInputError:  # the Med-RAD folder is there (base): say which patients are
        have = ", ".join(str(p) for p in list_patients(key, root)) or "none"
        msg = f"no {key} patient {patient} in {base} (have {have})"
        raise InvalidInputError("patient", msg) from None
    files = _files(folder)
    table = _LUNG if key == "lung" else _LIVER
    missing = [stem for stem in table if stem not in files]
    if missing:
        raise InvalidInputError(str(folder), f"missing segmentation(s): {', '.join(missing)}")
    target_masks = {
        _target_key(stem): path
        for stem, path in files.items()
        if not path.name.endswith(".txt") and re.fullmatch(r"nodule\d*", stem)
    }
    if not target_masks:
        raise InvalidInputError(str(folder), "no nodule segmentation (nodule*.nii.gz)")
    starts, targets = _starts_and_targets(files, folder)
    n_threads = int(threads) if threads else (os.cpu_count() or 1)

    paths = {table[stem][0]: files[stem] for stem in table}
    nodule_names = {tk: ("nodule" if tk == "target" else f"nodule{tk[6:]}") for tk in target_masks}
    paths.update({nodule_names[tk]: p for tk, p in target_masks.items()})
    region = next(v for v in table.values() if v[1] is Role.ALLOWED_REGION)[0]
    specs: list[_Spec] = [(name, role, colour, {}, name) for name, role, colour in table.values()]
    specs += [(nodule_names[tk], Role.TARGET, _TARGET_COLOUR, {"target": tk}, tk)
              for tk in sorted(target_masks)]  # fmt: skip
    if use_cache:
        prep = _prepare_cached(
            key, int(patient), paths, specs, region, n_threads, folder, cache_dir
        )
    else:
        prep = _prepare(paths, specs, region, n_threads, folder)

    structures = [
        Structure(name, role, prep.fields[name], colour, str(paths[name]), meta)
        for name, role, colour, meta, _ in specs
    ]
    scene = Scene(
        structures,
        name=f"Med-RAD {key} {int(patient)}",
        obstacle_field=ComplementField(prep.free_field),
    )
    return MedradCase(
        key,
        int(patient),
        scene,
        starts,
        targets,
        folder,
        prep.timings_s,
        prep.free_space,
        prep.occupancy,
        prep.cache_entry,
    )
