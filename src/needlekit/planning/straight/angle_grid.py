"""The angle grid of a CFRW map: how many polar and azimuth angles a resolution gives.

Pure arithmetic, no numpy: :func:`~needlekit.planning.straight.cfrw.build.cfrw_map` builds
its grid from it, and the command line sizes a request with it before anything loads.
"""

from __future__ import annotations

import math

__all__ = ["DEFAULT_PHI_RANGE_DEG", "DEFAULT_THETA_RANGE_DEG", "grid_shape"]

#: The ranges a multi-needle problem searches unless its scenario narrows them.
DEFAULT_THETA_RANGE_DEG: tuple[float, float] = (0.0, 90.0)
DEFAULT_PHI_RANGE_DEG: tuple[float, float] = (-180.0, 180.0)


def grid_shape(theta_range_deg, phi_range_deg, resolution_deg: float) -> tuple[int, int]:
    """Polar and azimuth angle counts of the grid.

    Parameters
    ----------
    theta_range_deg, phi_range_deg : (float, float)
        Ranges (deg); a full turn of azimuth is sampled without repeating its end.
    resolution_deg : float
        Grid step (deg), > 0.

    Returns
    -------
    (int, int)
        ``(m, k)``: ``m`` polar angles (both ends included), ``k`` azimuths.

    Examples
    --------
    >>> grid_shape((0.0, 90.0), (-180.0, 180.0), 1.0)
    (91, 360)
    >>> grid_shape((0.0, 90.0), (0.0, 90.0), 2.0)
    (46, 46)
    """
    step = math.radians(resolution_deg)
    t0, t1 = (math.radians(a) for a in theta_range_deg)
    p0, p1 = (math.radians(a) for a in phi_range_deg)
    m = int(round((t1 - t0) / step)) + 1
    if p1 - p0 >= 2 * math.pi - 1e-9:
        k = int(round(2 * math.pi / step))
    else:
        k = int(round((p1 - p0) / step)) + 1
    return m, k
