"""The closed loop on the Med-RAD lungs (``needlekit study execute-lungs``).

For each lung (start 1 to its target; the needle and the exact voxel-centre test of
``examples/medrad_lung1.yaml``):

1. **The margin the noise asks for.** RCS* plans with no margin; a pilot of closed-loop
   trials (their own seeds, never a trial's) carries that plan out and measures how far
   the true tip strays from the plan it follows (``cross_track_mm`` at every recorded
   point). The margin wanted is :func:`~needlekit.execute.replan.noise_margin_mm` of that
   deviation's RMS for the stated crossing probability (per recorded point; default
   0.001, ``k = 3.09``).
2. **The margin the anatomy allows.** RCS* plans again with the margin wanted, rounded up
   to 0.05 mm, then 0.1 mm less each time, down to none, until it solves: a tight
   passage (a transbronchial start on the airway wall, a vessel beside the path) may not
   leave room for the whole margin. Both are written per case.
3. **The study.** ``DIR/lungN/scenario.yaml`` (with the margin) and ``plan.json`` are
   written, and the trials run exactly as ``needlekit execute DIR/lungN/scenario.yaml
   DIR/lungN/plan.json --trials T --seed S --out DIR/lungN`` runs them
   (:func:`~needlekit.execute.trials.run_execute_study`), into
   ``DIR/lungN/execute.json``.

``DIR/execute_lungs.json`` gathers the cases and judges each against the closed loop's targets:
closed-loop mean error at most 0.5 mm, at least 95 % of trials within 1 mm, no obstacle
crossed (open or closed loop figures beside them, judged on nothing).

With a needle that bends by mechanics (``physics``), steps 1 and 2 are those of
:mod:`needlekit.studies.execute_lungs_physical` (a start and start direction the needle can
reach from, the largest margin kept), the loop's model is calibrated on the needle in each
lung, and the goal is that module's.
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np
import yaml

from needlekit import __version__
from needlekit.errors import INTERRUPT_FORMS, Interrupted, InvalidInputError, is_interrupt
from needlekit.execute.physical_setup import physical_settings
from needlekit.execute.replan import noise_margin_mm
from needlekit.execute.trials import (
    EXECUTE_FILE,
    ExecuteOptions,
    read_partial_execute,
    run_execute_study,
    run_execute_trial,
)
from needlekit.io.files import write_json, write_text
from needlekit.io.partial import partial_path, read_partial, write_partial
from needlekit.io.plans import write_plan_json
from needlekit.planning.steerable.plan import SteerablePlan
from needlekit.planning.steerable.rcs import solve_rcs
from needlekit.scenario.problems import ScenarioSource
from needlekit.studies.execute_lungs_physical import (
    choose_physical_plan,
    physical_scenario_document,
    physical_verdict,
    write_physical_case,
)

__all__ = [
    "CROSSING_PROBABILITY",
    "LUNG_R_MIN_MM",
    "PILOT_KEY",
    "TARGETS",
    "lung_scenario_document",
    "pilot_deviation",
    "plan_with_margin",
    "run_execute_lungs",
]

#: The study's record in its --out folder.
LUNGS_FILE = "execute_lungs.json"
#: The closed loop's targets on the five lungs.
TARGETS = {"closed_mean_error_mm": 0.5, "closed_within_1mm": 0.95, "crossed": 0}
#: The crossing probability (per recorded point) the margin wanted is set for.
CROSSING_PROBABILITY: float = 0.001
#: The pilot's seeds: ``SeedSequence(seed, spawn_key=(PILOT_KEY, k))`` (a trial's has
#: one key, so they never meet).
PILOT_KEY: int = 0x9170
#: The steps the margin comes down by when the anatomy does not leave room (mm).
MARGIN_STEP_MM: float = 0.1
#: RCS*'s budget for each plan of the study (s).
PLAN_TIME_LIMIT_S: float = 1.0


#: The needle of the lung scenarios (:func:`lung_scenario_document`): its r_min (mm).
LUNG_R_MIN_MM: float = 50.0


def lung_scenario_document(patient: int, margin_mm: float, medrad_dir=None) -> dict:
    """The scenario of Med-RAD lung ``patient``, start 1, to its target, as
    ``examples/medrad_lung1.yaml`` has it for patient 1 (the reference planner's needle and
    exact voxel-centre test), with a clearance margin.

    Parameters
    ----------
    patient : int
    margin_mm : float
        ``needle.safety_margin_mm``.
    medrad_dir : path-like, optional
        The Med-RAD folder (default: ``$NEEDLEKIT_MEDRAD`` or ``../shared/data/med-rad``).

    Returns
    -------
    dict
        A scenario document (:class:`~needlekit.scenario.problems.ScenarioSource.of_document`).
    """
    return physical_scenario_document(patient, 1, margin_mm, LUNG_R_MIN_MM, medrad_dir)


def pilot_deviation(problem, truth, plan, options: ExecuteOptions, seed: int, trials: int) -> float:
    """The RMS of the true tip's distance from the plan it follows, over closed-loop pilot
    trials.

    Parameters
    ----------
    problem, truth : SteerableProblem
        The problem (re-plans) and its margin-free twin (as for
        :func:`~needlekit.execute.trials.run_execute_trial`).
    plan : SteerablePlan
    options : ExecuteOptions
    seed, trials : int

    Returns
    -------
    float
        mm. Without injected faults (``settings.faults``): the margin is the noise's, and a
        fault holds the needle rather than widening its path.
    """
    if options.settings.faults is not None:
        options = replace(options, settings=replace(options.settings, faults=None))
    squares = []
    for k in range(trials):
        ss = np.random.SeedSequence(seed, spawn_key=(PILOT_KEY, k))
        rec = run_execute_trial(problem, truth, plan, ss, options, loops=("closed_loop",))
        squares += [d * d for d in rec.closed_loop.cross_track_mm]
    return math.sqrt(sum(squares) / len(squares)) if squares else 0.0


def plan_with_margin(patient: int, wanted_mm: float, medrad_dir=None):
    """Plan lung ``patient`` with the largest margin up to ``wanted_mm`` that RCS* solves.

    Parameters
    ----------
    patient : int
    wanted_mm : float
    medrad_dir : path-like, optional

    Returns
    -------
    (float, dict, ScenarioSource, PlanResult)
        The margin kept, the scenario document, its source and the plan (the last one
        tried, margin 0, when none solves).
    """
    top = math.ceil(wanted_mm / 0.05 - 1e-9) * 0.05
    margins = [round(top - i * MARGIN_STEP_MM, 4) for i in range(int(top / MARGIN_STEP_MM) + 1)]
    if margins[-1] > 0.0:
        margins.append(0.0)
    for m in margins:
        doc = lung_scenario_document(patient, m, medrad_dir)
        source = ScenarioSource.of_document(doc, ".", name=f"lung{patient}.yaml")
        _, problem = source.cached()
        res = solve_rcs(problem, time_limit_s=PLAN_TIME_LIMIT_S)
        if res.status.value == "solved":
            break
    return m, doc, source, res


@dataclass
class _Study:
    """What every case of one run shares."""

    out: Path
    trials: int
    seed: int
    options: ExecuteOptions
    executor: object
    progress: Callable | None
    medrad_dir: object
    pilot_trials: int
    crossing_probability: float
    physics: object = None  # PhysicalLungs, or None: the kinematic study
    say: Callable | None = None


def _decide(st: _Study, patient: int) -> dict:
    """The margin and the plan of one lung (steps 1 and 2), its files written."""
    if st.physics is not None:
        decided, doc, res = choose_physical_plan(patient, st.physics, executor=st.executor,
                                                 medrad_dir=st.medrad_dir, say=st.say)  # fmt: skip
        if res is None:
            return decided
        return write_physical_case(st.out / f"lung{patient}", decided, doc, res)
    doc0 = lung_scenario_document(patient, 0.0, st.medrad_dir)
    _, problem0 = ScenarioSource.of_document(doc0, ".", name=f"lung{patient}.yaml").cached()
    res0 = solve_rcs(problem0, time_limit_s=PLAN_TIME_LIMIT_S)
    if res0.status.value != "solved":
        return {"patient": patient, "status": res0.status.value,
                "reason": "no plan without a margin"}  # fmt: skip
    # no margin: the problem is its own margin-free twin
    sigma = pilot_deviation(problem0, problem0, res0.plan, st.options, st.seed, st.pilot_trials)
    wanted = noise_margin_mm(sigma, st.crossing_probability)
    margin, doc, _, res = plan_with_margin(patient, wanted, st.medrad_dir)
    if res.status.value != "solved":
        return {"patient": patient, "status": res.status.value,
                "reason": "no plan with the margin"}  # fmt: skip
    case_dir = st.out / f"lung{patient}"
    head = f"# Med-RAD lung {patient} (CC BY-NC-SA 4.0), written by needlekit study execute-lungs\n"
    write_text(case_dir / "scenario.yaml", head + yaml.safe_dump(doc, sort_keys=False))
    write_plan_json(case_dir / "plan.json", res, scenario="scenario.yaml")
    return {
        "patient": patient,
        "status": "planned",
        "plan_cost_mm": float(res.cost_mm),
        "plan_primitives": res.plan.primitives.tolist(),
        "pilot_cross_track_rms_mm": sigma,
        "margin_wanted_mm": wanted,
        "margin_mm": margin,
    }


def _run_case(st: _Study, decided: dict, resume: bool) -> dict:
    """The trials of one planned lung (step 3), carried on from its partial execute.json
    when ``resume``."""
    patient = decided["patient"]
    options = st.options
    if st.physics is None:
        doc = lung_scenario_document(patient, decided["margin_mm"], st.medrad_dir)
    else:
        doc = physical_scenario_document(patient, decided["start"], decided["margin_mm"],
                                         decided["r_min_mm"], st.medrad_dir)  # fmt: skip
    source = ScenarioSource.of_document(doc, ".", name=f"lung{patient}.yaml")
    scenario, problem = source.cached()
    start = decided.get("plan_start_pose", problem.start_pose)
    plan = SteerablePlan(np.asarray(start, dtype=np.float64), decided["plan_primitives"])
    if st.physics is not None:
        options = _physical_options(st, scenario, plan, problem)
        cal = options.settings.model
        if st.say is not None:
            st.say(f"lung {patient}: the loop's model calibrated on {cal.curved + cal.straight} "
                   f"insertions, r {cal.r_min_mm:.1f} mm, replay rms {cal.residual_rms_mm:.2f} mm")  # fmt: skip
    case_dir = st.out / f"lung{patient}"
    trials = list(range(st.trials))
    kept = None
    if resume and partial_path(case_dir / EXECUTE_FILE).exists():
        kept = read_partial_execute(case_dir, doc["name"], plan, st.seed, trials, options)
    study = run_execute_study(case_dir, source, plan, trials=trials, seed=st.seed,
                              options=options, executor=st.executor, progress=st.progress,
                              resume=kept, scenario_name=doc["name"])  # fmt: skip
    s = study.document["summary"]
    c, o = s["closed_loop"], s["open_loop"]
    if st.physics is None:
        verdict = {
            "closed_mean_error_mm": c["final_error_mm"].get("mean", math.inf)
            <= TARGETS["closed_mean_error_mm"],
            "closed_within_1mm": (c["within_1mm"] or 0.0) >= TARGETS["closed_within_1mm"],
            "crossed": c["violated"] == 0 and not s["crashed"],
        }
    else:
        verdict = physical_verdict(s, st.physics.judged)
    model = options.settings.model
    calibrated = {} if model is None else {"calibrated_r_mm": model.r_min_mm,
                                           "calibration_rms_mm": model.residual_rms_mm}  # fmt: skip
    sensing = {} if "sensing" not in s else {"sensing": {k: _sensed(v) for k, v in s["sensing"].items()}}
    return {
        **{k: v for k, v in decided.items() if k not in ("plan_primitives", "plan_start_pose")},
        **calibrated,
        **sensing,
        "status": "done",
        "closed_loop": _brief(c),
        "open_loop": _brief(o),
        **(
            {
                "breathing": {
                    k: _brief(v) | {"procedure_s": v["procedure_s"].get("mean")}
                    for k, v in s["breathing"].items()
                }
            }
            if "breathing" in s
            else {}
        ),
        "crashed": len(s["crashed"]),
        "verdict": verdict,
        "holds": all(verdict.values()),
        "execute_json": str(study.path.relative_to(st.out)),
    }


def _physical_options(st: _Study, scenario, plan, problem) -> ExecuteOptions:
    """The study's options with the needle, the lung and the loop's model calibrated on
    them (:func:`~needlekit.execute.physical_setup.physical_settings`)."""
    ph = st.physics
    settings = physical_settings(st.options.settings, scenario, plan, problem.goal_mm,
                                 1.0 / problem.kappa_max_per_mm, mechanics=ph.mechanics,
                                 boundary=ph.boundary, insertions=ph.calibration_insertions,
                                 seed=st.seed)  # fmt: skip
    return replace(st.options, settings=settings)


def _settings_record(patients, trials, seed, pilot_trials, crossing_probability, options,
                     physics=None) -> dict:  # fmt: skip
    """What a partial record holds besides its cases, and a resumed run must share."""
    return {
        "needlekit_version": __version__,
        "patients": list(patients),
        "trials": trials,
        "seed": seed,
        "pilot_trials": pilot_trials,
        "crossing_probability": crossing_probability,
        "targets": TARGETS if physics is None else physics.record()["targets"],
        "options": asdict(options),
        **({} if physics is None else {"physics": physics.record()}),
    }


def _sensed(run: dict) -> dict:
    """One sensing policy's closed loop in brief, with its scans, procedure time and how far
    the target moved (means over the trials)."""
    return _brief(run) | {
        "scans": run["scans"].get("mean"),
        "procedure_s": run["procedure_s"].get("mean"),
        "target_moved_mm": run["target_displacement_max_mm"].get("mean"),
    }


def _brief(loop: dict) -> dict:
    e = loop["final_error_mm"]
    return {
        "mean_error_mm": e.get("mean"),
        "sd_error_mm": e.get("sd"),
        "p95_error_mm": e.get("p95"),
        "max_error_mm": e.get("max"),
        "within_1mm": loop["within_1mm"],
        "violated": loop["violated"],
        "stopped_near_obstacle": loop.get("stopped_near_obstacle", 0),
        "min_clearance_mm": loop["min_clearance_mm"].get("min"),
        "replans_mean": loop["replans"].get("mean"),
        "replan_latency_p95_ms": loop["replan_latency_ms"].get("p95"),
        "cross_track_rms_mm": loop.get("cross_track_rms_mm"),
    }


def run_execute_lungs(
    out_dir: str | os.PathLike,
    *,
    patients=(1, 2, 3, 4, 5),
    trials: int = 100,
    seed: int = 0,
    options: ExecuteOptions | None = None,
    executor=None,
    progress: Callable[[dict], None] | None = None,
    medrad_dir=None,
    pilot_trials: int = 10,
    crossing_probability: float = CROSSING_PROBABILITY,
    resume: bool = False,
    physics=None,
    say: Callable[[str], None] | None = None,
) -> dict:
    """Run the study (module notes) and write ``out_dir/execute_lungs.json``.

    Parameters
    ----------
    out_dir : path-like
    patients : sequence of int
    trials : int
        Trials per lung.
    seed : int
    options : ExecuteOptions, optional
    executor : concurrent.futures.Executor, optional
        Runs each lung's trials.
    progress : callable, optional
        Called with each finished trial.
    medrad_dir : path-like, optional
    pilot_trials : int
        Closed-loop trials measuring the deviation, per lung.
    crossing_probability : float
    resume : bool
        Carry on from the partial ``execute_lungs.json`` an interrupted run wrote (signed:
        the lungs done kept as they are, the one under way from its margin, plan and
        partial ``execute.json``).
    physics : PhysicalLungs, optional
        A needle that bends by mechanics in a lung that deforms
        (:mod:`needlekit.studies.execute_lungs_physical`; ``options.settings.models.truth``
        ``"physical"``). Without it, the kinematic study (the pilot's margin).
    say : callable, optional
        Called with a line on each step of the physical study's plan choice.

    Returns
    -------
    dict
        The record written: ``cases`` (per lung: the pilot's deviation, the margin wanted
        and kept, closed- and open-loop figures, verdicts), ``targets``, ``holds``.

    Raises
    ------
    Interrupted
        Ctrl-C: the lungs done (and the one under way, with its margin and plan) written to
        ``execute_lungs.json`` marked partial, its trials done in its ``execute.json``.
    """
    options = options or ExecuteOptions()
    out = Path(out_dir)
    if physics is not None and options.settings.models.truth != "physical":
        raise InvalidInputError("truth", "a physical study's options run the physical truth")
    st = _Study(out, trials, seed, options, executor, progress, medrad_dir, pilot_trials,
                crossing_probability, physics, say)  # fmt: skip
    path = out / LUNGS_FILE
    head = _settings_record(patients, trials, seed, pilot_trials, crossing_probability, options,
                            physics)  # fmt: skip
    cases: list[dict] = []
    current = None
    if resume:
        data = read_partial(path, "execute-lungs record", head)
        cases, current = list(data.get("cases") or []), data.get("current")
    t0 = time.perf_counter()
    under_way = None  # the lung planned whose trials run
    try:
        for p in patients:
            if any(c["patient"] == p for c in cases):
                continue
            carried = current is not None and current["patient"] == p
            decided = current if carried else _decide(st, p)
            if decided["status"] != "planned":
                cases.append(decided)
                continue
            under_way = decided
            write_partial(path, {**head, "cases": cases, "current": decided})
            cases.append(_run_case(st, decided, resume=carried))
            under_way = None
            write_partial(path, {**head, "cases": cases})
    except (Interrupted, *INTERRUPT_FORMS) as exc:
        if not isinstance(exc, Interrupted) and not is_interrupt(exc):
            raise
        # written here, whenever Ctrl-C came (before the first lung was planned too): the
        # line names a record that is there
        written = write_partial(
            path, {**head, "cases": cases, **({"current": under_way} if under_way else {})}
        )
        trials = (  # the trial runs wrote theirs before raising Interrupted
            " (the trials of the one under way kept in its execute.partial.json)"
            if isinstance(exc, Interrupted)
            else ""
        )
        raise Interrupted(
            f"{len(cases)} of {len(patients)} lungs done{trials}; written to {written} marked "
            "partial; the same command with --resume carries on"
        ) from None
    record = {
        **head,
        "cases": cases,
        "holds": all(c.get("holds", False) for c in cases),
        "resumed": bool(resume),  # then wall_s covers the rest only
        "wall_s": time.perf_counter() - t0,
    }
    write_json(path, record)
    return record
