"""The controller's QP solver against brute-force active-set enumeration."""

import itertools

import numpy as np
import pytest

from needlekit.control.qp import QPStatus, solve_qp
from needlekit.errors import InvalidInputError


def _brute_force(H, f, A, b):
    """Minimiser of 1/2 x'Hx + f'x s.t. Ax <= b: the best feasible KKT point over every
    active set (H positive definite)."""
    n, m = len(f), len(b)
    best, best_val = None, np.inf
    for k in range(m + 1):
        for active in itertools.combinations(range(m), k):
            Aa = A[list(active)]
            kkt = np.block([[H, Aa.T], [Aa, np.zeros((k, k))]])
            try:
                sol = np.linalg.solve(kkt, np.concatenate([-f, b[list(active)]]))
            except np.linalg.LinAlgError:
                continue
            x, lam = sol[:n], sol[n:]
            if np.all(A @ x <= b + 1e-9) and np.all(lam >= -1e-9):
                val = 0.5 * x @ H @ x + f @ x
                if val < best_val:
                    best, best_val = x, val
    return best


@pytest.mark.parametrize("seed", range(30))
def test_matches_brute_force_active_sets(seed):
    rng = np.random.default_rng(seed)
    n, m = 3, 5
    M = rng.normal(size=(4, n))
    H = M.T @ M + 0.1 * np.eye(n)
    f = rng.normal(size=n) * 3
    A = rng.normal(size=(m, n))
    b = rng.uniform(0.1, 1.0, m)  # x = 0 is feasible
    s = solve_qp(H, f, A, b)
    assert s.status is QPStatus.OPTIMAL
    np.testing.assert_allclose(s.x, _brute_force(H, f, A, b), atol=1e-6)


def test_bounds_are_constraints_too():
    rng = np.random.default_rng(0)
    H = np.eye(3)
    f = rng.normal(size=3) * 5
    lo, hi = np.full(3, -0.5), np.full(3, 0.5)
    s = solve_qp(H, f, lower=lo, upper=hi)
    np.testing.assert_allclose(s.x, np.clip(-f, lo, hi), atol=1e-9)


def test_infeasible_problems_say_so_and_return_no_x():
    s = solve_qp(
        np.eye(2), np.zeros(2), np.array([[1.0, 0.0], [-1.0, 0.0]]), np.array([-1.0, -1.0])
    )
    assert s.status is QPStatus.INFEASIBLE and s.x is None
    s = solve_qp(np.eye(2), np.zeros(2), lower=[1.0, 0.0], upper=[0.0, 1.0])
    assert s.status is QPStatus.INFEASIBLE


def test_bad_shapes_name_the_field():
    with pytest.raises(InvalidInputError, match="H"):
        solve_qp(np.eye(3), np.zeros(2))
    with pytest.raises(InvalidInputError, match="b"):
        solve_qp(np.eye(2), np.zeros(2), np.ones((2, 2)), np.ones(3))
