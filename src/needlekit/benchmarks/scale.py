"""``needlekit bench scale``: how the cost grows with the problem's size.

Four series, each recorded with the machine's load average when it started and ended:

- **preparation**: one Med-RAD lung made ready for a first plan in a fresh process, cold
  (an empty prepared-anatomy cache) then warm (:mod:`needlekit.benchmarks.prepare`);
- **planning** against path length and obstacle density: every start of each Med-RAD lung
  to its target (the ``bench steerable`` problem at r_min 50 mm, RCS* by default), under
  an iteration budget with a time cap. Per case: the straight start-goal distance, the
  certified path length when solved, the planner's wall time, iterations, status, and the
  obstacle density, the share of obstacle voxels (the case's occupancy) in a capsule of
  :data:`~needlekit.benchmarks.scale_math.CAPSULE_RADIUS_MM` around the start-goal
  segment; log-log fits of time against both, with R^2;
- **sweep** against directions and workers: Feng's goal 1 on lung 5
  (:func:`needlekit.studies.feng_lungs.feng_lung_scenario`), RCS*, at each number of
  directions, in this process (1 worker), on process pools and on local Dask clusters (a
  fresh executor per point, so each point pays one preparation per worker), under an
  iteration budget so that every executor does the same work. Per point: the wall time,
  the planners' time in sum, the preparation per worker, the efficiency
  ``planner_s_sum / (workers x (wall_s - prep_s))`` and whether every direction's result
  equals the serial run's;
- **study** against trials: Tang's puncture study (:func:`run_puncture_study`) at each
  number of trials, in this process and on process pools; a line fitted per worker count
  and extrapolated to 100 trials.
"""

from __future__ import annotations

import importlib.util
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from needlekit.benchmarks.scale_series import (
    MAX_ITERATIONS,
    TIME_LIMIT_S,
    Progress,
    _load,
    _say,
    executor_label,
    planning_series,
    preparation_point,
    study_series,
    sweep_series,
)
from needlekit.errors import InvalidInputError
from needlekit.planning.interface import planner_class
from needlekit.provenance import machine_info
from needlekit.scenario.problems import ScenarioSource
from needlekit.studies.feng_lungs import feng_lung_scenario

__all__ = [
    "DEFAULTS",
    "QUICK",
    "planning_series",
    "run_scale_benchmark",
    "scale_settings",
    "study_series",
    "sweep_series",
]

#: The full run (about 15 minutes on 2 cores): lungs 1-5, five sweep sizes on three
#: executors, the study at four sizes on one and two workers.
DEFAULTS: dict[str, Any] = {
    "patients": (1, 2, 3, 4, 5),
    "planners": ("rcs_star",),
    "directions": (34, 68, 136, 272, 544),
    "workers": (1, 2),
    "dask_workers": (4,),
    "trials": (1, 2, 5, 10),
    "study_workers": (1, 2),
    "max_iterations": MAX_ITERATIONS,
    "time_limit_s": TIME_LIMIT_S,
    "seed": 0,
}
#: ``--quick`` (about a minute): lung 1, two sweep sizes, the study at 1 and 2 trials in
#: this process. The budgets stay as in the full run, so the points are comparable.
QUICK: dict[str, Any] = {
    "patients": (1,),
    "directions": (34, 68),
    "trials": (1, 2),
    "study_workers": (1,),
}
#: The sweep's case: Feng's goal 1 on Med-RAD lung 5 (its patient).
SWEEP_PATIENT: int = 5


def _ints(values, flag: str, minimum: int) -> tuple[int, ...]:
    out = []
    for v in values:
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < minimum:
            raise InvalidInputError(flag, f"expected whole numbers >= {minimum}, got {v!r}")
        out.append(int(v))
    return tuple(sorted(set(out)))


def scale_settings(
    *,
    quick: bool = False,
    patients: Sequence[int] | None = None,
    planners: Sequence[str] | None = None,
    directions: Sequence[int] | None = None,
    workers: Sequence[int] | None = None,
    dask_workers: Sequence[int] | None = None,
    trials: Sequence[int] | None = None,
    max_iterations: int | None = None,
    time_limit_s: float | None = None,
    medrad_dir=None,
) -> dict[str, Any]:
    """The run's settings, checked before any work: :data:`DEFAULTS`, or :data:`QUICK`,
    under the values given.

    Parameters
    ----------
    quick : bool
    patients : sequence of int, optional
        Med-RAD lungs of the planning series (0 alone: none).
    planners : sequence of str, optional
        Registered steerable planners of the planning series.
    directions : sequence of int, optional
        Sweep sizes (0 alone: no sweep).
    workers : sequence of int, optional
        Process-pool sizes of the sweep and the study (1: this process).
    dask_workers : sequence of int, optional
        Local Dask cluster sizes of the sweep (0 alone: none).
    trials : sequence of int, optional
        Study sizes (0 alone: no study).
    max_iterations : int, optional
        Iteration budget per planner run (planning and sweep).
    time_limit_s : float, optional
        Time cap per planner run (s): it only stops a run on a loaded machine.
    medrad_dir : path-like, optional

    Returns
    -------
    dict
        The settings, lists sorted and without repeats, ``medrad`` the folder (str) or
        None.

    Raises
    ------
    InvalidInputError
        Named by the flag: a bad number, an unknown planner, a missing lung, no Dask.
    """
    s = dict(DEFAULTS) | (QUICK if quick else {})
    given = {"patients": patients, "planners": planners, "directions": directions,
             "dask_workers": dask_workers, "trials": trials,
             "max_iterations": max_iterations, "time_limit_s": time_limit_s}  # fmt: skip
    s |= {k: v for k, v in given.items() if v is not None}
    if workers is not None:
        s["workers"] = s["study_workers"] = workers
    for key, minimum in (("patients", 0), ("directions", 0), ("dask_workers", 0), ("trials", 0)):
        s[key] = tuple(v for v in _ints(s[key], "--" + key.replace("_", "-"), minimum) if v)
    for key in ("workers", "study_workers"):
        s[key] = _ints(s[key], "--workers", 1)
    if not s["workers"]:
        raise InvalidInputError("--workers", "expected at least one worker count")
    if isinstance(s["max_iterations"], bool) or int(s["max_iterations"]) < 1:
        raise InvalidInputError("--max-iterations", "expected a whole number >= 1")
    s["max_iterations"] = int(s["max_iterations"])
    if not (np.isfinite(s["time_limit_s"]) and float(s["time_limit_s"]) > 0):
        raise InvalidInputError("--time-limit-s", "expected a finite time > 0")
    s["time_limit_s"] = float(s["time_limit_s"])
    s["planners"] = tuple(dict.fromkeys(s["planners"]))
    _check_planners(s["planners"])
    s["medrad"] = None
    if s["patients"] or s["directions"]:
        s["medrad"] = _check_lungs(s["patients"], bool(s["directions"]), medrad_dir)
    if s["directions"] and s["dask_workers"]:
        if importlib.util.find_spec("distributed") is None:
            raise InvalidInputError(
                "--dask-workers", "needs Dask distributed: pip install 'needlekit[dask]' "
                "(or --dask-workers 0)",
            )  # fmt: skip
    return s


def _check_planners(names) -> None:
    if not names:
        raise InvalidInputError("--planners", "expected at least one planner")
    for name in names:
        try:
            family = planner_class(name).family
        except InvalidInputError as exc:
            raise InvalidInputError("--planners", exc.reason) from None
        if family != "steerable":
            raise InvalidInputError("--planners", f"{name!r} plans {family} needles")


def _check_lungs(patients, sweep: bool, medrad_dir) -> str:
    from needlekit.io.medrad import list_patients, medrad_root

    try:
        root = medrad_root(medrad_dir)
    except InvalidInputError as exc:
        raise InvalidInputError("--medrad", exc.reason) from None
    have = list_patients("lung", root)
    if not have:
        raise InvalidInputError(
            "--medrad", f"{root} holds no Med-RAD lung (Lungs/TumorTargetEnvironments/PatientN)"
        )
    missing = [p for p in patients if p not in have]
    if missing:
        raise InvalidInputError(
            "--patients", f"no Med-RAD lung {', '.join(map(str, missing))} in {root} (have {have})"
        )
    if sweep and SWEEP_PATIENT not in have:
        raise InvalidInputError(
            "--medrad", f"no Med-RAD lung {SWEEP_PATIENT} in {root}: the sweep runs on it "
            "(--directions 0 for none)",
        )  # fmt: skip
    return str(root)


def run_scale_benchmark(settings: dict | None = None, *, progress: Progress = None) -> dict:
    """Run every series the settings ask for and return the record.

    Parameters
    ----------
    settings : dict, optional
        From :func:`scale_settings` (default: the full run).
    progress : callable, optional
        Called with a line after each case, sweep and study.

    Returns
    -------
    dict
        ``benchmark`` (``"scale"``), ``machine`` (:func:`machine_info`, at the end),
        ``load_average`` (start and end of the run), ``inputs``, ``preparation`` (or
        None), ``planning``, ``sweep``, ``study`` (each None when not run), ``wall_s``
        and ``results`` (one line per series for the terminal).
    """
    s = scale_settings() if settings is None else settings
    t0, load = time.perf_counter(), {"start": _load()}
    root = s.get("medrad")
    prep = plan = sweep = study = None
    if s["patients"] and s.get("prepare", True):
        _say(progress, f"preparation: lung {s['patients'][0]}, cold then warm")
        prep = preparation_point(s["patients"][0], root)
    if s["patients"]:
        plan = planning_series(s["patients"], s["planners"], max_iterations=s["max_iterations"],
                               time_limit_s=s["time_limit_s"], seed=s["seed"], medrad_dir=root,
                               progress=progress)  # fmt: skip
    if s["directions"]:
        sweep = sweep_series(
            s.get("sweep_source") or _feng_source(root), s["directions"], workers=s["workers"],
            dask_workers=s["dask_workers"], max_iterations=s["max_iterations"],
            time_limit_s=s["time_limit_s"], seed=s["seed"], progress=progress,
        )  # fmt: skip
        sweep["case"] = s.get("sweep_case", "Feng's goal 1 on Med-RAD lung 5, start 1 (RCS*)")
    if s["trials"]:
        study = study_series(s["trials"], workers=s["study_workers"], seed=s["seed"],
                             progress=progress)  # fmt: skip
    load["end"] = _load()
    inputs = {k: list(v) if isinstance(v, tuple) else v for k, v in s.items()
              if k not in ("sweep_source",)}  # fmt: skip
    record = {
        "benchmark": "scale",
        "machine": machine_info(),
        "load_average": load,
        "inputs": inputs,
        "preparation": prep,
        "planning": plan,
        "sweep": sweep,
        "study": study,
        "wall_s": time.perf_counter() - t0,
    }
    record["results"] = summary_lines(record)
    return record


def _feng_source(root):
    doc = feng_lung_scenario(1, medrad_dir=root)
    return ScenarioSource.of_document(doc, Path.cwd(), name="feng-goal1.yaml")


def _fmt(fit: dict | None, key: str, unit: str = "") -> str:
    if fit is None:
        return "no fit (fewer than two distinct sizes)"
    return f"{key} {fit[key]:.3g}{unit}, R^2 {fit['r2']:.2f} (n {fit['n']})"


def summary_lines(record: dict) -> list[dict]:
    """One ``name``/``summary`` row per series and executor (``format_record``'s rows)."""
    rows = []
    if record.get("preparation"):
        p = record["preparation"]
        rows.append({"name": f"prepare lung {p['patient']}",
                     "summary": f"cold {p['cold_s']:.2f} s, warm {p['warm_s']:.2f} s"})  # fmt: skip
    if record.get("planning"):
        pl = record["planning"]
        for planner, f in pl["fits"].items():
            mine = [r for r in pl["rows"] if r["planner"] == planner]
            solved = sum(r["status"] == "solved" for r in mine)
            rows.append({"name": f"planning {planner}",
                         "summary": f"{solved}/{len(mine)} solved; time ~ distance^"
                         + _fmt(f["time_vs_distance"], "exponent") + "; ~ density^"
                         + _fmt(f["time_vs_density"], "exponent")})  # fmt: skip
    if record.get("sweep"):
        for label, f in record["sweep"]["fits"].items():
            pts = [p for p in record["sweep"]["points"] if executor_label(p) == label]
            big = pts[-1]
            eff = "-" if big["efficiency"] is None else f"{big['efficiency']:.2f}"
            same = {True: "equal", False: "DIFFERENT", None: "-"}[big["equal_to_serial"]]
            rows.append({"name": f"sweep {label}",
                         "summary": f"{big['directions']} dirs {big['wall_s']:.1f} s, efficiency "
                         f"{eff}, results {same}; wall = a + b n: "
                         + _fmt(f["wall_vs_directions"], "slope", " s/dir")})  # fmt: skip
    if record.get("study"):
        st = record["study"]
        for w, f in st["fits"].items():
            at = "-" if f is None else f"{f['predicted']:.0f} s"
            rows.append({"name": f"study on {w} worker(s)",
                         "summary": f"{_fmt(f, 'slope', ' s/trial')}; "
                         f"{st['target_trials']} trials ~ {at}"})  # fmt: skip
    return rows
