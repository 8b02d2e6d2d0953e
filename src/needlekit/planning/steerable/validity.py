"""Validity of needle motions for the planners (OMPL's ``StateValidityChecker``).

A motion is valid when every sample along it (every ``spacing_mm`` of arc length, end
included) is collision-free, outside the start exclusion ball where obstacles are ignored,
and the direction stays within the heading limit. Collision-free is the one clearance rule
of :mod:`needlekit.constants` (half the sample spacing counted against the clearance), and
the samples are the ones :func:`~needlekit.planning.steerable.verify.motion_samples`
re-derives from a plan's primitives: the plan check certifies exactly what the search
accepted. Collisions are the problem's collision
checker's to decide (:mod:`needlekit.anatomy.collision`: the certified ``field`` model, the
reference's exact ``voxel_centres`` test, or a user's own); this module never asks which.

The problem was checked when it was built: the calls here go to unchecked kernels
(:func:`~needlekit.geometry.arcs.arc_points_unchecked`,
:func:`~needlekit.geometry.arcs.min_tangent_dot_unchecked`) with the poses the search
made, and validate nothing again.
"""

from __future__ import annotations

import math
import time

import numpy as np

from needlekit.constants import MOTION_SPACING_MM
from needlekit.geometry.arcs import (
    arc_end_unchecked,
    arc_points_unchecked,
    min_tangent_dot_unchecked,
)
from needlekit.planning.steerable.problem import SteerableProblem

__all__ = ["MOTION_SPACING_MM", "MotionValidator"]


class MotionValidator:
    """Checks motions (arcs from a pose) against a problem's obstacles and limits.

    Parameters
    ----------
    problem : SteerableProblem
        Its collision checker decides collisions.
    spacing_mm : float
        Largest gap between samples along a motion.

    Attributes
    ----------
    checker : CollisionChecker
        The problem's checker for this spacing.
    """

    def __init__(self, problem: SteerableProblem, spacing_mm: float = MOTION_SPACING_MM) -> None:
        self.problem = problem
        self.spacing_mm = float(spacing_mm)
        self.start = problem.start_pose
        self.start_point = problem.start_point_mm
        self.start_dir = (
            None
            if problem.start_pose is None
            else np.ascontiguousarray(problem.start_pose[:3, 2], dtype=np.float64)
        )
        self.cos_heading = float(np.cos(np.radians(problem.max_heading_change_deg)))
        self.checker = problem.collision_checker(self.spacing_mm)
        self._collides = self.checker.collides
        self._check_heading = self.start_dir is not None and self.cos_heading > -1.0

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
        return bool(self._collides(np.ascontiguousarray(points, dtype=np.float64)))

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
        return bool(self.checker.goal_collides(np.asarray(goal_mm, dtype=float)))

    def motion_valid(self, pose: np.ndarray, spin: float, kappa: float, length: float) -> bool:
        """Whether the motion ``(spin, kappa, length)`` from ``pose`` is valid.

        Parameters
        ----------
        pose : ndarray, shape (4, 4), float64, C-contiguous
            A pose the search made (not checked again).
        spin, kappa, length : float

        Returns
        -------
        bool
        """
        if length <= 0.0:
            return True
        # samples_for_spacing's count (inline: the hot path), so that the plan check
        # re-derives these very samples from the primitives
        m = max(2, math.ceil(length / self.spacing_mm - 1e-12) + 1)
        if self._check_heading:
            if kappa != 0.0:
                dot = min_tangent_dot_unchecked(pose, spin, kappa, length, self.start_dir)
            else:
                d = self.start_dir
                dot = pose[0, 2] * d[0] + pose[1, 2] * d[1] + pose[2, 2] * d[2]
            if dot < self.cos_heading - 1e-12:
                return False
        return not self._collides(arc_points_unchecked(pose, spin, kappa, length, m)[1:])

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
        g = np.ascontiguousarray(pose, dtype=np.float64)
        for spin, kappa, length in primitives:
            spin, kappa, length = float(spin), float(kappa), float(length)
            if not self.motion_valid(g, spin, kappa, length):
                return False
            g = arc_end_unchecked(g, spin, kappa, length)
        return True

    def warm_up(self) -> float:
        """Compile (or load from numba's cache) every kernel a search calls, so that time
        budgets measure search, not one-time set-up.

        Returns
        -------
        float
            Seconds it took.
        """
        t0 = time.perf_counter()
        pose = np.eye(4) if self.start is None else np.ascontiguousarray(self.start)
        self.motion_valid(pose, 0.0, self.problem.kappa_max_per_mm, self.spacing_mm)
        self.motion_valid(pose, 0.0, 0.0, self.spacing_mm)
        arc_end_unchecked(pose, 0.0, 0.0, 1.0)
        self.checker.warm_up()
        self.problem.scene.clearance(pose[:3, 3][None])  # the field the plan check reads
        return time.perf_counter() - t0
