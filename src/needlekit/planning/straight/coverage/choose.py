"""Choosing needle targets whose zones cover a region: :func:`choose_targets`.

Candidate zone centres on a lattice, a greedy set cover of the region's voxels, then a
local search that moves zones and removes needles (the guarantee is in
:mod:`needlekit.planning.straight.coverage`).
"""

from __future__ import annotations

import enum
import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy import sparse

from needlekit._validation import as_positive
from needlekit.errors import InvalidInputError
from needlekit.planning.straight.coverage.evaluate import CoverageReport, _cover_matrix, _evaluate
from needlekit.planning.straight.coverage.region import TargetRegion
from needlekit.planning.straight.coverage.zone import AblationZone, _directions
from needlekit.records import field_of

__all__ = [
    "CoveragePlan",
    "CoverageStatus",
    "DEFAULT_CANDIDATE_SPACING_FRACTION",
    "DEFAULT_COVERAGE_GOAL",
    "DEFAULT_MAX_NEEDLES",
    "choose_targets",
]


#: Fraction of the region's voxels the zones must cover: all of them, because the margin is
#: already the safety buffer; a lower goal could leave tumour voxels untreated.
DEFAULT_COVERAGE_GOAL: float = 1.0

#: Most zones :func:`choose_targets` places before giving up on the goal: a cap on the
#: work, not a clinical limit (the search already uses as few zones as it finds). The
#: largest Med-RAD liver nodule with its margin takes ~57 zones of 30 x 20 mm at full
#: coverage; a plan needing more than a handful says the zone is too small for the tumour.
DEFAULT_MAX_NEEDLES: int = 100

#: Candidate lattice spacing as a fraction of the zone's smaller semi-axis. Below
#: ``2/sqrt(3) = 1.15`` every voxel has a candidate that covers it; 0.5 leaves room to
#: place zones snugly while a 100 mL region gets ~10^3 candidates for a 20 mm diameter.
DEFAULT_CANDIDATE_SPACING_FRACTION: float = 0.5

#: Rounds of the move-one-zone local search (each tries every zone once); it stops earlier
#: as soon as a round improves nothing, which is what happens in practice after 1-3 rounds.
MAX_REFINE_ROUNDS: int = 10


class CoverageStatus(enum.Enum):
    """Whether a plan reached its coverage goal."""

    COVERED = "covered"
    #: ``max_needles`` zones were placed before the goal was reached.
    PARTIAL = "partial"


@dataclass(frozen=True, eq=False)
class CoveragePlan:
    """Needle targets chosen to cover a region, with the evidence.

    Attributes
    ----------
    status : CoverageStatus
    targets_mm : ndarray, shape (k, 3)
        Needle targets (tips), RAS mm, in the order they were chosen.
    centres_mm : ndarray, shape (k, 3)
        Zone centres (``tip_offset_mm`` behind the targets).
    directions : ndarray, shape (k, 3)
        Unit insertion directions assumed (+z when the zone does not depend on them).
    zone : AblationZone
    report : CoverageReport
        :func:`evaluate_coverage` of these targets.
    coverage_goal : float
    candidates : int
        Candidate zone centres the cover was drawn from.
    candidate_spacing_mm : float
    greedy_needles : int
        Needles of the plain greedy cover, before the local search.
    needles_lower_bound : int
        No cover from these candidates reaching the goal has fewer zones: the goal's voxel
        count over the most voxels one candidate covers.
    """

    status: CoverageStatus
    targets_mm: np.ndarray
    centres_mm: np.ndarray
    directions: np.ndarray
    zone: AblationZone
    report: CoverageReport
    coverage_goal: float
    candidates: int
    candidate_spacing_mm: float
    greedy_needles: int
    needles_lower_bound: int

    @property
    def needles(self) -> int:
        """Number of needles (zones)."""
        return len(self.targets_mm)

    def to_dict(self) -> dict:
        """JSON-ready fields (arrays as nested lists).

        Returns
        -------
        dict
        """
        z = self.zone
        return {
            "status": self.status.value,
            "targets_mm": self.targets_mm.tolist(),
            "centres_mm": self.centres_mm.tolist(),
            "directions": self.directions.tolist(),
            "zone": z.to_dict(),
            "report": self.report.to_dict(),
            "coverage_goal": self.coverage_goal,
            "candidates": self.candidates,
            "candidate_spacing_mm": self.candidate_spacing_mm,
            "greedy_needles": self.greedy_needles,
            "needles_lower_bound": self.needles_lower_bound,
        }

    @classmethod
    def from_dict(cls, data: dict, where: str, zone: AblationZone) -> CoveragePlan:
        """A plan from its record, as :meth:`to_dict` writes it.

        Parameters
        ----------
        data : dict
        where : str
            Names the record in messages.
        zone : AblationZone
            The zone (the record's ``zone``, read by the caller: an
            :class:`~needlekit.planning.straight.ablation.AblationOutcome` keeps it once).

        Returns
        -------
        CoveragePlan

        Raises
        ------
        InvalidInputError
            A field not as :meth:`to_dict` writes it (named).
        """
        try:
            status = CoverageStatus(field_of(data, "status", where, "str"))
        except ValueError:
            raise InvalidInputError(f"{where}: status", "expected covered or partial") from None
        arrays = []
        for key in ("targets_mm", "centres_mm", "directions"):
            a = np.asarray(field_of(data, key, where, "list"), dtype=float).reshape(-1, 3)
            if not np.all(np.isfinite(a)):
                raise InvalidInputError(f"{where}: {key}", "expected finite points (k, 3)")
            arrays.append(a)
        return cls(
            status,
            *arrays,
            zone,
            CoverageReport.from_dict(field_of(data, "report", where, "dict"), f"{where}: report"),
            float(field_of(data, "coverage_goal", where)),
            field_of(data, "candidates", where, "int"),
            float(field_of(data, "candidate_spacing_mm", where)),
            field_of(data, "greedy_needles", where, "int"),
            field_of(data, "needles_lower_bound", where, "int"),
        )


# -- choosing the targets ----------------------------------------------------------------------


class _Cover:
    """A set of chosen candidates, how many of them cover each voxel, and each candidate's
    gain (the uncovered voxels it covers), kept up to date as zones come and go: a change
    touches the candidates of the voxels it covers or uncovers, not the whole matrix (a
    product per step took 4.5 of 5.5 s on a Med-RAD liver nodule)."""

    def __init__(self, A: sparse.csr_matrix):
        self.A = A
        self.chosen: list[int] = []
        self.count = np.zeros(A.shape[1], dtype=np.int64)
        self._by_voxel: sparse.csr_matrix | None = None  # A transposed: voxel -> candidates
        self._gain: np.ndarray | None = None  # A @ (count == 0), once asked for

    def row(self, c: int) -> np.ndarray:
        return self.A.indices[self.A.indptr[c] : self.A.indptr[c + 1]]

    def _candidates_of(self, voxels: np.ndarray) -> np.ndarray:
        """How many of ``voxels`` each candidate covers, shape (candidates,)."""
        if self._by_voxel is None:
            self._by_voxel = self.A.T.tocsr()
        At = self._by_voxel
        starts, ends = At.indptr[voxels], At.indptr[voxels + 1]
        lengths = ends - starts
        first = np.repeat(starts - np.cumsum(lengths) + lengths, lengths)
        idx = At.indices[first + np.arange(int(lengths.sum()))]
        return np.bincount(idx, minlength=self.A.shape[0])

    def add(self, c: int) -> None:
        self.chosen.append(c)
        r = self.row(c)
        if self._gain is not None:
            self._gain -= self._candidates_of(r[self.count[r] == 0])
        self.count[r] += 1

    def remove(self, c: int) -> None:
        self.chosen.remove(c)
        r = self.row(c)
        self.count[r] -= 1
        if self._gain is not None:
            self._gain += self._candidates_of(r[self.count[r] == 0])

    @property
    def covered(self) -> int:
        return int(np.count_nonzero(self.count))

    def gains(self) -> np.ndarray:
        """Each candidate's count of uncovered voxels it covers (a copy)."""
        if self._gain is None:
            uncovered = (self.count == 0).astype(np.float32)
            self._gain = np.rint(self.A @ uncovered).astype(np.int64)
        return self._gain.astype(np.float32)

    def unique(self, c: int) -> int:
        return int(np.count_nonzero(self.count[self.row(c)] == 1))


def _greedy(cov: _Cover, goal: int, max_needles: int) -> None:
    while cov.covered < goal and len(cov.chosen) < max_needles:
        g = cov.gains()
        if not g.size:  # no candidate (all refused by ``allowed``)
            break
        best = int(np.argmax(g))  # ties: the first candidate in lattice order
        if g[best] <= 0:
            break
        cov.add(best)


def _hardest_first(cov: _Cover, goal: int, max_needles: int) -> None:
    """Each step covers the uncovered voxel with the fewest candidates, by the candidate
    covering it that covers most uncovered voxels: no straggler is left for the end."""
    At = cov.A.tocsc()
    degree = np.diff(At.indptr)
    while cov.covered < goal and len(cov.chosen) < max_needles:
        open_ = np.flatnonzero((cov.count == 0) & (degree > 0))
        if not len(open_):
            break
        v = open_[np.argmin(degree[open_])]
        options = At.indices[At.indptr[v] : At.indptr[v + 1]]
        g = cov.A[options] @ (cov.count == 0).astype(np.float32)
        cov.add(int(options[np.argmax(g)]))


def _move_zones(cov: _Cover) -> None:
    """Replace single zones by the candidate covering most voxels the others leave."""
    for _ in range(MAX_REFINE_ROUNDS):
        improved = False
        for c in list(cov.chosen):
            cov.remove(c)
            g = cov.gains()
            best = int(np.argmax(g))
            cov.add(best if g[best] > g[c] else c)
            improved |= g[best] > g[c]
        if not improved:
            return


def _drop_redundant(cov: _Cover, goal: int) -> None:
    while len(cov.chosen) > 1:
        c = min(cov.chosen, key=cov.unique)
        if cov.covered - cov.unique(c) < goal:
            return
        cov.remove(c)


def _fewer_zones(cov: _Cover, goal: int) -> None:
    """Remove the least useful zone and move the others while the goal still holds."""
    while len(cov.chosen) > 1:
        before = list(cov.chosen)
        cov.remove(min(cov.chosen, key=cov.unique))
        _move_zones(cov)
        if cov.covered >= goal:
            continue
        for c in list(cov.chosen):
            cov.remove(c)
        for c in before:
            cov.add(c)
        return


def _candidates(region: TargetRegion, spacing: float) -> np.ndarray:
    """Lattice points (spacing along world x, y, z) nearest some region voxel, shape (m, 3)."""
    pts = region.points_mm
    origin = pts[0]
    q = np.unique(np.rint((pts - origin) / spacing).astype(np.int64), axis=0)
    return origin + q * spacing


def choose_targets(
    region: TargetRegion,
    zone: AblationZone | None = None,
    *,
    direction: np.ndarray | Callable[[np.ndarray], np.ndarray] | None = None,
    max_needles: int = DEFAULT_MAX_NEEDLES,
    coverage_goal: float = DEFAULT_COVERAGE_GOAL,
    candidate_spacing_mm: float | None = None,
    refine: bool = True,
    allowed: Callable[[np.ndarray], np.ndarray] | None = None,
) -> CoveragePlan:
    """Needle targets whose zones cover the region with few needles.

    1. Candidates: zone centres on a lattice along world x, y, z, one per lattice cell
       holding a region voxel (every region voxel is within ``sqrt(3)/2`` spacings of one).
    2. Greedy set cover: each step adds the candidate covering the most still uncovered
       region voxels (a sparse matrix-vector product), until ``coverage_goal`` of the
       voxels are covered or ``max_needles`` zones are placed. A second cover starts each
       step from the uncovered voxel with the fewest candidates instead (it leaves no
       stragglers at the boundary for the end); the better of the two is kept, so the
       greedy bound of the module docstring holds.
    3. Local search (``refine``): move each zone to the candidate covering most of what the
       others leave, drop zones the goal does not need, and remove the least useful zone
       and move the rest for as long as the goal still holds.

    Parameters
    ----------
    region : TargetRegion
        From :func:`target_region`.
    zone : AblationZone, optional
        Default ``AblationZone()`` (:data:`DEFAULT_ZONE_LENGTH_MM` x
        :data:`DEFAULT_ZONE_DIAMETER_MM` ellipsoid).
    direction : array_like, shape (3,), or callable, optional
        Insertion direction (entry to tip) of every needle, e.g. the z axis of a start
        pose; or a function from zone centres ``(m, 3)`` to directions ``(m, 3)`` (e.g.
        ``lambda c: c - entry_mm`` for needles through one entry point). Needed unless
        the zone is a sphere at the tip. The planner's real directions differ: re-check
        with :func:`evaluate_coverage`.
    max_needles : int
        Most zones placed (default :data:`DEFAULT_MAX_NEEDLES`).
    coverage_goal : float
        Fraction of region voxels to cover, in (0, 1] (default 1).
    candidate_spacing_mm : float, optional
        Lattice spacing (mm); default :data:`DEFAULT_CANDIDATE_SPACING_FRACTION` times the
        zone's smaller semi-axis.
    refine : bool
        Run the local search after the greedy cover.
    allowed : callable, optional
        ``allowed(targets_mm (m, 3), directions (m, 3)) -> bool (m,)``: which candidate
        needle targets may be used (e.g. inside the organ and clear of vessels); the others
        are dropped before the cover, so full coverage may no longer be reachable.

    Returns
    -------
    CoveragePlan
        ``status`` COVERED when the goal was reached, else PARTIAL.

    Examples
    --------
    >>> from needlekit.planning.straight.coverage import target_region
    >>> m = np.zeros((21, 21, 21), bool); m[8:13, 8:13, 8:13] = True
    >>> r = target_region(m, np.eye(4), margin_mm=2.0)
    >>> plan = choose_targets(r, AblationZone.sphere(8.0))
    >>> plan.needles, plan.report.coverage
    (1, 1.0)
    """
    if not isinstance(region, TargetRegion):
        raise InvalidInputError("region", f"expected a TargetRegion, got {type(region).__name__}")
    zone = AblationZone() if zone is None else zone
    if not isinstance(zone, AblationZone):
        raise InvalidInputError("zone", f"expected an AblationZone, got {type(zone).__name__}")
    if isinstance(max_needles, bool) or not isinstance(max_needles, (int, np.integer)):
        raise InvalidInputError("max_needles", f"expected an integer, got {max_needles!r}")
    if max_needles < 1:
        raise InvalidInputError("max_needles", f"must be >= 1, got {max_needles}")
    goal_frac = as_positive(coverage_goal, "coverage_goal")
    if goal_frac > 1.0:
        raise InvalidInputError("coverage_goal", f"must be in (0, 1], got {goal_frac}")
    if candidate_spacing_mm is None:
        spacing = DEFAULT_CANDIDATE_SPACING_FRACTION * min(zone.semi_axes_mm)
    else:
        spacing = as_positive(candidate_spacing_mm, "candidate_spacing_mm")

    centres = _candidates(region, spacing)
    if callable(direction):
        w = _directions(direction(centres.copy()), len(centres), zone.needs_direction, "direction")
    else:
        w = _directions(direction, len(centres), zone.needs_direction, "direction")
    if allowed is not None:
        keep = np.asarray(allowed(centres + zone.tip_offset_mm * w, w.copy()), dtype=bool)
        if keep.shape != (len(centres),):
            raise InvalidInputError(
                "allowed", f"expected {len(centres)} booleans, got {keep.shape}"
            )
        centres, w = centres[keep], w[keep]
    A = _cover_matrix(region, zone, centres, w)
    n = A.shape[1]
    goal = min(n, math.ceil(goal_frac * n - 1e-9 * n))
    best, greedy_needles = None, 0
    for start in (_greedy, _hardest_first):
        cov = _Cover(A)
        start(cov, goal, int(max_needles))
        if start is _greedy:
            greedy_needles = len(cov.chosen)
        if refine and cov.chosen:
            _move_zones(cov)
            _drop_redundant(cov, goal)
            if cov.covered >= goal:
                _fewer_zones(cov, goal)
        key = (cov.covered < goal, len(cov.chosen), -cov.covered)
        if best is None or key < best[0]:
            best = (key, cov)
    cov = best[1]
    chosen = np.array(cov.chosen, dtype=np.int64)
    biggest = int(np.diff(A.indptr).max()) if len(centres) else 0
    targets = centres[chosen] + zone.tip_offset_mm * w[chosen]
    report = _evaluate(region, zone, centres[chosen].reshape(-1, 3), w[chosen].reshape(-1, 3))
    return CoveragePlan(
        status=CoverageStatus.COVERED if cov.covered >= goal else CoverageStatus.PARTIAL,
        targets_mm=targets.reshape(-1, 3),
        centres_mm=centres[chosen].reshape(-1, 3),
        directions=w[chosen].reshape(-1, 3),
        zone=zone,
        report=report,
        coverage_goal=goal_frac,
        candidates=len(centres),
        candidate_spacing_mm=spacing,
        greedy_needles=greedy_needles,
        needles_lower_bound=math.ceil(goal / biggest) if biggest else 0,
    )
