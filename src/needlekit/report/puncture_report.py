"""The puncture study's report: figures like Tang et al.'s Fig. 4 (the puncture of example
trials against the guide cylinder and cone) and Fig. 5 (the adaptation of the base and
needle estimates), the distribution of the final errors, and the comparison with the paper.
The figures are drawn in :mod:`needlekit.report.puncture_figures` (re-exported here).
"""

from __future__ import annotations

import math
import os
from pathlib import Path

from needlekit.report.html_page import FigureSection, TableSection, TextSection, write_report_html
from needlekit.report.puncture_figures import (
    _examples,
    adaptation_figure,
    error_histograms_figure,
    neck_figure,
    puncture_figure,
    start_and_angle_figure,
)

__all__ = [
    "adaptation_figure",
    "error_histograms_figure",
    "neck_figure",
    "puncture_figure",
    "puncture_sections",
    "start_and_angle_figure",
    "write_puncture_report",
]


#: The report page's title.
TITLE = "Robotic needle puncture: simulation study (Tang et al., Section III)"

_PAPER_TRIALS = 100  # Tang et al., Section III-B: the simulation was run 100 times

_REASON_WORDS = {
    "inside_patient_cylinder": "start point inside the patient cylinder",
    "wrist_too_close": "wrist too close to the shoulder",
    "wrist_too_far": "wrist beyond the arm's reach",
}


def _comparison_rows(summary: dict) -> list[dict]:
    rows = []
    for key, what in (("position_error_mm", "position error"), ("angle_error_deg", "angle")):
        unit = "mm" if key.endswith("mm") else "deg"
        for source, st in (("needlekit", summary[key]), ("Tang et al.", summary["paper"][key])):
            rows.append(
                {
                    "quantity": what,
                    "source": source,
                    f"mean_{unit}": st["mean"],
                    f"sd_{unit}": st["sd"],
                    f"min_{unit}": st["min"],
                    f"max_{unit}": st["max"],
                }
            )
    return rows


def _min_sample_sd(lo: float, hi: float, n: int) -> float:
    """The smallest sample SD (ddof 1) of ``n`` values with minimum ``lo`` and maximum
    ``hi``: two at the ends and the others at the midpoint."""
    return (hi - lo) / 2.0 * math.sqrt(2.0 / (n - 1))


def _angle_sd_note(paper: dict) -> str:
    a = paper["angle_error_deg"]
    least = _min_sample_sd(a["min"], a["max"], _PAPER_TRIALS)
    return (
        f"Tang et al.'s figures are shown as printed, but their angle SD ({a['sd']} deg) "
        f"cannot go with their range ({a['min']}-{a['max']} deg): {_PAPER_TRIALS} values "
        f"spanning {a['max'] - a['min']:.2f} deg have a sample SD of at least {least:.4f} deg "
        f"(two at the ends, the others at the midpoint), so the SD or the range is misprinted."
    )


def _reasons(by_reason: dict) -> str:
    return ", ".join(f"{n} {r}" for r, n in by_reason.items()) or "none"


def _redraw_sections(summary: dict) -> list:
    """The guide-line filter: its rule, what it did in this run (and, without redraws, the
    trials that kept a refused line), and its refusal rate on its own."""
    from needlekit.control.controller import ControllerSettings

    g, f = summary.get("guide_redraws"), summary.get("redraw_filter")
    if g is None or f is None:  # written before the filter was reported
        return []
    sc = summary["scenario"]
    rule = (
        f"Not in the paper: the study draws a trial's guide line again while its start point "
        f"{sc['start_distance_mm']:g} mm out lies inside the patient cylinder (radius "
        f"{ControllerSettings().patient_radius_mm:g} mm about the patient axis through the "
        f"target), or puts the arm's wrist closer than {sc['min_wrist_reach_mm']:g} mm to its "
        f"shoulder or farther than {sc['max_wrist_reach_mm']:g} mm (checked in that order; a "
        f"refused line counts under the first that holds)."
    )
    r, first = g["refused_draws"], g["first_line_refused"]
    counts = ", ".join(f"{r[k]} {w}" for k, w in _REASON_WORDS.items())
    if g["enabled"]:
        run = (
            f" In this run {g['trials_redrawn']} of {g['trials']} trials needed redraws: "
            f"{g['draws']} lines drawn, {r['total']} refused ({counts})."
        )
    else:
        kept, ok = g["kept_refused_line"], g["acceptable_first_line"]
        first_counts = ", ".join(f"{first[k]} {w}" for k, w in _REASON_WORDS.items())
        run = (
            f" This run did not redraw (--no-redraw): {kept['count']} of {g['trials']} trials "
            f"kept a first line the filter refuses ({first_counts}), and "
            f"{kept['aborted']['count']} of them aborted ({_reasons(kept['aborted']['by_reason'])}"
            f"); of the {ok['count']} trials with an acceptable line, {ok['aborted']['count']} "
            f"aborted ({_reasons(ok['aborted']['by_reason'])})."
        )
    a = f["all"]
    alone = (
        f" The filter on its own ({f['draws_per_octant']} random lines per octant, targets in "
        f"the target cube, seed {f['seed']}, no simulation) refuses {a['refusal_rate']:.1%} "
        f"of lines ({a['inside_patient_cylinder'] / a['draws']:.1%} inside the cylinder, "
        f"{a['wrist_too_close'] / a['draws']:.1%} wrist too close, "
        f"{a['wrist_too_far'] / a['draws']:.1%} wrist too far): without redraws that share "
        f"of trials keeps a refused line, and with them a trial takes "
        f"{a['expected_draws_per_trial']:.1f} draws on average."
    )
    octants = [
        {
            "octant": o["octant"],
            "refused_%": 100.0 * o["refusal_rate"],
            "inside_cylinder_%": 100.0 * o["inside_patient_cylinder"] / o["draws"],
            "wrist_too_close_%": 100.0 * o["wrist_too_close"] / o["draws"],
            "wrist_too_far_%": 100.0 * o["wrist_too_far"] / o["draws"],
            "draws_per_trial": o["expected_draws_per_trial"],
        }
        for o in f["octants"]
    ]
    octant_caption = "Octants in trial order (trial i takes octant i mod 4)."
    exact = f.get("inside_patient_cylinder_exact_share")
    if exact is not None:
        octant_caption += (
            f" Exactly {exact:.1%} of lines in every octant put the start point inside the "
            f"patient cylinder (the share depends on the line's direction alone)."
        )
    outcomes = [
        {
            "first line": "acceptable" if v == "acceptable" else f"refused: {_REASON_WORDS[v]}",
            "trials": o["count"],
            "completed": o["completed"],
            "aborted": o["aborted"]["count"],
            "abort reasons": _reasons(o["aborted"]["by_reason"]),
        }
        for v, o in g["by_first_line"].items()
        if o["count"]
    ]
    return [
        TextSection(rule + run + alone, heading="Guide-line redraws"),
        TableSection(
            "The guide-line filter on its own, per octant",
            octants,
            octant_caption,
        ),
        TableSection(
            "Outcomes by the verdict on each trial's first guide line",
            outcomes,
            (
                "The refused first lines were redrawn: those trials ran with an acceptable one."
                if g["enabled"]
                else "Without redraws each trial ran with its first line."
            ),
        ),
    ]


def _start_and_angle_caption(trials: list[dict], summary: dict) -> str:
    starts = "; ".join(
        f"trial {t['trial']} at {t['phase_times_s']['puncture']:.1f} s" for t in _examples(trials)
    )
    d = summary["scenario"]["start_distance_mm"]
    return (
        f"The same example trials as Fig. 5 (A, B), from the start: the arm stands still while "
        f"the estimate adapts, turns the needle onto the guide line, brings the tip to the start "
        f"point {d:g} mm out, waits there until the estimate agrees with the needle sensor, and "
        f"punctures (dotted vertical lines; (C) then climbs to {d:g} mm). The 0.5 deg bound "
        f"applies from the puncture's first step: needlekit's controller adds the cone VFI in "
        f"the puncture step only (Phase.PUNCTURE of control.procedure, step_vfis in "
        f"control.controller), as Tang et al. constrain the needle in their step 3. Their "
        f"Fig. 5 applies it from 15 s; here each trial reaches the puncture at its own time "
        f"({starts}). The controller steers its estimate of the tip and needle towards the "
        f"guide line it measured (one noisy bronchoscope sample), while these curves are the "
        f"real tip and needle against the real line: (C) settles at the estimation and "
        f"measurement errors rather than at zero, and (D) may pass the bound by them."
    )


def puncture_sections(summary: dict, trials: list[dict]) -> list:
    """The report's sections (figures, tables, text).

    Parameters
    ----------
    summary : dict
        The study summary (``puncture.json`` without ``per_trial``).
    trials : list of dict

    Returns
    -------
    list
    """
    v = summary["constraint_violations"]
    opts = summary["options"]
    text = (
        f"{summary['trials']} trials (seed {summary['seed']}): {summary['completed']} completed, "
        f"{summary['aborted']['count']} aborted; {v['total']} constraint violations beyond "
        f"the measurement noise ({v['tolerance']['position_mm']} mm, "
        f"{v['tolerance']['angle_deg']} deg). Sensors "
        f"{'exact' if opts['exact_sensors'] else 'noisy (1 mm, 0.2 deg, 100 Hz)'}, "
        f"stability radius {opts['stability_radius_mm']} mm, "
        f"{opts['history_keyframes']} measurement keyframes, guide line from "
        f"{opts['guide_samples'] or 'all'} bronchoscope sample"
        f"{'' if opts['guide_samples'] == 1 else 's'}. Constraints are checked on the real tip "
        f"and needle from the start of the puncture."
    )
    reached = summary.get("reached_target")
    if reached is not None:
        text += (
            f" Target reached (within the target tolerance): {reached['estimated']} by the "
            f"robot's estimate, {reached['real']} by the real tip."
        )
    viol = [
        {
            "constraint": k,
            "violations": v[k]["count"],
            "trials": ", ".join(map(str, v[k]["trials"])),
        }
        for k in ("guide_cylinder", "cone", "plane", "patient_cylinder")
    ]
    sections = [
        TextSection(text),
        TableSection(
            "Final errors beside Tang et al. (Section III-B)",
            _comparison_rows(summary),
            _angle_sd_note(summary["paper"]),
        ),
        FigureSection(
            "Final errors",
            error_histograms_figure(trials, summary["paper"]),
            "The angle's shaded band is the paper's mean +- SD as printed (see the note on "
            "its SD under the table above).",
        ),
        FigureSection(
            "The puncture (like Fig. 4)",
            puncture_figure(trials),
            "Example trials, one per octant of guide directions. Dotted lines: the guide "
            "cylinder's radius and the cone's half-angle. The VFIs act on the estimate; the "
            "curves are the real robot's.",
        ),
        FigureSection(
            "The adaptation (like Fig. 5 A and B)",
            adaptation_figure(trials),
            "Errors of the estimated base (transmitter to base) and needle tip (flange to tip) "
            "against the truth, over whole trials.",
        ),
    ]
    if _examples(trials):
        sections.append(
            FigureSection(
                "The start point and the needle angle (like Fig. 5 C and D)",
                start_and_angle_figure(
                    trials, start_distance_mm=summary["scenario"]["start_distance_mm"]
                ),
                _start_and_angle_caption(trials, summary),
            )
        )
    if any("tip_mm" in t.get("log", {}) for t in trials):
        sections.append(
            FigureSection(
                "The punctures in the neck phantom",
                neck_figure(trials),
                "The real tip paths of the example trials, each carried rigidly onto the "
                "phantom's guide line (between two tracheal rings below the thyroid isthmus, "
                "to the middle of the trachea).",
            )
        )
    sections.append(TableSection("Constraint violations beyond the measurement noise", viol))
    sections += _redraw_sections(summary)
    if summary["aborted"]["count"]:
        sections.append(TableSection("Aborted trials", summary["aborted"]["trials"]))
    return sections


def write_puncture_report(path: str | os.PathLike, summary: dict, trials: list[dict]) -> Path:
    """Write the study's report page atomically.

    Parameters
    ----------
    path : path-like
    summary : dict
    trials : list of dict

    Returns
    -------
    Path
    """
    return write_report_html(path, title=TITLE, sections=puncture_sections(summary, trials))
