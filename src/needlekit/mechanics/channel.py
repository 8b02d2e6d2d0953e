"""The channel a needle's tip has cut: the tissue's anchors for the shaft.

A channel is the curve the tip has travelled, stored as points at increasing depth (mm
from the entry), each with the unit tangent the tip cut along and a normal ``e_x``
carried along the curve by parallel transport (the rotation-minimising frame:
``e_x`` turns only as much as the tangent makes it, never about the tangent). Between
points the curve is the cubic Hermite interpolant of the positions and tangents, so
positions sampled at any depth are accurate to fourth order in the point spacing.

The tissue holds the shaft toward this curve (see :mod:`needlekit.mechanics.insertion`);
moving the curve (:meth:`Channel.displace`) moves the anchors, which is how a tissue
model deforming around the needle feeds back into it.
"""

from __future__ import annotations

import numpy as np

from needlekit.errors import InvalidInputError
from needlekit.mechanics._kernels import sample_channel_kernel

__all__ = ["Channel", "transport"]


def transport(v: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Carry vectors ``v`` (perpendicular to unit ``a``) by the minimal rotation ``a -> b``.

    Parameters
    ----------
    v : ndarray, shape (..., 3)
        Perpendicular to ``a``.
    a, b : ndarray, shape (..., 3)
        Unit vectors, not opposite.

    Returns
    -------
    ndarray, shape (..., 3)
        ``R v`` with ``R`` the rotation about ``a x b`` taking ``a`` to ``b``.
    """
    c = np.sum(a * b, axis=-1, keepdims=True)
    return v - np.sum(v * b, axis=-1, keepdims=True) / (1.0 + c) * (a + b)


class Channel:
    """A growing channel: the tip's path with its tangents and transported normals.

    Parameters
    ----------
    start_mm : ndarray, shape (3,)
        The entry point (depth 0).
    tangent : ndarray, shape (3,)
        Unit tangent at the entry.
    normal_x : ndarray, shape (3,)
        Unit normal at the entry (perpendicular to ``tangent``).
    """

    def __init__(self, start_mm, tangent, normal_x) -> None:
        cap = 256
        self._depth = np.zeros(cap)
        self._pos = np.zeros((cap, 3))
        self._tan = np.zeros((cap, 3))
        self._ex = np.zeros((cap, 3))
        self._pos[0] = start_mm
        self._tan[0] = tangent
        self._ex[0] = normal_x
        self.n = 1

    @property
    def depth_mm(self) -> np.ndarray:
        """Depth of each point (mm), increasing from 0."""
        return self._depth[: self.n]

    @property
    def points_mm(self) -> np.ndarray:
        """The points (RAS mm), shape (n, 3)."""
        return self._pos[: self.n]

    @property
    def tangents(self) -> np.ndarray:
        """Unit tangents, shape (n, 3)."""
        return self._tan[: self.n]

    @property
    def normals_x(self) -> np.ndarray:
        """Transported unit normals ``e_x``, shape (n, 3)."""
        return self._ex[: self.n]

    @property
    def end_depth_mm(self) -> float:
        """Depth of the channel's end (mm)."""
        return float(self._depth[self.n - 1])

    def _grow(self) -> None:
        cap = 2 * self._depth.size
        for name in ("_depth", "_pos", "_tan", "_ex"):
            old = getattr(self, name)
            new = np.zeros((cap,) + old.shape[1:])
            new[: self.n] = old[: self.n]
            setattr(self, name, new)

    def extend(self, length_mm: float, tangent: np.ndarray) -> None:
        """Cut ``length_mm`` more, ending with the tip's tangent ``tangent``.

        The new piece is the arc-like cubic between the end's tangent and ``tangent``: its
        end point is the end plus ``length_mm`` along the mean of the two tangents.

        Parameters
        ----------
        length_mm : float
            > 0.
        tangent : ndarray, shape (3,)
            Unit tangent the tip cut along at the new end.

        Returns
        -------
        None
        """
        if self.n == self._depth.size:
            self._grow()
        i = self.n - 1
        t0 = self._tan[i]
        mean = t0 + tangent
        mean /= np.linalg.norm(mean)
        self._pos[i + 1] = self._pos[i] + length_mm * mean
        self._tan[i + 1] = tangent
        ex = transport(self._ex[i], t0, tangent)
        self._ex[i + 1] = ex / np.linalg.norm(ex)
        self._depth[i + 1] = self._depth[i] + length_mm
        self.n += 1

    def retract(self) -> None:
        """Remove the last point (undo the last :meth:`extend`).

        Returns
        -------
        None
        """
        if self.n > 1:
            self.n -= 1

    def sample(self, depth_mm: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Points, unit tangents and unit normals ``e_x`` at the given depths (compiled).

        Parameters
        ----------
        depth_mm : ndarray, shape (m,)
            Depths within ``[0, end_depth_mm]`` (clipped to it).

        Returns
        -------
        tuple of ndarray, each shape (m, 3)
            ``(points_mm, tangents, normals_x)``, as :meth:`sample_reference`.
        """
        if self.n == 1:
            return self.sample_reference(depth_mm)
        n = self.n
        return sample_channel_kernel(
            self._depth[:n],
            self._pos[:n],
            self._tan[:n],
            self._ex[:n],
            np.ascontiguousarray(depth_mm, dtype=np.float64),
        )

    def sample_reference(self, depth_mm: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Points, unit tangents and unit normals ``e_x`` at the given depths (numpy).

        Parameters
        ----------
        depth_mm : ndarray, shape (m,)
            Depths within ``[0, end_depth_mm]`` (clipped to it).

        Returns
        -------
        tuple of ndarray, each shape (m, 3)
            ``(points_mm, tangents, normals_x)``; ``normals_x`` is perpendicular to its
            tangent.
        """
        d = self.depth_mm
        if self.n == 1:
            m = depth_mm.size
            return (
                np.repeat(self._pos[:1], m, axis=0),
                np.repeat(self._tan[:1], m, axis=0),
                np.repeat(self._ex[:1], m, axis=0),
            )
        q = np.clip(depth_mm, 0.0, d[-1])
        i = np.clip(np.searchsorted(d, q, side="right") - 1, 0, self.n - 2)
        h = (d[i + 1] - d[i])[:, None]
        tau = (q - d[i])[:, None] / h
        p0, p1 = self._pos[i], self._pos[i + 1]
        m0, m1 = h * self._tan[i], h * self._tan[i + 1]
        tau2, tau3 = tau * tau, tau * tau * tau
        pos = (
            (2 * tau3 - 3 * tau2 + 1) * p0
            + (tau3 - 2 * tau2 + tau) * m0
            + (-2 * tau3 + 3 * tau2) * p1
            + (tau3 - tau2) * m1
        )
        dpos = (
            (6 * tau2 - 6 * tau) * p0
            + (3 * tau2 - 4 * tau + 1) * m0
            + (-6 * tau2 + 6 * tau) * p1
            + (3 * tau2 - 2 * tau) * m1
        )
        tan = dpos / np.sqrt(np.sum(dpos * dpos, axis=1, keepdims=True))
        ex = (1.0 - tau) * self._ex[i] + tau * self._ex[i + 1]
        ex -= np.sum(ex * tan, axis=1, keepdims=True) * tan
        ex /= np.sqrt(np.sum(ex * ex, axis=1, keepdims=True))
        return pos, tan, ex

    def displace(self, displacement_mm: np.ndarray) -> None:
        """Move the channel's points (the tissue's anchors) by the given displacements.

        Tangents turn with the displacement's gradient along the channel
        (``t <- normalise(t + d(displacement)/d(depth))``); normals are made
        perpendicular to them again.

        Parameters
        ----------
        displacement_mm : ndarray, shape (n, 3)
            One finite displacement per point of :attr:`points_mm`.

        Returns
        -------
        None
        """
        disp = np.asarray(displacement_mm, dtype=np.float64)
        if disp.shape != (self.n, 3) or not np.all(np.isfinite(disp)):
            raise InvalidInputError(
                "displacement_mm", f"expected {self.n} finite 3-vectors, got shape {disp.shape}"
            )
        self._pos[: self.n] += disp
        if self.n > 1:
            grad = np.gradient(disp, self.depth_mm, axis=0)
            tan = self._tan[: self.n] + grad
            tan /= np.linalg.norm(tan, axis=1, keepdims=True)
            self._tan[: self.n] = tan
            ex = self._ex[: self.n]
            ex -= np.sum(ex * tan, axis=1, keepdims=True) * tan
            ex /= np.linalg.norm(ex, axis=1, keepdims=True)
