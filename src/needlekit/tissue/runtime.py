"""The deforming organ inside the loop: :class:`DeformingTissue`.

Each control step gives the needle's loads (points and forces, e.g. an elastic rod's
``shaft_loads()``) and the breathing displacement ``d(t)`` (mm, e.g.
:meth:`needlekit.execute.breathing.BreathingTrace.actual`); :meth:`DeformingTissue.apply`
turns them into the displacements of the corridor and tracked points by two small dense
products with the precomputed compliance (:mod:`needlekit.tissue.compliance`),
``u = C f + B d``.

**Loads at arbitrary points.** A load need not sit on a corridor point: each is projected
onto the corridor polyline *as it is now* (rest positions plus current displacements) and
shared between the two corridor points of its segment linearly (``1 - t`` and ``t``), the
consistent load of the polyline's hat functions. Loads farther than ``max_offset_mm``
(default 10 mm) from the corridor are refused: the compliance knows nothing of them.
Linear superposition holds: the loads of a step replace those of the previous one (they
are the needle's *current* loads, not increments).

**Positions.** World position = rest position + displacement; :meth:`to_rest` inverts it
(the material point that is now at a world point) by the fixed-point iteration
``X <- x - u(X)``, which contracts while the displacement gradient stays below one.
"""

from __future__ import annotations

from collections import OrderedDict

import numpy as np

from needlekit.errors import InvalidInputError
from needlekit.tissue.compliance import Compliance, locate

try:  # np.linalg.solve's own kernel (LAPACK gesv), without its per-call error-state set-up
    from numpy.linalg._umath_linalg import solve1 as _gesv1
except ImportError:  # pragma: no cover - another numpy's layout
    _gesv1 = None


def _solve3(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``np.linalg.solve(a, b)`` for one 3x3 system, bit for bit: the same kernel called
    directly (a sixth of the time); a system it cannot solve (not finite: singular) goes
    to ``np.linalg.solve``, which raises as it did."""
    if _gesv1 is not None:
        x = _gesv1(a, b, signature="dd->d")
        if np.isfinite(x).all():
            return x
    return np.linalg.solve(a, b)

__all__ = ["DeformingTissue"]

_HINTS = 4  # tetrahedra remembered for the next single-point lookup
#: Smallest barycentric weight with which a remembered tetrahedron answers alone: well
#: inside it, where no rounding can make another tetrahedron's smallest weight larger.
_HINT_MARGIN = 1e-9


def _array(v, name: str, shape_tail: tuple) -> np.ndarray:
    a = np.asarray(v, dtype=float)
    if a.ndim == 1 and len(shape_tail) == 1:
        a = a.reshape(1, -1) if a.shape == shape_tail else a
    if a.ndim != 1 + len(shape_tail) or a.shape[1:] != shape_tail or not np.all(np.isfinite(a)):
        raise InvalidInputError(name, f"expected finite values of shape (n, 3), got shape {np.shape(v)}")
    return a


def _vector(v, name: str) -> np.ndarray:
    a = np.asarray(v, dtype=float)
    if a.shape != (3,) or not np.all(np.isfinite(a)):
        raise InvalidInputError(name, f"expected a finite 3-vector (mm), got {v!r}")
    return a


class DeformingTissue:
    """An organ deforming under the needle and breathing (module notes).

    Parameters
    ----------
    compliance : Compliance
    max_offset_mm : float
        Farthest a load may lie from the corridor.
    """

    def __init__(self, compliance: Compliance, max_offset_mm: float = 10.0) -> None:
        from scipy.spatial import cKDTree

        if not (np.isfinite(max_offset_mm) and max_offset_mm > 0):
            raise InvalidInputError("max_offset_mm", f"expected a finite size > 0 mm, got {max_offset_mm!r}")
        self.compliance = compliance
        self.max_offset_mm = float(max_offset_mm)
        c = compliance
        self.m = len(c.corridor_mm)
        self.p = len(c.tracked_mm)
        self._rest = np.concatenate([c.corridor_mm, c.tracked_mm])
        self._C = np.ascontiguousarray(c.C)
        self._B = np.ascontiguousarray(c.B)
        self._u = np.zeros((self.m + self.p, 3))
        self._f = np.zeros((self.m, 3))
        self._Cf = self._C @ self._f.ravel()
        self._d = np.zeros(3)
        self._tree = cKDTree(c.mesh.nodes_mm[c.mesh.tets].mean(axis=1))
        self._cells: OrderedDict = OrderedDict()  # tetrahedron -> (x0, J^T, H rows, G rows)
        try:
            self._target = c.tracked_labels.index("target")
        except ValueError:
            self._target = None

    # -- the loop ------------------------------------------------------------------------

    def corridor_forces(self, points_mm, forces_N) -> np.ndarray:
        """The loads shared among the corridor points (module notes), shape (m, 3).

        Parameters
        ----------
        points_mm : array-like, shape (n, 3)
        forces_N : array-like, shape (n, 3)

        Returns
        -------
        ndarray, shape (m, 3)
        """
        pts = _array(points_mm, "points_mm", (3,))
        f = _array(forces_N, "forces_N", (3,))
        if len(pts) != len(f):
            raise InvalidInputError("forces_N", f"expected one force per point ({len(pts)}), got {len(f)}")
        out = np.zeros((self.m, 3))
        if len(pts) == 0:
            return out
        now = self.compliance.corridor_mm + self._u[: self.m]
        if self.m == 1:
            dist = np.linalg.norm(pts - now[0], axis=1)
            seg, t = np.zeros(len(pts), int), np.zeros(len(pts))
        else:
            a, ab = now[:-1], np.diff(now, axis=0)  # (s, 3)
            ab2 = np.maximum(np.einsum("ij,ij->i", ab, ab), 1e-18)
            tt = np.clip(np.einsum("nsj,sj->ns", pts[:, None, :] - a[None], ab) / ab2, 0.0, 1.0)
            d2 = np.sum((a[None] + tt[..., None] * ab[None] - pts[:, None, :]) ** 2, axis=2)
            seg = np.argmin(d2, axis=1)
            rows = np.arange(len(pts))
            t, dist = tt[rows, seg], np.sqrt(d2[rows, seg])
        far = dist > self.max_offset_mm
        if far.any():
            i = int(np.flatnonzero(far)[0])
            raise InvalidInputError(
                "points_mm", f"expected loads within {self.max_offset_mm:g} mm of the corridor, "
                f"point {i} is {dist[i]:.3g} mm from it",
            )  # fmt: skip
        np.add.at(out, seg, (1.0 - t)[:, None] * f)
        if self.m > 1:
            np.add.at(out, seg + 1, t[:, None] * f)
        return out

    def apply(self, points_mm, forces_N, breathing=None) -> np.ndarray:
        """Set the needle's current loads and the breathing displacement; update the
        displacements of the corridor and tracked points.

        Parameters
        ----------
        points_mm : array-like, shape (n, 3)
            Where the loads act (world, RAS mm), near the corridor.
        forces_N : array-like, shape (n, 3)
            The forces on the tissue (N).
        breathing : array-like, shape (3,), optional
            The breathing displacement ``d`` (mm); default zero.

        Returns
        -------
        ndarray, shape (m + p, 3)
            Displacements (mm) of the corridor points then the tracked points.
        """
        d = np.zeros(3) if breathing is None else _vector(breathing, "breathing")
        self._f = self.corridor_forces(points_mm, forces_N)
        self._d = d
        self._Cf = self._C @ self._f.ravel()  # kept: breathing alone changes B d only
        self._u = (self._Cf + self._B @ d).reshape(-1, 3)
        return self._u

    # -- reading the state ---------------------------------------------------------------

    @property
    def corridor_displacement_mm(self) -> np.ndarray:
        """Displacements of the corridor points, shape (m, 3)."""
        return self._u[: self.m]

    @property
    def tracked_displacement_mm(self) -> np.ndarray:
        """Displacements of the tracked points, shape (p, 3)."""
        return self._u[self.m :]

    def displacement_at(self, which: str = "tracked") -> np.ndarray:
        """Displacements of ``"corridor"``, ``"tracked"`` or ``"all"`` points.

        Parameters
        ----------
        which : str

        Returns
        -------
        ndarray, shape (k, 3)
        """
        parts = {"corridor": self._u[: self.m], "tracked": self._u[self.m :], "all": self._u}
        if which not in parts:
            raise InvalidInputError("which", f"expected corridor, tracked or all, got {which!r}")
        return parts[which].copy()

    def positions_mm(self, which: str = "tracked") -> np.ndarray:
        """World positions (rest + displacement) of ``"corridor"``, ``"tracked"`` or
        ``"all"`` points.

        Parameters
        ----------
        which : str

        Returns
        -------
        ndarray, shape (k, 3)
        """
        rest = {"corridor": self._rest[: self.m], "tracked": self._rest[self.m :], "all": self._rest}
        return rest[which] + self.displacement_at(which)

    @property
    def target_displacement_mm(self) -> np.ndarray:
        """The target's displacement (mm), shape (3,)."""
        if self._target is None:
            raise InvalidInputError("tracked_labels", "no tracked point is labelled 'target'")
        return self._u[self.m + self._target].copy()

    def target_mm(self) -> np.ndarray:
        """The target's current world position (RAS mm).

        Returns
        -------
        ndarray, shape (3,)
        """
        return self.compliance.tracked_mm[self._target if self._target is not None else 0] + (
            self.target_displacement_mm
        )

    # -- the whole field (not in the loop) -----------------------------------------------

    def mesh_displacement(self) -> np.ndarray:
        """Every node's displacement under the current loads and breathing: ``G f + H d``,
        the full solve's answer for loads at the corridor points.

        Returns
        -------
        ndarray, shape (n, 3)
        """
        c = self.compliance
        return (c.G @ self._f.ravel() + c.H @ self._d).reshape(-1, 3)

    def _field_at(self, points: np.ndarray, loads: bool = True, d=None) -> np.ndarray:
        c = self.compliance
        d = self._d if d is None else d
        if len(points) == 1:
            w, hb, gb = self._cell_of(points[0])
            u = hb @ d
            if loads:
                u = u + gb @ self._f.ravel()
            return np.einsum("ka,kac->kc", w[None], u.reshape(1, 4, 3))
        tet, w, _ = locate(c.mesh, points, self._tree)
        nodes = c.mesh.tets[tet]  # (k, 4)
        dofs = (3 * nodes[:, :, None] + np.arange(3)).reshape(-1)
        u = c.H[dofs] @ d
        if loads:
            u = u + c.G[dofs] @ self._f.ravel()
        return np.einsum("ka,kac->kc", w, u.reshape(len(points), 4, 3))

    def _cell_of(self, p: np.ndarray):
        """A single point's weights in its tetrahedron and the tetrahedron's rows of ``H``
        and ``G``. A tip's next point (and each step of :meth:`to_rest`) is most often in
        one of the last few points' tetrahedra: one whose weights are all above
        ``_HINT_MARGIN`` answers alone. In a mesh whose tetrahedra do not overlap, a point
        strictly inside one lies outside every other, so :func:`locate`'s search would
        choose the same one, with the same weights (the same 3x3 solve)."""
        cells = self._cells
        for t, (x0, jt, hb, gb) in cells.items():
            lam = _solve3(jt, p - x0)
            w = np.empty(4)
            w[0] = 1.0 - lam.sum()
            w[1:] = lam
            if w.min() > _HINT_MARGIN:
                cells.move_to_end(t, last=False)
                return w, hb, gb
        c = self.compliance
        tet, w, _ = locate(c.mesh, p[None], self._tree)
        t = int(tet[0])
        if t not in cells:
            x = c.mesh.nodes_mm[c.mesh.tets[t]]  # (4, 3)
            dofs = (3 * c.mesh.tets[t][:, None] + np.arange(3)).reshape(-1)
            cells[t] = (x[0], (x[1:] - x[0]).T, c.H[dofs], c.G[dofs])
        cells.move_to_end(t, last=False)
        if len(cells) > _HINTS:
            cells.popitem()  # the least recently used
        return w[0], cells[t][2], cells[t][3]

    def displacement_field(self, points_mm, loads: bool = True) -> np.ndarray:
        """The displacement (mm) at material points given at rest (interpolated in their
        tetrahedra; outside the organ, at its nearest point), shape (k, 3).

        Parameters
        ----------
        points_mm : array-like, shape (k, 3)
        loads : bool
            False: the breathing's part alone (``H d``).

        Returns
        -------
        ndarray, shape (k, 3)
        """
        return self._field_at(_array(points_mm, "points_mm", (3,)), loads)

    def breathing_field(self, points_mm, breathing) -> np.ndarray:
        """The displacement (mm) at material points given at rest under a breathing
        displacement ``breathing`` alone (``H d``, interpolated), shape (k, 3).

        Parameters
        ----------
        points_mm : array-like, shape (k, 3)
        breathing : array-like, shape (3,)

        Returns
        -------
        ndarray, shape (k, 3)
        """
        d = _vector(breathing, "breathing")
        return self._field_at(_array(points_mm, "points_mm", (3,)), False, d)

    @property
    def breathing_mm(self) -> np.ndarray:
        """The breathing displacement ``d`` now (mm), shape (3,)."""
        return self._d.copy()

    def breathe(self, breathing) -> None:
        """Set the breathing displacement ``d`` (mm), the needle's loads kept.

        Parameters
        ----------
        breathing : array-like, shape (3,)

        Returns
        -------
        None
        """
        self._d = _vector(breathing, "breathing")
        self._u = (self._Cf + self._B @ self._d).reshape(-1, 3)

    def to_rest(self, points_world, tol_mm: float = 1e-6, max_iter: int = 50,
                loads: bool = True) -> np.ndarray:  # fmt: skip
        """The material points (at rest) now at ``points_world``: the inverse of the
        deformation, by fixed-point iteration ``X <- x - u(X)``.

        Parameters
        ----------
        points_world : array-like, shape (k, 3)
        tol_mm : float
            Stop when no point moves more than this.
        max_iter : int
        loads : bool
            False: the inverse of the breathing's part alone.

        Returns
        -------
        ndarray, shape (k, 3)
        """
        x = _array(points_world, "points_world", (3,))
        rest = x - self._field_at(x, loads)
        for _ in range(max_iter):
            new = x - self._field_at(rest, loads)
            step = float(np.abs(new - rest).max()) if len(x) else 0.0
            rest = new
            if step <= tol_mm:
                break
        return rest
