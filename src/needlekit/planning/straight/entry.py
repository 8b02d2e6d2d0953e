"""Choosing the entry point in the CFRW (Liu et al. 2016, Eq. 13-14 and steps 1-6).

The paper's criterion is the shortest trajectory: the entry point nearest the target among
those whose trajectory lies in the CFRW. It searches the entry surface ``S(u, v)`` by grid
refinement: from the centre of the parameter box, look at the centre and the four
sub-cell centres, keep the nearest one whose trajectory is in the CFRW, halve the cells
around it, and stop when the trajectory is within ``delta`` of the surface normal (Eq. 14,
the sine of the angle between them) or the cells are smaller than ``epsilon``
(:func:`grid_refinement_entry`). Whether a trajectory is in the CFRW is decided as the
paper does, by the ray-casting test on a layer of the CFRW's boundary, or directly by its
certified clearance.

Beside it: the exhaustive reference on the map (:func:`best_on_map`), further objectives
(shortest, largest clearance, most perpendicular to the surface), and the Pareto front of
(length, clearance) instead of a weighted sum (:func:`pareto_front`).

Every entry these functions report as a solution passes the straight clearance rule as a
plan record holds it (:func:`~needlekit.planning.straight.certify.certified_entry`, the
certificate ``verify_multi`` re-derives): its points rounded, its length and clearance the
certificate's. A candidate whose certificate fails is dropped and the next one taken.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass, replace

import numpy as np

from needlekit.constants import RECORD_ROUNDING_ALLOWANCE_MM
from needlekit.errors import InvalidInputError
from needlekit.geometry.so3 import angle_between
from needlekit.planning.straight.certify import certified_entry, certify_needle, record_point
from needlekit.planning.straight.cfrw import Blocked, CFRWMap, inside_polylines
from needlekit.planning.straight.problem import angles_of
from needlekit.records import field_of

__all__ = [
    "Entry",
    "Objective",
    "ParametricSurface",
    "RECORD_CHECK_MAX_DIRECTIONS",
    "best_direction",
    "best_on_map",
    "certified_best",
    "grid_refinement_entry",
    "pareto_front",
]


#: Most directions of a CFRW whose needle is certified as recorded before the search gives
#: up: the map keeps RECORD_ROUNDING_ALLOWANCE_MM above gamma, so the best one passes but
#: where rounding moves the sphere tracing's samples (none seen in the tests' and
#: benchmarks' plans); each costs one segment's certificate (~ms).
RECORD_CHECK_MAX_DIRECTIONS: int = 32


class Objective(enum.Enum):
    """What the chosen trajectory optimises."""

    MIN_LENGTH = "min_length"  # the paper's criterion
    MAX_CLEARANCE = "max_clearance"
    MIN_NORMAL_ANGLE = "min_normal_angle"


@dataclass(frozen=True)
class Entry:
    """A chosen trajectory.

    Attributes
    ----------
    entry_mm, target_mm : ndarray, shape (3,)
    theta_rad, phi_rad : float
        Its direction in Sigma.
    length_mm, clearance_mm, normal_angle_deg : float
        Insertion length, certified clearance, angle to the inward surface normal.
    iterations : int
        Search iterations (0 for a map look-up).
    """

    entry_mm: np.ndarray
    target_mm: np.ndarray
    theta_rad: float
    phi_rad: float
    length_mm: float
    clearance_mm: float
    normal_angle_deg: float
    iterations: int = 0

    def to_dict(self) -> dict:
        """JSON-ready record.

        Returns
        -------
        dict
        """
        return {
            "entry_mm": np.round(self.entry_mm, 6).tolist(),
            "target_mm": np.round(self.target_mm, 6).tolist(),
            "theta_deg": float(np.degrees(self.theta_rad)),
            "phi_deg": float(np.degrees(self.phi_rad)),
            "length_mm": float(self.length_mm),
            "clearance_mm": float(self.clearance_mm),
            "normal_angle_deg": float(self.normal_angle_deg),
            "iterations": int(self.iterations),
        }

    @classmethod
    def from_dict(cls, row: dict, where: str) -> Entry | None:
        """A trajectory from its record, as :meth:`to_dict` writes it (also a needle of
        ``multi.json``, whose record holds the same fields).

        Parameters
        ----------
        row : dict
            ``entry_mm`` (None: no trajectory), ``target_mm``, ``theta_deg``, ``phi_deg``,
            ``length_mm``, ``clearance_mm``, ``normal_angle_deg`` and optionally
            ``iterations``.
        where : str
            Names the record in messages.

        Returns
        -------
        Entry or None
            None when the record holds no entry point.

        Raises
        ------
        InvalidInputError
            A field not as :meth:`to_dict` writes it (named).
        """
        entry = field_of(row, "entry_mm", where, "point", optional=True)
        if entry is None:
            return None
        return cls(
            entry,
            field_of(row, "target_mm", where, "point"),
            float(np.radians(field_of(row, "theta_deg", where))),
            float(np.radians(field_of(row, "phi_deg", where))),
            float(field_of(row, "length_mm", where)),
            float(field_of(row, "clearance_mm", where)),
            float(field_of(row, "normal_angle_deg", where)),
            field_of(row, "iterations", where, "int", optional=True) or 0,
        )


def _score(cfrw: CFRWMap, objective: Objective) -> np.ndarray:
    if objective is Objective.MIN_LENGTH:
        return cfrw.length_mm
    if objective is Objective.MAX_CLEARANCE:
        return -cfrw.clearance_mm
    return cfrw.normal_angle_deg


def best_direction(
    cfrw: CFRWMap, objective: Objective | str = Objective.MIN_LENGTH
) -> Entry | None:
    """The best direction of the map's CFRW by the map's own figures, not certified as
    recorded: for ranking (the insertion-order search), never reported as a solution
    (:func:`best_on_map` certifies it).

    Parameters
    ----------
    cfrw : CFRWMap
    objective : Objective or str

    Returns
    -------
    Entry or None
        None when the CFRW is empty. Ties go to the lowest index.
    """
    obj = Objective(objective)
    score = np.where(cfrw.feasible, _score(cfrw, obj), np.inf)
    if not np.isfinite(score).any():
        return None
    i, j = np.unravel_index(int(np.argmin(score)), score.shape)
    return Entry(
        cfrw.entry_mm[i, j].copy(),
        cfrw.problem.target_mm.copy(),
        float(cfrw.theta_rad[i]),
        float(cfrw.phi_rad[j]),
        float(cfrw.length_mm[i, j]),
        float(cfrw.clearance_mm[i, j]),
        float(cfrw.normal_angle_deg[i, j]),
    )


def certified_best(
    cfrw: CFRWMap,
    objective: Objective | str = Objective.MIN_LENGTH,
    *,
    problem=None,
    placed: tuple = (),
    bodies: tuple = (),
):
    """The best direction of the map whose needle, as the record will hold it, passes the
    straight clearance rule (:func:`~.certify.certified_entry`); a direction that fails is
    dropped and the next best tried, at most :data:`RECORD_CHECK_MAX_DIRECTIONS` of them.

    Parameters
    ----------
    cfrw : CFRWMap
    objective : Objective or str
    problem : StraightProblem, optional
        The problem to certify against (default the map's, its extra obstacles counted);
        the planner passes the anatomy's with the placed needles in ``placed``/``bodies``.
    placed, bodies : sequence
        The needles placed before it (:func:`~.certify.certify_needle`).

    Returns
    -------
    (Entry or None, NeedleCertificate or None, str)
        The accepted trajectory (its points, length and clearance as recorded) and its
        certificate, or None and why ("" when the CFRW is empty).
    """
    obj = Objective(objective)
    pr = cfrw.problem if problem is None else problem
    ok = cfrw.feasible.copy()
    why = ""
    for _ in range(RECORD_CHECK_MAX_DIRECTIONS):
        e = best_direction(_masked(cfrw, ok), obj)
        if e is None:
            return None, None, why
        chosen, cert = certified_entry(pr, e, placed, bodies)
        if chosen is not None:
            return chosen, cert, ""
        why = "its directions fail the clearance rule once rounded as the record holds them"
        ok &= ~((cfrw.theta_rad[:, None] == e.theta_rad) & (cfrw.phi_rad[None, :] == e.phi_rad))
    n = RECORD_CHECK_MAX_DIRECTIONS
    return None, None, f"its {n} best directions fail the clearance rule once rounded as recorded"


def _masked(cfrw: CFRWMap, ok: np.ndarray) -> CFRWMap:
    """The map with only the directions ``ok`` free (the others blocked as they are or by
    clearance)."""
    blocked = np.where(ok | (cfrw.blocked != Blocked.FREE), cfrw.blocked, Blocked.CLEARANCE)
    return replace(cfrw, blocked=blocked)


def best_on_map(cfrw: CFRWMap, objective: Objective | str = Objective.MIN_LENGTH) -> Entry | None:
    """The best direction of the map's CFRW (the exhaustive reference), certified as
    recorded (:func:`certified_best` on the map's problem).

    Parameters
    ----------
    cfrw : CFRWMap
    objective : Objective or str

    Returns
    -------
    Entry or None
        None when no direction of the CFRW passes the certificate. Ties go to the lowest
        index.
    """
    return certified_best(cfrw, objective)[0]


def pareto_front(cfrw: CFRWMap) -> np.ndarray:
    """The CFRW's directions that no other beats on both length (shorter) and clearance
    (larger): the trade-off curve, instead of a weighted sum of the two.

    Parameters
    ----------
    cfrw : CFRWMap

    Returns
    -------
    ndarray, shape (n, 2) of int
        Grid indices ``(i_theta, j_phi)``, by increasing length.
    """
    idx = np.argwhere(cfrw.feasible)
    if not len(idx):
        return idx
    length = cfrw.length_mm[idx[:, 0], idx[:, 1]]
    clear = cfrw.clearance_mm[idx[:, 0], idx[:, 1]]
    order = np.lexsort((-clear, length))  # by length, the clearest first among equals
    keep, best = [], -np.inf
    for k in order:
        if clear[k] > best:
            keep.append(k)
            best = clear[k]
    return idx[np.array(keep, dtype=int)]


class ParametricSurface:
    """An entry surface as ``S(u, v)`` with normals (the paper's skin).

    Parameters
    ----------
    point : callable
        ``point(u, v) -> (n, 3)`` world points (mm) for arrays ``u, v``.
    normal : callable
        ``normal(u, v) -> (n, 3)`` outward unit normals.
    u_range, v_range : (float, float)
        The parameter box.
    """

    def __init__(self, point, normal, u_range, v_range) -> None:
        self.point = point
        self.normal = normal
        self.u_range = tuple(float(x) for x in u_range)
        self.v_range = tuple(float(x) for x in v_range)
        for name, (a, b) in (("u_range", self.u_range), ("v_range", self.v_range)):
            if not (np.isfinite(a) and np.isfinite(b) and a < b):
                raise InvalidInputError(name, f"expected [min, max] with min < max, got {(a, b)}")

    @classmethod
    def from_skin(cls, skin) -> ParametricSurface:
        """The skin of a phantom (``skin_point``, ``skin_normal``, ``u_range_rad``,
        ``v_range_mm``, as :class:`~needlekit.anatomy.phantoms._skin.EllipticCylinderSkin`).

        Parameters
        ----------
        skin : object

        Returns
        -------
        ParametricSurface
        """
        return cls(
            lambda u, v: np.atleast_2d(skin.skin_point(u, v)),
            lambda u, v: np.atleast_2d(skin.skin_normal(u, v)),
            skin.u_range_rad,
            skin.v_range_mm,
        )


def grid_refinement_entry(
    cfrw: CFRWMap,
    surface: ParametricSurface,
    *,
    delta: float = 1e-5,
    epsilon: float = 1e-4,
    layer_h_mm: float | None = None,
    max_iterations: int = 200,
) -> Entry | None:
    """The paper's grid-refinement search for the nearest entry in the CFRW (steps 1-6).

    Parameters
    ----------
    cfrw : CFRWMap
        Its problem gives the target and the limits.
    surface : ParametricSurface
        The entry surface ``S(u, v)``.
    delta : float
        Eq. 14's convergence precision (sine of the angle between the trajectory and the
        surface normal); the paper uses 1e-5.
    epsilon : float
        Eq. 14's step precision (the larger cell size, in parameter units); the paper
        uses 1e-4.
    layer_h_mm : float, optional
        Decide membership as the paper does, by the ray-casting test on the CFRW's
        boundary in the plane ``z = h`` of Sigma; default: by each trajectory's own
        certified clearance and limits (exact, slower).
    max_iterations : int

    Returns
    -------
    Entry or None
        None when no point the search visits is in the CFRW with a needle that passes
        the certificate as recorded (:func:`~.certify.certify_needle` on its rounded
        points); the entry's points, length and clearance are the record's.
    """
    pr = cfrw.problem
    sigma = pr.world_T_sigma
    target = pr.target_mm
    polys = cfrw.layer(layer_h_mm) if layer_h_mm is not None else None

    def members(u, v):
        p = surface.point(u, v)
        d = p - target
        length = np.linalg.norm(d, axis=1)
        dirs = d / length[:, None]
        theta, phi = angles_of(dirs, sigma)
        ok = length <= pr.needle.max_length_mm
        t0, t1 = np.radians(pr.theta_range_deg)
        p0, p1 = np.radians(pr.phi_range_deg)
        ok &= (theta >= t0 - 1e-12) & (theta <= t1 + 1e-12)
        if p1 - p0 < 2 * np.pi - 1e-9:
            ok &= (phi >= p0 - 1e-12) & (phi <= p1 + 1e-12)
        n = surface.normal(u, v)
        # the needle goes along -dirs, inward is -n: the same angle as dirs to n
        ok &= np.degrees(angle_between(dirs, n)) <= pr.max_normal_angle_deg + 1e-9
        if pr.approach_direction is not None and pr.approach_cone_deg < 180.0:
            off = np.degrees(angle_between(dirs, pr.approach_direction))
            ok &= off <= pr.approach_cone_deg + 1e-9
        if polys is not None:
            local = d @ sigma[:3, :3]
            up = local[:, 2] > 1e-9
            xy = np.full((len(d), 2), np.inf)
            xy[up] = layer_h_mm * local[up, :2] / local[up, 2:3]
            ok &= up & inside_polylines(xy, polys)
        elif ok.any():
            c = np.full(len(d), -np.inf)
            c[ok] = cfrw.clearance_of(theta[ok], phi[ok])
            ok &= c >= pr.gamma_mm + RECORD_ROUNDING_ALLOWANCE_MM  # as the map's
        return ok, p, length, n, theta, phi

    def certificate(p):  # the needle to p as the record holds it, None when it fails
        cert = certify_needle(pr, record_point(target), record_point(p))
        passes = cert.passes(pr.gamma_mm) and cert.length_mm <= pr.needle.max_length_mm
        return cert if passes else None

    def search():
        u0 = 0.5 * (surface.u_range[0] + surface.u_range[1])
        v0 = 0.5 * (surface.v_range[0] + surface.v_range[1])
        L1 = 0.5 * (surface.u_range[1] - surface.u_range[0])
        L2 = 0.5 * (surface.v_range[1] - surface.v_range[0])
        best = None
        for it in range(1, max_iterations + 1):
            us = np.array([u0, u0 + 0.5 * L1, u0 - 0.5 * L1, u0 - 0.5 * L1, u0 + 0.5 * L1])
            vs = np.array([v0, v0 + 0.5 * L2, v0 + 0.5 * L2, v0 - 0.5 * L2, v0 - 0.5 * L2])
            inside = (
                (us >= surface.u_range[0])
                & (us <= surface.u_range[1])
                & (vs >= surface.v_range[0])
                & (vs <= surface.v_range[1])
            )
            ok, p, length, n, theta, phi = members(us, vs)
            ok &= inside
            # the nearest member whose needle passes the certificate as recorded (one that
            # fails it is out of the CFRW as verify sees it)
            k, cert = None, None
            for c in np.flatnonzero(ok)[np.argsort(length[ok], kind="stable")]:
                cert = certificate(p[c])
                if cert is not None:
                    k = int(c)
                    break
            if k is not None:
                u0, v0 = float(us[k]), float(vs[k])
                d = target - p[k]
                sine = float(
                    np.linalg.norm(np.cross(d, n[k])) / (np.linalg.norm(d) * np.linalg.norm(n[k]))
                )
                best = (p[k].copy(), float(theta[k]), float(phi[k]), cert, it, u0, v0)
                if sine <= delta:
                    break
            L1, L2 = 0.5 * L1, 0.5 * L2
            if max(L1, L2) <= epsilon:
                break
        return best

    # certifying only the search's result would leave it on the CFRW boundary the
    # membership test draws, where the record's certificate often fails (6 of 8 seeded
    # searches): each member the search keeps is certified instead
    best = search()
    if best is None:
        return None
    p, theta, phi, cert, it, u0, v0 = best
    nrm = surface.normal(np.array([u0]), np.array([v0]))[0]
    dirs = (p - target) / np.linalg.norm(p - target)
    angle = float(np.degrees(angle_between(dirs, nrm)))
    # as the record holds it: the certified points, length and clearance
    tip, entry = record_point(target), record_point(p)
    return Entry(entry, tip, theta, phi, cert.length_mm, cert.clearance_mm, angle, it)
