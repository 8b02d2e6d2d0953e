"""needlekit's ``rcs_star`` beside the UNC reference app, case by case, and the figures.

:class:`ReferenceComparison` writes each patient's obstacle file once and each case's
folder (:mod:`needlekit.benchmarks.reference_app`), then runs the app and needlekit's
``rcs_star`` one after the other in this process, the order alternating from case to
case (app first on even cases, needlekit first on odd ones), with the load averages
recorded before every run. Both answers are put in one verdict vocabulary
(``certified``, ``solved``, ``infeasible``, ``no plan``, ``invalid``, ``failed``) and
compared: verdicts, costs (within :data:`~needlekit.benchmarks.reference_app.COST_AGREEMENT_MM`)
and the needlekit / app ratios of the time to a certified plan, of the time to the first
solution and of the time per iteration.
"""

from __future__ import annotations

import math
import os
import statistics
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from needlekit.benchmarks.reference_app import (
    APP_ARGUMENTS,
    COST_AGREEMENT_MM,
    CROP_MARGIN_MM,
    EXHAUSTED_FRACTION,
    REFERENCE_BUDGET_S,
    SHELL_MM,
    check_reference_app,
    run_reference_app,
    write_case_folder,
    write_obstacle_file,
)
from needlekit.errors import InvalidInputError

__all__ = [
    "TABLE_HEADER",
    "WARM_UP_S",
    "ReferenceComparison",
    "comparison_summary",
    "format_comparison",
]

#: Warm-up budget of needlekit's first solve (numba kernels; not recorded as a case).
WARM_UP_S = 0.25


def _load() -> list[float]:
    """The 1, 5 and 15 min load averages (``/proc/loadavg``)."""
    return [round(v, 2) for v in os.getloadavg()]


def _needlekit_verdict(status: str, certified: bool) -> str:
    """needlekit's status in the verdict vocabulary of :func:`parse_app_log`."""
    if status == "solved":
        return "certified" if certified else "solved"
    if status == "infeasible":
        return "infeasible"
    if status.startswith("invalid"):
        return "invalid"
    return "no plan"  # approximate, timeout: the budget ran out without a plan


def _needlekit_figures(res) -> dict[str, Any]:
    st = res.stats
    status = res.status.value
    certified = bool(st.get("certified", False))
    iterations = st.get("iterations")
    wall = st.get("planner_wall_s", res.time_s)
    return {
        "status": status,
        "verdict": _needlekit_verdict(status, certified),
        "reason": st.get("reason"),
        "cost_mm": res.cost_mm if status == "solved" and math.isfinite(res.cost_mm) else None,
        "time_s": res.time_s,
        "certified": certified,
        "time_to_certified_s": res.time_s if certified else None,
        "first_solution_s": st.get("first_solution_s") if status == "solved" else None,
        "iterations": iterations,
        "us_per_iteration": 1e6 * wall / iterations if iterations else None,
    }


def _app_figures(run: dict[str, Any]) -> dict[str, Any]:
    it, solve_s = run.get("iterations"), run.get("solve_s")
    return {
        **run,
        "time_to_certified_s": solve_s if run["status"] == "certified" else None,
        "us_per_iteration": 1e6 * solve_s / it if it and solve_s is not None else None,
    }


def _ratio(num, den) -> float | None:
    return None if num is None or not den else num / den


def _compared(row: dict[str, Any]) -> dict[str, Any]:
    """A case's agreement and needlekit / app ratios."""
    a, n = row["app"], row["needlekit"]
    both_cost = a["cost_mm"] is not None and n["cost_mm"] is not None
    return {
        **row,
        "verdicts_agree": a["verdict"] == n["verdict"],
        "cost_difference_mm": n["cost_mm"] - a["cost_mm"] if both_cost else None,
        "ratio_time_to_certified": _ratio(n["time_to_certified_s"], a["time_to_certified_s"]),
        "ratio_first_solution": _ratio(n["first_solution_s"], a["first_solution_s"]),
        "ratio_time": _ratio(n["time_s"], a["solve_s"]),
        "ratio_us_per_iteration": _ratio(n["us_per_iteration"], a["us_per_iteration"]),
    }


class ReferenceComparison:
    """Runs the app beside needlekit's ``rcs_star``, case by case, in a work folder.

    Parameters
    ----------
    app : path-like
        The built ``rcs_star`` (checked by :func:`check_reference_app`).
    work_dir : path-like
        Where the obstacle files and case folders go (created if needed).
    needle : dict
        ``needle_diameter_mm``, ``max_length_mm``, ``max_heading_change_deg`` of the
        benchmark (the app's own settings: goal tolerance 1 mm, 3 mm start whitelist).
    budget_s : float
        Must be the app's :data:`REFERENCE_BUDGET_S`.
    """

    def __init__(
        self, app, work_dir, needle: dict[str, float], budget_s: float = REFERENCE_BUDGET_S
    ):
        if abs(budget_s - REFERENCE_BUDGET_S) > 1e-12:
            raise InvalidInputError(
                "--time-limit-s",
                f"the reference app's budget is its stock {REFERENCE_BUDGET_S:g} s; "
                f"use {REFERENCE_BUDGET_S:g} with --reference-app, got {budget_s:g}",
            )
        self.app = check_reference_app(app)
        self.work_dir = Path(work_dir)
        if self.work_dir.exists() and not self.work_dir.is_dir():
            raise InvalidInputError("--reference-work", f"{self.work_dir}: is not a folder")
        try:
            self.work_dir.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise InvalidInputError(
                "--reference-work", f"{self.work_dir}: {exc.strerror}"
            ) from None
        self.needle = dict(needle)
        self.budget_s = float(budget_s)
        self.obstacle_files: dict[int, Path] = {}
        self.patients: list[dict[str, Any]] = []
        self.rows: list[dict[str, Any]] = []
        self.warm_up: dict[str, Any] | None = None

    def add_patient(self, patient: int, case, extra_points_mm=None) -> None:
        """Write one patient's obstacle file (once; every case folder links to it).

        Parameters
        ----------
        patient : int
        case : needlekit.io.medrad.MedradCase
            Its ``voxel_obstacles``, ``starts`` and ``targets_mm["target"]`` are used.
        extra_points_mm : array_like, shape (n, 3), optional
            Further points the crop must cover (sampled targets: the app counts a point
            outside its crop as a collision).

        Returns
        -------
        None
        """
        t0 = time.perf_counter()
        obstacles = case.voxel_obstacles(needle_diameter_mm=self.needle["needle_diameter_mm"])
        points = [s.world_T_tip[:3, 3] for s in case.starts] + [case.targets_mm["target"]]
        if extra_points_mm is not None:
            points += list(np.asarray(extra_points_mm, dtype=float).reshape(-1, 3))
        path = self.work_dir / f"P{patient}_obstacles.txt"
        info = write_obstacle_file(path, obstacles.occupancy, obstacles.affine, np.array(points))
        self.obstacle_files[patient] = path
        self.patients.append(
            {
                "patient": patient,
                "obstacle_file": str(path),
                **info,
                "write_s": time.perf_counter() - t0,
            }
        )

    def compare(self, patient: int, start: int, world_T_tip, target_mm, r_min_mm: float,
                solve: Callable[[float], Any], sample: int | None = None):  # fmt: skip
        """Run one case with both planners, in this case's order, and record it.

        Parameters
        ----------
        patient, start : int
        world_T_tip : ndarray, shape (4, 4)
        target_mm : ndarray, shape (3,)
        r_min_mm : float
        solve : callable
            ``solve(time_limit_s) -> PlanResult``: needlekit's ``rcs_star`` on this case.
            The first call of a session is a warm-up (:data:`WARM_UP_S`, not recorded).
        sample : int, optional
            The number of a sampled target (in the case's folder name and its row).

        Returns
        -------
        PlanResult
            needlekit's result of the recorded run.
        """
        tag = "" if sample is None else f"_t{sample}"
        folder = write_case_folder(
            self.work_dir / f"P{patient}_s{start}{tag}_r{r_min_mm:g}",
            self.obstacle_files[patient],
            world_T_tip,
            target_mm,
            {**self.needle, "r_min_mm": float(r_min_mm)},
        )
        if self.warm_up is None:  # numba kernels compiled or loaded from their cache
            t0 = time.perf_counter()
            solve(min(WARM_UP_S, self.budget_s))
            self.warm_up = {"wall_s": time.perf_counter() - t0, "loadavg": _load()}
        order = ("app", "needlekit") if len(self.rows) % 2 == 0 else ("needlekit", "app")
        row: dict[str, Any] = {"patient": patient, "start": start, "r_min_mm": float(r_min_mm),
                               "target_mm": [float(v) for v in np.asarray(target_mm).reshape(3)],
                               "order": "+".join(order)}  # fmt: skip
        if sample is not None:
            row["sample"] = int(sample)
        result = None
        for who in order:
            load = _load()
            if who == "app":
                row["app"] = _app_figures(run_reference_app(self.app, folder, self.budget_s))
                row["app"]["loadavg"] = load
            else:
                result = solve(self.budget_s)
                row["needlekit"] = _needlekit_figures(result) | {"loadavg": load}
        self.rows.append(_compared(row))
        return result

    def record(self) -> dict[str, Any]:
        """Everything recorded so far.

        Returns
        -------
        dict
            ``inputs`` (app, arguments, work folder, budget, crop and shell), ``patients``
            (each obstacle file: crop, voxel counts, time to write), ``warm_up``, ``rows``
            (one per case: ``target_mm``, ``sample`` for a sampled target, ``order``,
            ``app`` and ``needlekit`` figures with ``loadavg``,
            ``verdicts_agree``, ``cost_difference_mm`` and the ``ratio_*`` figures) and
            ``summary`` (:func:`comparison_summary`).
        """
        return {
            "inputs": {
                "app": str(self.app),
                "arguments": list(APP_ARGUMENTS),
                "work_dir": str(self.work_dir),
                "budget_s": self.budget_s,
                "crop_margin_mm": CROP_MARGIN_MM,
                "shell_mm": SHELL_MM,
                "exhausted_below_fraction_of_budget": EXHAUSTED_FRACTION,
                "cost_agreement_mm": COST_AGREEMENT_MM,
            },
            "patients": self.patients,
            "warm_up": self.warm_up,
            "rows": self.rows,
            "summary": comparison_summary(self.rows),
        }


def _median(values: list[float]) -> dict[str, Any] | None:
    if not values:
        return None
    return {"median": statistics.median(values), "n": len(values),
            "min": min(values), "max": max(values)}  # fmt: skip


def _case_name(row: dict[str, Any]) -> str:
    sample = f" t{row['sample']}" if row.get("sample") is not None else ""
    return f"P{row['patient']} s{row['start']}{sample} r{row['r_min_mm']:g}"


def comparison_summary(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """Medians and agreement over the compared cases.

    Parameters
    ----------
    rows : list of dict
        :attr:`ReferenceComparison.rows`.

    Returns
    -------
    dict
        ``cases``; ``verdicts_agree`` (``"k/n"``) and ``verdict_disagreements`` (case
        names); ``costs_agree`` (``"k/n"`` over the cases both certified, within
        :data:`COST_AGREEMENT_MM`) and ``max_abs_cost_difference_mm`` (over the cases both
        solved); ``ratio_time_to_certified`` (needlekit / app over the cases both
        certified), ``ratio_first_solution`` (over the cases both solved) and
        ``ratio_us_per_iteration``, each ``{median, n, min, max}`` or None;
        ``median_us_per_iteration`` per side; ``loadavg_1min`` (lowest, highest).
    """
    both_cert = [r for r in rows
                 if r["app"]["verdict"] == r["needlekit"]["verdict"] == "certified"]  # fmt: skip
    diffs = [abs(r["cost_difference_mm"]) for r in rows if r["cost_difference_mm"] is not None]
    loads = [r[w]["loadavg"][0] for r in rows for w in ("app", "needlekit")]

    def per_iteration(side):
        v = [r[side]["us_per_iteration"] for r in rows if r[side]["us_per_iteration"] is not None]
        return statistics.median(v) if v else None

    return {
        "cases": len(rows),
        "verdicts_agree": f"{sum(r['verdicts_agree'] for r in rows)}/{len(rows)}",
        "verdict_disagreements": [_case_name(r) for r in rows if not r["verdicts_agree"]],
        "costs_agree": f"{sum(abs(r['cost_difference_mm']) <= COST_AGREEMENT_MM for r in both_cert)}"
        f"/{len(both_cert)}",
        "max_abs_cost_difference_mm": max(diffs) if diffs else None,
        "ratio_time_to_certified": _median(
            [r["ratio_time_to_certified"] for r in both_cert if r["ratio_time_to_certified"]]
        ),
        "ratio_first_solution": _median(
            [r["ratio_first_solution"] for r in rows if r["ratio_first_solution"] is not None]
        ),
        "ratio_us_per_iteration": _median(
            [r["ratio_us_per_iteration"] for r in rows if r["ratio_us_per_iteration"] is not None]
        ),
        "median_us_per_iteration": {
            "app": per_iteration("app"),
            "needlekit": per_iteration("needlekit"),
        },
        "loadavg_1min": [min(loads), max(loads)] if loads else None,
    }


def _ms(x) -> str:
    return "-" if x is None else f"{1000 * x:.1f}"


def _count(x) -> str:
    return "-" if x is None else str(x)


def _num(x, spec: str = ".4f") -> str:
    return "-" if x is None else format(x, spec)


#: Columns of :func:`format_comparison`'s table.
TABLE_HEADER = (
    "| case | order | app | app cost | app first ms | app end ms | app it | nk | nk cost | "
    "nk first ms | nk time ms | nk it | nk/app cert. | nk/app first | nk/app us/it | load app/nk |"
)


def format_comparison(comparison: dict[str, Any]) -> str:
    """The comparison as a Markdown table and its medians (for the terminal).

    Parameters
    ----------
    comparison : dict
        :meth:`ReferenceComparison.record`.

    Returns
    -------
    str
    """
    lines = [TABLE_HEADER, "|" + "---|" * (TABLE_HEADER.count("|") - 1)]
    for r in comparison["rows"]:
        a, n = r["app"], r["needlekit"]
        app_status = a["status"] + (f": {a['reason']}" if a["reason"] else "")
        lines.append(
            f"| {_case_name(r)} | {r['order']} | {app_status} | {_num(a['cost_mm'])} | "
            f"{_ms(a['first_solution_s'])} | {_ms(a['solve_s'])} | {_count(a['iterations'])} | "
            f"{n['verdict']} | {_num(n['cost_mm'])} | {_ms(n['first_solution_s'])} | "
            f"{_ms(n['time_s'])} | {_count(n['iterations'])} | "
            f"{_num(r['ratio_time_to_certified'], '.2f')} | "
            f"{_num(r['ratio_first_solution'], '.2f')} | "
            f"{_num(r['ratio_us_per_iteration'], '.2f')} | "
            f"{a['loadavg'][0]:.2f}/{n['loadavg'][0]:.2f} |"
        )
    s = comparison["summary"]

    def med(key):
        m = s[key]
        return "n/a" if m is None else (
            f"{m['median']:.2f} (n={m['n']}, {m['min']:.2f}-{m['max']:.2f})")  # fmt: skip

    lines += [
        f"needlekit / app, time to certified (both certified): {med('ratio_time_to_certified')}",
        f"needlekit / app, first solution (both solved): {med('ratio_first_solution')}",
        f"needlekit / app, us per iteration: {med('ratio_us_per_iteration')}",
        f"verdicts agree {s['verdicts_agree']}, costs agree {s['costs_agree']} "
        f"(both certified, within {COST_AGREEMENT_MM:g} mm), largest cost difference "
        f"{_num(s['max_abs_cost_difference_mm'], '.2g')} mm",
    ]
    return "\n".join(lines)
