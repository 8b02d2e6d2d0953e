"""Dense convex QPs of the controller, solved by DAQP (a dual active-set solver).

``minimise 1/2 x^T H x + f^T x  subject to  A x <= b,  lower <= x <= upper``.

The solver's exit flag is never ignored: an infeasible problem returns
``QPStatus.INFEASIBLE`` and no solution (DAQP's ``x`` is meaningless then), and the caller
decides what to do (the controller stops the robot, the adaptation keeps its estimate).
"""

from __future__ import annotations

import enum
from dataclasses import dataclass

import numpy as np

from needlekit.errors import InvalidInputError

__all__ = ["QPSolution", "QPStatus", "solve_qp"]

#: "No bound" for DAQP.
_INF = 1e30


class QPStatus(enum.Enum):
    """Outcome of :func:`solve_qp`."""

    OPTIMAL = "optimal"
    INFEASIBLE = "infeasible"
    FAILED = "failed"


@dataclass(frozen=True)
class QPSolution:
    """A QP's solution.

    Attributes
    ----------
    x : ndarray, shape (n,) or None
        None unless ``status`` is ``OPTIMAL``.
    status : QPStatus
    exitflag : int
        DAQP's exit flag (1 optimal, -1 infeasible, other negatives: failures).
    """

    x: np.ndarray | None
    status: QPStatus
    exitflag: int


def solve_qp(H, f, A=None, b=None, lower=None, upper=None, *, check: bool = True) -> QPSolution:
    """Solve a small dense QP.

    Parameters
    ----------
    H : ndarray, shape (n, n)
        Symmetric positive (semi)definite.
    f : ndarray, shape (n,)
    A : ndarray, shape (m, n), optional
    b : ndarray, shape (m,), optional
    lower, upper : ndarray, shape (n,), optional
        Bounds on x.
    check : bool
        Validate shapes and finiteness (the controller, which builds its QPs itself,
        skips this in its 1 kHz loop).

    Returns
    -------
    QPSolution

    Examples
    --------
    >>> s = solve_qp(np.eye(2), np.array([-1.0, -1.0]), np.array([[1.0, 1.0]]), np.array([1.0]))
    >>> s.status.value, np.round(s.x, 6).tolist()
    ('optimal', [0.5, 0.5])
    """
    H = np.ascontiguousarray(H, dtype=float)
    f = np.ascontiguousarray(f, dtype=float).reshape(-1)
    n = f.shape[0]
    if check and H.shape != (n, n):
        raise InvalidInputError("H", f"expected shape ({n}, {n}), got {H.shape}")
    if A is None:
        A = np.zeros((0, n))
        b = np.zeros(0)
    A = np.ascontiguousarray(A, dtype=float).reshape(-1, n)
    b = np.asarray(b, dtype=float).reshape(-1)
    if check and b.shape[0] != A.shape[0]:
        raise InvalidInputError("b", f"expected {A.shape[0]} values, got {b.shape[0]}")
    lo = np.full(n, -_INF) if lower is None else np.asarray(lower, dtype=float)
    hi = np.full(n, _INF) if upper is None else np.asarray(upper, dtype=float)
    if check and not (np.isfinite(H).all() and np.isfinite(f).all() and np.isfinite(A).all()):
        raise InvalidInputError("H", "the QP data must be finite")
    if (lo > hi).any():
        return QPSolution(None, QPStatus.INFEASIBLE, -1)
    bupper = np.concatenate([hi, b])
    blower = np.concatenate([lo, np.full(b.shape[0], -_INF)])
    sense = np.zeros(n + b.shape[0], dtype=np.int32)
    return _solve_prepared(H, f, A, bupper, blower, sense)


_daqp = None


def _solve_prepared(H, f, A, bupper, blower, sense) -> QPSolution:
    """DAQP on data already in its layout: C-contiguous float64 ``H`` (n, n), ``f`` (n,),
    ``A`` (m, n); ``bupper``, ``blower`` (n + m,: the bounds on x, then the rows' right-hand
    sides and ``-_INF``) and ``sense`` (n + m, ``np.intc``, zeros). DAQP copies what it
    changes (its workspace has its own ``sense``), so the controller passes the same buffers
    at every step; ``x`` is a new array."""
    global _daqp
    if _daqp is None:  # imported on first use (keeps ``needlekit --help`` light)
        import daqp

        _daqp = daqp
    x, _, exitflag, _ = _daqp.solve(H, f, A, bupper, blower, sense)
    if exitflag >= 1:
        return QPSolution(np.asarray(x, dtype=float), QPStatus.OPTIMAL, int(exitflag))
    status = QPStatus.INFEASIBLE if exitflag == -1 else QPStatus.FAILED
    return QPSolution(None, status, int(exitflag))
