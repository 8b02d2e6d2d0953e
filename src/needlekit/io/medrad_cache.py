"""A Med-RAD case's prepared anatomy through the prepared-anatomy cache.

The entry's key (the masks' content and the settings), the arrays an entry stores (the
free space, its field, the obstacle voxels, each mask cut to its set voxels), and the
case rebuilt from an entry, each structure's field built from its stored mask on first
use and added to the entry. :func:`_prepare_cached` opens the entry, or builds it with
:func:`needlekit.io.medrad_prepare._prepare` and stores it.
"""

from __future__ import annotations

import logging
import time
from pathlib import Path

import edt
import numpy as np

from needlekit.anatomy.fields import LazyField
from needlekit.anatomy.voxel import DEFAULT_MASK_PADDING_MM, MASK_OFFSET_MAX_FRACTION, VoxelSDF
from needlekit.anatomy.voxel_local import local_mask_sdf, preview_mask_sdf
from needlekit.io import anatomy_cache, cache_entries
from needlekit.io.cache_key import CacheKeyError
from needlekit.io.medrad_prepare import FREE_SPACE_PADDING_MM, _prepare, _Prepared, _Spec
from needlekit.io.prepare_progress import PreparationProgress, estimate_s, header_voxels
from needlekit.io.volumes import Mask

__all__: list[str] = []

#: The loader's logger, as before these pieces left :mod:`needlekit.io.medrad`.
log = logging.getLogger("needlekit.io.medrad")


def _cache_inputs(organ: str, paths: dict[str, Path], specs: list[_Spec], region: str) -> dict:
    """Everything that changes the stored arrays: the masks' content and roles, and the
    settings of the transforms (the EDT library's version among them)."""
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
    if not cache_entries.make_room(entry.path.parent, sdf.values.nbytes, keep=entry.path):
        log.info("the field of %s (%s) is not stored: the cache is at its limit", name,
                 cache_entries.format_size(sdf.values.nbytes))  # fmt: skip
        return sdf
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


def _cached_sdf_bounds(entry: anatomy_cache.CacheEntry, name: str) -> np.ndarray:
    """A structure's box as its field gives it (:func:`_cached_sdf` builds the field from
    this mask), from the stored (cropped) mask without building or reading the field."""
    mask = entry[f"mask_{name}"]
    meta = mask.meta
    return VoxelSDF.mask_bounds(
        mask.values, np.array(meta["affine"], dtype=np.float64), offset=meta["offset"],
        shape=meta["shape"], tight=True,  # stored cut to its set voxels (_cropped)
    )  # fmt: skip


def _lazy_cached_sdf(entry: anatomy_cache.CacheEntry, name: str, what: str) -> LazyField:
    return LazyField(
        lambda: _cached_sdf(entry, name),
        f"signed distance to {what}",
        local=lambda p, r, h=None: _local_cached_sdf(entry, name, p, r, h),
        preview=lambda cells: _preview_cached_sdf(entry, name, cells),
        bounds=lambda: _cached_sdf_bounds(entry, name),
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


def _estimate(paths: dict[str, Path], region: str) -> float | None:
    """Seconds a first preparation takes, from the masks' headers (None if unreadable)."""
    voxels = {name: header_voxels(p) for name, p in paths.items()}
    if any(v is None for v in voxels.values()):
        return None
    return estimate_s(list(voxels.values()), voxels[region])


def _entry_bytes(arrays: dict[str, tuple[np.ndarray, dict]]) -> int:
    """About the bytes an entry of these arrays takes (each array's ``.npy`` header and
    record counted as 2 kB)."""
    return sum(np.asarray(a).nbytes + 2048 for a, _ in arrays.values())


def _prepare_cached(organ: str, patient: int, paths: dict[str, Path], specs: list[_Spec],
                    region: str, n_threads: int, folder: Path, cache_dir) -> _Prepared:  # fmt: skip
    """:func:`_prepare` through the cache: open the entry of the masks' content, or build
    and store it, saying so (:class:`~needlekit.io.prepare_progress.PreparationProgress`)
    and keeping the cache within its limit (:func:`~needlekit.io.cache_entries.make_room`)."""
    t0 = time.perf_counter()
    limit = cache_entries.cache_limit(cache_dir)[0]  # a bad limit: one line, before any work
    inputs = _cache_inputs(organ, paths, specs, region)
    key = anatomy_cache.entry_key(inputs)
    label = f"medrad-{organ}{patient}"
    timings = {"hash_s": time.perf_counter() - t0}
    t0 = time.perf_counter()
    where = anatomy_cache.cache_root(cache_dir) / f"{label}-{key}"
    existed = where.is_dir()
    try:
        entry = anatomy_cache.open_entry(cache_dir, label, key)
    except CacheKeyError as exc:  # nothing can be checked or signed: no cache this run
        log.warning("prepared-anatomy cache unavailable (%s); going on without it", exc)
        prep = _prepare(paths, specs, region, n_threads, folder)
        prep.timings_s = {**timings, **prep.timings_s}
        return prep
    if entry is not None:
        timings["cache_load_s"] = time.perf_counter() - t0
        cache_entries.mark_used(entry.path)
        log.debug("prepared anatomy from the cache: %s", entry.path)
        return _from_entry(entry, specs, timings)
    what = f"Med-RAD {organ} {patient}"
    why = "its entry was damaged" if existed else "first use"
    progress = PreparationProgress(what, where, _estimate(paths, region), why=why)
    try:
        return _build_and_store(progress, paths, specs, region, n_threads, folder,
                                (cache_dir, label, key, inputs, limit), timings)  # fmt: skip
    finally:
        progress.close()


def _build_and_store(progress: PreparationProgress, paths, specs, region, n_threads, folder,
                     store: tuple, timings: dict[str, float]) -> _Prepared:  # fmt: skip
    """Prepare the anatomy and store it as a new entry, if it fits within the limit."""
    cache_dir, label, key, inputs, limit = store
    prep = _prepare(paths, specs, region, n_threads, folder, progress)
    timings.update(prep.timings_s)
    arrays = _entry_arrays(prep)
    need = _entry_bytes(arrays)
    progress(f"storing {cache_entries.format_size(need)}")
    t0 = time.perf_counter()
    if not cache_entries.make_room(cache_dir, need, limit=limit):
        why = ("it is larger than" if need > limit else
               "the entries in use or being written leave no room for it within")  # fmt: skip
        log.warning(
            "%s (%s) is not stored: %s the prepared-anatomy cache's limit of %s "
            "(needlekit cache limit SIZE raises it)", progress.what,
            cache_entries.format_size(need), why, cache_entries.format_size(limit),
        )  # fmt: skip
        progress.done("not stored (over the cache's limit)")
        prep.timings_s = timings
        return prep
    usage = cache_entries.usage_record(progress.what, str(folder))
    try:
        entry = anatomy_cache.write_entry(cache_dir, label, key, inputs, arrays, usage)
    except OSError as exc:
        log.warning("prepared-anatomy cache unavailable (%s); going on without it", exc)
        progress.done("not stored")
        prep.timings_s = timings
        return prep
    timings["cache_write_s"] = time.perf_counter() - t0
    cache_entries.mark_used(entry.path)
    progress.done(f"{cache_entries.format_size(need)} kept")
    log.debug("prepared anatomy stored in the cache: %s", entry.path)
    return _from_entry(entry, specs, timings)
