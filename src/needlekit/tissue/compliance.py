"""The precomputation that makes a deforming organ cheap inside the loop: the condensed
compliance of a corridor and of tracked points.

**Points in the mesh.** A point is embedded in the tetrahedron holding it
(:func:`locate`): its displacement is the barycentric interpolation of that tetrahedron's
four nodal displacements, and a force at it is shared among the four nodes by the same
weights (the consistent load of a point force on P1 elements). A point outside the mesh
takes the nearest tetrahedron's weights clipped to the tetrahedron (the nearest point of
the organ).

**Condensed compliance** (:func:`compute_compliance`). With ``W_c`` the interpolation of
the ``m`` corridor points, ``W_t`` that of the ``p`` tracked points and ``K_ff`` the
stiffness of the free degrees of freedom (factorised once), the nodal response to unit
forces at the corridor points is ``G = K_ff^-1 W_c^T`` (``3m`` solves), and

    C = [W_c; W_t] G,   shape (3 (m + p), 3 m)

gives the displacements of the corridor and tracked points per newton at the corridor
points. Breathing: ``H`` (three columns) is the nodal displacement when the held nodes
move by ``w e_x``, ``w e_y``, ``w e_z`` (:class:`~needlekit.tissue.fem.Boundary`), and
``B = [W_c; W_t] H``. In the loop, ``u = C f + B d``: two small dense products.

**Cache** (:func:`precompute`). The mesh, ``C``, ``B``, ``G`` and ``H`` are stored as a
prepared-anatomy cache entry (:mod:`needlekit.io.anatomy_cache`, label
``tissue-<organ>``), keyed by the mask's content (BLAKE3 of its bytes and affine), the
mesh settings, the material, the boundary mode, the corridor and the tracked points, and
kept within the cache's size limit like every entry (:mod:`needlekit.io.cache_entries`).
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field

import blake3
import numpy as np

from needlekit.errors import InvalidInputError
from needlekit.io import anatomy_cache, cache_entries
from needlekit.io.cache_key import CacheKeyError, hash_threads
from needlekit.tissue.fem import MATERIALS, ElasticProblem, Material, organ_boundary
from needlekit.tissue.meshing import DEFAULT_TARGET_TETS, TetMesh, _check_mask, mesh_mask

__all__ = [
    "TISSUE_FORMAT",
    "Compliance",
    "compute_compliance",
    "interpolation",
    "load_cached",
    "locate",
    "precompute",
    "resample_polyline",
    "sample_near",
]

log = logging.getLogger(__name__)

#: Version of what a tissue cache entry holds (part of its key).
TISSUE_FORMAT: int = 1
_K_CANDIDATES = 24


def _points(points, name: str) -> np.ndarray:
    p = np.asarray(points, dtype=float)
    if p.ndim != 2 or p.shape[1] != 3 or len(p) == 0 or not np.all(np.isfinite(p)):
        raise InvalidInputError(name, f"expected finite points of shape (n, 3), n >= 1, got shape {p.shape}")
    return p


def resample_polyline(path_mm, spacing_mm: float = 1.5) -> np.ndarray:
    """Points along a polyline (a plan's path) every ``spacing_mm`` or a little less, both
    ends kept.

    Parameters
    ----------
    path_mm : array-like, shape (k, 3)
    spacing_mm : float

    Returns
    -------
    ndarray, shape (m, 3)

    Examples
    --------
    >>> resample_polyline([[0, 0, 0], [0, 0, 3]], 1.5)[:, 2]
    array([0. , 1.5, 3. ])
    """
    p = _points(path_mm, "corridor")
    if not (np.isfinite(spacing_mm) and spacing_mm > 0):
        raise InvalidInputError("spacing_mm", f"expected a finite size > 0 mm, got {spacing_mm!r}")
    seg = np.linalg.norm(np.diff(p, axis=0), axis=1)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    if s[-1] == 0.0:
        return p[:1].copy()
    n = max(1, int(np.ceil(s[-1] / spacing_mm - 1e-9)))
    t = np.linspace(0.0, s[-1], n + 1)
    return np.stack([np.interp(t, s, p[:, c]) for c in range(3)], axis=1)


def locate(mesh: TetMesh, points, tree=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The tetrahedron holding each point and the point's barycentric weights.

    Parameters
    ----------
    mesh : TetMesh
    points : array-like, shape (k, 3)
    tree : scipy.spatial.cKDTree, optional
        Of the tetrahedra's centroids (built when not given).

    Returns
    -------
    (ndarray of int, ndarray, ndarray of bool)
        Tetrahedron (k,), weights (k, 4) summing to 1, inside (k,). A point outside the
        mesh gets the nearest candidate's weights clipped to [0, 1] and renormalised.
    """
    from scipy.spatial import cKDTree

    p = np.asarray(points, dtype=float).reshape(-1, 3)
    if tree is None:
        tree = cKDTree(mesh.nodes_mm[mesh.tets].mean(axis=1))
    k = min(_K_CANDIDATES, mesh.n_tets)
    _, cand = tree.query(p, k=k)
    cand = cand.reshape(len(p), k)
    x = mesh.nodes_mm[mesh.tets[cand]]  # (n, k, 4, 3)
    jac = np.stack([x[..., 1, :] - x[..., 0, :], x[..., 2, :] - x[..., 0, :],
                    x[..., 3, :] - x[..., 0, :]], axis=-1)  # fmt: skip
    lam = np.linalg.solve(jac, (p[:, None, :] - x[..., 0, :])[..., None])[..., 0]
    w = np.concatenate([1.0 - lam.sum(axis=-1, keepdims=True), lam], axis=-1)  # (n, k, 4)
    worst = w.min(axis=-1)
    best = np.argmax(worst, axis=1)
    rows = np.arange(len(p))
    tet = cand[rows, best]
    weights = w[rows, best]
    inside = worst[rows, best] >= -1e-9
    out = ~inside
    if out.any():
        c = np.clip(weights[out], 0.0, None)
        weights[out] = c / c.sum(axis=1, keepdims=True)
    return tet, weights, inside


def interpolation(mesh: TetMesh, points, tree=None):
    """The sparse map from nodal displacements (3n, node-major) to the displacements of
    ``points`` (3k), and which points lie inside the mesh.

    Parameters
    ----------
    mesh : TetMesh
    points : array-like, shape (k, 3)
    tree : scipy.spatial.cKDTree, optional

    Returns
    -------
    (scipy.sparse.csr_matrix, ndarray of bool)
    """
    from scipy import sparse

    tet, w, inside = locate(mesh, points, tree)
    k = len(tet)
    nodes = mesh.tets[tet]  # (k, 4)
    rows = (3 * np.arange(k)[:, None, None] + np.arange(3)[None, None, :]).repeat(4, axis=1)
    cols = 3 * nodes[:, :, None] + np.arange(3)[None, None, :]
    vals = np.repeat(w[:, :, None], 3, axis=2)
    m = sparse.coo_matrix((vals.ravel(), (rows.ravel(), cols.ravel())), shape=(3 * k, 3 * mesh.n_nodes))
    return m.tocsr(), inside


def sample_near(mask, affine, corridor_mm, radius_mm: float, max_points: int, seed: int = 0):
    """Up to ``max_points`` voxel centres of a mask (a vessel tree, the airways) within
    ``radius_mm`` of a corridor, drawn evenly at random (reproducibly, from ``seed``).

    Parameters
    ----------
    mask : ndarray of bool, shape (i, j, k)
    affine : ndarray, shape (4, 4)
    corridor_mm : array-like, shape (m, 3)
    radius_mm : float
    max_points : int
    seed : int

    Returns
    -------
    ndarray, shape (q, 3)
        RAS mm; empty when no voxel is that near.
    """
    from scipy.spatial import cKDTree

    c = resample_polyline(corridor_mm, 0.5)
    a = np.asarray(affine, dtype=float)
    lo_w, hi_w = c.min(axis=0) - radius_mm, c.max(axis=0) + radius_mm
    corners = np.array([[x, y, z] for x in (lo_w[0], hi_w[0]) for y in (lo_w[1], hi_w[1])
                        for z in (lo_w[2], hi_w[2])])  # fmt: skip
    idx = np.linalg.solve(a[:3, :3], (corners - a[:3, 3]).T).T
    lo = np.clip(np.floor(idx.min(axis=0)).astype(int), 0, np.array(mask.shape))
    hi = np.clip(np.ceil(idx.max(axis=0)).astype(int) + 1, 0, np.array(mask.shape))
    sub = np.asarray(mask[lo[0] : hi[0], lo[1] : hi[1], lo[2] : hi[2]])
    vox = np.argwhere(sub) + lo
    if len(vox) == 0:
        return np.zeros((0, 3))
    world = vox @ a[:3, :3].T + a[:3, 3]
    d, _ = cKDTree(c).query(world, distance_upper_bound=radius_mm + 0.5)
    near = world[d <= radius_mm]
    if len(near) > max_points:
        near = near[np.sort(np.random.default_rng(seed).choice(len(near), max_points, replace=False))]
    return near


@dataclass(eq=False)
class Compliance:
    """The condensed compliance of a corridor and tracked points (see the module notes).

    Attributes
    ----------
    mesh : TetMesh
    corridor_mm : ndarray, shape (m, 3)
        Corridor points at rest (RAS mm), in order along the path.
    tracked_mm : ndarray, shape (p, 3)
        Tracked points at rest.
    tracked_labels : tuple of str
        What each tracked point is (``"target"``, ``"vessels"``, ...).
    C : ndarray, shape (3 (m + p), 3 m)
        mm per N: displacements of [corridor; tracked] (point-major, x y z) per unit force
        at each corridor point and axis.
    B : ndarray, shape (3 (m + p), 3)
        mm per mm: their displacements per unit breathing displacement along x, y, z.
    G : ndarray, shape (3 n, 3 m)
        Nodal displacements per unit corridor force.
    H : ndarray, shape (3 n, 3)
        Nodal displacements per unit breathing displacement.
    info : dict
        Organ, material, boundary, settings, timings (s), cache entry.
    """

    mesh: TetMesh
    corridor_mm: np.ndarray
    tracked_mm: np.ndarray
    tracked_labels: tuple
    C: np.ndarray
    B: np.ndarray
    G: np.ndarray
    H: np.ndarray
    info: dict = field(default_factory=dict)

    def pinned(self) -> np.ndarray:
        """Which tracked points no load on the corridor can move: their rows of ``C`` are
        zero, every node of the tetrahedron holding them held in every direction (a point
        within a cell of a held surface).

        Returns
        -------
        ndarray of bool, shape (p,)
        """
        m = len(self.corridor_mm)
        rows = np.abs(self.C[3 * m :]).reshape(len(self.tracked_mm), -1)
        return ~np.any(rows > 0.0, axis=1)


def compute_compliance(problem: ElasticProblem, corridor_mm, tracked_mm, tracked_labels=None) -> Compliance:
    """The condensed compliance (module notes) from a factorised problem.

    Parameters
    ----------
    problem : ElasticProblem
    corridor_mm : array-like, shape (m, 3)
    tracked_mm : array-like, shape (p, 3)
    tracked_labels : sequence of str, optional

    Returns
    -------
    Compliance
    """
    mesh = problem.mesh
    corridor = _points(corridor_mm, "corridor")
    tracked = np.asarray(tracked_mm, dtype=float).reshape(-1, 3)
    if not np.all(np.isfinite(tracked)):
        raise InvalidInputError("tracked", "expected finite points")
    labels = tuple(tracked_labels) if tracked_labels is not None else ("tracked",) * len(tracked)
    if len(labels) != len(tracked):
        raise InvalidInputError("tracked_labels", f"expected {len(tracked)} labels, got {len(labels)}")
    t0 = time.perf_counter()
    w_c, _ = interpolation(mesh, corridor)
    w_all, _ = interpolation(mesh, np.concatenate([corridor, tracked]))
    g = problem.response(w_c.T.toarray())
    h = np.stack([problem.solve(held_displacement=problem.breathing_held(e)).ravel()
                  for e in np.eye(3)], axis=1)  # fmt: skip
    solve_s = time.perf_counter() - t0
    return Compliance(
        mesh, corridor, tracked, labels, w_all @ g, w_all @ h, g, h,
        {"solve_s": solve_s, "boundary": problem.boundary.description,
         "material": problem.material.as_dict()},
    )  # fmt: skip


def _mask_digest(mask: np.ndarray, affine: np.ndarray) -> str:
    h = blake3.blake3(max_threads=hash_threads())
    h.update(np.packbits(np.ascontiguousarray(mask, dtype=bool)).tobytes())
    h.update(np.asarray(mask.shape, dtype=np.int64).tobytes())
    h.update(np.ascontiguousarray(affine, dtype=np.float64).tobytes())
    return h.hexdigest()


def _array_digest(a: np.ndarray) -> str:
    return blake3.blake3(np.ascontiguousarray(a, dtype=np.float64).tobytes()).hexdigest(length=16)


#: What ``Compliance.info`` says of one run (where it came from, how long it took), not
#: stored with the entry.
_RUN_INFO = ("timings_s", "cache_entry", "cache_label", "cache_key")


def _arrays(comp: Compliance) -> dict:
    mesh = comp.mesh
    meta = {"tracked_labels": list(comp.tracked_labels), "cell_mm": mesh.cell_mm.tolist(),
            "method": mesh.method,
            "info": {k: v for k, v in comp.info.items() if k not in _RUN_INFO}}  # fmt: skip
    return {
        "nodes_mm": (mesh.nodes_mm, meta), "tets": (mesh.tets, {}),
        "corridor_mm": (comp.corridor_mm, {}), "tracked_mm": (comp.tracked_mm, {}),
        "C": (comp.C, {}), "B": (comp.B, {}), "G": (comp.G, {}), "H": (comp.H, {}),
    }  # fmt: skip


def _from_entry(entry) -> Compliance:
    meta = entry["nodes_mm"].meta
    mesh = TetMesh(entry["nodes_mm"].values, entry["tets"].values, np.asarray(meta["cell_mm"]),
                   meta["method"])  # fmt: skip
    return Compliance(
        mesh, entry["corridor_mm"].values, entry["tracked_mm"].values,
        tuple(meta["tracked_labels"]), entry["C"].values, entry["B"].values,
        entry["G"].values, entry["H"].values, dict(meta["info"]),
    )  # fmt: skip


def precompute(
    mask,
    affine,
    organ: str,
    corridor_mm,
    tracked_mm=None,
    tracked_labels=None,
    *,
    material: Material | None = None,
    target_tets: int = DEFAULT_TARGET_TETS,
    cell_mm: float | None = None,
    seed_mm=None,
    boundary_mode: str = "organ",
    solver: str = "auto",
    use_cache: bool = True,
    cache_dir=None,
    label: str | None = None,
) -> Compliance:
    """Mesh an organ, factorise its stiffness and condense it onto a corridor and tracked
    points, through the cache (module notes).

    Parameters
    ----------
    mask : ndarray of bool, shape (i, j, k)
        The organ body.
    affine : ndarray, shape (4, 4)
    organ : str
        ``"lung"`` or ``"liver"``: the boundary conditions and the default material.
    corridor_mm : array-like, shape (m, 3)
        Corridor points (e.g. :func:`resample_polyline` of a plan's path, 1-2 mm apart).
    tracked_mm : array-like, shape (p, 3), optional
        Points followed (the target first, then vessel and airway samples).
    tracked_labels : sequence of str, optional
    material : Material, optional
        Default: the organ's (:data:`~needlekit.tissue.fem.MATERIALS`).
    target_tets, cell_mm, seed_mm
        Mesh settings (:func:`~needlekit.tissue.meshing.mesh_mask`).
    boundary_mode : str
        ``"organ"`` or ``"uniform"`` (:func:`~needlekit.tissue.fem.organ_boundary`).
    solver : str
        The sparse factorisation (:class:`~needlekit.tissue.fem.ElasticProblem`); not part
        of the key (the solvers agree to round-off).
    use_cache : bool
    cache_dir : path-like, optional
    label : str, optional
        The entry's readable name (default ``tissue-<organ>``).

    Returns
    -------
    Compliance
        ``info["timings_s"]``: ``hash_s``, then ``cache_load_s``, or ``mesh_s``,
        ``factor_s`` (assembly and factorisation), ``solve_s`` and ``cache_write_s``.
    """
    if organ not in MATERIALS:
        raise InvalidInputError("organ", f"expected lung or liver, got {organ!r}")
    material = MATERIALS[organ] if material is None else material
    if not isinstance(material, Material):
        raise InvalidInputError("material", f"expected a Material, got {type(material).__name__}")
    corridor = _points(corridor_mm, "corridor")
    data, a = _check_mask(mask, affine, "mask")  # bad masks: one line, before any work
    if not data.any():
        raise InvalidInputError("mask", "expected a mask with set voxels, got an empty one")
    tracked = np.zeros((0, 3)) if tracked_mm is None else np.asarray(tracked_mm, float).reshape(-1, 3)
    labels = tuple(tracked_labels) if tracked_labels is not None else ("tracked",) * len(tracked)
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    key = inputs = None
    label = label or f"tissue-{organ}"
    if use_cache:
        inputs = {
            "tissue_format": TISSUE_FORMAT, "mask": _mask_digest(data, a), "organ": organ,
            "mesh": {"target_tets": int(target_tets), "cell_mm": cell_mm,
                     "seed_mm": None if seed_mm is None else [float(v) for v in seed_mm]},
            "material": material.as_dict(), "boundary": boundary_mode,
            "corridor": _array_digest(corridor), "tracked": _array_digest(tracked),
            "tracked_labels": list(labels),
        }  # fmt: skip
        key = anatomy_cache.entry_key(inputs)
        timings["hash_s"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        try:
            entry = anatomy_cache.open_entry(cache_dir, label, key)
        except CacheKeyError as exc:
            log.warning("tissue cache unavailable (%s); going on without it", exc)
            entry, key = None, None
        if entry is not None:
            return _loaded(entry, label, key, timings, t0)
    t0 = time.perf_counter()
    mesh = mesh_mask(data, a, target_tets=target_tets, cell_mm=cell_mm, seed_mm=seed_mm)
    timings["mesh_s"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    problem = ElasticProblem(mesh, material, organ_boundary(mesh, organ, boundary_mode), solver)
    timings["factor_s"] = time.perf_counter() - t0
    comp = compute_compliance(problem, corridor, tracked, labels)
    timings["solve_s"] = comp.info.pop("solve_s")
    comp.info.update(organ=organ, boundary_mode=boundary_mode, solver=problem.solver)
    if key is not None:
        t0 = time.perf_counter()
        arrays = _arrays(comp)
        need = sum(np.asarray(v).nbytes + 2048 for v, _ in arrays.values())
        try:
            if cache_entries.make_room(cache_dir, need):
                what = f"{organ} tissue" if label == f"tissue-{organ}" else f"{label} ({organ} tissue)"
                usage = cache_entries.usage_record(what, "tissue.precompute")
                entry = anatomy_cache.write_entry(cache_dir, label, key, inputs, arrays, usage)
                cache_entries.mark_used(entry.path)
                comp.info.update(cache_entry=str(entry.path), cache_label=label, cache_key=key)
            else:
                log.warning("the tissue precomputation (%d bytes) is over the cache's limit: not stored", need)
        except OSError as exc:
            log.warning("the tissue precomputation could not be stored: %s", exc)
        timings["cache_write_s"] = time.perf_counter() - t0
    comp.info["timings_s"] = timings
    return comp


def _loaded(entry, label: str, key: str, timings: dict, t0: float) -> Compliance:
    cache_entries.mark_used(entry.path)
    comp = _from_entry(entry)
    timings["cache_load_s"] = time.perf_counter() - t0
    comp.info.update(timings_s=timings, cache_entry=str(entry.path), cache_label=label, cache_key=key)
    return comp


def load_cached(cache_dir, label: str, key: str) -> Compliance | None:
    """The precomputation stored under ``label`` and ``key`` (``info["cache_label"]`` and
    ``info["cache_key"]`` of a :func:`precompute` that went through the cache), or None
    (not there, or no readable cache).

    Parameters
    ----------
    cache_dir : path-like or None
    label, key : str

    Returns
    -------
    Compliance or None
    """
    t0 = time.perf_counter()
    try:
        entry = anatomy_cache.open_entry(cache_dir, label, key)
    except CacheKeyError as exc:
        log.warning("tissue cache unavailable (%s); going on without it", exc)
        return None
    return None if entry is None else _loaded(entry, label, key, {}, t0)
