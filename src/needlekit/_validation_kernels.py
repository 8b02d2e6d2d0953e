"""The numba kernel of :func:`needlekit._validation._rotation_errors` for large batches,
in a module of its own so that small checks (a pose file, a few poses) do not load numba."""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["rotation_errors"]


@numba.njit(cache=True)
def rotation_errors(rot):  # pragma: no cover - compiled
    """Per matrix: max |R^T R - I| and |det R - 1| (numba; numpy's einsum is 10x slower)."""
    n = rot.shape[0]
    ortho = np.empty(n)
    det = np.empty(n)
    for k in range(n):
        worst = 0.0
        for i in range(3):
            for j in range(3):
                acc = (
                    rot[k, 0, i] * rot[k, 0, j]
                    + rot[k, 1, i] * rot[k, 1, j]
                    + rot[k, 2, i] * rot[k, 2, j]
                )
                if i == j:
                    acc -= 1.0
                worst = max(worst, abs(acc))
        ortho[k] = worst
        d = (
            rot[k, 0, 0] * (rot[k, 1, 1] * rot[k, 2, 2] - rot[k, 1, 2] * rot[k, 2, 1])
            - rot[k, 0, 1] * (rot[k, 1, 0] * rot[k, 2, 2] - rot[k, 1, 2] * rot[k, 2, 0])
            + rot[k, 0, 2] * (rot[k, 1, 0] * rot[k, 2, 1] - rot[k, 1, 1] * rot[k, 2, 0])
        )
        det[k] = abs(d - 1.0)
    return ortho, det
