"""quadprog (Goldfarb-Idnani's dual active-set method, Fortran) behind the QP adapter
(:class:`needlekit.control.qp.QPSolver`): an optional second solver,
``pip install 'needlekit[quadprog]'``.

quadprog solves ``min 1/2 x'Gx - a'x  s.t.  C'x >= b`` (the first ``meq`` rows
equalities); the adapter turns the layout's stacked bounds into those rows: every finite
upper bound ``r x <= u`` becomes ``-r x >= -u``, every finite lower bound ``r x >= l`` stays,
and a bound pair with ``l == u`` becomes one equality. It solves the KKT system of the
active set it ends on exactly (to rounding), with no feasibility tolerance of its own.
"""

from __future__ import annotations

import numpy as np

from needlekit.control.qp import CROSSED_BOUNDS, NO_BOUND, QPSolution, QPSolver, QPStatus
from needlekit.errors import NeedlekitError

__all__ = ["QuadprogSolver"]

#: quadprog's messages (``ValueError``) for an infeasible problem and a Hessian that is not
#: positive definite.
_INCONSISTENT = "constraints are inconsistent"
_NOT_DEFINITE = "not positive definite"


class QuadprogSolver(QPSolver):
    """quadprog through needlekit's QP layout.

    Raises
    ------
    NeedlekitError
        quadprog is not installed (when the solver is built).

    Examples
    --------
    >>> try:
    ...     solver = QuadprogSolver()
    ... except NeedlekitError:  # the extra is not installed: the same answer from DAQP
    ...     from needlekit.control.qp import DAQPSolver
    ...     solver = DAQPSolver()
    >>> s = solver.solve(np.eye(1), np.array([-2.0]), np.zeros((0, 1)),
    ...                  np.array([1.0]), np.array([-1.0]))
    >>> s.status.value, s.x.tolist()
    ('optimal', [1.0])
    """

    name = "quadprog"
    #: Exact at its active set; 1e-9 covers the rounding of the controller's QPs (H's
    #: condition number up to ~1e8 with the 1e-3 damping).
    tolerance = 1e-9

    def __init__(self) -> None:
        try:
            import quadprog
        except ImportError:
            raise NeedlekitError(
                "qp_solver: quadprog is not installed (pip install 'needlekit[quadprog]')"
            ) from None
        self._solve = quadprog.solve_qp

    def solve(self, H, f, A, upper, lower) -> QPSolution:
        # the docstring is QPSolver.solve's; exitflag 1 optimal, -1 infeasible, -2 failed
        if (lower > upper).any():
            return CROSSED_BOUNDS
        n = f.shape[0]
        rows = np.vstack([np.eye(n), A])  # (n + m, n): x, then A x
        has_hi, has_lo = upper < NO_BOUND, lower > -NO_BOUND
        eq = has_hi & has_lo & (upper == lower)
        hi, lo = has_hi & ~eq, has_lo & ~eq
        C = np.ascontiguousarray(np.vstack([rows[eq], -rows[hi], rows[lo]]).T)
        b = np.concatenate([upper[eq], -upper[hi], lower[lo]])
        if not b.shape[0]:  # quadprog takes no constraints as None, not an empty matrix
            C = b = None
        try:
            x = self._solve(np.array(H, dtype=float), -f, C, b, int(eq.sum()))[0]
        except ValueError as exc:
            if _INCONSISTENT in str(exc):
                return QPSolution(None, QPStatus.INFEASIBLE, -1)
            if _NOT_DEFINITE in str(exc):
                return QPSolution(None, QPStatus.FAILED, -2)
            raise
        return QPSolution(np.asarray(x, dtype=float), QPStatus.OPTIMAL, 1)
