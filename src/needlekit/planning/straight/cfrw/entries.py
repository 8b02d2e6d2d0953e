"""Where rays from the target leave the body: :func:`entry_points`.

Each ray marches in steps of ``|d| / L`` (``L`` the entry surface field's Lipschitz
bound), so no sign change is stepped over (but for parts shorter than
:data:`ENTRY_MIN_STEP_MM`), then bisects the crossing to :data:`ENTRY_TOL_MM`.
"""

from __future__ import annotations

import numpy as np

from needlekit.anatomy.fields import DistanceField

__all__ = ["entry_points"]


#: Entry points are located to within this (mm) along the ray.
ENTRY_TOL_MM: float = 1e-4

#: Smallest step (mm) of the march toward the entry surface: a part of the ray outside
#: the body shorter than this, before the first crossing found, can be stepped over.
ENTRY_MIN_STEP_MM: float = 0.05


def entry_points(
    body: DistanceField, target_mm: np.ndarray, directions: np.ndarray, max_length_mm: float
) -> tuple[np.ndarray, np.ndarray]:
    """Where rays from the target leave the body through its surface.

    Parameters
    ----------
    body : DistanceField
        The entry surface's structure (negative inside the body).
    target_mm : ndarray, shape (3,)
    directions : ndarray, shape (n, 3)
        Unit directions from the target.
    max_length_mm : float
        Rays are followed this far (plus a small slack to report "too long").

    Returns
    -------
    length_mm : ndarray, shape (n,)
        Distance from the target to the first crossing (``inf`` where none within the
        search length).
    entry_mm : ndarray, shape (n, 3)
        The crossing points (NaN where none).
    """
    u = np.asarray(directions, dtype=float).reshape(-1, 3)
    n = len(u)
    reach = float(max_length_mm) * 1.25 + 5.0
    lip = body.lipschitz_bound
    err = float(body.error_bound_mm)
    t = np.zeros(n)
    lo = np.zeros(n)
    hi = np.full(n, np.inf)
    active = np.arange(n)
    while active.size:
        d = body.signed_distance(target_mm + t[active, None] * u[active])
        out = d >= 0.0
        hi[active[out]] = t[active[out]]
        lo[active[~out]] = t[active[~out]]
        # no sign change of the field within |d| / L; without L, of the true surface
        # within |d| - err
        safe = -d / lip if lip is not None else -d - err
        step = np.maximum(safe, ENTRY_MIN_STEP_MM)
        t[active] = t[active] + step
        keep = ~out & (t[active] <= reach)
        active = active[keep]
    found = np.isfinite(hi)
    idx = np.flatnonzero(found)
    a, b = lo[idx], hi[idx]
    while idx.size and np.max(b - a) > ENTRY_TOL_MM:
        m = 0.5 * (a + b)
        d = body.signed_distance(target_mm + m[:, None] * u[idx])
        a = np.where(d < 0, m, a)
        b = np.where(d < 0, b, m)
    length = np.full(n, np.inf)
    length[idx] = b
    entry = np.full((n, 3), np.nan)
    entry[idx] = target_mm + b[:, None] * u[idx]
    return length, entry
