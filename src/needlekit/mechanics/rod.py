"""Euler-Bernoulli beam finite elements on an elastic foundation, banded.

One bending plane at a time: a beam along ``s`` (mm) with transverse deflection ``w(s)``
(mm), flexural rigidity ``EI`` (N mm^2) and a Winkler foundation of modulus ``k(s)``
(N/mm^2: force per unit length per unit deflection) minimises

    ``Pi = 1/2 int EI w''^2 ds + 1/2 int k w^2 ds - sum F_i w(s_i) - sum M_i w'(s_i)``.

Each element ``[s_e, s_e + l]`` carries the Hermite cubic interpolation of its end
deflections and slopes ``(w_0, theta_0, w_1, theta_1)``; its stiffness and its consistent
foundation matrix are the closed forms

    ``K_e = EI / l^3 [[12, 6l, -12, 6l], [6l, 4l^2, -6l, 2l^2], [-12, -6l, 12, -6l],
    [6l, 2l^2, -6l, 4l^2]]``,
    ``F_e = k l / 420 [[156, 22l, 54, -13l], [22l, 4l^2, 13l, -3l^2],
    [54, 13l, 156, -22l], [-13l, -3l^2, -22l, 4l^2]]``.

Node ``j`` owns degrees of freedom ``2j`` (deflection) and ``2j + 1`` (slope), so the
assembled matrix is banded with three diagonals above the main one; it is symmetric
positive definite once the beam is clamped or resting on a foundation, and is solved by a
banded Cholesky factorisation (LAPACK ``pbtrf``/``pbtrs`` through
:func:`scipy.linalg.cholesky_banded`), one factorisation for any number of right-hand
sides (the needle's two bending planes share it).

Hermite cubics reproduce the exact deflection of a beam without foundation under nodal
loads at the nodes; with a foundation the nodal error falls as ``h^4`` (tests measure it).
"""

from __future__ import annotations

import numpy as np
from scipy.linalg import cho_solve_banded, cholesky_banded

from needlekit.errors import InvalidInputError

__all__ = [
    "BAND",
    "assemble_upper_band",
    "element_foundation",
    "element_stiffness",
    "solve_beam",
    "solve_band",
]

#: Number of diagonals above the main one in the assembled matrix.
BAND = 3

_PAIRS = [(a, b) for a in range(4) for b in range(a, 4)]


def element_stiffness(lengths: np.ndarray, ei: float) -> np.ndarray:
    """Bending stiffness matrices of Hermite elements.

    Parameters
    ----------
    lengths : ndarray, shape (n,)
        Element lengths (mm), > 0.
    ei : float
        Flexural rigidity (N mm^2).

    Returns
    -------
    ndarray, shape (n, 4, 4)
        In the order ``(w_0, theta_0, w_1, theta_1)``.
    """
    el = np.asarray(lengths, dtype=np.float64)
    c = ei / el**3
    out = np.empty((el.size, 4, 4))
    l1, l2 = el, el * el
    rows = (
        (12.0, 6.0 * l1, -12.0, 6.0 * l1),
        (6.0 * l1, 4.0 * l2, -6.0 * l1, 2.0 * l2),
        (-12.0, -6.0 * l1, 12.0, -6.0 * l1),
        (6.0 * l1, 2.0 * l2, -6.0 * l1, 4.0 * l2),
    )
    for i, row in enumerate(rows):
        for j, v in enumerate(row):
            out[:, i, j] = c * v
    return out


def element_foundation(lengths: np.ndarray, k: np.ndarray | float) -> np.ndarray:
    """Consistent Winkler foundation matrices of Hermite elements.

    Parameters
    ----------
    lengths : ndarray, shape (n,)
        Element lengths (mm).
    k : float or ndarray, shape (n,)
        Foundation modulus per element (N/mm^2), >= 0.

    Returns
    -------
    ndarray, shape (n, 4, 4)
    """
    el = np.asarray(lengths, dtype=np.float64)
    c = np.broadcast_to(np.asarray(k, dtype=np.float64), el.shape) * el / 420.0
    l1, l2 = el, el * el
    rows = (
        (156.0, 22.0 * l1, 54.0, -13.0 * l1),
        (22.0 * l1, 4.0 * l2, 13.0 * l1, -3.0 * l2),
        (54.0, 13.0 * l1, 156.0, -22.0 * l1),
        (-13.0 * l1, -3.0 * l2, -22.0 * l1, 4.0 * l2),
    )
    out = np.empty((el.size, 4, 4))
    for i, row in enumerate(rows):
        for j, v in enumerate(row):
            out[:, i, j] = c * v
    return out


def assemble_upper_band(mats: np.ndarray) -> np.ndarray:
    """Assemble element matrices of consecutive elements into upper banded storage.

    Parameters
    ----------
    mats : ndarray, shape (n, 4, 4)
        Symmetric element matrices; element ``e`` couples nodes ``e`` and ``e + 1``.

    Returns
    -------
    ndarray, shape (BAND + 1, 2 (n + 1))
        ``ab[BAND + i - j, j] = A[i, j]`` for ``i <= j`` (LAPACK's upper band form).
    """
    n = mats.shape[0]
    ab = np.zeros((BAND + 1, 2 * (n + 1)))
    base = 2 * np.arange(n)
    for a, b in _PAIRS:
        ab[BAND + a - b, base + b] += mats[:, a, b]
    return ab


def solve_band(ab: np.ndarray, rhs: np.ndarray, n_fixed: int = 0) -> np.ndarray:
    """Solve the banded system with its first ``n_fixed`` unknowns held at zero.

    Parameters
    ----------
    ab : ndarray, shape (BAND + 1, N)
        Upper banded matrix from :func:`assemble_upper_band`.
    rhs : ndarray, shape (N,) or (N, m)
        Load vectors.
    n_fixed : int
        Unknowns fixed at zero (2 clamps the first node: deflection and slope).

    Returns
    -------
    ndarray, same shape as ``rhs``
        The solution, zeros in the fixed places.
    """
    sub = ab[:, n_fixed:]
    try:
        chol = cholesky_banded(sub, lower=False, check_finite=False)
    except np.linalg.LinAlgError as exc:
        raise InvalidInputError(
            "rod", "the beam is not held (no clamp and no foundation): singular stiffness"
        ) from exc
    out = np.zeros_like(rhs, dtype=np.float64)
    out[n_fixed:] = cho_solve_banded((chol, False), rhs[n_fixed:], check_finite=False)
    return out


def solve_beam(
    node_s_mm,
    ei: float,
    k_per_element=0.0,
    loads=None,
    *,
    clamp_first: bool = True,
) -> np.ndarray:
    """Deflections and slopes of a beam under nodal forces and moments.

    Parameters
    ----------
    node_s_mm : array_like, shape (n,)
        Increasing node positions along the beam (mm).
    ei : float
        Flexural rigidity (N mm^2), > 0.
    k_per_element : float or array_like, shape (n - 1,)
        Foundation modulus on each element (N/mm^2), >= 0.
    loads : array_like, shape (2 n,) or (2 n, m)
        Nodal force (N) at ``2j`` and moment (N mm) at ``2j + 1``.
    clamp_first : bool
        Clamp node 0 (deflection and slope zero); otherwise the beam is free and needs a
        foundation.

    Returns
    -------
    ndarray, shape like ``loads``
        Deflection (mm) at ``2j`` and slope (rad) at ``2j + 1``.
    """
    s = np.asarray(node_s_mm, dtype=np.float64)
    if s.ndim != 1 or s.size < 2 or not np.all(np.isfinite(s)):
        raise InvalidInputError("node_s_mm", "expected at least 2 finite node positions")
    lengths = np.diff(s)
    if np.any(lengths <= 0):
        raise InvalidInputError("node_s_mm", "expected strictly increasing node positions")
    if not (np.isfinite(ei) and ei > 0):
        raise InvalidInputError("ei", f"expected a flexural rigidity > 0, got {ei!r}")
    k = np.broadcast_to(np.asarray(k_per_element, dtype=np.float64), lengths.shape)
    if not np.all(np.isfinite(k)) or np.any(k < 0):
        raise InvalidInputError("k_per_element", "expected finite foundation moduli >= 0")
    if not clamp_first and not np.any(k > 0):
        raise InvalidInputError(
            "rod", "the beam is not held (no clamp and no foundation): singular stiffness"
        )
    rhs = np.zeros(2 * s.size) if loads is None else np.asarray(loads, dtype=np.float64)
    if rhs.shape[0] != 2 * s.size:
        raise InvalidInputError("loads", f"expected {2 * s.size} rows, got {rhs.shape[0]}")
    mats = element_stiffness(lengths, ei) + element_foundation(lengths, k)
    return solve_band(assemble_upper_band(mats), rhs, 2 if clamp_first else 0)
