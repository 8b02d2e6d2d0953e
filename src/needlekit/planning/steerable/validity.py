"""Validity of needle motions for the planners (OMPL's ``StateValidityChecker``).

A motion is valid when every sample along it (every ``spacing_mm`` of arc length, end
included) is collision-free, outside the start exclusion ball where obstacles are ignored,
and the direction stays within the heading limit. Collisions follow the problem's collision
model (:class:`~needlekit.planning.steerable.problem.CollisionModel`):

- ``field``: certified. A sample is clear only when the scene's obstacle field, grown by the
  needle radius plus margin, exceeds the field's stated error bound plus half the sample
  spacing there: the field is 1-Lipschitz, so every point between samples is then clear
  too, whatever the field's error;
- ``voxel_centres``: the reference planner's exact test against obstacle voxel centres
  (:class:`~needlekit.anatomy.occupancy.VoxelObstacles`), sample by sample as it does.
"""

from __future__ import annotations

import numpy as np

from needlekit.geometry.arcs import propagate_arcs, sample_arcs
from needlekit.planning.steerable.problem import CollisionModel, SteerableProblem

__all__ = ["MotionValidator", "MOTION_SPACING_MM"]

#: Spacing of the collision samples along motions (mm), as in the reference planner.
MOTION_SPACING_MM: float = 0.5


class MotionValidator:
    """Checks motions (arcs from a pose) against a problem's obstacles and limits.

    Parameters
    ----------
    problem : SteerableProblem
        Its collision model decides collisions.
    spacing_mm : float
        Largest gap between samples along a motion.

    Attributes
    ----------
    threshold_mm : float
        ``field`` model: the smallest grown-field value a sample must exceed (the field's
        error bound plus half the spacing); 0 for ``voxel_centres``.
    """

    def __init__(self, problem: SteerableProblem, spacing_mm: float = MOTION_SPACING_MM) -> None:
        self.problem = problem
        self.spacing_mm = float(spacing_mm)
        self.start = problem.start_pose
        self.start_point = problem.start_point_mm
        self.start_dir = None if problem.start_pose is None else problem.start_pose[:3, 2].copy()
        self.cos_heading = float(np.cos(np.radians(problem.max_heading_change_deg)))
        if problem.collision_model is CollisionModel.VOXEL_CENTRES:
            self.obstacles = problem.voxel_obstacles
            self._field = None
            self.threshold_mm = 0.0
        else:
            self.obstacles = None
            self._field = problem.scene.obstacle_field(problem.clearance_margin_mm)
            self.threshold_mm = float(self._field.error_bound_mm) + 0.5 * self.spacing_mm

    def points_collide(self, points: np.ndarray) -> bool:
        """Whether any of the points (n, 3) collides (start exclusion applied).

        Parameters
        ----------
        points : ndarray, shape (n, 3)

        Returns
        -------
        bool
        """
        if len(points) == 0:
            return False
        excl = self.problem.start_exclusion_mm
        if self.obstacles is not None:
            return bool(
                self.obstacles.collides(
                    points, exclude_near=self.start_point, exclusion_mm=excl
                ).any()
            )
        far = np.linalg.norm(points - self.start_point, axis=1) >= excl
        if not far.any():
            return False
        return bool((self._field.signed_distance(points[far]) < self.threshold_mm).any())

    def goal_collides(self, goal_mm: np.ndarray) -> bool:
        """Whether the goal point itself provably lies where the needle cannot be (no
        start exclusion; for the field model, beyond the field's error bound, so that the
        verdict holds for the true anatomy).

        Parameters
        ----------
        goal_mm : ndarray, shape (3,)

        Returns
        -------
        bool
        """
        g = np.asarray(goal_mm, dtype=float).reshape(1, 3)
        if self.obstacles is not None:
            return bool(self.obstacles.collides(g)[0])
        return bool(self._field.signed_distance(g)[0] < -self._field.error_bound_mm)

    def motion_valid(self, pose: np.ndarray, spin: float, kappa: float, length: float) -> bool:
        """Whether the motion ``(spin, kappa, length)`` from ``pose`` is valid.

        Parameters
        ----------
        pose : ndarray, shape (4, 4)
        spin, kappa, length : float

        Returns
        -------
        bool
        """
        if length <= 0.0:
            return True
        m = max(2, int(np.ceil(length / self.spacing_mm - 1e-9)) + 1)
        pts = sample_arcs(pose, spin, kappa, length, m)[1:]
        if kappa != 0.0 and self.start_dir is not None and self.cos_heading > -1.0:
            s = np.linspace(0.0, length, m)[1:]
            ends = propagate_arcs(pose, np.full(s.shape, spin), np.full(s.shape, kappa), s)
            if (ends[:, :3, 2] @ self.start_dir).min() < self.cos_heading - 1e-12:
                return False
        elif (
            self.start_dir is not None
            and float(pose[:3, 2] @ self.start_dir) < self.cos_heading - 1e-12
        ):
            return False
        return not self.points_collide(pts)

    def primitives_valid(self, pose: np.ndarray, primitives: np.ndarray) -> bool:
        """Whether a chain of primitives from ``pose`` is valid (heading not checked for the
        goal connection's straight part beyond its arc).

        Parameters
        ----------
        pose : ndarray, shape (4, 4)
        primitives : ndarray, shape (k, 3)

        Returns
        -------
        bool
        """
        g = pose
        for spin, kappa, length in primitives:
            if not self.motion_valid(g, spin, kappa, length):
                return False
            g = propagate_arcs(g, spin, kappa, length)
        return True

    def warm_up(self) -> float:
        """Compile (or load from numba's cache) every kernel a search calls, so that time
        budgets measure search, not one-time set-up.

        Returns
        -------
        float
            Seconds it took.
        """
        import time

        t0 = time.perf_counter()
        pose = np.eye(4) if self.start is None else self.start
        self.motion_valid(pose, 0.0, self.problem.kappa_max_per_mm, self.spacing_mm)
        self.motion_valid(pose, 0.0, 0.0, self.spacing_mm)
        self.problem.scene.clearance(pose[:3, 3][None])  # the field the plan check reads
        return time.perf_counter() - t0
