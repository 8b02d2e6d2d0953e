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

This module finds a case's files and assembles the case; building the anatomy from the
masks is in :mod:`needlekit.io.medrad_prepare`, the cache's side in
:mod:`needlekit.io.medrad_cache`, and the data's folders in :mod:`needlekit.io.medrad_paths`.
"""

from __future__ import annotations

import logging
import os
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from needlekit.anatomy.fields import ComplementField
from needlekit.anatomy.occupancy import VoxelObstacles
from needlekit.anatomy.scene import Role, Scene, Structure
from needlekit.errors import InvalidInputError
from needlekit.io.medrad_cache import _prepare_cached
from needlekit.io.medrad_paths import (  # noqa: F401 - re-exported
    _ORGANS,
    MEDRAD_ENV,
    _organ,
    _repo_candidates,
    list_patients,
    medrad_root,
    patient_folder,
)
from needlekit.io.medrad_prepare import (  # noqa: F401 - FREE_SPACE_PADDING_MM re-exported
    FREE_SPACE_PADDING_MM,
    _prepare,
    _Spec,
)
from needlekit.io.poses import read_point_txt, read_pose_txt
from needlekit.io.volumes import Mask

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
