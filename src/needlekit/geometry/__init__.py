"""Geometry: rotations, rigid motions, Euler-angle rate maps and constant-curvature arcs.

Pure functions over numpy arrays, batch-first (see :mod:`needlekit.conventions`).
"""

from needlekit.geometry.arcs import (
    arc_transform,
    propagate_arcs,
    propagate_arcs_reference,
    sample_arcs,
    sample_arcs_reference,
    samples_for_spacing,
)
from needlekit.geometry.euler import (
    CONVENTIONS,
    EULER_CONVENTIONS,
    FIXED_AXIS_CONVENTIONS,
    analytic_jacobian,
    angular_velocity_to_euler_rates,
    euler_rate_matrix,
    euler_rate_matrix_inv,
    euler_rates_to_angular_velocity,
    euler_to_matrix,
    matrix_to_euler,
)
from needlekit.geometry.se3 import (
    adjoint,
    hat6,
    make_pose,
    pose_inverse,
    se3_exp,
    se3_log,
    transform_points,
    vee6,
)
from needlekit.geometry.so3 import hat, rot_x, rot_y, rot_z, so3_exp, so3_log, vee

__all__ = [
    "CONVENTIONS",
    "EULER_CONVENTIONS",
    "FIXED_AXIS_CONVENTIONS",
    "adjoint",
    "analytic_jacobian",
    "angular_velocity_to_euler_rates",
    "arc_transform",
    "euler_rate_matrix",
    "euler_rate_matrix_inv",
    "euler_rates_to_angular_velocity",
    "euler_to_matrix",
    "hat",
    "hat6",
    "make_pose",
    "matrix_to_euler",
    "pose_inverse",
    "propagate_arcs",
    "propagate_arcs_reference",
    "rot_x",
    "rot_y",
    "rot_z",
    "sample_arcs",
    "sample_arcs_reference",
    "samples_for_spacing",
    "se3_exp",
    "se3_log",
    "so3_exp",
    "so3_log",
    "transform_points",
    "vee",
    "vee6",
]
