"""How well given needle targets and directions cover a region: :func:`evaluate_coverage`.

A voxel is ablated when its centre lies in some zone; volumes are voxel counts times the
voxel volume (:class:`CoverageReport`). The sparse voxel-by-zone matrix built here is also
what :mod:`.choose` searches.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import sparse

from needlekit._validation import as_points
from needlekit.errors import InvalidInputError
from needlekit.planning.straight.coverage.region import TargetRegion, _world
from needlekit.planning.straight.coverage.zone import AblationZone, _directions
from needlekit.records import field_of

__all__ = ["CoverageReport", "evaluate_coverage", "fraction_text"]


# -- which zone covers which voxel -------------------------------------------------------------


def _zone_boxes(zone: AblationZone, centres: np.ndarray, w: np.ndarray, affine: np.ndarray):
    """Voxel-index boxes (lo, hi inclusive), shape (m, 3) each, holding each zone."""
    a, b = zone.semi_axes_mm
    half = np.sqrt(a * a * w * w + b * b * (1.0 - w * w))  # world AABB half extents, (m, 3)
    corners = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)])
    world = centres[:, None, :] + corners[None] * half[:, None, :]  # (m, 8, 3)
    inv = np.linalg.inv(affine)
    ijk = world @ inv[:3, :3].T + inv[:3, 3]
    return np.floor(ijk.min(axis=1)).astype(np.int64), np.ceil(ijk.max(axis=1)).astype(np.int64)


def _inside(points: np.ndarray, centre: np.ndarray, w: np.ndarray, a: float, b: float):
    d = points - centre
    axial = d @ w
    radial2 = np.maximum(np.einsum("nk,nk->n", d, d) - axial * axial, 0.0)
    return axial * axial / (a * a) + radial2 / (b * b) <= 1.0


def _cover_matrix(region: TargetRegion, zone: AblationZone, centres, w) -> sparse.csr_matrix:
    """Candidates x region voxels, 1 where the voxel centre is in the candidate's zone."""
    label = np.full(region.mask.shape, -1, dtype=np.int64)
    label[region.mask] = np.arange(int(region.mask.sum()))
    pts = region.points_mm
    lo, hi = _zone_boxes(zone, centres, w, region.affine)
    lo = np.maximum(lo, 0)
    hi = np.minimum(hi + 1, region.mask.shape)
    a, b = zone.semi_axes_mm
    rows, cols = [], []
    for c in range(len(centres)):
        if np.any(hi[c] <= lo[c]):
            continue
        sub = label[lo[c, 0] : hi[c, 0], lo[c, 1] : hi[c, 1], lo[c, 2] : hi[c, 2]]
        ids = sub[sub >= 0]
        ids = ids[_inside(pts[ids], centres[c], w[c], a, b)]
        rows.append(np.full(len(ids), c, dtype=np.int64))
        cols.append(ids)
    rows_a = np.concatenate(rows) if rows else np.zeros(0, np.int64)
    cols_a = np.concatenate(cols) if cols else np.zeros(0, np.int64)
    data = np.ones(len(rows_a), dtype=np.float32)  # counts stay exact below 2^24
    return sparse.csr_matrix((data, (rows_a, cols_a)), shape=(len(centres), len(pts)))


# -- reports -----------------------------------------------------------------------------------


@dataclass(frozen=True)
class CoverageReport:
    """How well a set of ablation zones covers a target region (voxel counts, mL).

    Attributes
    ----------
    coverage : float
        Fraction of region (tumour plus margin) voxels inside some zone.
    tumour_coverage : float
        Fraction of tumour voxels inside some zone.
    needles : int
    region_volume_ml, tumour_volume_ml : float
    ablated_ml : float
        Voxels inside some zone, on the region's grid extended to hold every zone.
    healthy_ablated_ml : float
        Of those, outside the tumour (the margin counts as healthy tissue ablated).
    ablated_outside_region_ml : float
        Of those, outside the tumour plus margin: ablation beyond what was asked for.
    uncovered_ml : float
        Region voxels in no zone.
    voxel_volume_mm3 : float
        The accounting unit; volumes are uncertain by about the voxels along the surfaces.
    """

    coverage: float
    tumour_coverage: float
    needles: int
    region_volume_ml: float
    tumour_volume_ml: float
    ablated_ml: float
    healthy_ablated_ml: float
    ablated_outside_region_ml: float
    uncovered_ml: float
    voxel_volume_mm3: float

    def to_dict(self) -> dict:
        """JSON-ready fields.

        Returns
        -------
        dict
        """
        return {k: (int(v) if k == "needles" else float(v)) for k, v in vars(self).items()}

    @classmethod
    def from_dict(cls, data: dict, where: str) -> CoverageReport:
        """A report from its record, as :meth:`to_dict` writes it.

        Parameters
        ----------
        data : dict
        where : str
            Names the record in messages.

        Returns
        -------
        CoverageReport

        Raises
        ------
        InvalidInputError
            A field missing or not a number (named).
        """
        return cls(
            **{
                k: field_of(data, k, where, "int" if k == "needles" else "number")
                for k in cls.__dataclass_fields__
            }
        )


def evaluate_coverage(region: TargetRegion, zone: AblationZone, targets_mm,
                      directions=None) -> CoverageReport:  # fmt: skip
    """Coverage and ablated volumes of needles at ``targets_mm`` (tips) along ``directions``.

    Call it again with the planned trajectories' tips and directions: targets chosen for
    one approach direction are only as good as the real directions the planner finds.

    Parameters
    ----------
    region : TargetRegion
    zone : AblationZone
    targets_mm : array_like, shape (3,) or (m, 3)
        Needle targets (tips), RAS mm; ``m = 0`` (shape (0, 3)) means no needle.
    directions : array_like, shape (3,) or (m, 3), optional
        Insertion directions (entry to tip). Needed unless the zone is a sphere at the tip.

    Returns
    -------
    CoverageReport
        Voxels count by their centres, on the region's grid extended over every zone.
    """
    if not isinstance(region, TargetRegion):
        raise InvalidInputError("region", f"expected a TargetRegion, got {type(region).__name__}")
    if not isinstance(zone, AblationZone):
        raise InvalidInputError("zone", f"expected an AblationZone, got {type(zone).__name__}")
    if np.size(targets_mm) == 0:
        t = np.zeros((0, 3))
    else:
        t, _ = as_points(targets_mm, "targets_mm")
    w = _directions(directions, len(t), zone.needs_direction)
    return _evaluate(region, zone, t - zone.tip_offset_mm * w, w)


def _evaluate(region: TargetRegion, zone: AblationZone, centres: np.ndarray,
              w: np.ndarray) -> CoverageReport:  # fmt: skip
    g_lo, g_hi = np.zeros(3, np.int64), np.array(region.mask.shape)
    if len(centres):
        lo, hi = _zone_boxes(zone, centres, w, region.affine)
        g_lo = np.minimum(lo.min(axis=0), g_lo)
        g_hi = np.maximum(hi.max(axis=0) + 1, g_hi)
    ablated = np.zeros(tuple(g_hi - g_lo), dtype=bool)
    a, b = zone.semi_axes_mm
    for c in range(len(centres)):
        box = np.indices(tuple(hi[c] - lo[c] + 1)).reshape(3, -1).T + lo[c]
        inside = _inside(_world(region.affine, box), centres[c], w[c], a, b)
        sel = box[inside] - g_lo
        ablated[sel[:, 0], sel[:, 1], sel[:, 2]] = True
    at = tuple(slice(-l, -l + s) for l, s in zip(g_lo, region.mask.shape, strict=True))
    reg = np.zeros_like(ablated)
    reg[at] = region.mask
    tum = np.zeros_like(ablated)
    tum[at] = region.tumour
    unit = region.voxel_volume_mm3 / 1000.0
    n_reg, n_tum = int(region.mask.sum()), int(region.tumour.sum())
    return CoverageReport(
        coverage=int((ablated & reg).sum()) / n_reg,
        tumour_coverage=int((ablated & tum).sum()) / n_tum,
        needles=len(centres),
        region_volume_ml=n_reg * unit,
        tumour_volume_ml=n_tum * unit,
        ablated_ml=int(ablated.sum()) * unit,
        healthy_ablated_ml=int((ablated & ~tum).sum()) * unit,
        ablated_outside_region_ml=int((ablated & ~reg).sum()) * unit,
        uncovered_ml=int((reg & ~ablated).sum()) * unit,
        voxel_volume_mm3=region.voxel_volume_mm3,
    )


def fraction_text(value: float, digits: int = 4) -> str:
    """A coverage fraction rounded down, so that short of 1 never reads as 1.

    Parameters
    ----------
    value : float
        In [0, 1].
    digits : int

    Returns
    -------
    str

    Examples
    --------
    >>> fraction_text(0.99997), fraction_text(1.0), fraction_text(0.43166)
    ('0.9999', '1.0000', '0.4316')
    """
    scale = 10**digits
    return f"{math.floor(value * scale + 1e-9) / scale:.{digits}f}"
