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
from dataclasses import dataclass

import numpy as np

from needlekit.anatomy.phantoms._tubes import (  # the tubes are re-exported
    CollisionWorld,
    Tree,
    _any_perpendicular,
    _unit,
    chain_atoms,
    rotate,
    sample_in_region,
    segment_ok,
)
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
