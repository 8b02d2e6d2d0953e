"""Bevel-tip needle kinematics: planar and 3D models, steering, reachability.

The tip frame's z axis is the insertion direction and the bevel bends the needle toward
the tip's -y axis (:mod:`needlekit.conventions`).
"""

from needlekit.needle.bevel3d import (
    BevelTrajectory,
    body_twist,
    pose_rate,
    propagate_bevel,
    simulate_bevel,
)
from needlekit.needle.planar import (
    PlanarSteering,
    PlanarTrajectory,
    planar_inverse,
    planar_rates,
    planar_steer_waypoints,
    simulate_planar,
)
from needlekit.needle.reachability import (
    ArcLinePath,
    SingleArc,
    is_reachable,
    lecture_reachability_condition,
    shortest_arc_line,
    single_arc_to,
    tip_coordinates,
)
from needlekit.needle.state_rates import (
    needle_jacobian,
    pose_from_state,
    state_from_pose,
    state_rates,
)
from needlekit.needle.transform_method import (
    SteeringSolution,
    tm_inverse,
    tm_pose,
    tm_transform,
    tm_waypoints,
)

__all__ = [
    "ArcLinePath",
    "BevelTrajectory",
    "PlanarSteering",
    "PlanarTrajectory",
    "SingleArc",
    "SteeringSolution",
    "body_twist",
    "is_reachable",
    "lecture_reachability_condition",
    "needle_jacobian",
    "planar_inverse",
    "planar_rates",
    "planar_steer_waypoints",
    "pose_from_state",
    "pose_rate",
    "propagate_bevel",
    "shortest_arc_line",
    "simulate_bevel",
    "simulate_planar",
    "single_arc_to",
    "state_from_pose",
    "state_rates",
    "tip_coordinates",
    "tm_inverse",
    "tm_pose",
    "tm_transform",
    "tm_waypoints",
]
