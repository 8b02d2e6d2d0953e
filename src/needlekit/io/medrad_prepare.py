"""A Med-RAD case's anatomy built from its masks: read, put on one grid, the free space and
its signed distance field, and each structure's field made lazily.

:func:`_prepare` is what :func:`needlekit.io.medrad.load_medrad` runs without the
prepared-anatomy cache (and, through :mod:`needlekit.io.medrad_cache`, to fill a new
entry); :class:`_Prepared` is what it returns.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.ndimage import map_coordinates

from needlekit.anatomy.fields import LazyField
from needlekit.anatomy.scene import Role
from needlekit.anatomy.voxel import VoxelSDF
from needlekit.anatomy.voxel_local import local_mask_sdf, preview_mask_sdf
from needlekit.errors import InvalidInputError
from needlekit.io.volumes import Mask, read_masks

__all__ = ["FREE_SPACE_PADDING_MM"]

#: The loader's logger, as before these pieces left :mod:`needlekit.io.medrad`.
log = logging.getLogger("needlekit.io.medrad")


def _align(mask: Mask, ref: Mask, name: str) -> Mask:
    """``mask`` on ``ref``'s voxel grid, through their affines.

    Med-RAD masks of one patient share a grid except for a few (Patient 4's fissures sit on
    an offset grid with the same spacing): for those the voxels are shifted by the whole
    number of voxels between the grids, exactly. Other grids are resampled by nearest
    neighbour. Set voxels that fall outside the reference grid are reported; a mask none of
    whose set voxels falls inside it is an error naming its file.
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
    total = int(mask.data.sum())
    lost = total - int(out.sum())
    if total > 0 and lost == total:
        raise InvalidInputError(
            str(mask.path or name),
            f"none of its {total} set voxels lies in the volume of {ref.path or 'the reference mask'} "
            "(the masks do not overlap: a mask of another patient, or a wrong affine?)",
        )
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
        bounds=lambda: VoxelSDF.mask_bounds(mask.data, mask.affine),
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
             folder: Path, progress=None) -> _Prepared:  # fmt: skip
    """Read the masks onto one grid and build the free space's field (no cache);
    ``progress(stage)``, if given, is told each stage as it begins."""
    t0 = time.perf_counter()
    read = read_masks(paths, progress)
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
    if progress is not None:
        progress("free-space field")
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
