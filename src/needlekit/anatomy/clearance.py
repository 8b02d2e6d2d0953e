"""Clearance of straight segments and constant-curvature arcs against a distance field.

The paths are sampled evenly in arc length; with samples ``g`` mm apart every point of the
path lies within ``g / 2`` of a sample, and a true signed distance is 1-Lipschitz, so

    true clearance  >=  min over samples of d  -  g / 2  -  error_bound

No obstacle, however thin, slips between samples: :attr:`Clearance.clearance_mm` is never
larger than the true minimum clearance by more than the field's stated error, and
:attr:`Clearance.certified_mm` (which also subtracts the error bound) is never larger at
all.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from needlekit._validation import as_points, as_positive
from needlekit.anatomy.fields import DistanceField
from needlekit.constants import DEFAULT_SAMPLE_SPACING_MM
from needlekit.errors import InvalidInputError
from needlekit.geometry.arcs import sample_arcs

__all__ = ["Clearance", "segment_clearance", "arc_clearance", "path_clearance"]


@dataclass(frozen=True)
class Clearance:
    """Minimum clearance along paths (arrays of shape (n,), one entry per path).

    Attributes
    ----------
    clearance_mm : ndarray
        ``min sampled distance - gap / 2``: at most the true minimum clearance plus the
        field's error bound.
    certified_mm : ndarray
        ``clearance_mm - error_bound_mm``: never above the true minimum clearance.
    sampled_min_mm : ndarray
        Smallest distance among the samples (an estimate, not a bound).
    at_mm : ndarray, shape (n, 3)
        The sample where the smallest distance occurred (world, mm).
    gap_mm : ndarray
        Spacing of the samples along each path (mm).
    """

    clearance_mm: np.ndarray
    certified_mm: np.ndarray
    sampled_min_mm: np.ndarray
    at_mm: np.ndarray
    gap_mm: np.ndarray


def _n_samples(lengths: np.ndarray, spacing: float) -> int:
    longest = float(lengths.max()) if lengths.size else 0.0
    return max(2, int(np.ceil(longest / spacing - 1e-12)) + 1)


def path_clearance(field: DistanceField, samples: np.ndarray, lengths: np.ndarray) -> Clearance:
    """Clearance from points sampled evenly along paths.

    Parameters
    ----------
    field : DistanceField
        Obstacle field (e.g. :meth:`needlekit.anatomy.scene.Scene.obstacle_field`).
    samples : ndarray, shape (n, m, 3)
        ``m >= 2`` points per path, evenly spaced in arc length, ends included (world, mm).
    lengths : ndarray, shape (n,)
        Arc length of each path (mm).

    Returns
    -------
    Clearance
    """
    s = np.asarray(samples, dtype=np.float64)
    if s.ndim != 3 or s.shape[2] != 3 or s.shape[1] < 2:
        raise InvalidInputError("samples", f"expected shape (n, m >= 2, 3), got {s.shape}")
    n, m, _ = s.shape
    d = field.signed_distance(s.reshape(-1, 3)).reshape(n, m)
    idx = np.argmin(d, axis=1)
    rows = np.arange(n)
    sampled = d[rows, idx]
    gap = np.asarray(lengths, dtype=np.float64) / (m - 1)
    clearance = sampled - 0.5 * gap
    return Clearance(clearance, clearance - field.error_bound_mm, sampled, s[rows, idx], gap)


def segment_clearance(
    field: DistanceField, start_mm, end_mm, *, spacing_mm: float = DEFAULT_SAMPLE_SPACING_MM
) -> Clearance:
    """Minimum clearance along straight segments.

    Parameters
    ----------
    field : DistanceField
    start_mm, end_mm : array_like, shape (3,) or (n, 3)
        Segment ends (world, mm).
    spacing_mm : float
        Largest gap between samples; smaller is tighter and slower.

    Returns
    -------
    Clearance
        Arrays of shape (n,) (n = 1 for a single segment).

    Examples
    --------
    >>> import numpy as np
    >>> from needlekit.anatomy.fields import DistanceField
    >>> class Ball(DistanceField):
    ...     def _signed_distance(self, p):
    ...         return np.linalg.norm(p, axis=1) - 1.0
    ...     def bounds(self):
    ...         return np.array([[-1.0] * 3, [1.0] * 3])
    >>> c = segment_clearance(Ball(), [-5.0, 3.0, 0.0], [5.0, 3.0, 0.0], spacing_mm=0.1)
    >>> bool(1.9 < c.clearance_mm[0] <= 2.0)
    True
    """
    a, _ = as_points(start_mm, "start_mm")
    b, _ = as_points(end_mm, "end_mm")
    if a.shape[0] != b.shape[0] and 1 not in (a.shape[0], b.shape[0]):
        raise InvalidInputError("end_mm", f"{b.shape[0]} ends do not match {a.shape[0]} starts")
    a, b = np.broadcast_arrays(a, b)
    spacing = as_positive(spacing_mm, "spacing_mm")
    lengths = np.linalg.norm(b - a, axis=1)
    m = _n_samples(lengths, spacing)
    t = np.linspace(0.0, 1.0, m)
    samples = a[:, None, :] + t[None, :, None] * (b - a)[:, None, :]
    return path_clearance(field, samples, lengths)


def arc_clearance(
    field: DistanceField,
    world_T_tip,
    spin_rad,
    kappa_per_mm,
    length_mm,
    *,
    spacing_mm: float = DEFAULT_SAMPLE_SPACING_MM,
) -> Clearance:
    """Minimum clearance along constant-curvature arcs (see :mod:`needlekit.geometry.arcs`).

    Parameters
    ----------
    field : DistanceField
    world_T_tip : array_like, shape (4, 4) or (n, 4, 4)
        Start poses (world, mm).
    spin_rad, kappa_per_mm, length_mm : float or array_like, shape (n,)
        The arcs.
    spacing_mm : float
        Largest gap in arc length between samples.

    Returns
    -------
    Clearance
        Arrays of shape (n,).
    """
    spacing = as_positive(spacing_mm, "spacing_mm")
    lengths = np.atleast_1d(np.asarray(length_mm, dtype=np.float64))
    if not np.all(np.isfinite(lengths)):
        raise InvalidInputError("length_mm", "must be finite")
    m = _n_samples(lengths, spacing)
    samples = sample_arcs(world_T_tip, spin_rad, kappa_per_mm, length_mm, m)
    if samples.ndim == 2:
        samples = samples[None]
    lengths = np.broadcast_to(lengths, (samples.shape[0],))
    return path_clearance(field, samples, lengths)
