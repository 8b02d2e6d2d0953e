"""Tubes for the phantoms' trees: the segments of a tree, the world of placed capsules
that a new segment must clear, and the small geometry they need.

A :class:`Tree` holds round-cone segments (:func:`~needlekit.anatomy.phantoms._shapes.round_cone`)
as arrays; a :class:`CollisionWorld` holds capsules and gives the exact surface gap of a
new one (a numba kernel, with :func:`segment_distances` as its oracle: Ericson,
*Real-Time Collision Detection*, 5.1.9, against the sum of the largest radii, which is
conservative for tapered tubes); :func:`segment_ok` checks a new segment against the
organ, the forbidden zones and the world. Lengths in mm, world frame.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np

from needlekit.anatomy.fields import DistanceField
from needlekit.anatomy.phantoms._shapes import round_cone
from needlekit.geometry.segments import closest_segment_params, segment_distances
from needlekit.geometry.so3 import cross3

__all__ = ["CollisionWorld", "Tree", "chain_atoms", "rotate", "sample_in_region", "segment_ok"]


#: Spacing (mm) of the samples along a new segment at which the organ and the forbidden
#: zones are checked; the checks add half of it (the fields are 1-Lipschitz).
CHECK_SPACING_MM: float = 1.5


# ----------------------------------------------------------------------------------------
# small geometry


def rotate(v: np.ndarray, axis: np.ndarray, angle: float) -> np.ndarray:
    """Rotate ``v`` about the unit ``axis`` by ``angle`` (rad), Rodrigues' formula.

    Parameters
    ----------
    v, axis : ndarray, shape (3,)
    angle : float

    Returns
    -------
    ndarray, shape (3,)
    """
    c, s = np.cos(angle), np.sin(angle)
    return v * c + cross3(axis, v) * s + axis * (axis @ v) * (1.0 - c)


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v)


def _any_perpendicular(u: np.ndarray) -> np.ndarray:
    e = np.zeros(3)
    e[int(np.argmin(np.abs(u)))] = 1.0
    return _unit(cross3(u, e))


@numba.njit(cache=True)
def _capsule_clearance(p0, p1, r, q0, q1, rq, n, exempt):  # pragma: no cover - compiled
    """min over ``i < n`` not in ``exempt`` of ``dist(p0-p1, q0[i]-q1[i]) - rq[i] - r``
    (:func:`~needlekit.geometry.segments.closest_segment_params`, one pair at a time)."""
    best = np.inf
    d1x = p1[0] - p0[0]
    d1y = p1[1] - p0[1]
    d1z = p1[2] - p0[2]
    for i in range(n):
        skip = False
        for j in range(exempt.shape[0]):
            if exempt[j] == i:
                skip = True
        if skip:
            continue
        d2x = q1[i, 0] - q0[i, 0]
        d2y = q1[i, 1] - q0[i, 1]
        d2z = q1[i, 2] - q0[i, 2]
        rx = p0[0] - q0[i, 0]
        ry = p0[1] - q0[i, 1]
        rz = p0[2] - q0[i, 2]
        s, t = closest_segment_params(rx, ry, rz, d1x, d1y, d1z, d2x, d2y, d2z)
        cx = p0[0] + s * d1x - q0[i, 0] - t * d2x
        cy = p0[1] + s * d1y - q0[i, 1] - t * d2y
        cz = p0[2] + s * d1z - q0[i, 2] - t * d2z
        best = min(best, math.sqrt(cx * cx + cy * cy + cz * cz) - rq[i] - r)
    return best


def sample_in_region(
    rng: np.random.Generator,
    region: DistanceField,
    n: int,
    *,
    depth_mm: float = 0.0,
    box=None,
    exclude=None,
) -> np.ndarray:
    """``n`` points uniform in ``{region sd <= -depth_mm}``, by rejection in its box.

    Parameters
    ----------
    rng : numpy.random.Generator
    region : DistanceField
    n : int
    depth_mm : float
        Least depth (mm) below the region's surface.
    box : array_like, shape (2, 3), optional
        Sampling box (default: the region's bounds).
    exclude : callable, optional
        ``exclude(points (k, 3)) -> bool (k,)`` marks points to reject.

    Returns
    -------
    ndarray, shape (n, 3)
    """
    b = region.bounds() if box is None else np.asarray(box, float)
    out: list[np.ndarray] = []
    have = 0
    while have < n:
        p = rng.uniform(b[0], b[1], size=(max(4 * n, 256), 3))
        ok = region.signed_distance(p) <= -depth_mm
        if exclude is not None:
            ok &= ~exclude(p)
        out.append(p[ok])
        have += int(ok.sum())
    return np.concatenate(out)[:n]


def chain_atoms(points, radii) -> list:
    """Round cones joining consecutive points of a polyline (a curved tube).

    Parameters
    ----------
    points : array_like, shape (n, 3)
    radii : float or array_like, shape (n,)

    Returns
    -------
    list of (int, ndarray)
        ``n - 1`` atoms.
    """
    p = np.asarray(points, float)
    r = np.broadcast_to(np.asarray(radii, float), (len(p),))
    return [round_cone(p[i], p[i + 1], r[i], r[i + 1]) for i in range(len(p) - 1)]


# ----------------------------------------------------------------------------------------
# trees


@dataclass
class Tree:
    """Tapered tube segments forming a tree.

    Attributes
    ----------
    start, end : ndarray, shape (m, 3)
        Segment end points (world RAS, mm).
    r_start, r_end : ndarray, shape (m,)
        Radii (mm) at the two ends.
    parent : ndarray of int, shape (m,)
        Index of the parent segment, -1 for roots.
    generation : ndarray of int, shape (m,)
        Branching generation (0 for roots).
    """

    start: np.ndarray
    end: np.ndarray
    r_start: np.ndarray
    r_end: np.ndarray
    parent: np.ndarray
    generation: np.ndarray

    @classmethod
    def from_rows(cls, rows: list[tuple]) -> Tree:
        """From rows ``(start, end, r_start, r_end, parent, generation)``."""
        if not rows:
            z = np.zeros((0, 3))
            return cls(z, z, np.zeros(0), np.zeros(0), np.zeros(0, int), np.zeros(0, int))
        st, en, r0, r1, par, gen = zip(*rows, strict=True)
        return cls(
            np.array(st),
            np.array(en),
            np.array(r0),
            np.array(r1),
            np.array(par, dtype=int),
            np.array(gen, dtype=int),
        )

    def __len__(self) -> int:
        return len(self.start)

    def concat(self, other: Tree) -> Tree:
        """This tree's segments followed by ``other``'s (parents re-indexed).

        Parameters
        ----------
        other : Tree

        Returns
        -------
        Tree
        """
        shift = np.where(other.parent >= 0, other.parent + len(self), -1)
        return Tree(
            np.concatenate([self.start, other.start]),
            np.concatenate([self.end, other.end]),
            np.concatenate([self.r_start, other.r_start]),
            np.concatenate([self.r_end, other.r_end]),
            np.concatenate([self.parent, shift]),
            np.concatenate([self.generation, other.generation]),
        )

    def atoms(self) -> list:
        """Round-cone atoms of the segments.

        Returns
        -------
        list
            One round cone per segment, in segment order.
        """
        return [
            round_cone(a, b, r0, r1)
            for a, b, r0, r1 in zip(self.start, self.end, self.r_start, self.r_end, strict=True)
        ]

    def diameters_mm(self) -> np.ndarray:
        """Largest diameter of each segment (mm), shape (m,).

        Returns
        -------
        ndarray, shape (m,)
        """
        return 2.0 * np.maximum(self.r_start, self.r_end)

    def lengths_mm(self) -> np.ndarray:
        """Axis length of each segment (mm), shape (m,).

        Returns
        -------
        ndarray, shape (m,)
        """
        return np.linalg.norm(self.end - self.start, axis=1)

    def children(self) -> list[list[int]]:
        """Children of every segment.

        Returns
        -------
        list of list of int
            Per segment, the indices of the segments whose parent it is.
        """
        out: list[list[int]] = [[] for _ in range(len(self))]
        for i, p in enumerate(self.parent):
            if p >= 0:
                out[p].append(i)
        return out

    def branch_angles_deg(self) -> np.ndarray:
        """Angle (deg) between each non-root segment and its parent, shape (m,)
        (NaN for roots).

        Returns
        -------
        ndarray, shape (m,)
        """
        d = self.end - self.start
        d = d / np.linalg.norm(d, axis=1, keepdims=True)
        out = np.full(len(self), np.nan)
        has = self.parent >= 0
        cos = np.einsum("ij,ij->i", d[has], d[self.parent[has]])
        out[has] = np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))
        return out


class CollisionWorld:
    """Capsules placed so far (axis segment and largest radius), for clearance checks."""

    def __init__(self, capacity: int = 1024) -> None:
        self.a = np.empty((capacity, 3))
        self.b = np.empty((capacity, 3))
        self.r = np.empty(capacity)
        self.n = 0

    def add(self, a, b, r: float) -> int:
        """Add a capsule; returns its id.

        Parameters
        ----------
        a, b : array_like, shape (3,)
            Axis end points (mm).
        r : float
            Radius (mm).

        Returns
        -------
        int
        """
        if self.n == len(self.r):
            self.a = np.concatenate([self.a, np.empty_like(self.a)])
            self.b = np.concatenate([self.b, np.empty_like(self.b)])
            self.r = np.concatenate([self.r, np.empty_like(self.r)])
        self.a[self.n], self.b[self.n], self.r[self.n] = a, b, r
        self.n += 1
        return self.n - 1

    def add_tree(self, tree: Tree) -> list[int]:
        """Add every segment of a tree; returns their ids.

        Parameters
        ----------
        tree : Tree
            Each segment is added as a capsule of its larger radius.

        Returns
        -------
        list of int
        """
        return [
            self.add(a, b, max(r0, r1))
            for a, b, r0, r1 in zip(tree.start, tree.end, tree.r_start, tree.r_end, strict=True)
        ]

    def clearance(self, a, b, r: float, exempt=()) -> float:
        """Smallest surface gap (mm) between the capsule ``(a, b, r)`` and the others
        (numba; :meth:`clearance_reference` is the numpy oracle).

        Parameters
        ----------
        a, b : array_like, shape (3,)
            Axis end points (mm).
        r : float
            Radius (mm).
        exempt : iterable of int
            Capsule ids left out (e.g. the parent segment).

        Returns
        -------
        float
            Negative when they overlap; inf with no other capsule.
        """
        ex = np.array(list(exempt), dtype=np.int64)
        return float(
            _capsule_clearance(
                np.asarray(a, float),
                np.asarray(b, float),
                float(r),
                self.a,
                self.b,
                self.r,
                self.n,
                ex,
            )
        )

    def clearance_reference(self, a, b, r: float, exempt=()) -> float:
        """:meth:`clearance` by :func:`segment_distances` (plain numpy).

        Parameters
        ----------
        a, b : array_like, shape (3,)
            Axis end points (mm).
        r : float
            Radius (mm).
        exempt : iterable of int
            Capsule ids left out.

        Returns
        -------
        float
        """
        if self.n == 0:
            return np.inf
        d = segment_distances(a, b, self.a[: self.n], self.b[: self.n]) - self.r[: self.n] - r
        if exempt:
            d[list(exempt)] = np.inf
        return float(d.min())


def _samples_along(a, b, skip_mm: float) -> tuple[np.ndarray, np.ndarray]:
    length = float(np.linalg.norm(b - a))
    t0 = min(skip_mm / length, 1.0) if length > 0 else 1.0
    n = max(2, int(np.ceil((1.0 - t0) * length / CHECK_SPACING_MM)) + 1)
    t = np.linspace(t0, 1.0, n)
    return a + t[:, None] * (b - a), t


def segment_ok(
    a,
    b,
    r0: float,
    r1: float,
    *,
    region,
    region_margin: float,
    zones,
    world: CollisionWorld,
    gap: float,
    exempt=(),
    skip_mm: float = 0.0,
) -> bool:
    """Whether the tube ``a-b`` (radii ``r0 -> r1``) fits: inside ``region`` by
    ``region_margin``, clear of each ``(zone_field, clearance)`` and of the world.

    Parameters
    ----------
    a, b : ndarray, shape (3,)
    r0, r1 : float
    region : DistanceField or None
    region_margin : float
    zones : sequence of (DistanceField, float) or (DistanceField, float, float)
        Forbidden zones, the clearance to keep from each and, optionally, the least tube
        radius (mm) the zone concerns (e.g. only main vessels keep far from a tumour).
    world : CollisionWorld
    gap : float
    exempt : iterable of int
        World ids not checked (parent and siblings).
    skip_mm : float
        Length at the start not checked against region and zones (inside the parent).

    Returns
    -------
    bool
    """
    pts, t = _samples_along(a, b, skip_mm)
    r = r0 + (r1 - r0) * t
    half = 0.5 * CHECK_SPACING_MM
    if region is not None and np.any(region.signed_distance(pts) + half > -(r + region_margin)):
        return False
    for zone in zones:
        field_, clearance = zone[0], zone[1]
        if len(zone) > 2 and max(r0, r1) < zone[2]:
            continue  # the zone only concerns thicker tubes
        if np.any(field_.signed_distance(pts) - half < r + clearance):
            return False
    return world.clearance(a, b, max(r0, r1), exempt) >= gap
