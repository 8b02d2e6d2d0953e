"""What one trial of ``needlekit execute`` records: each run's figures
(:class:`LoopRecord`) and the trial's (:class:`TrialRecord`), with its status in the one
result contract (:class:`needlekit.records.Status`).

A trial's status is read from the run needlekit steers, the closed loop (the open loop
when the trial ran open loop only), judged on the true tip, never the estimate:

========================  =====================================================================
``solved``                the insertion ended within the scenario's goal tolerance of the
                          target, its path crossed no obstacle (certified without the margin)
                          and it was not aborted
``approximate``           no obstacle crossed and not aborted, but the tip ended farther from
                          the target than the tolerance (``final_error_mm`` says how far),
                          among them the insertions stopped with the estimated tip near an
                          obstacle (``stopped_near_obstacle``)
``infeasible``            the executed path crossed an obstacle, or a point of it could not be
                          checked (``violated``): not a valid path
``timeout``               the sensor guard aborted the insertion (``--on-fault abort``, or a
                          hold longer than ``--hold-timeout-s``) before the goal was reached
``invalid_input``         the trial did not run to its end: it raised, and ``error`` says what
========================  =====================================================================

Both records are frozen dataclasses with ``to_dict()`` (what ``execute.json`` holds) and
``from_dict(data, where)``, which checks every field as it reads it, as the other results
do (:mod:`needlekit.records`).
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import numpy as np

from needlekit.anatomy.collision import ClearanceCertificate
from needlekit.errors import InvalidInputError
from needlekit.records import Status, enum_of, field_of, is_number

__all__ = ["LoopRecord", "TrialRecord", "path_record", "trial_status"]

#: The fields every run has (their values may be null where the type says ``or None``).
_ALWAYS = ("final_error_mm", "min_clearance_mm", "sampled_clearance_mm", "violated",
           "violation", "inserted_mm", "estimate_error_mm", "samples", "replans",
           "replan_attempts", "replan_latency_s", "points_mm", "cross_track_mm",
           "replan_events")  # fmt: skip
#: The closed loop's sensor guard (first in the record), and what only some runs have.
_GUARD = ("faults", "rejected", "accepted", "holds", "held_s", "aborted", "procedure_s",
          "faults_injected")  # fmt: skip
_AFTER = ("replans_refused", "warm_start_kept", "shaft_loads", "points_rest_mm",
          "stopped_near_obstacle")  # fmt: skip
#: What a run under a sensing policy records of the target
#: (:meth:`needlekit.execute.target_sensing.TargetSensing.record`).
_TARGET = ("sensing", "target_displacement_mm", "target_displacement_max_mm",
           "target_error_mm", "scans", "target_samples_used", "target_samples_refused",
           "scan_tip_used", "scan_tip_refused", "scan_tip_reseeded")  # fmt: skip


@dataclasses.dataclass(frozen=True)
class LoopRecord:
    """One run's figures (open loop, closed loop, or closed loop under a breathing policy);
    the fields as ``docs/execute.md`` lists them. The guard's fields are those of a closed
    loop (None in an open loop's), ``replans_refused`` and ``warm_start_kept`` those of a
    run that re-planned, ``shaft_loads`` those of a truth that reports them,
    ``points_rest_mm`` those of a truth that maps its tissue back to rest (``to_rest``;
    ``points_mm`` is then the path in the world and the clearance is judged on this one),
    ``stopped_near_obstacle`` those of a closed loop stopped with its estimated tip near an
    obstacle (:mod:`needlekit.execute.proximity`),
    and the target's fields (``sensing`` to ``scan_tip_reseeded``) those of a closed loop
    under a sensing policy other than ``em`` or with a truth that carries the target."""

    final_error_mm: float
    min_clearance_mm: float | None
    sampled_clearance_mm: float | None
    violated: bool
    violation: str | None
    inserted_mm: float
    estimate_error_mm: float | None
    samples: int
    replans: int
    replan_attempts: int
    replan_latency_s: tuple
    points_mm: tuple
    cross_track_mm: tuple | None
    replan_events: tuple
    faults: tuple | None = None
    rejected: dict | None = None
    accepted: int | None = None
    holds: int | None = None
    held_s: float | None = None
    aborted: bool | None = None
    procedure_s: float | None = None
    faults_injected: tuple | None = None
    replans_refused: int | None = None
    warm_start_kept: int | None = None
    shaft_loads: dict | None = None
    points_rest_mm: tuple | None = None
    stopped_near_obstacle: dict | None = None
    sensing: str | None = None
    target_displacement_mm: float | None = None
    target_displacement_max_mm: float | None = None
    target_error_mm: float | None = None
    scans: int | None = None
    target_samples_used: int | None = None
    target_samples_refused: dict | None = None
    scan_tip_used: int | None = None
    scan_tip_refused: int | None = None
    scan_tip_reseeded: int | None = None

    def to_dict(self) -> dict:
        """The record as ``execute.json`` holds it (fields a run has not, left out).

        Returns
        -------
        dict
        """
        out: dict[str, Any] = {}
        for key in (*_GUARD, *_ALWAYS, *_AFTER, *_TARGET):
            value = getattr(self, key)
            if value is None and key not in _ALWAYS:
                continue
            out[key] = _plain(value)
        return out

    @classmethod
    def from_dict(cls, data: dict, where: str) -> LoopRecord:
        """Read a run's record back, checking every field.

        Parameters
        ----------
        data : dict
        where : str
            Names the record in messages (``"execute.json: trials[3].closed_loop"``).

        Returns
        -------
        LoopRecord

        Raises
        ------
        InvalidInputError
            ``"<where>: <field>: ..."``.
        """
        f = field_of
        known = {*_ALWAYS, *_GUARD, *_AFTER, *_TARGET}
        unknown = sorted(set(data) - known) if isinstance(data, dict) else []
        if unknown:
            raise InvalidInputError(f"{where}: {unknown[0]}", "not a field of a run's record")
        violation = f(data, "violation", where, "str", optional=True)
        return cls(
            final_error_mm=float(f(data, "final_error_mm", where)),
            min_clearance_mm=_opt_number(data, "min_clearance_mm", where),
            sampled_clearance_mm=_opt_number(data, "sampled_clearance_mm", where),
            violated=f(data, "violated", where, "bool"),
            violation=violation,
            inserted_mm=float(f(data, "inserted_mm", where)),
            estimate_error_mm=_opt_number(data, "estimate_error_mm", where),
            samples=f(data, "samples", where, "int"),
            replans=f(data, "replans", where, "int"),
            replan_attempts=f(data, "replan_attempts", where, "int"),
            replan_latency_s=_numbers(data, "replan_latency_s", where),
            points_mm=_points(data, "points_mm", where),
            cross_track_mm=None if data.get("cross_track_mm") is None
            else _numbers(data, "cross_track_mm", where),
            replan_events=tuple(_event(e, f"{where}: replan_events[{k}]")
                                for k, e in enumerate(f(data, "replan_events", where, "list"))),
            faults=_dicts(data, "faults", where),
            rejected=_counts(data, "rejected", where),
            accepted=f(data, "accepted", where, "int", optional=True),
            holds=f(data, "holds", where, "int", optional=True),
            held_s=_opt_number(data, "held_s", where),
            aborted=f(data, "aborted", where, "bool", optional=True),
            procedure_s=_opt_number(data, "procedure_s", where),
            faults_injected=_dicts(data, "faults_injected", where),
            replans_refused=f(data, "replans_refused", where, "int", optional=True),
            warm_start_kept=f(data, "warm_start_kept", where, "int", optional=True),
            shaft_loads=f(data, "shaft_loads", where, "dict", optional=True),
            points_rest_mm=None if data.get("points_rest_mm") is None
            else _points(data, "points_rest_mm", where),
            stopped_near_obstacle=_stop(data, where),
            sensing=f(data, "sensing", where, "str", optional=True),
            target_displacement_mm=_opt_number(data, "target_displacement_mm", where),
            target_displacement_max_mm=_opt_number(data, "target_displacement_max_mm", where),
            target_error_mm=_opt_number(data, "target_error_mm", where),
            scans=f(data, "scans", where, "int", optional=True),
            target_samples_used=f(data, "target_samples_used", where, "int", optional=True),
            target_samples_refused=_counts(data, "target_samples_refused", where),
            scan_tip_used=f(data, "scan_tip_used", where, "int", optional=True),
            scan_tip_refused=f(data, "scan_tip_refused", where, "int", optional=True),
            scan_tip_reseeded=f(data, "scan_tip_reseeded", where, "int", optional=True),
        )  # fmt: skip


@dataclasses.dataclass(frozen=True)
class TrialRecord:
    """One trial: its seed, its status (module notes) and its runs, or the error it raised.

    Attributes
    ----------
    trial, seed : int
    seed_spawn_key : tuple of int
        The trial's ``SeedSequence(seed, spawn_key=...)``.
    status : Status
    open_loop, closed_loop : LoopRecord or None
        The runs (None: not run, or the trial raised).
    breathing : dict of str to LoopRecord, or None
        The closed loop under each breathing policy.
    sensing : dict of str to LoopRecord, or None
        Several sensing policies side by side: the closed loop under each
        (:mod:`needlekit.execute.target_sensing`), the first the same run as
        ``closed_loop``.
    error : str or None
        What the trial raised (``"Type: message (file:line)"``).
    """

    trial: int
    seed: int
    seed_spawn_key: tuple
    status: Status
    open_loop: LoopRecord | None = None
    closed_loop: LoopRecord | None = None
    breathing: dict | None = None
    error: str | None = None
    sensing: dict | None = None

    def to_dict(self) -> dict:
        """The record as ``execute.json`` holds it.

        Returns
        -------
        dict
        """
        out: dict[str, Any] = {"trial": self.trial, "seed": self.seed,
                               "seed_spawn_key": list(self.seed_spawn_key),
                               "status": self.status.value}  # fmt: skip
        for key in ("open_loop", "closed_loop"):
            if getattr(self, key) is not None:
                out[key] = getattr(self, key).to_dict()
        if self.breathing is not None:
            out["breathing"] = {k: v.to_dict() for k, v in self.breathing.items()}
        if self.sensing is not None:
            out["sensing"] = {k: v.to_dict() for k, v in self.sensing.items()}
        if self.error is not None:
            out["error"] = self.error
        return out

    @classmethod
    def from_dict(cls, data: dict, where: str) -> TrialRecord:
        """Read a trial's record back, checking every field.

        Parameters
        ----------
        data : dict
        where : str

        Returns
        -------
        TrialRecord

        Raises
        ------
        InvalidInputError
        """
        f = field_of
        key = f(data, "seed_spawn_key", where, "list")
        if not all(isinstance(k, int) and not isinstance(k, bool) for k in key):
            raise InvalidInputError(f"{where}: seed_spawn_key", "expected whole numbers")
        runs = {k: None if data.get(k) is None else LoopRecord.from_dict(data[k], f"{where}: {k}")
                for k in ("open_loop", "closed_loop")}  # fmt: skip
        breathing = f(data, "breathing", where, "dict", optional=True)
        if breathing is not None:
            breathing = {k: LoopRecord.from_dict(v, f"{where}: breathing: {k}")
                         for k, v in breathing.items()}  # fmt: skip
        sensing = f(data, "sensing", where, "dict", optional=True)
        if sensing is not None:
            sensing = {k: LoopRecord.from_dict(v, f"{where}: sensing: {k}")
                       for k, v in sensing.items()}  # fmt: skip
        return cls(
            trial=f(data, "trial", where, "int"),
            seed=f(data, "seed", where, "int"),
            seed_spawn_key=tuple(key),
            status=enum_of(Status, f(data, "status", where, "str"), f"{where}: status"),
            breathing=breathing,
            sensing=sensing,
            error=f(data, "error", where, "str", optional=True),
            **runs,
        )


def trial_status(run: LoopRecord | None, tolerance_mm: float, error: str | None = None) -> Status:
    """A trial's status from the run it is judged by (module notes).

    Parameters
    ----------
    run : LoopRecord or None
        The closed loop (or the open loop of an open-loop-only trial); None when it raised.
    tolerance_mm : float
        The scenario's goal tolerance.
    error : str, optional

    Returns
    -------
    Status

    Examples
    --------
    >>> trial_status(None, 1.0, "ValueError: x").value
    'invalid_input'
    """
    if error is not None or run is None:
        return Status.INVALID_INPUT
    if run.violated:
        return Status.INFEASIBLE
    if run.aborted:
        return Status.TIMEOUT
    return Status.SOLVED if run.final_error_mm <= tolerance_mm else Status.APPROXIMATE


#: Samples per piece in :func:`certify_in_pieces` (about 4 mm of a path recorded every
#: 0.25 mm).
PIECE_SAMPLES = 16


def certify_in_pieces(checker, points: np.ndarray, piece: int = PIECE_SAMPLES):
    """A recorded path's clearance certificate, each piece of it (``piece`` samples, the
    pieces sharing their ends) certified with its own largest gap rather than the whole
    path's: each piece is a sampled path as :meth:`~needlekit.anatomy.collision.
    CollisionChecker.certify` takes one, so the smallest bound over the pieces bounds the
    whole path, and a stretch where the samples lie farther apart (a tissue stretched at
    rest, say) widens only its own bound.

    Parameters
    ----------
    checker : CollisionChecker
    points : ndarray, shape (n, 3), float64
    piece : int

    Returns
    -------
    ClearanceCertificate
        The smallest sampled and certified clearances over the pieces, the first piece's
        violation, the colliding samples summed (a shared end counted in both pieces).
    """
    n = len(points)
    certs = []
    for i in range(0, max(n - 1, 1), piece - 1):
        chunk = np.ascontiguousarray(points[i : i + piece])
        gap = float(np.linalg.norm(np.diff(chunk, axis=0), axis=1).max()) if len(chunk) > 1 else 0.0
        certs.append(checker.certify(chunk, max(gap, 1e-6)))
    return ClearanceCertificate(
        colliding_samples=sum(c.colliding_samples for c in certs),
        sampled_clearance_mm=_least(c.sampled_clearance_mm for c in certs),
        certified_clearance_mm=_least(c.certified_clearance_mm for c in certs),
        violation=next((c.violation for c in certs if c.violation is not None), None),
    )


def _least(values) -> float:
    """The smallest value, NaN if any is NaN (a piece not checked leaves the path not
    checked)."""
    values = [float(v) for v in values]
    return math.nan if any(math.isnan(v) for v in values) else min(values)


def path_record(run, judge) -> LoopRecord:
    """One run's figures, its path judged against the anatomy without the margin.

    Parameters
    ----------
    run : needlekit.execute.run.ExecutionRun
    judge : SteerableProblem
        The scenario's anatomy and collision model without the margin.

    Returns
    -------
    LoopRecord
    """
    pts = np.ascontiguousarray(run.points_mm, dtype=np.float64)
    rest = getattr(run, "points_rest_mm", None)
    judged = pts if rest is None else np.ascontiguousarray(rest, dtype=np.float64)
    cert = certify_in_pieces(judge.collision_checker(), judged)
    guard: dict[str, Any] = {}
    if run.guard is not None:  # closed loop: its faults, holds and rejected samples
        guard = {**run.guard, "procedure_s": float(run.procedure_s)}
        guard["faults"] = tuple(guard["faults"])
        if run.faults_injected:
            guard["faults_injected"] = tuple(run.faults_injected)
    return LoopRecord(
        final_error_mm=float(run.final_error_mm),
        min_clearance_mm=_finite(cert.certified_clearance_mm),
        sampled_clearance_mm=_finite(cert.sampled_clearance_mm),
        violated=cert.violation is not None,
        violation=cert.violation,
        inserted_mm=float(run.inserted_mm),
        estimate_error_mm=_finite(run.estimate_error_mm),
        samples=int(run.samples),
        replans=int(run.replans),
        replan_attempts=len(run.replan_latency_s),
        replan_latency_s=tuple(float(v) for v in run.replan_latency_s),
        points_mm=tuple(map(tuple, np.round(pts, 4).tolist())),
        cross_track_mm=None if run.cross_track_mm is None
        else tuple(np.round(run.cross_track_mm, 4).tolist()),
        replan_events=tuple(
            {"asked_at_mm": a, "applied_at_mm": b,
             "points_mm": np.round(plan.points_mm(1.0), 3).tolist()}
            for a, b, plan in run.replan_events
        ),
        shaft_loads=run.shaft_loads,
        points_rest_mm=None if rest is None else tuple(map(tuple, np.round(judged, 4).tolist())),
        stopped_near_obstacle=getattr(run, "stopped_near_obstacle", None),
        **guard,
        **_target(getattr(run, "target", None)),
    )  # fmt: skip


#: The fields of ``stopped_near_obstacle`` (:class:`~needlekit.execute.run.ExecutionRun`).
_STOP_FIELDS = ("inserted_mm", "estimated_clearance_mm", "stop_mm")


def _stop(data: dict, where: str) -> dict | None:
    """``stopped_near_obstacle``: None, or its three numbers (the clearance may be -inf
    written as null: outside the image)."""
    stop = field_of(data, "stopped_near_obstacle", where, "dict", optional=True)
    if stop is None:
        return None
    if sorted(stop) != sorted(_STOP_FIELDS):
        raise InvalidInputError(f"{where}: stopped_near_obstacle",
                                f"expected the fields {', '.join(_STOP_FIELDS)}")  # fmt: skip
    for k in _STOP_FIELDS:
        v = stop[k]
        if not (v is None and k == "estimated_clearance_mm") and not (
            is_number(v) and math.isfinite(v)
        ):
            raise InvalidInputError(f"{where}: stopped_near_obstacle: {k}", "expected a finite number")
    return dict(stop)


def _target(target: dict | None) -> dict:
    """A run's target record as the record's fields (none when it has none)."""
    if target is None:
        return {}
    return {**target, "target_samples_refused": dict(target["target_samples_refused"])}


def _finite(v):
    return None if v is None or not math.isfinite(float(v)) else float(v)


def _plain(value):
    """Tuples as lists, for JSON (and for equality with what is read back)."""
    if isinstance(value, tuple):
        return [_plain(v) for v in value]
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items()}
    return value


def _opt_number(data: dict, key: str, where: str) -> float | None:
    v = field_of(data, key, where, optional=True)
    return None if v is None else float(v)


def _numbers(data: dict, key: str, where: str) -> tuple:
    values = field_of(data, key, where, "list")
    if not all(is_number(v) and math.isfinite(v) for v in values):
        raise InvalidInputError(f"{where}: {key}", "expected a list of finite numbers")
    return tuple(float(v) for v in values)


def _points(data: dict, key: str, where: str) -> tuple:
    values = field_of(data, key, where, "list")
    ok = all(isinstance(p, list) and len(p) == 3 and all(is_number(c) and math.isfinite(c)
                                                        for c in p) for p in values)  # fmt: skip
    if not ok:
        raise InvalidInputError(f"{where}: {key}", "expected a list of points (three numbers)")
    return tuple(tuple(float(c) for c in p) for p in values)


def _event(e, where: str) -> dict:
    field_of(e, "asked_at_mm", where)
    field_of(e, "applied_at_mm", where)
    _points(e, "points_mm", where)
    return e


def _dicts(data: dict, key: str, where: str) -> tuple | None:
    values = field_of(data, key, where, "list", optional=True)
    if values is None:
        return None
    if not all(isinstance(v, dict) for v in values):
        raise InvalidInputError(f"{where}: {key}", "expected a list of objects")
    return tuple(values)


def _counts(data: dict, key: str, where: str) -> dict | None:
    values = field_of(data, key, where, "dict", optional=True)
    if values is not None and not all(
        isinstance(n, int) and not isinstance(n, bool) for n in values.values()
    ):
        raise InvalidInputError(f"{where}: {key}", "expected whole numbers by kind")
    return values
