"""Ablation coverage: choose needle targets whose ablation zones cover a tumour plus margin.

A large liver tumour is destroyed by several overlapping ablations (Liu et al. 2016,
introduction: "multiple overlapping MC"); the paper takes the number of needles and their
targets as given (refs. 25-27, 29-30) and plans only the trajectories. This module supplies
them, on voxel grids in patient RAS millimetres:

1. :func:`target_region`: the tumour mask grown by a margin (exact Euclidean distance
   transform on the voxel grid, anisotropic spacing respected), cropped with padding.
2. :class:`AblationZone`: a sphere, or a spheroid along the needle, centred at the needle
   target or ``tip_offset_mm`` behind it; inside test and exact signed distance.
3. :func:`choose_targets`: candidate zone centres on a lattice, a greedy set cover of the
   region's voxels, then a local search that moves zones and removes needles.
4. :func:`evaluate_coverage`: coverage, needles, tumour, region and ablated volumes, for
   any targets and needle directions (re-run it once the trajectories are planned).

Voxel accounting. A voxel belongs to a set when its *centre* does: the region is the set of
voxel centres within ``margin_mm`` of a tumour voxel centre, and a voxel is ablated when
its centre lies in some zone. Volumes are voxel counts times the voxel volume.

Guarantee. Greedy set cover uses at most ``H(d) <= 1 + ln d`` times the fewest zones drawn
from the same candidates that reach the same coverage (Johnson 1974, Chvatal 1979; the
same for partial cover), ``d`` being the most region voxels one candidate covers; the
local search never adds a zone. Nothing is claimed against placements off the lattice.
Every region voxel lies within ``sqrt(3)/2`` lattice spacings of a candidate, so a lattice
finer than ``2/sqrt(3)`` times the zone's smaller semi-axis can always reach full coverage.

One concept per module: :mod:`.zone` (the zone), :mod:`.region` (tumour plus margin),
:mod:`.evaluate` (coverage of given targets) and :mod:`.choose` (the set cover); every
public name imports from this package.

References
----------
S. Liu et al., PLoS ONE 11(3): e0149482 (2016). D. S. Johnson, J. Comput. Syst. Sci. 9
(1974); V. Chvatal, Math. Oper. Res. 4 (1979).
"""

from __future__ import annotations

from needlekit.planning.straight.coverage.choose import (
    DEFAULT_CANDIDATE_SPACING_FRACTION,
    DEFAULT_COVERAGE_GOAL,
    DEFAULT_MAX_NEEDLES,
    CoveragePlan,
    CoverageStatus,
    choose_targets,
)
from needlekit.planning.straight.coverage.evaluate import (
    CoverageReport,
    evaluate_coverage,
    fraction_text,
)
from needlekit.planning.straight.coverage.region import (
    DEFAULT_MARGIN_MM,
    TargetRegion,
    target_region,
)
from needlekit.planning.straight.coverage.zone import (
    DEFAULT_TIP_OFFSET_MM,
    DEFAULT_ZONE_DIAMETER_MM,
    DEFAULT_ZONE_LENGTH_MM,
    AblationZone,
)

__all__ = [
    "DEFAULT_CANDIDATE_SPACING_FRACTION",
    "DEFAULT_COVERAGE_GOAL",
    "DEFAULT_MARGIN_MM",
    "DEFAULT_MAX_NEEDLES",
    "DEFAULT_TIP_OFFSET_MM",
    "DEFAULT_ZONE_DIAMETER_MM",
    "DEFAULT_ZONE_LENGTH_MM",
    "AblationZone",
    "CoveragePlan",
    "CoverageReport",
    "CoverageStatus",
    "TargetRegion",
    "choose_targets",
    "evaluate_coverage",
    "fraction_text",
    "target_region",
]
