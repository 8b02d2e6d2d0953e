"""Branching tubes for the phantoms: space-filling trees, companion trees, chains.

Trees are grown by the volume-filling method of Tawhai et al. (2000), with the sizes the
phantoms need stated in :class:`TreeSpec`:

* every branch owns a *territory*, a set of seed points of the organ it supplies; at a
  branch point the territory is split in two by a plane containing the parent's axis
  (through the territory's centroid, across its widest spread), and each half gets a
  child heading for its centroid;
* diameters follow Murray's law through the territory sizes: a branch supplying ``N`` of
  the root's ``N0`` points has ``d = d0 (N / N0)^(1/3)`` (flow ~ volume ~ N, ``d^3 ~``
  flow), so ``d_parent^3 = d_1^3 + d_2^3``; a branch thinner than ``d_min`` is not made;
* a child leaves its parent at ``theta_min..theta_max`` (the direction to its centroid,
  clamped) and is ``ratio x d`` long (``ratio`` drawn in ``ratio_range``, at most 90 %
  of the way to the centroid), tapering by ``taper`` along its length;
* a child is kept only if it stays inside the organ with a margin, clear of forbidden
  zones (a nodule, a fissure) and of every tube already placed (the parent and siblings
  at its branch point excepted); otherwise shorter and deflected variants are tried,
  then its territory is split again at the same branch point (twice at most: thinner
  branches pass where a thick one could not), and finally dropped;
* the trees of one organ (bronchi and veins; portal and hepatic veins) grow together
  (:func:`grow_forest`), the thickest pending branch of any tree first, so that every
  tree's large vessels find their way before small branches fill the space;
* :func:`companion_tree` then lays a tube beside every branch that has room (a
  pulmonary artery beside its bronchus).

Segments are round cones (:func:`~needlekit.anatomy.phantoms._shapes.round_cone`).
Collision checks use the exact distance between segment axes (Ericson, *Real-Time
Collision Detection*, 5.1.9) against the sum of the largest radii, which is
conservative for tapered tubes.

References
----------
M. H. Tawhai, A. J. Pullan, P. J. Hunter, "Generation of an anatomically based
three-dimensional model of the conducting airways", Ann. Biomed. Eng. 28 (2000) 793-802.
"""

from __future__ import annotations

import heapq
import math
from dataclasses import dataclass

import numba
import numpy as np

from needlekit.anatomy.fields import DistanceField
from needlekit.anatomy.phantoms._shapes import round_cone
from needlekit.geometry.segments import segment_distances

__all__ = [
    "CollisionWorld",
    "Tree",
    "TreeSeed",
    "TreeSpec",
    "chain_atoms",
    "companion_tree",
    "grow_forest",
    "rotate",
    "sample_in_region",
    "segment_distances",
]

#: Rotations (rad) about a branch tried for a companion's offset, nearest first.
_TURNS = (0.0, 0.5, -0.5, 1.0, -1.0, 1.5, -1.5, 2.0, -2.0, 2.6, -2.6, np.pi)

#: Times the territory of a branch that does not fit is split again at its branch point
#: (its parts, thinner, may pass where it could not); then the territory is dropped.
RESPLITS: int = 2

#: Length factors of the successive variants of a branch that does not fit.
_SHORTEN = (1.0, 1.0, 0.75, 0.75, 0.55, 0.55, 0.4, 0.4)

#: Spacing (mm) of the samples along a new segment at which the organ and the forbidden
#: zones are checked; the checks add half of it (the fields are 1-Lipschitz).
CHECK_SPACING_MM: float = 1.5


# ----------------------------------------------------------------------------------------
# small geometry


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    # np.cross costs ~20 us on single vectors; this is the same product
    return np.array(
        [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]
    )


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
    return v * c + _cross(axis, v) * s + axis * (axis @ v) * (1.0 - c)


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v)


def _any_perpendicular(u: np.ndarray) -> np.ndarray:
    e = np.zeros(3)
    e[int(np.argmin(np.abs(u)))] = 1.0
    return _unit(_cross(u, e))


@numba.njit(cache=True)
def _capsule_clearance(p0, p1, r, q0, q1, rq, n, exempt):  # pragma: no cover - compiled
    """min over ``i < n`` not in ``exempt`` of ``dist(p0-p1, q0[i]-q1[i]) - rq[i] - r``
    (the closest-points logic of :func:`segment_distances`, one pair at a time)."""
    best = np.inf
    d1x = p1[0] - p0[0]
    d1y = p1[1] - p0[1]
    d1z = p1[2] - p0[2]
    a = d1x * d1x + d1y * d1y + d1z * d1z
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
        e = d2x * d2x + d2y * d2y + d2z * d2z
        f = d2x * rx + d2y * ry + d2z * rz
        if a <= 1e-18 and e <= 1e-18:
            s = 0.0
            t = 0.0
        elif a <= 1e-18:
            s = 0.0
            t = min(max(f / e, 0.0), 1.0)
        else:
            c = d1x * rx + d1y * ry + d1z * rz
            if e <= 1e-18:
                t = 0.0
                s = min(max(-c / a, 0.0), 1.0)
            else:
                b = d1x * d2x + d1y * d2y + d1z * d2z
                denom = a * e - b * b
                s = min(max((b * f - c * e) / denom, 0.0), 1.0) if denom > 1e-12 * a * e else 0.0
                t = (b * s + f) / e
                if t < 0.0:
                    t = 0.0
                    s = min(max(-c / a, 0.0), 1.0)
                elif t > 1.0:
                    t = 1.0
                    s = min(max((b - c) / a, 0.0), 1.0)
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


@dataclass(frozen=True)
class TreeSpec:
    """Sizes and rules of a grown tree (module notes).

    Attributes
    ----------
    d_min_mm : float
        Thinnest branch made (mm).
    ratio_range : tuple of float
        Length / diameter ratio drawn per branch.
    angle_range_deg : tuple of float
        Angle between a child and its parent (deg).
    taper : float
        End radius / start radius of a segment.
    region_margin_mm : float
        Least depth of a tube's surface inside the organ (mm).
    gap_mm : float
        Least gap to tubes already placed (mm).
    attempts : int
        Variants (shorter, deflected) tried before a branch is dropped.
    """

    d_min_mm: float = 2.0
    ratio_range: tuple[float, float] = (2.5, 3.5)
    angle_range_deg: tuple[float, float] = (30.0, 70.0)
    taper: float = 0.9
    region_margin_mm: float = 1.5
    gap_mm: float = 1.0
    attempts: int = 8


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


def _split(points: np.ndarray, u: np.ndarray, plane=None):
    """Split territory points by a plane containing ``u`` (or a given ``(q, n)``)."""
    if plane is not None:
        q, n = plane
        side = (points - q) @ n > 0.0
        return side, n
    rel = points - points.mean(axis=0)
    perp = rel - np.outer(rel @ u, u)
    _, v = np.linalg.eigh(perp.T @ perp)
    e = v[:, -1]
    proj = perp @ e
    side = proj > 0.0
    if side.all() or not side.any():
        side = proj > np.median(proj)
    return side, e


@dataclass
class TreeSeed:
    """Where and how one tree of a forest starts (see :func:`grow_forest`).

    Attributes
    ----------
    node : ndarray, shape (3,)
        The first branch point (end of the root segment, placed by the caller).
    direction : ndarray, shape (3,)
        Direction of the root segment there.
    diameter_mm : float
        Root diameter ``d0``: a branch supplying all ``N0`` territory points would have it.
    territory : ndarray, shape (N0, 3)
        Seed points of the organ this tree supplies.
    spec : TreeSpec
    zones : sequence of (DistanceField, float)
        Forbidden zones and the clearance to keep from each.
    first_split : tuple of ndarray, optional
        ``(point, normal)`` of the plane splitting the root territory (e.g. a fissure).
    root_world_id : int, optional
        World id of the root segment (exempt for the first children).
    first_generation : int
        Generation number of the first children.
    """

    node: np.ndarray
    direction: np.ndarray
    diameter_mm: float
    territory: np.ndarray
    spec: TreeSpec
    zones: tuple = ()
    first_split: tuple | None = None
    root_world_id: int | None = None
    first_generation: int = 1


def grow_forest(
    rng: np.random.Generator, seeds: list[TreeSeed], *, region, world: CollisionWorld
) -> list[Tree]:
    """Grow space-filling trees together (module notes), thickest pending branch first.

    Trees sharing an organ (bronchi and veins) compete for room; expanding the pending
    branch points in order of decreasing diameter across all trees lets the large
    vessels of every tree find their way before small branches fill the space.

    Parameters
    ----------
    rng : numpy.random.Generator
    seeds : list of TreeSeed
    region : DistanceField
        The organ (negative inside); branches keep ``spec.region_margin_mm`` inside.
    world : CollisionWorld
        Tubes already placed; the new segments are added to it.

    Returns
    -------
    list of Tree
        One per seed, without the root segment; ``parent`` indexes into the tree (-1:
        child of the root).
    """
    rows: list[list[tuple]] = [[] for _ in seeds]
    wids: list[list[int]] = [[] for _ in seeds]
    at_node: dict[tuple[int, int], list[int]] = {}  # world ids of the children of a branch
    heap: list = []
    counter = 0
    for t, sd in enumerate(seeds):
        item = (
            np.asarray(sd.node, float),
            _unit(np.asarray(sd.direction, float)),
            -1,
            np.arange(len(sd.territory)),
            sd.first_generation,
            RESPLITS,
        )
        heapq.heappush(heap, (-sd.diameter_mm, counter, t, item))
        counter += 1
    while heap:
        neg_d, _, t, (p, u, par, idx, gen, resplits) = heapq.heappop(heap)
        sd = seeds[t]
        spec = sd.spec
        lo_t, hi_t = np.radians(spec.angle_range_deg)
        n0 = len(sd.territory)
        if len(idx) < 2:
            continue
        first = par == -1 and resplits == RESPLITS
        side, e = _split(sd.territory[idx], u, sd.first_split if first else None)
        parent_wid = sd.root_world_id if par == -1 else wids[t][par]
        siblings = at_node.setdefault((t, par), [])
        for half in (idx[side], idx[~side]):
            d = sd.diameter_mm * (len(half) / n0) ** (1.0 / 3.0)
            if d < spec.d_min_mm or len(half) == 0:
                continue
            w = sd.territory[half].mean(axis=0) - p
            dist = float(np.linalg.norm(w))
            w_hat = w / dist if dist > 0 else e
            cos_phi = float(np.clip(w_hat @ u, -1.0, 1.0))
            perp = w_hat - cos_phi * u
            perp = _unit(perp) if np.linalg.norm(perp) > 1e-9 else _unit(e - (e @ u) * u)
            phi = float(np.clip(np.arccos(cos_phi), lo_t, hi_t))
            base_dir = np.cos(phi) * u + np.sin(phi) * perp
            ratio = rng.uniform(*spec.ratio_range)
            length = max(min(ratio * d, 0.9 * dist), d)
            r0 = 0.5 * d
            r1 = r0 * spec.taper
            jitter = rng.normal(size=(spec.attempts, 3))
            exempt = [*siblings] + ([parent_wid] if parent_wid is not None else [])
            for k in range(spec.attempts):
                v = base_dir
                if k > 0:  # deflect by up to 8 deg x k about a random perpendicular
                    axis = jitter[k] - (jitter[k] @ v) * v
                    v = rotate(v, _unit(axis), np.radians(8.0 * k) * (0.5 + 0.5 * (k % 2)))
                    ang = np.arccos(np.clip(v @ u, -1, 1))
                    if not lo_t - 1e-9 <= ang <= hi_t + 1e-9:
                        continue
                seg_len = max(length * _SHORTEN[min(k, len(_SHORTEN) - 1)], d)
                q = p + seg_len * v
                if segment_ok(
                    p,
                    q,
                    r0,
                    r1,
                    region=region,
                    region_margin=spec.region_margin_mm,
                    zones=sd.zones,
                    world=world,
                    gap=spec.gap_mm,
                    exempt=exempt,
                    skip_mm=r0,
                ):
                    rows[t].append((p, q, r0, r1, par, gen))
                    wid = world.add(p, q, r0)
                    wids[t].append(wid)
                    siblings.append(wid)
                    item = (q, v, len(rows[t]) - 1, half, gen + 1, RESPLITS)
                    heapq.heappush(heap, (-d, counter, t, item))
                    counter += 1
                    break
            else:  # no variant fits: split this territory again at the same branch point
                if resplits > 0 and len(half) >= 4:
                    heapq.heappush(heap, (neg_d, counter, t, (p, u, par, half, gen, resplits - 1)))
                    counter += 1
    return [Tree.from_rows(r) for r in rows]


def companion_tree(
    tree: Tree,
    *,
    scale: float,
    d_max_mm: float,
    gap_mm: float,
    region,
    world: CollisionWorld,
    zones=(),
    root_node_radius_mm: float = 0.0,
    root_side=None,
    root_skip_mm: float = 0.0,
) -> tuple[Tree, list[int]]:
    """Tubes running beside the branches of a tree (pulmonary arteries beside bronchi).

    Each branch gets a companion offset perpendicular to it by the largest radii at its
    ends plus ``gap_mm``, on the side away from its sibling branch, continuing from its
    parent's companion; when blocked by a placed tube, offsets rotated about the branch
    and thinner companions (0.8, 0.6 of ``scale``) are tried. A branch whose companion
    does not fit has none, and its children's companions restart beside them.

    Parameters
    ----------
    tree : Tree
        Parents come before their children.
    scale : float
        Companion radius / branch radius.
    d_max_mm : float
        Largest companion diameter (mm).
    gap_mm : float
        Surface gap between a branch and its companion (mm).
    region : DistanceField or None
        Organ the companions stay inside (0.5 mm margin).
    world : CollisionWorld
        Tubes placed so far, ``tree`` included; the companions are added.
    zones : sequence of (DistanceField, float)
    root_node_radius_mm : float
        Radius of the tube the roots leave (their companions start beside it).
    root_side : array_like, shape (3,), optional
        Preferred side of the roots' companions.
    root_skip_mm : float
        Length at the start of the roots' companions not checked against the organ and
        the zones (they leave a trunk outside it).

    Returns
    -------
    companions : Tree
        Companion segments; ``parent`` -1 marks a companion starting afresh.
    root_rows : list of int
        Rows of ``companions`` beside the roots of ``tree`` (to join to a trunk).
    """
    n = len(tree)
    dirs = tree.end - tree.start
    dirs = dirs / np.linalg.norm(dirs, axis=1, keepdims=True)
    kids = tree.children()
    r_max = np.maximum(tree.r_start, tree.r_end)
    rows: list[tuple] = []
    root_rows: list[int] = []
    comp = np.full(n, -1)  # companion row of each branch
    wids: list[int] = []
    for s in range(n):
        p = tree.parent[s]
        sib = [c for c in (kids[p] if p >= 0 else []) if c != s]
        if sib:
            side = -(dirs[sib[0]] - (dirs[sib[0]] @ dirs[s]) * dirs[s])
        elif p < 0 and root_side is not None:
            side = np.asarray(root_side, float)
        else:
            side = _any_perpendicular(dirs[s])
        side = side - (side @ dirs[s]) * dirs[s]
        side = _unit(side) if np.linalg.norm(side) > 1e-6 else _any_perpendicular(dirs[s])
        cont = p >= 0 and comp[p] >= 0
        exempt = [wids[comp[p]]] if cont else []
        exempt += [wids[comp[c]] for c in sib if comp[c] >= 0]
        found = None
        for f in (1.0, 0.8, 0.6):
            r_c0 = min(f * scale * r_max[s], 0.5 * d_max_mm)
            if cont:
                r_c0 = min(r_c0, rows[comp[p]][3])
            r_c1 = min(f * scale * tree.r_end[s], r_c0)
            for turn in _TURNS:
                o = rotate(side, dirs[s], turn)
                if cont:
                    a = rows[comp[p]][1]
                else:
                    r_node = root_node_radius_mm if p < 0 else r_max[p]
                    a = tree.start[s] + o * (max(r_node, r_max[s]) + r_c0 + gap_mm)
                b = tree.end[s] + o * (r_max[s] + r_c0 + gap_mm)
                skip = root_skip_mm if p < 0 else (0.0 if cont else r_c0)
                if segment_ok(
                    a,
                    b,
                    r_c0,
                    r_c1,
                    region=region,
                    region_margin=0.5,
                    zones=zones,
                    world=world,
                    gap=0.5 * gap_mm,
                    exempt=exempt,
                    skip_mm=skip,
                ):
                    found = (a, b, r_c0, r_c1)
                    break
            if found is not None:
                break
        if found is None:
            continue
        a, b, r_c0, r_c1 = found
        comp[s] = len(rows)
        if p < 0:
            root_rows.append(len(rows))
        rows.append((a, b, r_c0, r_c1, comp[p] if cont else -1, tree.generation[s]))
        wids.append(world.add(a, b, r_c0))
    return Tree.from_rows(rows), root_rows
