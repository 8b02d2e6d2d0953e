"""Linear elasticity on P1 (four-node) tetrahedra: material, stiffness, boundary
conditions and solves.

**Model.** Small-strain, isotropic, homogeneous linear elasticity, quasi-static (the
needle advances at millimetres per second; the tissue's elastic waves cross the organ in
milliseconds). Units: millimetres, newtons, so moduli in N/mm^2 (1 kPa = 1e-3 N/mm^2) and
displacements in millimetres. Not co-rotational: rotations of more than a few degrees
inflate the linear model's strains (stated in docs/tissue.md).

**Stiffness** (:func:`stiffness`): assembled in numpy, every element at once. For a
tetrahedron of volume ``V`` with barycentric gradients ``g_a`` (constant),
``K_ab = V (lambda g_a g_b^T + mu g_b g_a^T + mu (g_a . g_b) I)``, the 12x12 blocks
scattered into one sparse matrix (CSR, degrees of freedom node-major: ``3 i + c``).
Measured against scikit-fem's ``linear_elasticity`` form on the same mesh: the same
matrix to round-off and several times faster (docs/tissue.md).

**Boundary conditions** (:class:`Boundary`): a set of *held* nodes whose displacement is
prescribed (zero under needle loads; ``w_i d`` under a breathing displacement ``d``), the
rest of the surface traction-free. :func:`organ_boundary` gives the organ's:

- lung: the whole pleural surface held (the visceral pleura lies against the parietal
  pleura of the chest wall and the diaphragm, held there by the negative pleural
  pressure); breathing moves it by ``w d``, ``w`` rising linearly from 0 at the apex to 1
  at the base (the diaphragm's side), the cranio-caudal gradient of lung motion;
- liver: the surface facing superiorly held (the bare area and the coronary and
  triangular ligaments fixing it to the diaphragm); breathing moves that surface by ``d``
  (``w = 1``), so the liver, free elsewhere, translates with the diaphragm.

``mode="sliding"`` (lung) lets the pleural surface slide: each surface node's
displacement is held only along its normal (to ``n . w d``), free along the surface; the
degrees of freedom of those nodes are turned into their (normal, tangent, tangent) frame
and the normal one eliminated, exactly (no penalty).

``mode="uniform"`` holds and moves the whole surface by ``d``: the displacement is then
``d`` everywhere, exactly: the rigid breathing of :mod:`needlekit.execute.breathing`.

**Solves** (:class:`ElasticProblem`): the free block ``K_ff`` is factorised once and each
solve is ``u_f = K_ff^-1 (f_f - K_fh u_h)``. The factorisation, chosen by measurement
(docs/tissue.md): SuperLU (:func:`scipy.sparse.linalg.splu`, minimum-degree ordering on
``A + A^T``, symmetric mode), which needs nothing beyond scipy; MKL PARDISO (through the
optional ``pypardiso``) when it is installed, 4 to 7 times faster on these meshes but
x86-64 only and some 700 MB of MKL. CHOLMOD (scikit-sparse) has no wheels; pyamg's
multigrid needs an iterative solve per right-hand side (about 0.5 s each here, against
milliseconds from a factorisation).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from needlekit.errors import InvalidInputError
from needlekit.tissue.meshing import TetMesh, tet_volumes

__all__ = [
    "BOUNDARY_MODES",
    "LIVER",
    "LUNG",
    "MATERIALS",
    "Boundary",
    "ElasticProblem",
    "Material",
    "SOLVERS",
    "barycentric_gradients",
    "kelvin_displacement",
    "organ_boundary",
    "stiffness",
]

#: N/mm^2 per kPa.
KPA: float = 1e-3


@dataclass(frozen=True)
class Material:
    """An isotropic linear elastic material.

    Attributes
    ----------
    young_modulus_kpa : float
        Young's modulus E (kPa), finite and > 0.
    poisson_ratio : float
        nu, 0 <= nu < 0.5.

    Examples
    --------
    >>> Material(1.0, 0.3).lame_n_per_mm2()[1]  # mu = E / (2 (1 + nu)), in N/mm^2
    0.0003846153846153846
    """

    young_modulus_kpa: float
    poisson_ratio: float

    def __post_init__(self) -> None:
        e, nu = self.young_modulus_kpa, self.poisson_ratio
        if isinstance(e, bool) or not (isinstance(e, (int, float)) and math.isfinite(e) and e > 0):
            raise InvalidInputError("young_modulus_kpa", f"expected a finite number > 0, got {e!r}")
        if e > 1e9:
            raise InvalidInputError("young_modulus_kpa", f"expected at most 1e9 kPa, got {e!r}")
        if isinstance(nu, bool) or not (
            isinstance(nu, (int, float)) and math.isfinite(nu) and 0.0 <= nu < 0.5
        ):
            raise InvalidInputError("poisson_ratio", f"expected 0 <= nu < 0.5, got {nu!r}")

    def lame_n_per_mm2(self) -> tuple[float, float]:
        """Lamé's ``(lambda, mu)`` in N/mm^2.

        Returns
        -------
        (float, float)
        """
        e, nu = self.young_modulus_kpa * KPA, self.poisson_ratio
        return e * nu / ((1 + nu) * (1 - 2 * nu)), e / (2 * (1 + nu))

    def as_dict(self) -> dict:
        """The material as a plain dict (cache keys, records).

        Returns
        -------
        dict
        """
        return {"young_modulus_kpa": float(self.young_modulus_kpa),
                "poisson_ratio": float(self.poisson_ratio)}  # fmt: skip


#: Lung parenchyma: E 1.5 to 2 times the inflation (transpulmonary) pressure and nu about
#: 0.43 ("Elastic constants of inflated lobes of dog lungs", Lai-Fook, Wilson, Hyatt and
#: Rodarte, J. Appl. Physiol. 1976: uniaxial and indentation tests); at functional
#: residual capacity (about 5 cmH2O, 0.5 kPa) E is about 1 kPa.
LUNG = Material(1.0, 0.43)
#: Liver: healthy liver's shear-wave elastography stiffness (reported as E = 3 mu) about
#: 4.7 kPa (mean 4.74 +- 0.91 kPa in 115 healthy adults, Dhar, Gupta and Gupta, IJMRR);
#: nu 0.45, nearly incompressible soft tissue short of the locking of P1 elements.
LIVER = Material(4.7, 0.45)
#: The organ presets.
MATERIALS: dict[str, Material] = {"lung": LUNG, "liver": LIVER}


def kelvin_displacement(points_mm, force_N, material: Material) -> np.ndarray:
    """Kelvin's solution: the displacement (mm) at ``points_mm`` (relative to the load) of a
    point force ``force_N`` in an infinite body of ``material``,
    ``u = [(3 - 4 nu) F + r_hat (r_hat . F)] / (16 pi mu (1 - nu) r)``.

    Parameters
    ----------
    points_mm : array-like, shape (k, 3)
        Offsets from the load, none zero.
    force_N : array-like, shape (3,)
    material : Material

    Returns
    -------
    ndarray, shape (k, 3)

    Examples
    --------
    >>> m = Material(3.0, 0.25)  # mu = 1.2 kPa
    >>> float(kelvin_displacement([[10.0, 0.0, 0.0]], [0.0, 0.0, 0.01], m)[0, 2])  # (3 - 1) F / (16 pi mu 0.75 r)
    0.0442097064...
    """
    x = np.asarray(points_mm, dtype=float).reshape(-1, 3)
    f = np.asarray(force_N, dtype=float).reshape(3)
    nu = material.poisson_ratio
    mu = material.lame_n_per_mm2()[1]
    r = np.linalg.norm(x, axis=1)[:, None]
    rh = x / r
    return (f[None, :] * (3.0 - 4.0 * nu) + rh * (rh @ f)[:, None]) / (16.0 * np.pi * mu * (1.0 - nu) * r)


def barycentric_gradients(nodes: np.ndarray, tets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The gradients of the four barycentric (P1 shape) functions of every tetrahedron,
    shape (m, 4, 3), and the volumes, shape (m,).

    Parameters
    ----------
    nodes : ndarray, shape (n, 3)
    tets : ndarray of int, shape (m, 4)

    Returns
    -------
    (ndarray, ndarray)
    """
    p = nodes[tets]
    jac = np.stack([p[:, 1] - p[:, 0], p[:, 2] - p[:, 0], p[:, 3] - p[:, 0]], axis=2)
    inv = np.linalg.inv(jac)  # rows: gradients of lambda_1..3
    grads = np.concatenate([-inv.sum(axis=1, keepdims=True), inv], axis=1)
    return grads, tet_volumes(nodes, tets)


def stiffness(mesh: TetMesh, material: Material):
    """The global stiffness matrix (no boundary conditions): sparse CSR, shape (3n, 3n),
    degrees of freedom node-major (``3 i + c``).

    Parameters
    ----------
    mesh : TetMesh
    material : Material

    Returns
    -------
    scipy.sparse.csr_matrix
    """
    from scipy import sparse

    lam, mu = material.lame_n_per_mm2()
    g, vol = barycentric_gradients(mesh.nodes_mm, mesh.tets)
    gg = np.einsum("mai,mbj->mabij", g, g)  # g_a g_b^T
    dot = np.einsum("mai,mbi->mab", g, g)
    ke = lam * gg + mu * gg.transpose(0, 1, 2, 4, 3)
    ke += mu * dot[:, :, :, None, None] * np.eye(3)
    ke *= vol[:, None, None, None, None]
    # rows (a, i), columns (b, j) -> 12x12, dof 3 node + component
    ke = ke.transpose(0, 1, 3, 2, 4).reshape(-1, 12, 12)
    dofs = (3 * mesh.tets[:, :, None] + np.arange(3)).reshape(-1, 12)
    rows = np.repeat(dofs, 12, axis=1).ravel()
    cols = np.tile(dofs, (1, 12)).ravel()
    n = 3 * mesh.n_nodes
    k = sparse.coo_matrix((ke.ravel(), (rows, cols)), shape=(n, n)).tocsr()
    k.sum_duplicates()
    return k


@dataclass(frozen=True, eq=False)
class Boundary:
    """Held nodes and how breathing moves them.

    Attributes
    ----------
    held : ndarray of int, shape (h,)
        Sorted node indices whose displacement is prescribed.
    weight : ndarray, shape (h,)
        A breathing displacement ``d`` moves held node ``held[k]`` by ``weight[k] d``.
    description : str
        The choice, in words (records, docs).
    sliding_normals : ndarray, shape (h, 3), or None
        Unit normals when the held nodes slide (only the normal component of their
        displacement prescribed, the tangential free), a zero row for a node held in all
        directions; None: every node held in all directions.
    """

    held: np.ndarray
    weight: np.ndarray
    description: str
    sliding_normals: np.ndarray | None = None


#: The boundary modes of :func:`organ_boundary`.
BOUNDARY_MODES: tuple[str, ...] = ("organ", "uniform", "sliding")


def organ_boundary(mesh: TetMesh, organ: str, mode: str = "organ") -> Boundary:
    """The organ's boundary conditions (see the module notes).

    Parameters
    ----------
    mesh : TetMesh
    organ : str
        ``"lung"`` or ``"liver"``.
    mode : str
        ``"organ"`` (the organ's own), ``"uniform"`` (the whole surface held and moved by
        the breathing displacement: rigid breathing) or ``"sliding"`` (lung: the pleural
        surface slides, only its normal displacement prescribed, ``n . w d``).

    Returns
    -------
    Boundary
    """
    if organ not in MATERIALS:
        raise InvalidInputError("organ", f"expected lung or liver, got {organ!r}")
    if mode not in BOUNDARY_MODES:
        raise InvalidInputError("boundary", f"expected one of {', '.join(BOUNDARY_MODES)}, got {mode!r}")
    surface = mesh.boundary_nodes()
    if mode == "uniform":
        return Boundary(surface, np.ones(len(surface)), "whole surface held, moved by d")
    s = mesh.nodes_mm[surface, 2]  # superior (RAS S)
    if mode == "sliding":
        if organ != "lung":
            raise InvalidInputError("boundary", f"expected sliding for a lung only, got {organ!r}")
        w = (s.max() - s) / max(float(s.max() - s.min()), 1e-9)
        return Boundary(
            surface, w, "pleural surface sliding: its normal displacement n . w d, w 0 at the "
            "apex to 1 at the base", _sliding_normals(mesh, surface),
        )  # fmt: skip
    if organ == "lung":
        w = (s.max() - s) / max(float(s.max() - s.min()), 1e-9)
        return Boundary(
            surface, w, "pleural surface held; breathing moves it by w d, w 0 at the apex to 1 at the base"
        )
    normals = mesh.boundary_normals()[surface]
    held = surface[normals[:, 2] > 0.5]
    return Boundary(held, np.ones(len(held)), "superior (diaphragmatic) surface held, moved by d")


class ElasticProblem:
    """The stiffness of a mesh with its held nodes, factorised once.

    Parameters
    ----------
    mesh : TetMesh
    material : Material
    boundary : Boundary
    solver : str
        ``"splu"`` (SuperLU, in scipy), ``"pardiso"`` (MKL PARDISO through the optional
        ``pypardiso``: 4 to 7 times faster here, x86-64 only) or ``"auto"``: PARDISO when
        ``pypardiso`` is installed, else SuperLU (:data:`SOLVERS`).

    Raises
    ------
    InvalidInputError
        A component of the mesh holds no held node (it would float free: the stiffness
        would be singular).
    """

    def __init__(self, mesh: TetMesh, material: Material, boundary: Boundary, solver: str = "auto") -> None:
        from scipy.sparse import csgraph
        from scipy.sparse.linalg import splu

        self.mesh, self.material, self.boundary = mesh, material, boundary
        self.K = stiffness(mesh, material)
        n = mesh.n_nodes
        held = np.zeros(n, dtype=bool)
        held[boundary.held] = True
        # every component must be held somewhere
        adj = _node_graph(mesh)
        n_comp, labels = csgraph.connected_components(adj, directed=False)
        free_comps = np.setdiff1d(np.arange(n_comp), labels[held])
        if len(free_comps) > 0:
            raise InvalidInputError(
                "boundary", f"expected every part of the mesh to be held, {len(free_comps)} float free"
            )
        self.held_nodes = np.flatnonzero(held)
        held_dof = np.repeat(held, 3)
        # sliding nodes: their dofs in the frame (n, t1, t2), only the normal one held
        self._R, k = None, self.K
        if boundary.sliding_normals is not None:
            self._R = _normal_frames(n, boundary.held, boundary.sliding_normals)
            k = (self._R @ self.K @ self._R.T).tocsr()
            held_dof = np.zeros(3 * n, dtype=bool)
            held_dof[3 * np.asarray(boundary.held)] = True
            creased = np.asarray(boundary.held)[np.linalg.norm(boundary.sliding_normals, axis=1) < 0.5]
            held_dof[(3 * creased[:, None] + np.arange(3)).ravel()] = True
        self.free_dofs = np.flatnonzero(~held_dof)
        self.held_dofs = np.flatnonzero(held_dof)
        kf = k[self.free_dofs][:, self.free_dofs]
        self.K_fh = k[self.free_dofs][:, self.held_dofs].tocsr()
        self.solver = _pick_solver(solver)
        if self.solver == "pardiso":
            import pypardiso

            self._kf = kf.tocsr()
            self._pardiso = pypardiso.PyPardisoSolver()
            self._pardiso.factorize(self._kf)
        else:
            self._lu = splu(kf.tocsc(), permc_spec="MMD_AT_PLUS_A", options={"SymmetricMode": True})

    def solve_free(self, rhs: np.ndarray) -> np.ndarray:
        """``K_ff^-1 rhs`` (rows: free dofs; one or many columns).

        Parameters
        ----------
        rhs : ndarray, shape (f,) or (f, k)

        Returns
        -------
        ndarray, the shape of ``rhs``
        """
        b = np.ascontiguousarray(rhs, dtype=float)
        if self.solver == "pardiso":
            return self._pardiso.solve(self._kf, b)
        return self._lu.solve(b)

    def solve(self, nodal_forces: np.ndarray | None = None, held_displacement: np.ndarray | None = None):
        """The full displacement field (mm) under nodal forces (N) and a prescribed
        displacement of the held nodes.

        Parameters
        ----------
        nodal_forces : ndarray, shape (n, 3) or (3n,), optional
            Forces on the free nodes (those on held nodes are taken by the support).
        held_displacement : ndarray, shape (h, 3), optional
            Displacement of ``held_nodes`` (default zero).

        Returns
        -------
        ndarray, shape (n, 3)
        """
        n3 = 3 * self.mesh.n_nodes
        f = np.zeros(n3) if nodal_forces is None else np.asarray(nodal_forces, float).reshape(n3)
        if self._R is not None:
            f = self._R @ f
        u = np.zeros(n3)
        rhs = f[self.free_dofs]
        if held_displacement is not None:
            g = np.asarray(held_displacement, float).reshape(-1, 3)
            if self._R is not None:  # the normal component of each sliding node's
                full = np.zeros((self.mesh.n_nodes, 3))
                full[self.held_nodes] = g
                g = (self._R @ full.ravel())[self.held_dofs]
            g = g.reshape(-1)
            u[self.held_dofs] = g
            rhs = rhs - self.K_fh @ g
        u[self.free_dofs] = self.solve_free(rhs)
        if self._R is not None:
            u = self._R.T @ u
        return u.reshape(-1, 3)

    def response(self, nodal_forces: np.ndarray) -> np.ndarray:
        """Nodal displacements under many load cases at once, the held nodes still.

        Parameters
        ----------
        nodal_forces : ndarray, shape (3n, k)
            One load case a column (N, dofs node-major).

        Returns
        -------
        ndarray, shape (3n, k)
        """
        f = np.asarray(nodal_forces, dtype=float)
        if self._R is not None:
            f = self._R @ f
        u = np.zeros(f.shape)
        u[self.free_dofs] = self.solve_free(f[self.free_dofs])
        return self._R.T @ u if self._R is not None else u

    def breathing_held(self, d) -> np.ndarray:
        """The held nodes' displacement under a breathing displacement ``d`` (mm).

        Parameters
        ----------
        d : array-like, shape (3,)

        Returns
        -------
        ndarray, shape (h, 3)
        """
        w = np.zeros(self.mesh.n_nodes)
        w[self.boundary.held] = self.boundary.weight
        return w[self.held_nodes, None] * np.asarray(d, float)[None, :]


def _sliding_normals(mesh: TetMesh, surface: np.ndarray) -> np.ndarray:
    """Unit normals of the surface nodes; zero where the surface has no one normal (the
    area-weighted normals of the faces around the node cancel: cells touching by an edge
    or a corner, a crease folded back), which are then held in every direction."""
    faces = mesh.boundary_faces()
    p = mesh.nodes_mm[faces]
    area_n = 0.5 * np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    area = np.linalg.norm(area_n, axis=1)
    sums = np.zeros((mesh.n_nodes, 3))
    total = np.zeros(mesh.n_nodes)
    for c in range(3):
        np.add.at(sums, faces[:, c], area_n)
        np.add.at(total, faces[:, c], area)
    s, t = sums[surface], total[surface]
    norm = np.linalg.norm(s, axis=1)
    ok = norm > 0.3 * t
    out = np.zeros_like(s)
    out[ok] = s[ok] / norm[ok, None]
    return out


def _normal_frames(n: int, nodes: np.ndarray, normals: np.ndarray):
    """The block-diagonal rotation taking node-major dofs to each listed node's frame
    (n, t1, t2), the identity elsewhere: sparse, shape (3n, 3n)."""
    from scipy import sparse

    nrm = np.asarray(normals, dtype=float)
    keep = np.linalg.norm(nrm, axis=1) > 0.5  # the others keep the identity (held fully)
    nodes, nrm = np.asarray(nodes)[keep], nrm[keep]
    helper = np.where(np.abs(nrm[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    t1 = np.cross(nrm, helper)
    t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
    t2 = np.cross(nrm, t1)
    blocks = np.repeat(np.eye(3)[None], n, axis=0)
    blocks[nodes] = np.stack([nrm, t1, t2], axis=1)  # rows: the frame's axes
    rows = (3 * np.arange(n)[:, None, None] + np.arange(3)[None, :, None]).repeat(3, axis=2)
    cols = (3 * np.arange(n)[:, None, None] + np.arange(3)[None, None, :]).repeat(3, axis=1)
    return sparse.csr_matrix((blocks.ravel(), (rows.ravel(), cols.ravel())), shape=(3 * n, 3 * n))


#: The sparse direct solvers of :class:`ElasticProblem`.
SOLVERS: tuple[str, ...] = ("auto", "splu", "pardiso")


def _pick_solver(solver: str) -> str:
    if solver not in SOLVERS:
        raise InvalidInputError("solver", f"expected one of {', '.join(SOLVERS)}, got {solver!r}")
    if solver == "splu":
        return solver
    try:
        import pypardiso  # noqa: F401
    except ImportError:
        if solver == "pardiso":
            raise InvalidInputError(
                "solver", "pardiso needs the optional package pypardiso (pip install pypardiso)"
            ) from None
        return "splu"
    return "pardiso"


def _node_graph(mesh: TetMesh):
    from scipy import sparse

    t = mesh.tets
    rows = np.concatenate([t[:, 0], t[:, 0], t[:, 0]])
    cols = np.concatenate([t[:, 1], t[:, 2], t[:, 3]])
    n = mesh.n_nodes
    return sparse.coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(n, n)).tocsr()
