"""The per-child kernel of RCS and RCS*: one compiled call per child motion gives its end
pose, its cost-to-go and, for curved motions, the spun start pose with its duplicate
cell (:class:`~needlekit.planning.steerable.rcs._DuplicateIndex`), so the search loop pays
one dispatch instead of four.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from needlekit.geometry.arcs import arc_end_unchecked
from needlekit.planning.steerable.goal import connection_length_unchecked

__all__ = ["child_motion", "se3_gap"]


@numba.njit(cache=True)
def child_motion(pose, spin, kappa, length, goal, r, tau, cell, tol):  # pragma: no cover
    """One child motion of a node.

    Parameters
    ----------
    pose : ndarray, shape (4, 4), float64, C-contiguous
        The parent's pose.
    spin, kappa, length : float
        The motion.
    goal : ndarray, shape (3,)
    r, tau : float
        r_min and the goal tolerance.
    cell, tol : float
        The duplicate index's cell size and tolerance.

    Returns
    -------
    spun : ndarray, shape (4, 4)
        The parent's pose turned by the spin.
    key : tuple of 6 int
        The spun pose's duplicate cell (position and x axis, in cells).
    near_face : bool
        Some coordinate lies within ``tol`` of its cell's face (neighbours must be asked).
    end : ndarray, shape (4, 4)
        The pose after the motion (bit for bit ``propagate_arcs``).
    h : float
        The goal connection's length from ``end`` (``inf`` for none).
    """
    c, s = math.cos(spin), math.sin(spin)
    spun = np.empty((4, 4))
    for i in range(4):
        spun[i, 0] = c * pose[i, 0] + s * pose[i, 1]
        spun[i, 1] = -s * pose[i, 0] + c * pose[i, 1]
        spun[i, 2] = pose[i, 2]
        spun[i, 3] = pose[i, 3]
    vals = (spun[0, 3], spun[1, 3], spun[2, 3], spun[0, 0], spun[1, 0], spun[2, 0])
    near = False
    k = np.empty(6, dtype=np.int64)
    for n in range(6):
        q = vals[n] / cell
        f = math.floor(q)
        k[n] = f
        frac = q - f
        if frac * cell <= tol or (1.0 - frac) * cell <= tol:
            near = True
    end = arc_end_unchecked(pose, spin, kappa, length)
    h = connection_length_unchecked(end, goal, r, tau)
    return spun, (k[0], k[1], k[2], k[3], k[4], k[5]), near, end, h


@numba.njit(cache=True)
def se3_gap(a, b):  # pragma: no cover - compiled
    """The duplicate test's SE(3) distance ``10 |Ra - Rb|_F / sqrt(2) + |ta - tb|``.

    Parameters
    ----------
    a, b : ndarray, shape (4, 4)

    Returns
    -------
    float
    """
    rot = 0.0
    for i in range(3):
        for j in range(3):
            d = a[i, j] - b[i, j]
            rot += d * d
    pos = 0.0
    for i in range(3):
        d = a[i, 3] - b[i, 3]
        pos += d * d
    return 10.0 * math.sqrt(rot) / math.sqrt(2.0) + math.sqrt(pos)
