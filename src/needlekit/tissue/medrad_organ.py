"""A Med-RAD patient's organ as the deforming-tissue precomputation takes it: the organ's
body (its mask with the nodule and the vessels and airways lying in it,
:func:`~needlekit.tissue.meshing.organ_body`) and the tracked points (the target, then up
to ``per_structure`` voxels of every vessel and airway structure within ``radius_mm`` of
the corridor)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from needlekit.io.volumes import read_masks
from needlekit.tissue.compliance import sample_near
from needlekit.tissue.meshing import organ_body

__all__ = ["ORGAN_FILES", "organ_files", "organ_inputs"]

#: The organ's body mask and the structures followed beside the corridor, by organ.
ORGAN_FILES: dict[str, tuple[str, tuple[str, ...]]] = {
    "lung": ("pleuralBoundary", ("vessels", "bronchialTree")),
    "liver": ("liver", ("hepaticVein", "portalVein", "hepaticArtery")),
}


def organ_files(folder, organ: str) -> list[Path]:
    """The mask files :func:`organ_inputs` reads for ``organ`` in a patient folder: the
    body's, then the nodule's and each structure's that is there.

    Parameters
    ----------
    folder : path-like
    organ : str

    Returns
    -------
    list of Path
    """
    folder = Path(folder)
    body_name, structures = ORGAN_FILES[organ]
    return [folder / f"{body_name}.nii.gz"] + [
        p for name in ("nodule", *structures) if (p := folder / f"{name}.nii.gz").is_file()
    ]


def organ_inputs(folder, organ: str, corridor_mm, target_mm, radius_mm: float = 15.0,
                 per_structure: int = 100):  # fmt: skip
    """Read one patient's organ body and the points tracked beside a corridor.

    Parameters
    ----------
    folder : path-like
        The Med-RAD patient folder.
    organ : str
        ``"lung"`` or ``"liver"`` (:data:`ORGAN_FILES`).
    corridor_mm : array_like, shape (m, 3)
    target_mm : array_like, shape (3,)
    radius_mm : float
    per_structure : int

    Returns
    -------
    body : ndarray of bool
        The organ body on the organ mask's grid.
    affine : ndarray, shape (4, 4)
    tracked : ndarray, shape (p, 3)
        The target first.
    labels : list of str
        ``"target"``, then each structure's name per point.
    """
    body_path, *others = organ_files(folder, organ)
    names = ["body"] + [p.name.removesuffix(".nii.gz") for p in others]
    masks = read_masks(dict(zip(names, [body_path, *others], strict=True)), allow_empty=names[1:])
    mask = masks["body"]
    target = np.asarray(target_mm, dtype=np.float64)
    corridor = np.asarray(corridor_mm, dtype=np.float64)
    tracked, labels, inside = [target[None]], ["target"], []
    for name in names[1:]:
        m = masks[name]
        inside.append((m.data, m.affine))
        if name != "nodule":
            near = sample_near(m.data, m.affine, corridor, radius_mm, per_structure)
            tracked.append(near)
            labels += [name] * len(near)
    body = organ_body(mask.data, mask.affine, inside)  # the liver's masks leave them out
    return body, mask.affine, np.concatenate(tracked), labels
