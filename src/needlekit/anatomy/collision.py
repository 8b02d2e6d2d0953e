"""Collision checkers: how a planning problem decides whether the needle collides.

One protocol, :class:`CollisionChecker` (OMPL's ``StateValidityChecker``), with two built-in
implementations that are peers:

- ``field`` (:class:`FieldChecker`): the scene's obstacle field. Certified: a sample is
  clear only when the field, grown by the needle radius plus margin, exceeds the field's
  stated error bound plus half the sample spacing, so every point between samples is
  clear too (the field is 1-Lipschitz), whatever the field's error;
- ``voxel_centres`` (:class:`VoxelCentresChecker`): the reference planner's test against
  obstacle voxel centres (:class:`~needlekit.anatomy.occupancy.VoxelObstacles`), certified
  the same way: a sample is clear only when no obstacle voxel centre lies closer than the
  reference's threshold (needle radius, half a voxel diagonal, margin) plus half the
  sample spacing, so the needle keeps the margin from every obstacle voxel ball along the
  whole motion, not only at its samples.

Both apply the one clearance rule of :mod:`needlekit.constants`: ``collides`` (the
search's question, at the checker's spacing) refuses a sample that ``certify`` (the plan
check's, at the same spacing) would refuse, and a little more
(:data:`~needlekit.constants.CLEARANCE_ROUNDING_MM`), so that what a search accepts the
check accepts.

A checker is bound to one needle and one start: obstacles within the start exclusion of
the start point are ignored (a transbronchial needle leaves the airway through its wall).
Planners, the plan check and the moving-obstacle code call only the protocol; nobody
branches on a checker's name. A new checker registers a factory by name
(:func:`register_collision_checker`, or the ``needlekit.collision_checkers`` entry-point
group; :mod:`needlekit.anatomy.collision_registry`) and problems name it in
``collision_model``.

Examples
--------
>>> import numpy as np
>>> from needlekit.anatomy.primitives import Sphere
>>> from needlekit.anatomy.scene import Role, Scene, Structure
>>> scene = Scene([Structure("vessel", Role.OBSTACLE, Sphere([0.0, 0.0, 20.0], 5.0))])
>>> checker = FieldChecker(scene, needle_radius_mm=0.5, safety_margin_mm=0.0,
...                        start_point_mm=np.zeros(3), exclusion_mm=0.0, spacing_mm=0.5)
>>> checker.collides(np.array([[0.0, 0.0, 14.7], [0.0, 0.0, 10.0]]))
True
>>> checker.collides(np.array([[0.0, 0.0, 10.0]]))
False
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Protocol, runtime_checkable

import numpy as np

from needlekit.anatomy.collision_registry import (
    collision_checker_names,
    collision_factory,
    register_collision_checker,
    unregister_collision_checker,
)
from needlekit.anatomy.occupancy import VoxelObstacles, any_collides_unchecked, colliding_samples
from needlekit.anatomy.scene import Scene
from needlekit.anatomy.voxel_clearance import smallest_obstacle_distance
from needlekit.anatomy.voxel_connectivity import goal_connected, warm_up
from needlekit.constants import CLEARANCE_ROUNDING_MM
from needlekit.errors import InvalidInputError

__all__ = [
    "ClearanceCertificate",
    "CollisionChecker",
    "CollisionSetup",
    "FieldChecker",
    "VoxelCentresChecker",
    "collision_checker_names",
    "make_collision_checker",
    "register_collision_checker",
    "unregister_collision_checker",
]

#: Beyond this clearance (mm) the voxel-centre model reports the cap (its kernel visits only
#: the voxels within it); far above any margin a plan is judged by.
CLEARANCE_REPORT_CAP_MM: float = 10.0
#: Cells the finer connectivity proof may visit before it gives up (about 30-50 ms on a
#: Med-RAD lung; a sealed start is closed within a few hundred).
FINER_MAX_CELLS: int = 100_000


@dataclass(frozen=True)
class ClearanceCertificate:
    """What a checker certifies about a sampled path.

    Attributes
    ----------
    colliding_samples : int
        Samples that collide under the checker's rule.
    sampled_clearance_mm : float
        Smallest sampled distance from the needle's surface to an obstacle (an estimate).
    certified_clearance_mm : float
        A lower bound of that distance for the whole path, not only its samples.
    violation : str or None
        One line when the path collides under the checker's rule, else None.
    """

    colliding_samples: int
    sampled_clearance_mm: float
    certified_clearance_mm: float
    violation: str | None


@dataclass(frozen=True)
class CollisionSetup:
    """What a checker factory is given: the problem's needle, start and anatomy.

    Attributes
    ----------
    scene : Scene
    needle_diameter_mm, safety_margin_mm : float
    start_point_mm : ndarray, shape (3,)
    exclusion_mm : float
        Obstacles within this distance of the start point are ignored.
    spacing_mm : float
        Largest gap between the samples the checker is asked about along a motion.
    voxel_obstacles : VoxelObstacles or None
        The problem's obstacle voxels, when it has them.
    options : dict
        The problem's ``collision_options`` (a checker's own settings).
    """

    scene: Scene
    needle_diameter_mm: float
    safety_margin_mm: float
    start_point_mm: np.ndarray
    exclusion_mm: float
    spacing_mm: float
    voxel_obstacles: VoxelObstacles | None = None
    options: dict | None = None


@runtime_checkable
class CollisionChecker(Protocol):
    """What planners, the plan check and the moving-obstacle code ask of a collision model.

    A checker may also define ``connected_finer(goal_mm, **limits) -> bool | None``, a
    costlier proof than :meth:`connected` (the same arguments) which a search runs once
    when it has found no plan after a few milliseconds; checkers without it are asked
    nothing more (``voxel_centres`` fills cells half a voxel wide there).

    Attributes
    ----------
    name : str
        The model's registered name (recorded in results).
    reads_scene : bool
        Whether collisions come from the scene's obstacle field, so that obstacles added to
        the scene (moving ones) count.
    """

    name: str
    reads_scene: bool

    def collides(self, points: np.ndarray) -> bool:
        """Whether any of the motion samples collides (start exclusion applied).

        Parameters
        ----------
        points : ndarray, shape (n, 3), float64, C-contiguous
            Samples no farther apart than the checker's spacing.

        Returns
        -------
        bool
            True unless the needle is certainly clear along the whole motion: at least
            whenever :meth:`certify` at the checker's spacing finds a violation on them
            (the search never accepts what the plan check refuses).
        """

    def goal_collides(self, goal_mm: np.ndarray) -> bool:
        """Whether the goal point provably lies where the needle cannot be (no exclusion).

        Parameters
        ----------
        goal_mm : ndarray, shape (3,)

        Returns
        -------
        bool
        """

    def certify(self, points: np.ndarray, spacing_mm: float) -> ClearanceCertificate:
        """The plan check's verdict and clearance bound for a densely sampled path.

        Parameters
        ----------
        points : ndarray, shape (n, 3)
            The path's samples (start exclusion applied by the checker).
        spacing_mm : float
            Largest gap between them.

        Returns
        -------
        ClearanceCertificate
        """

    def connected(
        self,
        goal_mm: np.ndarray,
        *,
        max_length_mm: float,
        goal_tolerance_mm: float,
        start_direction: np.ndarray,
        r_min_mm: float,
        max_heading_change_deg: float,
    ) -> bool | None:
        """Whether free space connects the start to the goal.

        Parameters
        ----------
        goal_mm : ndarray, shape (3,)
        max_length_mm, goal_tolerance_mm : float
        start_direction : ndarray, shape (3,)
        r_min_mm, max_heading_change_deg : float
            The path limits: they bound where a valid path can go.

        Returns
        -------
        bool or None
            False only with a proof that no valid path reaches the goal; None when the
            checker has no such argument.
        """

    def warm_up(self) -> None:
        """Compile or load every kernel the checker's calls use.

        Returns
        -------
        None
        """


class FieldChecker(CollisionChecker):
    """The ``field`` model: the scene's obstacle field, certified (module notes).

    Parameters
    ----------
    scene : Scene
    needle_radius_mm, safety_margin_mm : float
    start_point_mm : ndarray, shape (3,)
    exclusion_mm : float
    spacing_mm : float
        Largest gap between motion samples.
    """

    name = "field"
    reads_scene = True

    def __init__(
        self,
        scene: Scene,
        *,
        needle_radius_mm: float,
        safety_margin_mm: float,
        start_point_mm: np.ndarray,
        exclusion_mm: float,
        spacing_mm: float,
    ) -> None:
        self.scene = scene
        self.radius = float(needle_radius_mm)
        self.margin = float(safety_margin_mm)
        self.start = np.ascontiguousarray(start_point_mm, dtype=np.float64).reshape(3)
        self.exclusion = float(exclusion_mm)
        self.spacing_mm = float(spacing_mm)
        self._grown = None

    @property
    def grown(self):
        """The obstacle field grown by the needle radius plus margin (built on first use)."""
        if self._grown is None:
            self._grown = self.scene.obstacle_field(self.radius + self.margin)
        return self._grown

    @property
    def threshold_mm(self) -> float:
        """The smallest grown-field value a motion sample must reach: the field's error
        bound plus half the sample spacing (and the rounding allowance)."""
        return self._threshold(self.spacing_mm) + CLEARANCE_ROUNDING_MM

    def _threshold(self, spacing_mm: float) -> float:
        return float(self.grown.error_bound_mm) + 0.5 * float(spacing_mm)

    def _far(self, points: np.ndarray) -> np.ndarray:
        if self.exclusion <= 0.0:
            return points
        d = points - self.start
        return points[np.einsum("ij,ij->i", d, d) >= self.exclusion * self.exclusion]

    def collides(self, points: np.ndarray) -> bool:
        far = self._far(points)
        if len(far) == 0:
            return False
        return bool((self.grown.signed_distance(far) < self.threshold_mm).any())

    def goal_collides(self, goal_mm: np.ndarray) -> bool:
        g = np.asarray(goal_mm, dtype=float).reshape(1, 3)
        return bool(self.grown.signed_distance(g)[0] < -self.grown.error_bound_mm)

    def certify(self, points: np.ndarray, spacing_mm: float) -> ClearanceCertificate:
        # the grown field the search reads, with its own error bound: one rule for both
        far = self._far(points)
        g = self.grown.signed_distance(far) if len(far) else np.array([np.inf])
        half_gap, bound = 0.5 * float(spacing_mm), float(self.grown.error_bound_mm)
        sampled = float(g.min()) + self.margin  # distance from the needle's surface
        certified = sampled - half_gap - bound
        hits = int(np.count_nonzero(g < self._threshold(spacing_mm)))
        violation = None
        if hits:
            violation = (
                f"collision: certified clearance {certified:.4f} mm (sampled {sampled:.4f} mm, "
                f"less half the {spacing_mm:g} mm sample gap and the field's "
                f"{bound:.4f} mm error bound) below the safety margin "
                f"{self.margin:g} mm, outside the start exclusion"
            )
        return ClearanceCertificate(hits, sampled, certified, violation)

    def connected(self, goal_mm, **limits) -> bool | None:
        return None

    def warm_up(self) -> None:
        # a motion's worth of samples: more than the few-point lookups, so the kernels
        # the search calls are the ones compiled (or loaded) here
        p = self.start[None] + 1e-3 * np.arange(1, 33)[:, None]
        self.grown.signed_distance(p)


class VoxelCentresChecker(CollisionChecker):
    """The ``voxel_centres`` model: the reference planner's exact voxel-centre test.

    Parameters
    ----------
    obstacles : VoxelObstacles
        Built for this needle's diameter and margin.
    needle_radius_mm : float
    start_point_mm : ndarray, shape (3,)
    exclusion_mm : float
    spacing_mm : float
        Largest gap between motion samples (the connectivity proof needs it below the
        voxel spacing).
    """

    name = "voxel_centres"
    reads_scene = False

    def __init__(
        self,
        obstacles: VoxelObstacles,
        *,
        needle_radius_mm: float,
        start_point_mm: np.ndarray,
        exclusion_mm: float,
        spacing_mm: float,
    ) -> None:
        self.obstacles = obstacles
        self.radius = float(needle_radius_mm)
        self.start = np.ascontiguousarray(start_point_mm, dtype=np.float64).reshape(3)
        self.exclusion = float(exclusion_mm)
        self.spacing_mm = float(spacing_mm)
        o = obstacles
        # the reference's threshold plus half the sample gap (every point between samples
        # keeps the margin from the voxel balls), plus the rounding allowance
        self.threshold_mm = self._threshold(self.spacing_mm) + CLEARANCE_ROUNDING_MM
        self._args = (o.occupancy, o.blocks, o.inv_affine, o.affine, self.threshold_mm)

    def _threshold(self, spacing_mm: float) -> float:
        """The smallest distance (mm) a sample must keep from every obstacle voxel centre."""
        return self.obstacles.min_distance_mm + 0.5 * float(spacing_mm)

    def collides(self, points: np.ndarray) -> bool:
        return bool(any_collides_unchecked(*self._args, self.start, self.exclusion, points))

    def goal_collides(self, goal_mm: np.ndarray) -> bool:
        return bool(self.obstacles.collides(np.asarray(goal_mm, dtype=float).reshape(1, 3))[0])

    def certify(self, points: np.ndarray, spacing_mm: float) -> ClearanceCertificate:
        o = self.obstacles
        pts = np.ascontiguousarray(points, dtype=np.float64)
        threshold = self._threshold(spacing_mm)
        hits = colliding_samples(o, pts, threshold, self.start, self.exclusion)
        n_hits = int(np.count_nonzero(hits))
        violation = None
        if n_hits:
            first = pts[np.flatnonzero(hits)[0]]
            violation = (
                f"collision: {n_hits} samples within {threshold:.4f} mm of an obstacle voxel "
                f"centre (the reference's {o.min_distance_mm:.4f} mm and half the "
                f"{float(spacing_mm):g} mm sample gap) or outside the image, first at "
                f"{np.round(first, 2).tolist()}"
            )
        ball = o.voxel_radius_mm + self.radius
        nearest = smallest_obstacle_distance(
            o,
            pts,
            cap_mm=ball + CLEARANCE_REPORT_CAP_MM,
            near_mm=o.min_distance_mm,
            exclude_near=self.start,
            exclusion_mm=self.exclusion,
        )
        sampled = nearest - ball if len(pts) else math.inf
        return ClearanceCertificate(n_hits, sampled, sampled - 0.5 * float(spacing_mm), violation)

    def connected(
        self,
        goal_mm,
        *,
        max_length_mm,
        goal_tolerance_mm,
        start_direction=None,
        r_min_mm=None,
        max_heading_change_deg=None,
    ) -> bool | None:
        return self._fill(
            goal_mm,
            max_length_mm=max_length_mm,
            goal_tolerance_mm=goal_tolerance_mm,
            start_direction=start_direction,
            r_min_mm=r_min_mm,
            max_heading_change_deg=max_heading_change_deg,
        )

    def connected_finer(self, goal_mm, **limits) -> bool | None:
        """The same proof over cells half a voxel wide (``subdivide=2``), which seal gaps
        one voxel wide that the needle cannot pass, up to :data:`FINER_MAX_CELLS` cells.

        Parameters
        ----------
        goal_mm : ndarray, shape (3,)
        **limits
            As :meth:`connected` takes them.

        Returns
        -------
        bool or None
            False only with a proof that no valid path reaches the goal; None when the
            fill could not tell within its cells.
        """
        return self._fill(goal_mm, subdivide=2, max_cells=FINER_MAX_CELLS, **limits)

    def _fill(self, goal_mm, **kwargs) -> bool | None:
        """:func:`goal_connected` from this checker's start, exclusion and spacing."""
        connected, _ = goal_connected(
            self.obstacles,
            self.start,
            np.asarray(goal_mm, dtype=float),
            exclusion_mm=self.exclusion,
            spacing_mm=self.spacing_mm,
            **kwargs,
        )
        return connected

    def warm_up(self) -> None:
        p = self.start[None].copy()
        self.collides(p)
        self.certify(p, self.spacing_mm)
        warm_up(self.obstacles, self.start, self.exclusion, self.spacing_mm)


# -- the built-in factories (the registry is needlekit.anatomy.collision_registry) --------


def _field(setup: CollisionSetup) -> FieldChecker:
    if setup.voxel_obstacles is not None:
        raise InvalidInputError(
            "voxel_obstacles",
            "given with the field collision model, which would ignore them; "
            "set collision_model='voxel_centres'",
        )
    return FieldChecker(
        setup.scene,
        needle_radius_mm=0.5 * setup.needle_diameter_mm,
        safety_margin_mm=setup.safety_margin_mm,
        start_point_mm=setup.start_point_mm,
        exclusion_mm=setup.exclusion_mm,
        spacing_mm=setup.spacing_mm,
    )


def _voxel_centres(setup: CollisionSetup) -> VoxelCentresChecker:
    obs = setup.voxel_obstacles
    if not isinstance(obs, VoxelObstacles):
        raise InvalidInputError(
            "voxel_obstacles",
            "the voxel_centres collision model needs the obstacle voxels "
            "(e.g. a Med-RAD case's voxel_obstacles(...))",
        )
    wanted = 0.5 * setup.needle_diameter_mm + obs.voxel_radius_mm + setup.safety_margin_mm
    if abs(obs.min_distance_mm - wanted) > 1e-9:
        raise InvalidInputError(
            "voxel_obstacles",
            f"built for a threshold of {obs.min_distance_mm:.4f} mm, but this needle "
            f"(diameter {setup.needle_diameter_mm:g} mm, margin "
            f"{setup.safety_margin_mm:g} mm) needs {wanted:.4f} mm",
        )
    return VoxelCentresChecker(
        obs,
        needle_radius_mm=0.5 * setup.needle_diameter_mm,
        start_point_mm=setup.start_point_mm,
        exclusion_mm=setup.exclusion_mm,
        spacing_mm=setup.spacing_mm,
    )


def make_collision_checker(name: str, setup: CollisionSetup) -> CollisionChecker:
    """Build the named checker for one problem.

    Parameters
    ----------
    name : str
    setup : CollisionSetup

    Returns
    -------
    CollisionChecker

    Raises
    ------
    InvalidInputError
        An unknown name, or a factory that refuses the setup or returns something that
        is not a checker.
    """
    checker: Any = collision_factory(name)(setup)
    if not isinstance(checker, CollisionChecker):
        raise InvalidInputError(
            "collision_model",
            f"the factory of {name!r} returned a {type(checker).__name__}, not a CollisionChecker",
        )
    return checker
