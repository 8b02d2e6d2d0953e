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
from needlekit.records import field_of, is_number

__all__ = ["SteerablePlan", "plan_from_dict"]


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

    @classmethod
    def from_dict(cls, data: dict, where: str) -> SteerablePlan:
        """A path from its start pose and primitives, as :meth:`to_dict` writes them (no
        primitives: nothing inserted).

        Parameters
        ----------
        data : dict
            ``start_pose`` (4x4) and ``primitives``.
        where : str
            Names the record in messages.

        Returns
        -------
        SteerablePlan

        Raises
        ------
        InvalidInputError
            A field not as :meth:`to_dict` writes it (named after ``where``).
        """
        start = field_of(data, "start_pose", where, "pose")
        rows = []
        for i, q in enumerate(field_of(data, "primitives", where, "list")):
            at = f"{where}: primitives[{i}]"
            rows.append(
                [field_of(q, k, at) for k in ("rotation_rad", "curvature_per_mm", "length_mm")]
            )
        try:
            return cls(start, np.array(rows, dtype=float).reshape(-1, 3))
        except InvalidInputError as exc:
            raise InvalidInputError(f"{where}: {exc.field}", exc.reason) from None


def plan_from_dict(data: dict, where: str):
    """The plan and goal of a ``plan.json`` document (or of one plan inside another file,
    such as a sweep's best plans).

    Parameters
    ----------
    data : dict
        ``goal_mm``, ``cost_mm``, ``start_pose`` and ``primitives`` as
        :meth:`PlanResult.to_dict
        <needlekit.planning.steerable.result.PlanResult.to_dict>` writes them.
    where : str
        Names the document in messages (``"plan.json"``, ``"sweep.json: best_plans.rrt"``).

    Returns
    -------
    plan : SteerablePlan or None
        None when the document holds no plan (e.g. status ``timeout``).
    goal_mm : ndarray, shape (3,)

    Raises
    ------
    InvalidInputError
        A field not as the format says (named after ``where``).
    """
    if not isinstance(data, dict):
        raise InvalidInputError(where, "expected a JSON object (a plan)")
    goal = field_of(data, "goal_mm", where, "point")
    field_of(data, "cost_mm", where, optional=True)
    prims = data.get("primitives")
    if data.get("start_pose") is None or not prims:
        if prims is not None and not isinstance(prims, list):
            raise InvalidInputError(f"{where}: primitives", "expected a list")
        return None, goal
    start = field_of(data, "start_pose", where, "pose")
    keys = ("rotation_rad", "curvature_per_mm", "length_mm")
    if not isinstance(prims, list) or not all(
        isinstance(q, dict) and all(is_number(q.get(k)) for k in keys) for q in prims
    ):
        raise InvalidInputError(
            f"{where}: primitives",
            "expected objects with numbers rotation_rad, curvature_per_mm, length_mm",
        )
    rows = np.array([[float(q[k]) for k in keys] for q in prims])
    try:
        plan = SteerablePlan(start, rows)
    except InvalidInputError as exc:
        raise InvalidInputError(f"{where}: {exc.field}", exc.reason) from None
    return plan, goal
