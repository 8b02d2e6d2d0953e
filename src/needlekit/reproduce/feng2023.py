"""Feng et al. 2023 re-run: the effective-puncture-region sweep on a Med-RAD lung.

Feng et al. print their start and goals but not their lung obstacles, so their case cannot
be rerun; their protocol can (:mod:`needlekit.studies.feng_lungs`): one start point, 544
candidate directions, those at least alpha = 20 deg off the punctured surface effective,
RCS*, RCS and RRT for 1 s from each, to two targets, with their needle. Compared with the
paper: what its Table 4 and text claim of the planners (the order of the mean costs, RCS*
cheapest in mean and best cost), the counts beside theirs, and every path checked.

Needs the Med-RAD data (``$NEEDLEKIT_MEDRAD`` or ``../shared/data/med-rad``).
"""

from __future__ import annotations

import os
from pathlib import Path

from needlekit.report.html_page import TextSection
from needlekit.reproduce._page import Reproduction, Stages
from needlekit.studies.feng_lungs import run_feng_lungs
from needlekit.studies.feng_timing import timing_verdict

__all__ = ["run"]

CITATION = (
    "Feng et al., 'Path planning of flexible needles based on the effective puncture "
    "region' (RRT, RCS and RCS*; minimum puncture angle; effective puncture region), 2023"
)
_LABELS = {"rcs": "RCS", "rcs_star": "RCS*", "rrt": "RRT"}
_GOALS = {"goal1": "goal 1", "goal2": "goal 2"}


def _claims(record: dict) -> list[dict]:
    """Feng's claims about the planners, per target, beside what the run measured."""
    feng = record["feng"]["table4"]
    rows = []
    for g, rec in record["goals"].items():
        t4 = rec["table4"]
        means = {k: v["mean_cost_mm"] for k, v in t4.items()}
        bests = {k: v["best_cost_mm"] for k, v in t4.items()}
        fm = {k: v["mean_cost_mm"] for k, v in feng[g].items()}
        name = _GOALS[g]
        order = rec["order"]
        rows.append(
            {
                "quantity": f"{name}: order of the mean costs",
                "paper": " < ".join(f"{_LABELS[k]} {fm[k]:.3f}" for k in record["feng"]["order"]),
                "needlekit": "-"
                if order is None
                else " < ".join(f"{_LABELS[k]} {means[k]:.3f}" for k in order),
                "agrees": "yes" if rec["order_holds"] else "no",
                "note": "mm, over each planner's own solved directions (as Feng's)",
            }
        )
        solved = [k for k, v in means.items() if v is not None]
        lowest_mean = min(solved, key=lambda k: means[k]) if solved else None
        rows.append(
            {
                "quantity": f"{name}: RCS* has the lowest mean cost",
                "paper": "yes",
                "needlekit": "-" if lowest_mean is None else f"{_LABELS[lowest_mean]} lowest",
                "agrees": "yes" if lowest_mean == "rcs_star" else "no",
                "note": "",
            }
        )
        solved_b = [k for k, v in bests.items() if v is not None]
        lowest_best = min(solved_b, key=lambda k: bests[k]) if solved_b else None
        fb = {k: v["best_cost_mm"] for k, v in feng[g].items()}
        rows.append(
            {
                "quantity": f"{name}: RCS* has the lowest best cost",
                "paper": f"yes ({', '.join(f'{_LABELS[k]} {v:.3f}' for k, v in fb.items())})",
                "needlekit": "-"
                if lowest_best is None
                else f"{_LABELS[lowest_best]} lowest ("
                + ", ".join(f"{_LABELS[k]} {bests[k]:.3f}" for k in solved_b)
                + ")",
                "agrees": "yes" if lowest_best == "rcs_star" else "no",
                "note": "mm",
            }
        )
        rows.append(
            {
                "quantity": f"{name}: directions solved (RCS*, RCS, RRT)",
                "paper": ", ".join(str(feng[g][k]["n_solved"]) for k in ("rcs_star", "rcs", "rrt")),
                "needlekit": ", ".join(str(t4[k]["n_solved"]) for k in ("rcs_star", "rcs", "rrt"))
                + f" of {t4['rcs_star']['n_effective']} effective",
                "agrees": "-",
                "note": "different anatomy and directions: the counts are not comparable",
            }
        )
        d = rec["direct"]
        blocked, valid = d.get("collision", 0), d.get("valid", 0)
        rows.append(
            {
                "quantity": f"{name}: paths bend around obstacles",
                "paper": "yes (Fig. 7)",
                "needlekit": f"the direct turn-then-straight is blocked from {blocked} "
                f"of {blocked + valid} directions that can reach the target",
                "agrees": "yes" if blocked > valid else "no",
                "note": "direct connection through the independent check",
            }
        )
    checked = [
        (c["solved"], c["passed"])
        for rec in record["goals"].values()
        for c in rec["checks"].values()
    ]
    n, ok = sum(a for a, _ in checked), sum(b for _, b in checked)
    rows.append(
        {
            "quantity": "every solved path passes the independent check",
            "paper": "-",
            "needlekit": f"{ok} of {n}",
            "agrees": "-",
            "note": "certified clearance, puncture angle, heading, length, goal, cost",
        }
    )
    return rows


def run(out_dir: str | os.PathLike, *, quick: bool = False, executor=None, progress=print):
    """Run Feng's protocol on the Med-RAD lung; see the module's docstring.

    Parameters
    ----------
    out_dir : path-like
        The study lands in ``out_dir/feng2023/`` (``goal1/``, ``goal2/``,
        ``feng_lungs.json``).
    quick : bool
        136 directions and 300 iterations per direction (the same on every machine).
    executor : concurrent.futures.Executor, optional
        Runs the directions.
    progress : callable

    Returns
    -------
    Reproduction
    """
    from needlekit.report.feng_lungs_report import differences_from_feng, feng_lungs_sections

    stage = Stages(progress, 1, "feng2023")

    bars: list = []

    def sweep_progress(label: str):  # one batch: every target and planner at once
        stage(f"sweep {label}")
        bars.append(stage.bar(label, unit="dir"))
        return bars[-1]

    study = run_feng_lungs(
        Path(out_dir) / "feng2023",
        quick=quick,
        executor=executor,
        progress=sweep_progress,
        report=False,
    )
    for b in bars:
        b.close()
    record = study.record
    s, n = record["settings"], record["settings"]["needle"]
    checks = [c for rec in record["goals"].values() for c in rec["checks"].values()]
    checks_ok = all(c["passed"] == c["solved"] for c in checks)
    setup = [
        {"item": "anatomy", "paper": "their lung CT: vessels, bronchi, bone (not published)",
         "needlekit": record["case"]["medrad"] + ": bronchial tree, vessels, fissures"},
        {"item": "start", "paper": "(-64.83, 139.49, -654.10) mm, their frame",
         "needlekit": "Med-RAD start pose 1's point, its direction swept"},
        {"item": "goals", "paper": "goal 2 = goal 1 + (-10, -10, 10) mm",
         "needlekit": "Med-RAD's target; it + (-10, -10, 10) mm (RAS)"},
        {"item": "needle", "paper": "2 mm, r_min 50 mm, l_max 100 mm",
         "needlekit": f"{n['diameter_mm']:g} mm, r_min {n['r_min_mm']:g} mm, l_max "
         f"{n['max_length_mm']:g} mm"},
        {"item": "minimum puncture angle alpha", "paper": "20 deg",
         "needlekit": f"{n['min_puncture_angle_deg']:g} deg"},
        {"item": "goal tolerance tau", "paper": "1 mm", "needlekit": f"{s['tolerance_mm']:g} mm"},
        {"item": "directions", "paper": "544", "needlekit": str(s["directions"])},
        {"item": "budget per direction", "paper": "1 s",
         "needlekit": f"{s['time_limit_s']:g} s"
         + ("" if s["max_iterations"] is None else f" or {s['max_iterations']} iterations")},
        {"item": "planners", "paper": "RRT, RCS, RCS* (their implementation)",
         "needlekit": "RRT (goal by one arc), RCS, RCS* (needlekit's)"},
    ]  # fmt: skip
    deviations = differences_from_feng(record)
    if quick:
        deviations.insert(0, f"Quick run: {s['directions']} directions and "
                          f"{s['max_iterations']} iterations per direction, not Feng's 544 "
                          "directions at 1 s.")  # fmt: skip
    t = record["timing"]
    sections = [
        TextSection(
            "The study in full: Table 4 beside Feng's, the order of the mean costs, the "
            "targets, the direct connections, the checks, then per target Tables 2-3 and "
            "Figs. 7, 8 and 9.",
            heading="Feng's protocol on a Med-RAD lung",
        ),
        TextSection(
            f"{timing_verdict(t)}. The bound: the planners' own time shared by the workers, "
            f"{t['bound_factor']:g} times, plus one preparation of the patient per worker. "
            f"Runs' set-up outside their clocks {t['setup_s_sum']:.1f} s in sum; checks "
            f"{t['post_s']:.1f} s; files {t['write_s']:.1f} s.",
            heading="Where the time went",
        ),
        *feng_lungs_sections(record, study.sweeps, study.problems, study.options),
    ]
    commands = [
        "needlekit study feng-lungs --out out/feng-lungs --workers 2",
        "needlekit study feng-lungs --out out/feng-lungs --dask-workers 2",
        "needlekit study feng-lungs --out out/feng-quick --quick",
        "needlekit sweep examples/medrad_lung_feng_goal1.yaml --planner rcs_star rcs rrt "
        "--time-limit-s 1 --rrt-connection arc --out sweep.json --report sweep.html",
    ]
    return Reproduction(
        key="feng2023",
        title="Reproducing Feng et al. 2023: the effective puncture region on a real lung",
        citation=CITATION,
        quick=quick,
        summary=(
            "Feng et al.'s protocol (Algorithm 1, Tables 2-4, Figs. 7-9) on real anatomy: "
            "their needle, 544 start directions at one start point, RCS*, RCS and RRT from "
            "each effective direction, to two targets. Their lung obstacles are not public, "
            "so the case is a Med-RAD lung; their claims about the planners are compared, "
            "their numbers listed beside ours."
        ),
        comparisons=_claims(record),
        setup=setup,
        deviations=deviations,
        sections=sections,
        commands=commands,
        record={"checks_ok": checks_ok, "study": record},
        files=dict(study.files),
    )
