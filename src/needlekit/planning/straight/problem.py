"""The straight-needle planning problem (Liu et al. 2016), separate from its planners.

A straight needle is a segment from an entry point on the entry surface to a target. With
the target fixed, a trajectory is a direction: Liu's needle is "an arm with a single
ball-hinge joint" at the target, its position given by two angles in a frame Sigma whose
origin is the target and whose z axis points up, out of the patient (Eq. 1):

    u(theta, phi) = (sin theta cos phi, sin theta sin phi, cos theta)   (target -> entry)

``theta`` (from Sigma's z) and ``phi`` (about it, from its x) are limited to boxes (Eq. 2).
A :class:`StraightProblem` says what a trajectory must satisfy; the CFRW map
(:mod:`needlekit.planning.straight.cfrw`) evaluates every direction against it.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from needlekit._validation import as_points, as_positive
from needlekit.anatomy.fields import DistanceField, union
from needlekit.anatomy.scene import Role, Scene
from needlekit.constants import DEFAULT_MAX_LENGTH_MM
from needlekit.errors import InvalidInputError
from needlekit.planning.straight.angle_grid import DEFAULT_PHI_RANGE_DEG, DEFAULT_THETA_RANGE_DEG

__all__ = [
    "DEFAULT_GAMMA_MM",
    "StraightNeedle",
    "StraightProblem",
    "angles_of",
    "directions_of",
    "sigma_frame",
]

#: Liu et al.'s safety distance gamma (mm): the CFRW boundary keeps the needle 1.5 mm from
#: every obstacle (their Fig. 12 measures exactly this).
DEFAULT_GAMMA_MM: float = 1.5


@dataclass(frozen=True)
class StraightNeedle:
    """A straight needle.

    Attributes
    ----------
    radius_mm : float
        Radius of the tube (the capsule around the trajectory).
    max_length_mm : float
        Longest insertion, target to entry point.
    """

    radius_mm: float = 1.0
    max_length_mm: float = DEFAULT_MAX_LENGTH_MM

    def __post_init__(self) -> None:
        object.__setattr__(self, "radius_mm", as_positive(self.radius_mm, "radius_mm"))
        object.__setattr__(self, "max_length_mm", as_positive(self.max_length_mm, "max_length_mm"))


def sigma_frame(target_mm, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """Liu's frame Sigma: origin at the target, z along ``up`` (out of the patient).

    Parameters
    ----------
    target_mm : array_like, shape (3,)
    up : array_like, shape (3,)
        World direction of Sigma's z axis (default RAS +z); its x axis is the component
        of world x (else world y) orthogonal to it.

    Returns
    -------
    ndarray, shape (4, 4)
        ``world_T_sigma``.
    """
    z = np.asarray(up, dtype=float).reshape(3)
    n = float(np.linalg.norm(z))
    if not (np.isfinite(n) and n > 1e-12):
        raise InvalidInputError("up", f"expected a non-zero vector, got {up!r}")
    z = z / n
    helper = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = helper - (helper @ z) * z
    x /= np.linalg.norm(x)
    g = np.eye(4)
    g[:3, :3] = np.column_stack([x, np.cross(z, x), z])
    g[:3, 3] = np.asarray(target_mm, dtype=float).reshape(3)
    return g


def directions_of(theta_rad, phi_rad, world_T_sigma: np.ndarray) -> np.ndarray:
    """World unit directions (target toward entry) of angles in Sigma (Eq. 1).

    Parameters
    ----------
    theta_rad, phi_rad : array_like, broadcastable
    world_T_sigma : ndarray, shape (4, 4)

    Returns
    -------
    ndarray, shape (..., 3)
    """
    t, p = np.broadcast_arrays(np.asarray(theta_rad, float), np.asarray(phi_rad, float))
    local = np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], axis=-1)
    return local @ world_T_sigma[:3, :3].T


def angles_of(directions, world_T_sigma: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Sigma angles ``(theta, phi)`` (rad) of world directions (the inverse of
    :func:`directions_of`; ``phi`` in ``(-pi, pi]``).

    Parameters
    ----------
    directions : array_like, shape (n, 3)
    world_T_sigma : ndarray, shape (4, 4)

    Returns
    -------
    theta, phi : ndarray, shape (n,)
    """
    d = np.asarray(directions, dtype=float).reshape(-1, 3)
    local = d @ world_T_sigma[:3, :3]
    theta = np.arctan2(np.hypot(local[:, 0], local[:, 1]), local[:, 2])
    phi = np.arctan2(local[:, 1], local[:, 0])
    return theta, phi


def _range(value, name: str, lo: float, hi: float) -> tuple[float, float]:
    a, b = (float(v) for v in np.asarray(value, dtype=float).reshape(2))
    if not (np.isfinite(a) and np.isfinite(b) and lo <= a < b <= hi):
        raise InvalidInputError(
            name, f"expected [min, max] with {lo:g} <= min < max <= {hi:g} (deg), got {value!r}"
        )
    return a, b


@dataclass(frozen=True)
class StraightProblem:
    """A straight-needle planning problem (RAS mm; angles in degrees in names).

    Attributes
    ----------
    scene : Scene
        The anatomy: its ``obstacle`` structures are what trajectories avoid.
    target_mm : ndarray, shape (3,)
        Where the tip must be (possibly displaced by deformation: ``P'_B`` of Eq. 1).
    entry_surface : str
        Structure whose surface the needle enters through (its inside is the body): the
        skin, or a Med-RAD liver's capsule.
    needle : StraightNeedle
    gamma_mm : float
        Safety distance: every trajectory keeps the needle's surface at least this far from
        every obstacle (certified: see :mod:`~needlekit.planning.straight.cfrw`).
    theta_range_deg, phi_range_deg : (float, float)
        Eq. 2's limits of the Sigma angles (``theta`` in [0, 180], ``phi`` in [-180, 180]).
    up : ndarray, shape (3,)
        World direction of Sigma's z axis (out of the patient; default RAS +z as in the
        paper's "vertical-up" frame).
    max_normal_angle_deg : float
        Largest angle between the needle and the entry surface's inward normal at the
        entry point (90: no limit).
    extra_obstacles : tuple of DistanceField
        Further obstacles (placed needles: their bodies).
    approach_direction : ndarray, shape (3,) or None
        With ``approach_cone_deg``: trajectories must point (target to entry) within that
        cone of this direction (e.g. the reverse of a Med-RAD start pose's z axis).
    approach_cone_deg : float
        Half-angle of that cone (180: no limit).
    """

    scene: Scene
    target_mm: np.ndarray
    entry_surface: str
    needle: StraightNeedle = field(default_factory=StraightNeedle)
    gamma_mm: float = DEFAULT_GAMMA_MM
    theta_range_deg: tuple = DEFAULT_THETA_RANGE_DEG
    phi_range_deg: tuple = DEFAULT_PHI_RANGE_DEG
    up: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, 1.0]))
    max_normal_angle_deg: float = 90.0
    extra_obstacles: tuple = ()
    approach_direction: np.ndarray | None = None
    approach_cone_deg: float = 180.0

    def __post_init__(self) -> None:
        if not isinstance(self.scene, Scene):
            raise InvalidInputError("scene", f"expected a Scene, got {type(self.scene).__name__}")
        p, single = as_points(self.target_mm, "target_mm")
        if not single:
            raise InvalidInputError("target_mm", "expected one point (3,)")
        object.__setattr__(self, "target_mm", p[0])
        if self.entry_surface not in self.scene:
            raise InvalidInputError(
                "entry_surface", f"no structure named {self.entry_surface!r} in the scene"
            )
        if not isinstance(self.needle, StraightNeedle):
            raise InvalidInputError("needle", "expected a StraightNeedle")
        g = float(self.gamma_mm)
        if not (np.isfinite(g) and g >= 0):
            raise InvalidInputError(
                "gamma_mm", f"must be a finite number >= 0, got {self.gamma_mm!r}"
            )
        object.__setattr__(self, "gamma_mm", g)
        object.__setattr__(
            self, "theta_range_deg", _range(self.theta_range_deg, "theta_range_deg", 0.0, 180.0)
        )
        object.__setattr__(
            self, "phi_range_deg", _range(self.phi_range_deg, "phi_range_deg", -180.0, 180.0)
        )
        sigma_frame(self.target_mm, self.up)  # checks up
        object.__setattr__(self, "up", np.asarray(self.up, dtype=float).reshape(3))
        a = float(self.max_normal_angle_deg)
        if not (np.isfinite(a) and 0 < a <= 90):
            raise InvalidInputError(
                "max_normal_angle_deg", f"must lie in (0, 90], got {self.max_normal_angle_deg!r}"
            )
        for i, f in enumerate(self.extra_obstacles):
            if not isinstance(f, DistanceField):
                raise InvalidInputError(f"extra_obstacles[{i}]", "expected a DistanceField")
        object.__setattr__(self, "extra_obstacles", tuple(self.extra_obstacles))
        c = float(self.approach_cone_deg)
        if not (np.isfinite(c) and 0 < c <= 180):
            raise InvalidInputError(
                "approach_cone_deg", f"must lie in (0, 180], got {self.approach_cone_deg!r}"
            )
        if self.approach_direction is not None:
            d = np.asarray(self.approach_direction, dtype=float).reshape(-1)
            n = float(np.linalg.norm(d)) if d.shape == (3,) else 0.0
            if not (np.isfinite(n) and n > 1e-12):
                raise InvalidInputError("approach_direction", "expected a non-zero vector (3,)")
            object.__setattr__(self, "approach_direction", d / n)
        if not self.scene.by_role(Role.OBSTACLE) and not self.extra_obstacles:
            raise InvalidInputError("scene", "has no obstacles to plan around")

    @property
    def world_T_sigma(self) -> np.ndarray:
        """Liu's frame Sigma at the target (:func:`sigma_frame`), shape (4, 4)."""
        return sigma_frame(self.target_mm, self.up)

    @property
    def clearance_needed_mm(self) -> float:
        """Distance the needle's axis keeps from every obstacle: radius plus gamma (mm)."""
        return self.needle.radius_mm + self.gamma_mm

    def obstacle_field(self) -> DistanceField:
        """The union of the scene's obstacles and the extra ones (placed needles).

        Returns
        -------
        DistanceField
        """
        parts = [s.field for s in self.scene.by_role(Role.OBSTACLE)]
        return union(*parts, *self.extra_obstacles)

    def anatomy_field(self) -> DistanceField | None:
        """The union of the scene's obstacles alone (None when it has none: every obstacle
        is an extra one).

        Returns
        -------
        DistanceField or None
        """
        parts = [s.field for s in self.scene.by_role(Role.OBSTACLE)]
        return union(*parts) if parts else None

    def with_target(self, target_mm) -> StraightProblem:
        """The same problem for another target.

        Parameters
        ----------
        target_mm : array_like, shape (3,)

        Returns
        -------
        StraightProblem
        """
        return replace(self, target_mm=np.asarray(target_mm, dtype=float))

    def with_obstacles(self, *fields: DistanceField) -> StraightProblem:
        """The same problem with further obstacles (e.g. the needles placed so far).

        Parameters
        ----------
        *fields : DistanceField

        Returns
        -------
        StraightProblem
        """
        return replace(self, extra_obstacles=self.extra_obstacles + tuple(fields))
