"""A displacement field sampled on a regular grid (array + affine, NIfTI vector image or
``.npz``), read by trilinear interpolation: the data behind
:class:`~needlekit.planning.straight.deformation.GridDeformation`.
"""

from __future__ import annotations

import logging
import os
from pathlib import Path

import numpy as np

from needlekit._validation import as_points, unbatch
from needlekit.constants import MM_WARNING_MIN_EXTENT_MM
from needlekit.errors import InvalidInputError

__all__ = ["GRID_INSIDE_TOL_VOXELS", "MAX_PLAUSIBLE_DISPLACEMENT_MM", "DisplacementGrid"]

_log = logging.getLogger(__name__)

#: Points within this fraction of a voxel outside the outermost voxel centres still count
#: as inside a :class:`DisplacementGrid` (rounding of the world-to-index map, ~1e-13
#: voxel for grids within a metre of the origin, must not turn a boundary point away).
GRID_INSIDE_TOL_VOXELS: float = 1e-9

#: Largest displacement (mm) a grid may hold. Tissue moved by needle insertion,
#: ultrasound-probe pressure or breathing moves millimetres to a few centimetres; a field
#: with more than 10 cm is almost surely in other units (micrometres, voxels) and refused.
MAX_PLAUSIBLE_DISPLACEMENT_MM: float = 100.0


class DisplacementGrid:
    """A displacement field sampled on a regular grid, read by trilinear interpolation.

    Voxel ``(i, j, k)`` holds the displacement (mm, world RAS components) of the tissue at
    ``affine @ [i, j, k, 1]`` (world RAS, mm). Between voxel centres the field is
    trilinear; points beyond the outermost centres are *outside* (see :meth:`sample`).

    Parameters
    ----------
    displacement_mm : array_like, shape (i, j, k, 3)
        Displacements (mm), finite, each spatial size >= 2, none above
        :data:`MAX_PLAUSIBLE_DISPLACEMENT_MM`.
    affine : array_like, shape (4, 4)
        Voxel index to world RAS (mm), invertible, last row ``[0, 0, 0, 1]``.
    source : str
        Where the arrays came from, named in error messages.

    Examples
    --------
    >>> field = np.zeros((2, 2, 2, 3))
    >>> field[1, :, :, 0] = 1.0  # x-displacement 0 at x = 0 mm, 1 mm at x = 10 mm
    >>> grid = DisplacementGrid(field, np.diag([10.0, 10.0, 10.0, 1.0]))
    >>> grid.sample([[2.5, 5.0, 5.0]]).tolist()
    [[0.25, 0.0, 0.0]]
    """

    def __init__(self, displacement_mm, affine, *, source: str = "") -> None:
        pre = f"{source}: " if source else ""
        name = f"{pre}displacement_mm"
        try:
            u = np.array(displacement_mm, dtype=np.float64)
        except (TypeError, ValueError) as exc:
            raise InvalidInputError(
                name, f"expected numbers, got {type(displacement_mm).__name__}"
            ) from exc
        if u.ndim != 4 or u.shape[3] != 3:
            raise InvalidInputError(name, f"expected shape (i, j, k, 3), got {u.shape}")
        if min(u.shape[:3]) < 2:
            raise InvalidInputError(
                name, f"needs at least 2 voxels along each axis for interpolation, got {u.shape}"
            )
        bad = ~np.isfinite(u)
        if bad.any():
            first = tuple(int(v) for v in np.argwhere(bad)[0][:3])
            what = "NaN" if np.isnan(u).any() else "infinite"
            raise InvalidInputError(
                name, f"{int(bad.any(axis=3).sum())} voxels hold {what} values (first at {first})"
            )
        largest = float(np.sqrt(np.einsum("...i,...i->...", u, u)).max())
        if largest > MAX_PLAUSIBLE_DISPLACEMENT_MM:
            raise InvalidInputError(
                name,
                f"largest displacement {largest:.6g} mm exceeds "
                f"{MAX_PLAUSIBLE_DISPLACEMENT_MM:g} mm: displacements must be millimetres "
                "(not micrometres or voxels)",
            )
        aname = f"{pre}affine"
        try:
            a = np.array(affine, dtype=np.float64)
        except (TypeError, ValueError) as exc:
            raise InvalidInputError(
                aname, f"expected a 4x4 matrix, got {type(affine).__name__}"
            ) from exc
        if a.shape != (4, 4):
            raise InvalidInputError(aname, f"expected shape (4, 4), got {a.shape}")
        if not np.all(np.isfinite(a)):
            raise InvalidInputError(aname, "must be finite, got NaN or infinity")
        if not np.array_equal(a[3], [0.0, 0.0, 0.0, 1.0]):
            raise InvalidInputError(aname, f"last row must be [0, 0, 0, 1], got {a[3].tolist()}")
        lin = a[:3, :3]
        scale = float(np.abs(lin).max())
        if scale == 0.0 or abs(np.linalg.det(lin)) <= 1e-12 * scale**3:
            raise InvalidInputError(aname, "the voxel-to-world part is singular")
        self.displacement_mm = u
        self.displacement_mm.setflags(write=False)
        self.affine = a
        self.affine.setflags(write=False)
        self.source = source
        self._shape = np.array(u.shape[:3])
        self._inv = np.linalg.inv(lin)
        extent = float(np.max(np.linalg.norm(lin, axis=0) * (self._shape - 1)))
        if extent < MM_WARNING_MIN_EXTENT_MM:
            _log.warning(
                "%sthe displacement grid is only %.3g mm across; grids are in millimetres "
                "(was the affine written in cm or m?)",
                pre,
                extent,
            )

    @property
    def shape(self) -> tuple[int, int, int]:
        """Voxels along each axis."""
        return tuple(int(v) for v in self._shape)

    def bounds(self) -> np.ndarray:
        """World box ``[[xmin, ymin, zmin], [xmax, ymax, zmax]]`` (mm) of the voxel centres.

        Returns
        -------
        ndarray, shape (2, 3)
        """
        n = self._shape - 1
        corners = np.array([[i, j, k] for i in (0, n[0]) for j in (0, n[1]) for k in (0, n[2])])
        world = corners @ self.affine[:3, :3].T + self.affine[:3, 3]
        return np.stack([world.min(axis=0), world.max(axis=0)])

    def _index(self, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        ijk = (p - self.affine[:3, 3]) @ self._inv.T
        tol = GRID_INSIDE_TOL_VOXELS
        inside = np.all((ijk >= -tol) & (ijk <= self._shape - 1 + tol), axis=1)
        return ijk, inside

    def contains(self, points_mm) -> np.ndarray:
        """Whether points lie within the grid (between the outermost voxel centres).

        Parameters
        ----------
        points_mm : array_like, shape (3,) or (n, 3)
            World points (RAS, mm).

        Returns
        -------
        ndarray of bool, shape () or (n,)
        """
        p, single = as_points(points_mm, "points_mm")
        return unbatch(self._index(p)[1], single)

    def sample(self, points_mm, *, outside: str = "error") -> np.ndarray:
        """Trilinear displacement at world points.

        Parameters
        ----------
        points_mm : array_like, shape (3,) or (n, 3)
            World points (RAS, mm).
        outside : {"error", "zero"}
            Points outside the grid raise (the default: more often a frame or affine
            mistake than tissue at rest) or get zero displacement.

        Returns
        -------
        ndarray, shape (3,) or (n, 3)
            Displacement (mm, world RAS).
        """
        if outside not in ("error", "zero"):
            raise InvalidInputError("outside", f"expected 'error' or 'zero', got {outside!r}")
        p, single = as_points(points_mm, "points_mm")
        ijk, inside = self._index(p)
        if outside == "error" and not inside.all():
            k = int(np.flatnonzero(~inside)[0])
            lo, hi = self.bounds()
            raise InvalidInputError(
                "points_mm",
                f"{int((~inside).sum())} of {len(p)} points lie outside the displacement grid "
                f"{self.source or ''} (first {p[k].tolist()} mm; grid spans "
                f"{lo.round(3).tolist()} to {hi.round(3).tolist()} mm); pass outside='zero' "
                "to treat tissue there as at rest",
            )
        c = np.clip(ijk, 0.0, self._shape - 1)
        i0 = np.minimum(np.floor(c).astype(np.intp), self._shape - 2)
        f = c - i0
        u = self.displacement_mm
        out = np.zeros_like(p)
        for di in (0, 1):
            wi = f[:, 0] if di else 1.0 - f[:, 0]
            for dj in (0, 1):
                wj = f[:, 1] if dj else 1.0 - f[:, 1]
                for dk in (0, 1):
                    wk = f[:, 2] if dk else 1.0 - f[:, 2]
                    corner = u[i0[:, 0] + di, i0[:, 1] + dj, i0[:, 2] + dk]
                    out += (wi * wj * wk)[:, None] * corner
        out[~inside] = 0.0
        return unbatch(out, single)

    @classmethod
    def from_nifti(cls, path, *, vector_frame: str = "RAS") -> DisplacementGrid:
        """Read a NIfTI vector image: shape (i, j, k, 1, 3) (the NIfTI/ITK layout) or
        (i, j, k, 3).

        The affine is nibabel's (sform or qform, voxel to RAS); spatial units of metres or
        micrometres in the header are converted to millimetres (affine and vectors),
        unknown units are taken as millimetres.

        Parameters
        ----------
        path : str or os.PathLike
            ``.nii`` or ``.nii.gz`` file.
        vector_frame : {"RAS", "LPS"}
            Frame of the vector components. Fields written by ITK-based tools (ANTs,
            Slicer transforms saved as displacement fields) hold LPS components: pass
            ``"LPS"`` and they are turned to RAS (x and y negated).

        Returns
        -------
        DisplacementGrid
        """
        import nibabel as nib

        if vector_frame not in ("RAS", "LPS"):
            raise InvalidInputError(
                "vector_frame", f"expected 'RAS' or 'LPS', got {vector_frame!r}"
            )
        p = Path(os.fspath(path))
        if not p.is_file():
            raise InvalidInputError(str(p), "no such file")
        try:
            img = nib.load(str(p))
            data = np.asarray(img.get_fdata(dtype=np.float64))
            units = img.header.get_xyzt_units()[0]
        except Exception as exc:  # nibabel raises several types for unreadable files
            raise InvalidInputError(str(p), f"not a readable NIfTI image ({exc})") from exc
        if data.ndim == 5 and data.shape[3] == 1 and data.shape[4] == 3:
            data = data[:, :, :, 0, :]
        elif not (data.ndim == 4 and data.shape[3] == 3):
            raise InvalidInputError(
                str(p), f"expected a vector image of shape (i, j, k, 1, 3), got {data.shape}"
            )
        to_mm = {"meter": 1000.0, "mm": 1.0, "micron": 1e-3, "unknown": 1.0}.get(units)
        if to_mm is None:
            raise InvalidInputError(str(p), f"spatial units {units!r} are not a length")
        affine = np.array(img.affine, dtype=np.float64)
        affine[:3] *= to_mm
        data = data * to_mm
        if vector_frame == "LPS":
            data[..., :2] *= -1.0
        return cls(data, affine, source=str(p))

    @classmethod
    def from_npz(cls, path) -> DisplacementGrid:
        """Read an ``.npz`` holding ``displacement_mm`` (i, j, k, 3) and ``affine`` (4, 4).

        Parameters
        ----------
        path : str or os.PathLike
            The file (as written by :meth:`to_npz`).

        Returns
        -------
        DisplacementGrid
        """
        p = Path(os.fspath(path))
        if not p.is_file():
            raise InvalidInputError(str(p), "no such file")
        try:
            with np.load(p, allow_pickle=False) as z:
                arrays = {k: z[k] for k in z.files}
        except Exception as exc:  # zipfile / numpy format errors of several types
            raise InvalidInputError(str(p), f"not a readable .npz file ({exc})") from exc
        missing = [k for k in ("displacement_mm", "affine") if k not in arrays]
        if missing:
            raise InvalidInputError(
                str(p),
                f"missing {missing} (displacements in millimetres under 'displacement_mm', "
                f"voxel-to-RAS under 'affine'); found {sorted(arrays)}",
            )
        return cls(arrays["displacement_mm"], arrays["affine"], source=str(p))

    @classmethod
    def load(cls, path, **kwargs) -> DisplacementGrid:
        """Read a ``.nii``/``.nii.gz`` (:meth:`from_nifti`) or ``.npz`` (:meth:`from_npz`).

        Parameters
        ----------
        path : str or os.PathLike
        **kwargs
            Passed to :meth:`from_nifti` (``vector_frame``).

        Returns
        -------
        DisplacementGrid
        """
        name = os.fspath(path).lower()
        if name.endswith((".nii", ".nii.gz")):
            return cls.from_nifti(path, **kwargs)
        if name.endswith(".npz"):
            if kwargs:
                raise InvalidInputError(sorted(kwargs)[0], "applies to NIfTI files only")
            return cls.from_npz(path)
        raise InvalidInputError(str(path), "expected a .nii, .nii.gz or .npz displacement field")

    def to_npz(self, path) -> Path:
        """Write ``displacement_mm`` and ``affine`` to an ``.npz`` file.

        Parameters
        ----------
        path : str or os.PathLike
            Output file.

        Returns
        -------
        Path
            The file written.
        """
        p = Path(os.fspath(path))
        np.savez(p, displacement_mm=self.displacement_mm, affine=self.affine)
        return p if p.suffix == ".npz" else p.with_name(p.name + ".npz")

    def __repr__(self) -> str:
        src = f", source={self.source!r}" if self.source else ""
        return f"DisplacementGrid(shape={self.shape}{src})"
