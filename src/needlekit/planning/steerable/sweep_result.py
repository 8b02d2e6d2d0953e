"""A start-direction sweep's data: the candidate directions, the effective puncture region,
and the sweep's record (:class:`SweepResult`, its statistics, ``sweep.json`` written and
read back).

Feng et al. (2023) sample candidate directions on a small sphere around the start point
(544 of them) and keep those whose angle to the punctured surface is at least the minimum
physiological puncture angle alpha: in polar coordinates about the surface normal,
``theta in [0, pi/2 - alpha]``, ``phi in [0, 2 pi)`` (their Eq. 1-3; the printed y
components read ``sin(theta) cos(phi)`` where ``sin(theta) sin(phi)`` is meant). A planner
then runs from every effective direction, and the lowest-cost plan gives the best
direction (their Algorithm 1 and Tables 2-4).

Here the directions are a Fibonacci lattice on the unit sphere (near-uniform for any
count) or the equal-area HEALPix pixel centres, the surface normal is the entry surface's
outward normal at the start (the distance gradient; for a transbronchial start, out of the
airway into the tissue), and the needle's angle to the surface is
``90 deg - angle(direction, normal)``. Running a sweep is
:func:`needlekit.planning.steerable.sweep.sweep` (one) and
:func:`needlekit.planning.steerable.sweep_batch.sweep_many` (several as one batch).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from needlekit.errors import InvalidInputError
from needlekit.planning.result import PlanStatus
from needlekit.planning.steerable.result import PlanResult
from needlekit.records import Status, enum_of, field_of, number_or_inf

__all__ = [
    "DEFAULT_DIRECTIONS",
    "SweepResult",
    "effective_directions",
    "healpix_directions",
    "solved_costs",
    "solved_plans_from_dict",
    "solved_plans_to_dict",
    "sphere_directions",
    "sweep_stats",
    "sweeps_from_dict",
    "sweeps_to_dict",
]

#: Candidate start directions, as in Feng et al. (2023).
DEFAULT_DIRECTIONS: int = 544


def sphere_directions(n: int = DEFAULT_DIRECTIONS) -> np.ndarray:
    """Near-uniform unit vectors on the sphere (Fibonacci lattice).

    Parameters
    ----------
    n : int
        Number of directions (>= 1).

    Returns
    -------
    ndarray, shape (n, 3)

    Examples
    --------
    >>> d = sphere_directions(544)
    >>> d.shape, bool(np.allclose(np.linalg.norm(d, axis=1), 1.0))
    ((544, 3), True)
    """
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1:
        raise InvalidInputError("n", f"expected a whole number >= 1, got {n!r}")
    i = np.arange(n) + 0.5
    z = 1.0 - 2.0 * i / n
    phi = np.pi * (3.0 - np.sqrt(5.0)) * i
    rho = np.sqrt(1.0 - z * z)
    return np.column_stack([rho * np.cos(phi), rho * np.sin(phi), z])


def healpix_directions(nside: int) -> np.ndarray:
    """Centres of the ``12 nside^2`` equal-area HEALPix pixels (ring scheme) as unit vectors.

    Every direction stands for the same solid angle, so averages over the directions are
    area-weighted without weights (e.g. ``nside = 7`` gives 588 directions, close to
    Feng's 544).

    Parameters
    ----------
    nside : int
        Resolution (>= 1).

    Returns
    -------
    ndarray, shape (12 nside^2, 3)

    Examples
    --------
    >>> healpix_directions(2).shape
    (48, 3)
    """
    if isinstance(nside, bool) or not isinstance(nside, (int, np.integer)) or nside < 1:
        raise InvalidInputError("nside", f"expected a whole number >= 1, got {nside!r}")
    n = int(nside)
    zs, phis = [], []
    for i in range(1, 4 * n):
        if i < n or i > 3 * n:  # polar caps: 4 k pixels on the k-th ring from the pole
            k = i if i < n else 4 * n - i
            z = 1.0 - k * k / (3.0 * n * n)
            z = z if i < n else -z
            phi = np.pi / (2 * k) * (np.arange(1, 4 * k + 1) - 0.5)
        else:  # equatorial belt: 4 n pixels per ring, every other ring shifted by half a pixel
            z = 4.0 / 3.0 - 2.0 * i / (3.0 * n)
            shift = (i - n + 1) % 2
            phi = np.pi / (2 * n) * (np.arange(1, 4 * n + 1) - 0.5 * shift)
        zs.append(np.full(phi.shape, z))
        phis.append(phi)
    z = np.concatenate(zs)
    phi = np.concatenate(phis)
    rho = np.sqrt(np.maximum(1.0 - z * z, 0.0))
    return np.column_stack([rho * np.cos(phi), rho * np.sin(phi), z])


def effective_directions(directions, normal, min_puncture_angle_deg: float) -> np.ndarray:
    """Which directions make at least alpha with the surface (Feng's effective region).

    Parameters
    ----------
    directions : array_like, shape (n, 3)
        Unit vectors.
    normal : array_like, shape (3,)
        Unit normal of the punctured surface, pointing into the tissue entered.
    min_puncture_angle_deg : float
        alpha, in [0, 90).

    Returns
    -------
    ndarray of bool, shape (n,)
        ``90 deg - angle(direction, normal) >= alpha``, i.e. ``theta <= 90 deg - alpha``.
    """
    d = np.asarray(directions, dtype=float).reshape(-1, 3)
    n = np.asarray(normal, dtype=float).reshape(3)
    n = n / np.linalg.norm(n)
    alpha = float(min_puncture_angle_deg)
    if not (0.0 <= alpha < 90.0):
        raise InvalidInputError("min_puncture_angle_deg", f"must lie in [0, 90), got {alpha}")
    angle_to_surface = np.degrees(np.arcsin(np.clip(d @ n, -1.0, 1.0)))
    return angle_to_surface >= alpha - 1e-12


@dataclass(frozen=True)
class SweepResult:
    """Plans over the effective start directions (Feng's Tables 2-4 for one case).

    Attributes
    ----------
    directions : ndarray, shape (n, 3)
        All candidate directions.
    effective : ndarray of bool, shape (n,)
        Inside the effective puncture region.
    results : list of PlanResult or None
        Per candidate direction (None outside the effective region).
    planner : str
    stats : dict
        ``n_directions``, ``n_effective``, ``n_solved``, ``best_index``,
        ``best_cost_mm``, ``mean_cost_mm`` (over solved directions), ``cost_before_lowest_mm``
        (Feng's planning-rapidity figure of Table 4: the sum of the solved directions'
        costs in sweep order up to and including the lowest) and ``time_s``.
    """

    directions: np.ndarray
    effective: np.ndarray
    results: list
    planner: str
    stats: dict = field(default_factory=dict)

    @property
    def costs_mm(self) -> np.ndarray:
        """Cost per candidate direction, ``inf`` where there is no solved plan."""
        return solved_costs(self.results)

    @property
    def best(self) -> PlanResult | None:
        """The lowest-cost result, or None."""
        i = self.stats.get("best_index")
        return None if i is None else self.results[i]

    def to_dict(self) -> dict:
        """JSON-ready table: one row per candidate direction, and the summary.

        Returns
        -------
        dict
        """
        rows = []
        for i, (d, eff) in enumerate(zip(self.directions, self.effective, strict=True)):
            r = self.results[i]
            rows.append(
                {
                    "index": i,
                    "direction": [float(v) for v in d],
                    "effective": bool(eff),
                    "status": None if r is None else r.status.value,
                    "cost_mm": None
                    if r is None or not np.isfinite(r.cost_mm)
                    else float(r.cost_mm),
                    "time_s": None if r is None else float(r.time_s),
                }
            )
        return {"planner": self.planner, "summary": dict(self.stats), "directions": rows}

    @classmethod
    def from_dict(cls, data: dict, where: str, goal_mm=None) -> SweepResult:
        """A sweep from its record, as :meth:`to_dict` writes it (one planner's table).

        Every effective direction gets a result with its status, cost and time; the record
        keeps no path, so none carries a plan.

        Parameters
        ----------
        data : dict
            ``planner``, ``summary`` and ``directions`` (rows of ``index``,
            ``direction``, ``effective``, ``status``, ``cost_mm``, ``time_s``).
        where : str
            Names the record in messages.
        goal_mm : array_like, shape (3,), optional
            The goal of the results (default NaN: the table does not keep it).

        Returns
        -------
        SweepResult

        Raises
        ------
        InvalidInputError
            A field not as :meth:`to_dict` writes it (named).
        """
        planner = field_of(data, "planner", where, "str")
        stats = field_of(data, "summary", where, "dict")
        rows = field_of(data, "directions", where, "list")
        goal = np.full(3, np.nan) if goal_mm is None else np.asarray(goal_mm, dtype=float)
        dirs, eff = _direction_rows(rows, where)
        results: list = [None] * len(rows)
        for i in np.flatnonzero(eff):
            at = f"{where}: directions[{i}]"
            row = rows[i]
            status = enum_of(Status, field_of(row, "status", at, "str"), f"{at}: status")
            cost = number_or_inf(row, "cost_mm", at)
            t = field_of(row, "time_s", at, optional=True)
            results[i] = PlanResult(status, planner, None, cost, float(t or 0.0), goal)
        return cls(dirs, eff, results, planner, dict(stats))


def solved_costs(results) -> np.ndarray:
    """Cost of each result that has a solved plan, ``inf`` elsewhere.

    Parameters
    ----------
    results : sequence of PlanResult or None

    Returns
    -------
    ndarray, shape (len(results),)
    """
    return np.array(
        [r.cost_mm if r is not None and r.status is PlanStatus.SOLVED else np.inf for r in results],
        dtype=float,
    )


def sweep_stats(directions, effective, results, time_s: float = 0.0) -> dict:
    """The summary of a sweep (Feng's Table 4 and the best direction).

    Parameters
    ----------
    directions : ndarray, shape (n, 3)
    effective : ndarray of bool, shape (n,)
    results : sequence of PlanResult or None
        Per direction, in sweep order; only ``SOLVED`` results count.
    time_s : float
        Wall-clock time of the sweep.

    Returns
    -------
    dict
        See :class:`SweepResult`.

    Examples
    --------
    Feng's Table 2, RCS*: the lowest cost is the 6th solved direction, and the costs up to
    it sum to Table 4's 365.1960 ("before lowest").

    >>> from needlekit.planning.steerable.result import PlanResult
    >>> costs = [63.1118, 61.3853, 60.6194, 60.0265, 60.1770, 59.8760, 60.6104, 60.2192,
    ...          63.0487, 62.3829]
    >>> res = [PlanResult(PlanStatus.SOLVED, "rcs_star", None, c, 0.0, np.zeros(3)) for c in costs]
    >>> st = sweep_stats(np.eye(3)[[0] * 10], np.ones(10, bool), res)
    >>> round(st["cost_before_lowest_mm"], 4), round(st["mean_cost_mm"], 4), st["best_index"]
    (365.196, 61.1457, 5)
    """
    dirs = np.asarray(directions, dtype=float).reshape(-1, 3)
    eff = np.asarray(effective, dtype=bool)
    costs = solved_costs(results)
    solved = np.isfinite(costs)
    best = int(np.argmin(costs)) if solved.any() else None
    # Feng's Table 4 "before lowest": the sum of the solved directions' costs, in sweep
    # order, up to and including the lowest
    before = costs[: 0 if best is None else best + 1]
    return {
        "n_directions": len(dirs),
        "n_effective": int(eff.sum()),
        "n_solved": int(solved.sum()),
        "best_index": best,
        "best_cost_mm": None if best is None else float(costs[best]),
        "best_direction": None if best is None else [float(v) for v in dirs[best]],
        "mean_cost_mm": float(costs[solved].mean()) if solved.any() else None,
        "cost_before_lowest_mm": None if best is None else float(before[np.isfinite(before)].sum()),
        "time_s": float(time_s),
    }


def sweeps_to_dict(sweeps, *, spacing_mm: float = 0.5) -> dict:
    """Feng's Tables 2-4 for one case as a JSON-ready record (the ``sweep.json`` format).

    Parameters
    ----------
    sweeps : mapping of str to SweepResult
        One sweep per planner, all over the same candidate directions.
    spacing_mm : float
        Spacing of the best plans' ``points_mm``.

    Returns
    -------
    dict
        ``planners``; ``summary`` (per planner: the :class:`SweepResult` stats, Feng's
        Table 4); ``directions`` (one row per candidate: ``index``, ``direction``,
        ``effective``, and per planner ``status``, ``cost_mm`` and ``time_s``, Feng's
        Tables 2-3); ``best_plans`` (per planner, the lowest-cost plan in the
        ``plan.json`` format, or None).

    Raises
    ------
    InvalidInputError
        No sweeps, or sweeps over different directions.
    """
    if not sweeps:
        raise InvalidInputError("sweeps", "expected at least one sweep")
    names = list(sweeps)
    first = sweeps[names[0]]
    for name in names[1:]:
        other = sweeps[name]
        if other.directions.shape != first.directions.shape or not np.allclose(
            other.directions, first.directions
        ):
            raise InvalidInputError("sweeps", f"{name!r} swept other directions than {names[0]!r}")
    tables = {name: sweeps[name].to_dict()["directions"] for name in names}
    rows = []
    for i, (d, eff) in enumerate(zip(first.directions, first.effective, strict=True)):
        rows.append(
            {
                "index": i,
                "direction": [float(v) for v in d],
                "effective": bool(eff),
                "status": {n: tables[n][i]["status"] for n in names},
                "cost_mm": {n: tables[n][i]["cost_mm"] for n in names},
                "time_s": {n: tables[n][i]["time_s"] for n in names},
            }
        )
    return {
        "planners": names,
        "summary": {n: dict(sweeps[n].stats) for n in names},
        "directions": rows,
        "best_plans": {
            n: None if sweeps[n].best is None else sweeps[n].best.to_dict(spacing_mm) for n in names
        },
    }


def _direction_rows(rows: list, where: str) -> tuple[np.ndarray, np.ndarray]:
    """The candidate directions and the effective mask of a record's direction rows."""
    dirs, eff = np.zeros((len(rows), 3)), np.zeros(len(rows), dtype=bool)
    for i, row in enumerate(rows):
        at = f"{where}: directions[{i}]"
        if field_of(row, "index", at, "int") != i:
            raise InvalidInputError(f"{at}: index", f"expected {i} (rows in sweep order)")
        dirs[i] = field_of(row, "direction", at, "point")
        eff[i] = field_of(row, "effective", at, "bool")
    return dirs, eff


def sweeps_from_dict(data: dict, where: str, goal_mm=None) -> dict:
    """The sweeps of a ``sweep.json`` record, one per planner (what :func:`sweeps_to_dict`
    writes, read back).

    Every effective direction gets a result with its status, cost and time; only the best
    direction's carries a plan (the file keeps no other path).

    Parameters
    ----------
    data : dict
        As :func:`sweeps_to_dict` writes it.
    where : str
        Names the record in messages.
    goal_mm : array_like, shape (3,), optional
        The goal of the results without a plan (default: a best plan's goal, else NaN).

    Returns
    -------
    dict of str to SweepResult
        In the file's planner order.

    Raises
    ------
    InvalidInputError
        A field not as the format says (named).
    """
    planners = field_of(data, "planners", where, "list")
    if not planners or not all(isinstance(p, str) for p in planners):
        raise InvalidInputError(f"{where}: planners", "expected one or more planner names")
    rows = field_of(data, "directions", where, "list")
    summary = field_of(data, "summary", where, "dict")
    bests = field_of(data, "best_plans", where, "dict")
    best = {}
    for name in planners:
        b = bests.get(name)
        best[name] = None if b is None else PlanResult.from_dict(b, f"{where}: best_plans.{name}")
    if goal_mm is None:
        found = [b.goal_mm for b in best.values() if b is not None]
        goal_mm = found[0] if found else np.full(3, np.nan)
    goal = np.asarray(goal_mm, dtype=float)
    dirs, eff = _direction_rows(rows, where)
    out = {}
    for name in planners:
        stats = field_of(summary, name, f"{where}: summary", "dict")
        best_index = field_of(stats, "best_index", f"{where}: summary.{name}", "int", optional=True)
        results: list = [None] * len(rows)
        partial = data.get("partial") is True
        for i in np.flatnonzero(eff):
            at = f"{where}: directions[{i}]"
            row = rows[i]
            given = field_of(row, "status", at, "dict").get(name)
            if given is None and partial:  # an interrupted sweep had not reached it
                continue
            status = enum_of(Status, given, f"{at}: status")
            cost = number_or_inf(field_of(row, "cost_mm", at, "dict"), name, f"{at}: cost_mm")
            t = field_of(field_of(row, "time_s", at, "dict"), name, f"{at}: time_s", optional=True)
            results[i] = PlanResult(status, name, None, cost, float(t or 0.0), goal)
        b = best[name]
        if best_index is not None:
            if not 0 <= best_index < len(rows) or results[best_index] is None:
                msg = f"{best_index} is not an effective direction"
                raise InvalidInputError(f"{where}: summary.{name}.best_index", msg)
            if b is None or b.plan is None:
                raise InvalidInputError(f"{where}: best_plans.{name}", "missing the best plan")
            results[best_index] = b
        out[name] = SweepResult(dirs, eff, results, name, dict(stats))
    return out


def solved_plans_to_dict(sweeps: dict) -> dict:
    """Every plan of every sweep, per planner and direction index: what a partial record
    keeps (``sweep.json`` keeps the best ones only), so that a resumed run checks the
    plans found before the interruption as its own.

    Parameters
    ----------
    sweeps : mapping of str to SweepResult

    Returns
    -------
    dict
        Per planner, per direction index (as text), the ``plan.json`` record without its
        ``points_mm`` (derived from the primitives).
    """
    out: dict = {}
    for name, sw in sweeps.items():
        out[name] = {}
        for i, r in enumerate(sw.results):
            if r is not None and r.plan is not None:
                rec = r.to_dict(spacing_mm=1e6)  # the ends alone: dropped below
                rec["points_mm"] = []
                rec["stats"] = {  # e.g. a search's best cost before any solution (inf)
                    k: None if isinstance(v, float) and not np.isfinite(v) else v
                    for k, v in rec["stats"].items()
                }
                out[name][str(i)] = rec
    return out


def solved_plans_from_dict(sweeps: dict, data, where: str) -> dict:
    """Put the plans :func:`solved_plans_to_dict` kept back into the sweeps read from the
    same record (:func:`sweeps_from_dict`, whose results carry no plan).

    Parameters
    ----------
    sweeps : dict of str to SweepResult
        Changed in place.
    data : dict
        Per planner, per direction index, a plan record.
    where : str
        Names the record in messages.

    Returns
    -------
    dict of str to SweepResult
        ``sweeps``.

    Raises
    ------
    InvalidInputError
        A plan for a planner, or a direction, that the sweeps do not have, or a plan not as
        the format says (named).
    """
    for name, plans in field_of({"p": data}, "p", where, "dict").items():
        if name not in sweeps:
            raise InvalidInputError(f"{where}.{name}", "not a planner of the sweep")
        results = sweeps[name].results
        for key, rec in field_of({"p": plans}, "p", f"{where}.{name}", "dict").items():
            at = f"{where}.{name}.{key}"
            i = int(key) if key.isdigit() else -1
            if not 0 <= i < len(results) or results[i] is None:
                raise InvalidInputError(at, "not a direction the sweep planned")
            r = PlanResult.from_dict(rec, at)
            if r.status is not results[i].status or r.cost_mm != results[i].cost_mm:
                raise InvalidInputError(at, "not the result the sweep's table gives")
            results[i] = r
    return sweeps
