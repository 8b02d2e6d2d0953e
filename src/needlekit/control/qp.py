"""Dense convex QPs of the controller and the adaptation, in one solver-neutral layout, and
the solver adapter they go through (:class:`QPSolver`; DAQP, a dual active-set solver, is
the default).

``minimise 1/2 x^T H x + f^T x  subject to  lower <= [x; A x] <= upper``.

The layout (what the 1 kHz kernels in :mod:`needlekit.control._tick` and
:mod:`needlekit.control._adaptation_kernels` fill, and what every solver takes): ``H``
(n, n) and ``f`` (n,) C-contiguous float64, ``A`` (m, n) the constraint rows, and the
stacked bounds ``upper`` and ``lower`` (n + m,): entries ``0..n-1`` bound ``x`` itself,
entries ``n..n+m-1`` bound the rows ``A x``; :data:`NO_BOUND` (or its negative) means
none. A solver converts from it if it needs another form, outside the numba kernels;
nothing above this module branches on a solver's name (the registry,
:mod:`needlekit.control.qp_registry`, makes a name an object).

The solver's exit flag is never ignored: an infeasible problem returns
``QPStatus.INFEASIBLE`` and no solution (a solver's ``x`` is meaningless then), and the
caller decides what to do (the controller stops the robot, the adaptation keeps its
estimate).
"""

from __future__ import annotations

import abc
import enum
from dataclasses import dataclass

import numpy as np

from needlekit.errors import InvalidInputError

__all__ = ["NO_BOUND", "DAQPSolver", "QPSolution", "QPSolver", "QPStatus", "solve_qp"]

#: "No bound" in the layout (DAQP's own "infinite" bound; finite, so numba kernels and
#: every solver read it alike).
NO_BOUND = 1e30


class QPStatus(enum.Enum):
    """Outcome of a QP solve."""

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
        The solver's own exit code (DAQP: 1 optimal, -1 infeasible, other negatives:
        failures; other adapters map theirs onto the same signs; -1 also when a bound pair
        is crossed before any solver runs).
    """

    x: np.ndarray | None
    status: QPStatus
    exitflag: int


class QPSolver(abc.ABC):
    """A dense convex QP solver behind needlekit's layout (see the module).

    A subclass sets :attr:`name` and :attr:`tolerance` and implements :meth:`solve`; it
    takes checked data (the kernels build it; :func:`solve_qp` checks a user's) and must
    not keep references to the arrays, which the controller overwrites at every tick.

    Attributes
    ----------
    name : str
        The registry name.
    tolerance : float
        The accuracy its solutions are good to (absolute, on ``x`` and on the constraint
        rows, for the well-conditioned QPs of the controller): what two solvers' results
        may differ by.
    """

    name: str = ""
    tolerance: float = 1e-6

    def prepare(self, n_vars: int, n_constraints: int) -> None:  # noqa: B027 - optional hook
        """Allocate what a problem of this size needs (optional; :meth:`solve` works
        without it).

        Parameters
        ----------
        n_vars : int
            ``n``.
        n_constraints : int
            ``m``, the rows of ``A``.

        Returns
        -------
        None
        """

    @abc.abstractmethod
    def solve(self, H, f, A, upper, lower) -> QPSolution:
        """Solve one QP in the layout.

        Parameters
        ----------
        H : ndarray, shape (n, n)
            Symmetric positive definite.
        f : ndarray, shape (n,)
        A : ndarray, shape (m, n)
        upper, lower : ndarray, shape (n + m,)
            Bounds on ``x``, then on ``A x`` (:data:`NO_BOUND`: none).

        Returns
        -------
        QPSolution
        """

    def __repr__(self) -> str:
        return f"{type(self).__name__}()"


class DAQPSolver(QPSolver):
    """DAQP (Arnström, Bemporad, Axehill): dual active-set, the layout is its own.

    Its primal feasibility tolerance is 1e-6 (its default ``primal_tol``); at the active
    set it finds, ``x`` solves the KKT system to rounding.

    Examples
    --------
    >>> s = DAQPSolver().solve(np.eye(1), np.array([-2.0]), np.zeros((0, 1)),
    ...                        np.array([1.0]), np.array([-1.0]))
    >>> s.status.value, s.x.tolist()
    ('optimal', [1.0])
    """

    name = "daqp"
    tolerance = 1e-6

    def __init__(self) -> None:
        self._sense: dict[int, np.ndarray] = {}

    def prepare(self, n_vars: int, n_constraints: int) -> None:
        # DAQP's sense vector: zeros, every bound an inequality
        self._sense_of(n_vars + n_constraints)

    def _sense_of(self, size: int) -> np.ndarray:
        # DAQP copies what it changes (its workspace has its own sense): one per size
        sense = self._sense.get(size)
        if sense is None:
            sense = self._sense[size] = np.zeros(size, dtype=np.intc)
        return sense

    def solve(self, H, f, A, upper, lower) -> QPSolution:
        # the docstring is QPSolver.solve's; x is a new array
        x, _, exitflag, _ = _daqp().solve(H, f, A, upper, lower, self._sense_of(upper.shape[0]))
        if exitflag >= 1:
            return QPSolution(np.asarray(x, dtype=float), QPStatus.OPTIMAL, int(exitflag))
        status = QPStatus.INFEASIBLE if exitflag == -1 else QPStatus.FAILED
        return QPSolution(None, status, int(exitflag))


_daqp_module = None


def _daqp():
    global _daqp_module
    if _daqp_module is None:  # imported on first use (keeps ``needlekit --help`` light)
        import daqp

        _daqp_module = daqp
    return _daqp_module


#: The default solver (one instance: it only caches DAQP's ``sense`` vectors).
DEFAULT_SOLVER = DAQPSolver()

#: Returned when a bound pair is crossed before a solver runs.
CROSSED_BOUNDS = QPSolution(None, QPStatus.INFEASIBLE, -1)


def solve_qp(
    H, f, A=None, b=None, lower=None, upper=None, *, check: bool = True, solver=None
) -> QPSolution:
    """Solve a small dense QP ``min 1/2 x'Hx + f'x  s.t.  A x <= b, lower <= x <= upper``.

    Parameters
    ----------
    H : ndarray, shape (n, n)
        Symmetric positive definite.
    f : ndarray, shape (n,)
    A : ndarray, shape (m, n), optional
    b : ndarray, shape (m,), optional
    lower, upper : ndarray, shape (n,), optional
        Bounds on x.
    check : bool
        Validate shapes and finiteness.
    solver : QPSolver, optional
        Default DAQP (a name: :func:`needlekit.control.qp_registry.get_qp_solver`).

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
    lo = np.full(n, -NO_BOUND) if lower is None else np.asarray(lower, dtype=float)
    hi = np.full(n, NO_BOUND) if upper is None else np.asarray(upper, dtype=float)
    if check and not (np.isfinite(H).all() and np.isfinite(f).all() and np.isfinite(A).all()):
        raise InvalidInputError("H", "the QP data must be finite")
    if (lo > hi).any():
        return CROSSED_BOUNDS
    bupper = np.concatenate([hi, b])
    blower = np.concatenate([lo, np.full(b.shape[0], -NO_BOUND)])
    return (solver or DEFAULT_SOLVER).solve(H, f, A, bupper, blower)
