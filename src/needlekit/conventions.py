"""The conventions every part of needlekit follows, written once.

Units
    Lengths in millimetres, angles in radians, time in seconds, curvature in 1/mm.
    Public arguments and JSON fields carry the unit in their name where it is not obvious
    (``length_mm``, ``alpha_deg``, ``time_s``, ``kappa_per_mm``). Degrees appear only at
    the boundary (command line, reports) and behind an explicit ``degrees=`` flag.

World frame
    Patient RAS in mm (+x toward the patient's Right, +y Anterior, +z Superior), as NIfTI
    world space and 3D Slicer use. Conversion to LPS happens only where a file format asks for it.

Poses
    4x4 homogeneous matrices as numpy arrays, batches as ``(n, 4, 4)``, points as
    ``(n, 3)``. A transform is named by its frames: ``world_T_tip`` maps tip-frame
    coordinates to world coordinates.

Twists
    A twist is a 6-vector ``(v, omega)``: linear velocity first, angular velocity second,
    as in the lecture's ``mu1 = (0, 0, 1, kappa, 0, 0)``. Body twists are expressed in the
    moving frame (``g_dot = g @ hat(xi)``).

Needle tip frame
    z is the insertion direction (:data:`TIP_INSERTION_AXIS`). Inserting a bevel-tip
    needle with curvature ``kappa`` produces the body twist ``(0, 0, 1, kappa, 0, 0)`` per
    mm, a rotation about the tip's x axis, which turns the tangent toward the tip's
    **-y** axis: the bevel bends the needle toward -y (:data:`TIP_BEND_DIRECTION`).
    Spinning the needle by ``+psi`` about z turns the bend direction with it.

    The lecture's planar model (z, y, theta) with bevel side ``lambda = -1`` is this model
    in the tip's y-z plane with no spin; ``lambda = +1`` is the same needle spun by pi.
    The lecture's transformation-matrix method bends toward +x of a frame turned by
    ``alpha`` about z; its tip frame equals this model's tip frame turned by -pi/2 about z
    (``R_tm = R_twist @ Rz(-pi/2)``), with spin ``psi = alpha + pi/2``. Tests check all
    three against each other.

Randomness
    Functions that draw random numbers take ``rng: numpy.random.Generator`` (or a seed);
    nothing seeds a global generator.

Errors
    Deliberate errors derive from :class:`needlekit.errors.NeedlekitError`; bad input
    raises :class:`needlekit.errors.InvalidInputError` whose message starts with the
    argument or field name. The command line prints ``error: <message>`` and exits 2.
"""

from __future__ import annotations

import numpy as np

__all__ = ["TIP_BEND_DIRECTION", "TIP_INSERTION_AXIS", "TWIST_ORDER"]

#: Insertion direction in the tip frame.
TIP_INSERTION_AXIS = np.array([0.0, 0.0, 1.0])
TIP_INSERTION_AXIS.flags.writeable = False

#: Direction, in the tip frame, toward which the bevel bends the needle when inserted
#: without spin (follows from the body twist (0, 0, 1, kappa, 0, 0)).
TIP_BEND_DIRECTION = np.array([0.0, -1.0, 0.0])
TIP_BEND_DIRECTION.flags.writeable = False

#: Order of the components of a twist vector.
TWIST_ORDER = ("vx", "vy", "vz", "wx", "wy", "wz")
