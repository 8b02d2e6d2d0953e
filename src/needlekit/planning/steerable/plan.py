"""A steerable-needle plan: a start pose and a sequence of motion primitives.

Each primitive is ``(rotation_rad, curvature_per_mm, length_mm)``: spin the tip about its
own z axis, then insert along an arc of that curvature, bending toward the spun tip's -y
axis (:mod:`needlekit.conventions`, :mod:`needlekit.geometry.arcs`). Curvature 0 is a
straight segment.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from needlekit._validation import as_batch, as_poses
from needlekit.constants import DEFAULT_SAMPLE_SPACING_MM
from needlekit.errors import InvalidInputError
from needlekit.geometry.arcs import propagate_arcs, sample_arcs, samples_for_spacing

__all__ = ["SteerablePlan"]


@dataclass(frozen=True)
class SteerablePlan:
    """Start pose plus primitives.

    Attributes
    ----------
    start_pose : ndarray, shape (4, 4)
        World tip pose at the start (RAS mm; z = insertion direction).
    primitives : ndarray, shape (m, 3)
        Rows ``(rotation_rad, curvature_per_mm, length_mm)``.

    Examples
    --------
    >>> import numpy as np
    >>> plan = SteerablePlan(np.eye(4), [[0.0, 0.02, 25 * np.pi], [0.0, 0.0, 10.0]])
    >>> round(plan.length_mm, 6), np.round(plan.end_pose()[:3, 3], 6).tolist()
    (88.539816, [0.0, -60.0, 50.0])
    """

    start_pose: np.ndarray
    primitives: np.ndarray

    def __post_init__(self) -> None:
        g, single = as_poses(self.start_pose, "start_pose")
        if not single:
            raise InvalidInputError("start_pose", "expected one 4x4 pose")
        prims = np.asarray(self.primitives, dtype=np.float64)
        if prims.size == 0:
            prims = np.zeros((0, 3))
        prims, _ = as_batch(prims, "primitives", (3,))
        if np.any(prims[:, 2] < 0):
            raise InvalidInputError("primitives", "lengths (third column) must be >= 0")
        object.__setattr__(self, "start_pose", g[0])
        object.__setattr__(self, "primitives", prims)

    @property
    def length_mm(self) -> float:
        """Inserted length: the sum of the primitives' lengths (mm)."""
        return float(self.primitives[:, 2].sum())

    def poses(self) -> np.ndarray:
        """Tip poses at the start and after each primitive.

        Returns
        -------
        ndarray, shape (m + 1, 4, 4)
        """
        out = np.empty((len(self.primitives) + 1, 4, 4))
        out[0] = self.start_pose
        for i, (spin, kappa, length) in enumerate(self.primitives):
            out[i + 1] = propagate_arcs(out[i], spin, kappa, length)
        return out

    def end_pose(self) -> np.ndarray:
        """Tip pose at the end of the plan.

        Returns
        -------
        ndarray, shape (4, 4)
        """
        return self.poses()[-1]

    def points_mm(self, spacing_mm: float = DEFAULT_SAMPLE_SPACING_MM) -> np.ndarray:
        """Tip path sampled at most ``spacing_mm`` apart in arc length, ends included.

        Parameters
        ----------
        spacing_mm : float

        Returns
        -------
        ndarray, shape (k, 3)
            World points (mm), starting at the start point.
        """
        poses = self.poses()
        chunks = [poses[0, :3, 3][None]]
        for i, (spin, kappa, length) in enumerate(self.primitives):
            if length <= 0:
                continue
            m = samples_for_spacing(length, spacing_mm)
            chunks.append(sample_arcs(poses[i], spin, kappa, length, m)[1:])
        return np.concatenate(chunks)

    def to_dict(self) -> dict:
        """JSON-ready primitives and start pose.

        Returns
        -------
        dict
            ``start_pose`` (4x4 rows) and ``primitives`` (each ``rotation_rad``,
            ``curvature_per_mm``, ``length_mm``).
        """
        return {
            "start_pose": self.start_pose.tolist(),
            "primitives": [
                {"rotation_rad": float(s), "curvature_per_mm": float(k), "length_mm": float(ell)}
                for s, k, ell in self.primitives
            ],
        }
