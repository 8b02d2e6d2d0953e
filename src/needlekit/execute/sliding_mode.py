"""The ``sliding_mode`` feedback law: bang-bang spin about the bevel's switching surface,
after Rucker, Das, Gilbert, Swaney, Miga, Sarkar and Webster, "Sliding mode control of
steerable needles", IEEE Transactions on Robotics 29(5), 2013.

A bevel tip always bends toward its bevel, at the needle's own curvature; what a robot
commands is how fast the needle turns about its axis. Rucker et al. make the bevel's
direction the sliding variable: the angle ``sigma`` from the bevel's bending direction
(the tip frame's -y axis, :mod:`needlekit.conventions`) to the target's direction in the
tip's cross-section. The law turns the needle at full rate toward the surface
``sigma = 0``,

    spin per step = omega_max dt sign(sigma),     curvature = 1 / r_min,

so that the bevel reaches the target's side in at most ``|sigma_0| / (omega_max dt)`` steps and
then chatters about it by at most ``omega_max dt``, the needle bending toward the target at
its full curvature. A target straight ahead asks for no bending: when the arc through it
needs less than ``straight_fraction`` of the needle's curvature, the needle spins
continuously at ``omega_max`` (duty-cycled insertion: on average straight), Rucker et
al.'s second mode.

The target is the plan's point ``lookahead_mm`` ahead of the point nearest the estimated
tip (the goal past the plan's end), as pure pursuit takes it
(:mod:`needlekit.execute.feedback`); the law differs in what it commands: the full
curvature always and the spin rate bounded, where pure pursuit spins at once and scales
the curvature.
"""

from __future__ import annotations

import math

import numpy as np

from needlekit.errors import InvalidInputError
from needlekit.execute.feedback import PlanReference

__all__ = ["SPIN_RATE_RAD_S", "STRAIGHT_FRACTION", "SlidingMode", "sliding_mode_law"]

#: The needle's fastest turn about its axis (rad/s): one revolution a second.
SPIN_RATE_RAD_S: float = 2.0 * math.pi
#: Below this fraction of the needle's curvature the needle spins to go straight.
STRAIGHT_FRACTION: float = 0.1


class SlidingMode:
    """The sliding-mode law (see the module notes).

    Parameters
    ----------
    lookahead_mm : float
    kappa_max_per_mm : float
        The needle's curvature, ``1 / r_min``.
    dt_s : float
        The control step: the spin per step is at most ``spin_rate_rad_s * dt_s``.
    spin_rate_rad_s : float
    straight_fraction : float
    """

    def __init__(self, lookahead_mm: float, kappa_max_per_mm: float, dt_s: float,
                 spin_rate_rad_s: float = SPIN_RATE_RAD_S,
                 straight_fraction: float = STRAIGHT_FRACTION) -> None:  # fmt: skip
        for name, v in (("spin_rate_rad_s", spin_rate_rad_s), ("dt_s", dt_s)):
            if not (math.isfinite(v) and v > 0):
                raise InvalidInputError(name, f"expected a number > 0, got {v!r}")
        if not 0.0 <= straight_fraction < 1.0:
            raise InvalidInputError(
                "straight_fraction", f"expected [0, 1), got {straight_fraction!r}"
            )
        self.lookahead_mm = float(lookahead_mm)
        self.kappa_max_per_mm = float(kappa_max_per_mm)
        self.max_spin_rad = float(spin_rate_rad_s * dt_s)
        self.straight_fraction = float(straight_fraction)

    def command(self, pose, target_mm) -> tuple[float, float]:
        """The spin and curvature toward ``target_mm`` from the tip ``pose``.

        Parameters
        ----------
        pose : ndarray, shape (4, 4)
        target_mm : array_like, shape (3,)

        Returns
        -------
        (float, float)
            ``(spin_rad, kappa_per_mm)``; the curvature is always ``1 / r_min``.

        Examples
        --------
        A target to the tip's +x side: the bevel (-y) turns toward it, one full step.

        >>> law = SlidingMode(10.0, 0.02, 0.005)
        >>> spin, kappa = law.command(np.eye(4), [5.0, 0.0, 10.0])
        >>> round(spin / law.max_spin_rad, 12), kappa
        (1.0, 0.02)
        """
        q = pose[:3, :3].T @ (np.asarray(target_mm, dtype=np.float64) - pose[:3, 3])
        lateral = math.hypot(q[0], q[1])
        qq = float(q @ q)
        if q[2] > 0.0 and 2.0 * lateral <= self.straight_fraction * self.kappa_max_per_mm * qq:
            return self.max_spin_rad, self.kappa_max_per_mm  # spin on: straight on average
        sigma = math.atan2(q[0], -q[1])  # the spin that would face the bevel to the target
        return math.copysign(self.max_spin_rad, sigma) if sigma else 0.0, self.kappa_max_per_mm

    def __call__(self, pose, reference: PlanReference, index: int) -> tuple[float, float]:
        """The command from the estimated tip (the feedback-law protocol).

        Parameters
        ----------
        pose : ndarray, shape (4, 4)
        reference : PlanReference
        index : int

        Returns
        -------
        (float, float)
        """
        return self.command(pose, reference.ahead(index, self.lookahead_mm))


def sliding_mode_law(setup) -> SlidingMode:
    """The ``sliding_mode`` law of a run: its look-ahead and step, the needle's ``1 / r_min``.

    Parameters
    ----------
    setup : needlekit.execute.plugins.Setup

    Returns
    -------
    SlidingMode
    """
    s = setup.settings
    return SlidingMode(s.lookahead_mm, 1.0 / setup.r_min_mm, s.dt_s)


sliding_mode_law.parameters = lambda settings: {
    "lookahead_mm": settings.lookahead_mm,
    "spin_rate_rad_s": SPIN_RATE_RAD_S,
    "straight_fraction": STRAIGHT_FRACTION,
}
