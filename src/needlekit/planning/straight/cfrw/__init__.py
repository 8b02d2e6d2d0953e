"""The collision-free reachable workspace (CFRW) of a straight needle (Liu et al. 2016).

For a fixed target, a trajectory is a direction ``u(theta, phi)`` (target toward entry,
:mod:`~needlekit.planning.straight.problem`). :func:`cfrw_map` evaluates a dense grid of
directions and keeps, for each, the entry point (where the ray leaves the body through the
entry surface), the insertion length, the angle to the surface's inward normal, and the
**certified clearance**: a lower bound on the distance from the needle's surface (the
capsule of the needle's radius around the segment target-entry) to every obstacle.

Certified clearance along a segment. A signed distance ``d`` is 1-Lipschitz, so between
two samples ``t_i < t_j`` of the segment the distance is at least
``(d_i + d_j - (t_j - t_i)) / 2``. The samples are taken by sphere tracing: far from
obstacles the step is the distance itself less a cap (so whole stretches are certified to
clear the cap at once), near them at most :data:`NEAR_STEP_MM`; the bound over all
intervals, less the field's stated error bound and the needle radius, is the certified
clearance (reported up to ``cap``). A direction belongs to the CFRW when that clearance is
at least gamma (the paper's safety distance), and the other limits hold.

Convex obstacles and placed needles. The clearance of a union is the smallest of its
parts', so each placed needle is bounded on its own (:func:`obstacle_segment_bound`,
:func:`clearance_bound`). Its tube is a capsule: the distance between the candidate
segment and the tube's axis, less the radius, is exact in closed form. Its head (Eq. 4's
superquadric, every exponent >= 2) is convex, and the signed distance to a convex solid is
a convex function, so along a segment its tangent lines lie below it:
:func:`convex_segment_bound` keeps a bracket where the slope changes sign, bounds the
minimum by where the two end tangents meet (or by the 1-Lipschitz bound, whichever is
higher), and splits until the bound and the best sample differ by at most
:data:`CONVEX_TOL_MM`; each slope is widened by its error (the projection's error over the
distance) and each part let go keeps its tangent's bound, so the result stays a lower
bound. Segments farther than the cap from the head's enclosing capsule (closed form) are
certified at the cap without evaluating the head, and a segment found inside the head gets
the head's depth bound. :meth:`CFRWMap.with_obstacles` adds placed needles to a map of the
anatomy without searching the entries or tracing the anatomy again; the result equals
:func:`cfrw_map` of the problem with them, number for number.

Entry points. From the target, each ray marches in steps of ``|d| / L`` (``L`` the entry
surface field's Lipschitz bound: 1 for exact distances, computed from the grid for voxel
fields), so no sign change of the field is stepped over (but for parts shorter than
:data:`ENTRY_MIN_STEP_MM`), then bisects the crossing to :data:`ENTRY_TOL_MM`.

The CFRW's boundary is drawn, as in the paper's Fig. 11, in layered planes ``z = h`` of
Sigma: each direction meets the plane at ``h tan(theta) (cos phi, sin phi)``. Boundary
points are found on the grid (marching squares over ``clearance - gamma``) and refined by
bisection in ``theta`` on a finely sampled clearance, so that trajectories on the boundary
clear the obstacles by gamma to within :data:`BOUNDARY_TOL_MM`. The paper's ray-casting
test (step 3 of its entry search) decides whether a point of a layer lies inside the
closed boundary polylines, holes included (:func:`inside_polylines`).

One concept per module: :mod:`.bounds` (certified clearance along a segment),
:mod:`.entries` (entry points), :mod:`.map` (the map, its layers and boundary) and
:mod:`.build` (:func:`cfrw_map`); every public name imports from this package.
"""

from __future__ import annotations

from needlekit.planning.straight.cfrw.bounds import (
    CLEARANCE_CAP_ABOVE_GAMMA_MM,
    CONVEX_MAX_ITER,
    CONVEX_TOL_MM,
    NEAR_STEP_MM,
    clearance_bound,
    convex_segment_bound,
    obstacle_segment_bound,
    segment_clearance_bound,
)
from needlekit.planning.straight.cfrw.build import cfrw_map
from needlekit.planning.straight.cfrw.entries import ENTRY_MIN_STEP_MM, ENTRY_TOL_MM, entry_points
from needlekit.planning.straight.cfrw.map import (
    BOUNDARY_TOL_MM,
    FINE_STEP_MM,
    Blocked,
    CFRWMap,
    inside_polylines,
)

__all__ = [
    "BOUNDARY_TOL_MM",
    "CLEARANCE_CAP_ABOVE_GAMMA_MM",
    "CONVEX_MAX_ITER",
    "CONVEX_TOL_MM",
    "ENTRY_MIN_STEP_MM",
    "ENTRY_TOL_MM",
    "FINE_STEP_MM",
    "NEAR_STEP_MM",
    "Blocked",
    "CFRWMap",
    "cfrw_map",
    "clearance_bound",
    "convex_segment_bound",
    "entry_points",
    "inside_polylines",
    "obstacle_segment_bound",
    "segment_clearance_bound",
]
