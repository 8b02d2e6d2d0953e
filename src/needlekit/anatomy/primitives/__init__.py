"""Exact signed Euclidean distance to analytic shapes: the obstacles of Liu et al. (2016).

Every shape here is a :class:`~needlekit.anatomy.fields.DistanceField` defined in its own
local frame (mm) and placed in the world (RAS, mm) by an optional pose ``world_T_local``
(4x4, identity by default). Distances are the true Euclidean distance to the surface,
negative inside, and gradients are the analytic outward unit normal at the closest
surface point (on the medial axis, where the closest point is not unique, one of the
candidate normals).

========================  ===================================  ===================
shape                     local definition                     distance
========================  ===================================  ===================
:class:`Sphere`           ``|x - c| <= r``                     closed form
:class:`Capsule`          points within ``r`` of segment p0-p1 closed form
:class:`Cylinder`         finite, flat caps                    closed form (edges too)
:class:`Box`              ``|x_i| <= h_i``                     closed form
:class:`HalfSpace`        ``(x - q) . n <= 0``                 closed form
:class:`Ellipsoid`        ``sum (x_i / a_i)^2 <= 1``           1-D root (Eberly)
:class:`Superquadric`     ``sum |x_i / a_i|^{e_i} <= 1``       1-D root / projection
========================  ===================================  ===================

Superquadrics are the obstacle model of Liu et al. (2016), Eq. 4: the needle head is
``(x/60)^8 + (y/0.1)^2 + (z/0.1)^2 - 1000 = 0`` in a frame at its centre with x along
the needle (:meth:`Superquadric.from_liu`). Planners need a *safety* distance, so this
module projects points onto the surface exactly instead of using the "radial"
inside-outside estimate, which overestimates clearance several times near elongated
shapes; :func:`radial_distance_approximation` is kept only to show that.

Fast kernels (numba, ``cache=True``) sit beside slow references that the tests hold them
to: :func:`ellipsoid_distance` vs :func:`ellipsoid_distance_reference` (the same
bisection in plain Python) and :func:`superquadric_distance` vs
:func:`superquadric_distance_reference` (scipy SLSQP from many starts, then a Newton
polish of the Lagrange conditions).

References
----------
D. Eberly, "Distance from a point to an ellipse, an ellipsoid, or a hyperellipsoid",
Geometric Tools (2013).
T. Liu et al., "Automatic multiple-needle surgical planning of robotic-assisted microwave
coagulation in large liver tumor therapy", PLoS ONE 11(3): e0149482 (2016).
"""

from needlekit.anatomy.primitives._base import (
    ELLIPSOID_ERROR_BOUND_MM,
    MIN_AXIS_LENGTH_MM,
    SUPERQUADRIC_ERROR_BOUND_MM,
    SUPERQUADRIC_MAX_EXPONENT,
)
from needlekit.anatomy.primitives.closed_forms import Box, Capsule, Cylinder, HalfSpace, Sphere
from needlekit.anatomy.primitives.ellipsoid import (
    Ellipsoid,
    ellipsoid_distance,
    ellipsoid_distance_reference,
)
from needlekit.anatomy.primitives.reference import (
    radial_distance_approximation,
    superquadric_distance_reference,
)
from needlekit.anatomy.primitives.superquadric import Superquadric, superquadric_distance

__all__ = [
    "ELLIPSOID_ERROR_BOUND_MM",
    "MIN_AXIS_LENGTH_MM",
    "SUPERQUADRIC_ERROR_BOUND_MM",
    "SUPERQUADRIC_MAX_EXPONENT",
    "Box",
    "Capsule",
    "Cylinder",
    "Ellipsoid",
    "HalfSpace",
    "Sphere",
    "Superquadric",
    "ellipsoid_distance",
    "ellipsoid_distance_reference",
    "radial_distance_approximation",
    "superquadric_distance",
    "superquadric_distance_reference",
]
