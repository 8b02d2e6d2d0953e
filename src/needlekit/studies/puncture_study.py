"""The simulation study of Tang et al. (Section III): many robotic punctures with random
targets, guide lines and kinematic uncertainty, summarised beside the paper's figures.

Each trial draws (from its own seed, so results do not depend on the executor or the
order the trials finish in):

- the target uniformly in a cube (10 mm) around ``target_center_mm``;
- the guide line ``l_g`` from random x-y-z components in one of the four octants above the
  horizontal plane (trial ``i`` takes octant ``i mod 4``), redrawn while the start point
  300 mm out would lie inside the patient cylinder (``R_p``) or put the arm's wrist
  outside its comfortable reach (``min_wrist_reach_mm`` to ``max_wrist_reach_mm`` from the
  shoulder); the draws and the filter's reasons for refusing each are counted
  (:mod:`needlekit.studies.guide_filter`);
- the controller's initial estimate of the base and needle uniformly within the
  uncertainty box around the nominal values (+-200 mm and +-10 deg on the base, +-10 mm
  and +-5 deg on the needle). As in the paper, the real arm has the nominal values ("an
  ideal Panda with nominal geometric parameters"; the uncertain parameters are "randomly
  generated around the nominal ones"), so every trial works in the same workspace. The
  adaptation keeps its estimate in the box of the same size around its initial value,
  which contains the truth without telling where it is.

:func:`run_puncture_study` runs the trials on any :class:`concurrent.futures.Executor`
(:func:`needlekit.batch.open_executor`), writes ``puncture.json`` (summary statistics,
constraint violations, aborted trials, the guide-line redraws and the outcomes by the
verdict on each trial's first line (``guide_redraws``), the filter's refusal rate measured
on its own (``redraw_filter``), every trial's outcome and the logs of the example trials)
and a report page, both atomically.
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np

from needlekit import __version__
from needlekit.errors import InvalidInputError
from needlekit.execute.trial_runs import collect_trials
from needlekit.io.files import json_text, staged_outputs, write_text
from needlekit.io.partial import read_partial
from needlekit.records import trial_solved
from needlekit.studies.guide_filter import (
    ACCEPTABLE,
    OCTANT_SIGNS,
    REFUSAL_REASONS,
    GuideFilter,
    redraw_filter_rates,
    redraw_summary,
)
from needlekit.studies.puncture_summary import _Bounds, _violations, summary_stats

__all__ = [
    "PAPER_RESULTS",
    "PunctureScenario",
    "PunctureStudy",
    "TrialOptions",
    "read_partial_puncture",
    "run_puncture_study",
    "run_puncture_trial",
    "sample_trial",
    "summary_stats",
    "trial_settings",
]

#: Tang et al., Section III-B: final tip-to-target error and needle-to-guide-line angle.
PAPER_RESULTS = {
    "position_error_mm": {"mean": 1.55, "sd": 0.40, "min": 0.64, "max": 2.34},
    "angle_error_deg": {"mean": 0.38, "sd": 0.021, "min": 0.08, "max": 0.71},
}

_Q_READY = (0.0, -math.pi / 4, 0.0, -3 * math.pi / 4, 0.0, math.pi / 2, math.pi / 4)


@dataclass(frozen=True)
class PunctureScenario:
    """Where the study's trials come from (mm, deg; transmitter frame).

    Attributes
    ----------
    nominal_base, nominal_needle : tuple of 6 floats
        The nominal base pose (in the transmitter frame) and needle tip (in the flange
        frame), ``[t (mm), x-y-z Euler angles (deg)]``: the controller's prior.
    base_spread_mm, base_spread_deg, needle_spread_mm, needle_spread_deg : float
        Half-widths of the uniform uncertainty (+-200 mm, +-10 deg, +-10 mm, +-5 deg).
    target_center_mm : tuple of 3 floats
    target_cube_mm : float
        Edge of the cube the targets are drawn from (10 mm).
    q0 : tuple of 7 floats
        Initial joint angles (rad; the Panda's ready pose).
    start_distance_mm : float
    min_wrist_reach_mm, max_wrist_reach_mm : float
        Distances from the arm's shoulder to its wrist (flange and needle lengths back from
        the start point along ``l_g``) when the tip is at the start point. The Panda reaches
        about 800 mm; closer than 300 mm it has to fold onto itself (in a first run of 100
        trials without this limit, all 12 that failed had the wrist within 245 mm of the
        shoulder, guide lines leaning towards the robot).
    max_draws : int
        Guide-line draws per trial before giving up.
    redraw_guides : bool
        Redraw a guide line whose start point lies inside the patient cylinder or out of
        the arm's comfortable reach (False: every trial keeps its first draw).
    """

    nominal_base: tuple = (-650.0, 0.0, -450.0, 0.0, 0.0, 0.0)
    nominal_needle: tuple = (0.0, 0.0, 100.0, 0.0, 0.0, 0.0)
    base_spread_mm: float = 200.0
    base_spread_deg: float = 10.0
    needle_spread_mm: float = 10.0
    needle_spread_deg: float = 5.0
    target_center_mm: tuple = (-150.0, 0.0, -250.0)
    target_cube_mm: float = 10.0
    q0: tuple = _Q_READY
    start_distance_mm: float = 300.0
    min_wrist_reach_mm: float = 300.0
    max_wrist_reach_mm: float = 700.0
    max_draws: int = 1000
    redraw_guides: bool = True

    @property
    def nominal_parameters(self) -> np.ndarray:
        """The 12 nominal parameters (mm, rad)."""
        b, n = np.asarray(self.nominal_base, float), np.asarray(self.nominal_needle, float)
        return np.concatenate([b[:3], np.radians(b[3:]), n[:3], np.radians(n[3:])])

    @property
    def spread(self) -> np.ndarray:
        """Half-widths of the uncertainty box of the 12 parameters (mm, rad)."""
        rb, rn = math.radians(self.base_spread_deg), math.radians(self.needle_spread_deg)
        return np.array(
            [self.base_spread_mm] * 3 + [rb] * 3 + [self.needle_spread_mm] * 3 + [rn] * 3
        )


@dataclass(frozen=True)
class TrialOptions:
    """How each trial runs: sensors, controller, adaptation and procedure settings.

    Attributes
    ----------
    exact_sensors : bool
        Noise-free sensors (latency and rate unchanged).
    stability_radius_mm : float
        :attr:`needlekit.control.adaptation.AdaptationSettings.stability_radius_mm`
        (0: the paper's stability row).
    history_keyframes : int
        Keyframes in the adaptation objective (0: the newest measurement alone).
    guide_samples : int
        Bronchoscope samples averaged into the guide line: 1 (the paper's simulation: one
        noisy measurement of the target), 100 (the 1 s at 100 Hz of its mannequin
        experiments), or 0 (the running mean of every sample of the trial).
    clamp_vfi_rows : bool
        :attr:`needlekit.control.adaptation.AdaptationSettings.clamp_vfi_rows`.
    adaptation_delay_steps : int
        :attr:`needlekit.control.procedure.ProcedureSettings.adaptation_delay_steps` (D > 0:
        off the step, applied D control periods later, default 2; 0: the adaptation inline
        in the sample's control step).
    qp_solver : str
        :attr:`needlekit.control.procedure.ProcedureSettings.qp_solver`: the registered
        name of the controller's and the adaptation's QP solver.
    """

    exact_sensors: bool = False
    stability_radius_mm: float = 1.5
    history_keyframes: int = 40
    guide_samples: int = 1
    clamp_vfi_rows: bool = True
    # control.schedule.DEFAULT_ADAPTATION_DELAY_STEPS, without importing the controller
    # here (a test keeps them equal)
    adaptation_delay_steps: int = 2
    qp_solver: str = "daqp"


def sample_trial(
    scenario: PunctureScenario,
    rng: np.random.Generator,
    index: int,
    *,
    verdicts: list | None = None,
):
    """Draw one trial of the study.

    Parameters
    ----------
    scenario : PunctureScenario
    rng : numpy.random.Generator
    index : int
        The trial's number (picks the octant).
    verdicts : list, optional
        Receives the filter's verdict on every guide line drawn, in order
        (:data:`~needlekit.studies.guide_filter.ACCEPTABLE` or the reason it refuses the
        line, :data:`~needlekit.studies.guide_filter.REFUSAL_REASONS`); without redraws,
        the verdict on the one line kept, whatever it is.

    Returns
    -------
    setup : needlekit.control.procedure.TrialSetup
    draws : int
        Guide-line draws it took.

    Raises
    ------
    InvalidInputError
        No acceptable guide line within ``max_draws``.
    """
    from needlekit.control.panda import PandaModel
    from needlekit.control.procedure import TrialSetup

    nominal, spread = scenario.nominal_parameters, scenario.spread
    initial = nominal + rng.uniform(-1.0, 1.0, 12) * spread
    true_a = nominal
    half = scenario.target_cube_mm / 2.0
    target = np.asarray(scenario.target_center_mm, float) + rng.uniform(-half, half, 3)
    sx, sy = OCTANT_SIGNS[index % 4]
    guide_filter = GuideFilter.from_scenario(scenario)
    for draw in range(1, scenario.max_draws + 1):
        c = rng.uniform(0.0, 1.0, 3) * np.array([sx, sy, 1.0])
        if np.linalg.norm(c) < 1e-6:
            continue
        lg = c / np.linalg.norm(c)
        verdict = guide_filter.verdict(target, lg)
        if verdicts is not None:
            verdicts.append(verdict)
        if not scenario.redraw_guides or verdict == ACCEPTABLE:
            q0 = np.asarray(scenario.q0, float)
            return TrialSetup(PandaModel(), true_a, initial, q0, target, lg), draw
    raise InvalidInputError(
        "scenario", f"no acceptable guide line in {scenario.max_draws} draws (octant {index % 4})"
    )


def trial_settings(scenario: PunctureScenario, options: TrialOptions, initial):
    """The adaptation, procedure and sensor settings of a trial.

    Parameters
    ----------
    scenario : PunctureScenario
    options : TrialOptions
    initial : ndarray, shape (12,)
        The controller's initial estimate (the parameter box is centred on it).

    Returns
    -------
    adaptation : needlekit.control.adaptation.AdaptationSettings
    procedure : needlekit.control.procedure.ProcedureSettings
    sensor : needlekit.control.em.EMSensorSpec
        Both sensors'.
    """
    from needlekit.control.adaptation import AdaptationSettings
    from needlekit.control.em import EMSensorSpec
    from needlekit.control.procedure import ProcedureSettings

    spread = scenario.spread
    adaptation = AdaptationSettings(
        initial - spread,
        initial + spread,
        stability_radius_mm=options.stability_radius_mm,
        clamp_vfi_rows=options.clamp_vfi_rows,
    )
    procedure = ProcedureSettings(
        start_distance_mm=scenario.start_distance_mm,
        history_keyframes=options.history_keyframes,
        guide_samples=options.guide_samples,
        adaptation_delay_steps=options.adaptation_delay_steps,
        qp_solver=options.qp_solver,
    )
    spec = EMSensorSpec()
    if options.exact_sensors:
        spec = replace(spec, position_sigma_mm=0.0, orientation_sigma_deg=0.0)
    return adaptation, procedure, spec


def run_puncture_trial(
    scenario: PunctureScenario,
    options: TrialOptions,
    index: int,
    seed_sequence: np.random.SeedSequence,
    keep_log: bool = False,
    timings: list | None = None,
) -> dict:
    """Run trial ``index`` and return its outcome as plain data (JSON-ready).

    Parameters
    ----------
    scenario : PunctureScenario
    options : TrialOptions
    index : int
    seed_sequence : numpy.random.SeedSequence
        The trial's own seed (its first child draws the trial, the second drives the
        sensors).
    keep_log : bool
        Include the trial's time series.
    timings : list, optional
        Receives the controller's time per step (see
        :func:`needlekit.control.procedure.run_trial`).

    Returns
    -------
    dict
    """
    from needlekit.control.procedure import run_trial

    draw_seed, sensor_seed = seed_sequence.spawn(2)
    verdicts: list[str] = []
    setup, draws = sample_trial(
        scenario, np.random.default_rng(draw_seed), index, verdicts=verdicts
    )
    adaptation, procedure, spec = trial_settings(scenario, options, setup.nominal_parameters)
    r = run_trial(
        setup,
        np.random.default_rng(sensor_seed),
        procedure=procedure,
        adaptation=adaptation,
        needle_sensor=spec,
        scope_sensor=spec,
        timings=timings,
    )
    out = {
        "trial": index,
        "octant": index % 4,
        "status": r.status.value,
        "reason": r.reason,
        "position_error_mm": r.position_error_mm,
        "angle_error_deg": r.angle_error_deg,
        "max_guide_distance_mm": r.max_guide_distance_mm,
        "max_cone_angle_deg": r.max_cone_angle_deg,
        "start_guide_distance_mm": _finite_or_none(r.start_guide_distance_mm),
        "start_cone_angle_deg": _finite_or_none(r.start_cone_angle_deg),
        "max_guide_distance_inside_mm": _finite_or_none(r.max_guide_distance_inside_mm),
        "max_cone_angle_inside_deg": _finite_or_none(r.max_cone_angle_inside_deg),
        "reached_estimated": bool(r.reached_estimated),
        "reached": bool(r.reached),
        "min_plane_distance_mm": _finite_or_none(r.min_plane_distance_mm),
        "min_patient_distance_mm": _finite_or_none(r.min_patient_distance_mm),
        "phase_times_s": r.phase_times_s,
        "counts": r.counts,
        "guide_draws": draws,
        # the filter's refusals (redrawn lines) by reason, and its verdict on the first line
        # (kept whatever it is when the study does not redraw)
        "guide_refused": {
            reason: sum(v == reason for v in verdicts[:-1] if scenario.redraw_guides)
            for reason in REFUSAL_REASONS
        },
        "first_guide_verdict": verdicts[0] if verdicts else ACCEPTABLE,
        "events": [[float(t), what] for t, what in r.events],
        "target_mm": setup.target_mm.tolist(),
        "guide_direction": setup.guide_direction.tolist(),
        "initial_parameters": setup.nominal_parameters.tolist(),
    }
    if keep_log:
        out["log"] = {k: _jsonable(v) for k, v in r.log.items()}
        out["log"]["to_start_mm"] = _to_start_series(r.log, setup, scenario.start_distance_mm)
    return out


def _to_start_series(log: dict, setup, start_distance_mm: float) -> list:
    """The real tip's distance from the real start point (``d`` out along the real guide
    line), at the log's samples, to 1 micron (Fig. 5C)."""
    tips = np.asarray(log["tip_mm"], dtype=float).reshape(-1, 3)
    start = setup.target_mm + start_distance_mm * setup.guide_direction
    return np.round(np.linalg.norm(tips - start, axis=1), 3).tolist()


def _run_job(job: tuple) -> dict:
    return run_puncture_trial(*job)


def _jsonable(series: np.ndarray) -> list:
    """A logged series as JSON: NaN as None, positions (rows of 3) to 0.1 micron."""
    if series.dtype.kind != "f":
        return series.tolist()
    if series.ndim > 1:
        return np.round(series, 4).tolist()
    return [_finite_or_none(float(x)) for x in series]


def _finite_or_none(v: float):
    return float(v) if math.isfinite(v) else None


@dataclass
class PunctureStudy:
    """What :func:`run_puncture_study` produced."""

    summary: dict
    trials: list[dict] = field(default_factory=list)
    files: dict = field(default_factory=dict)


def run_puncture_study(
    out_dir: str | os.PathLike,
    *,
    trials: int = 100,
    seed: int = 0,
    scenario: PunctureScenario | None = None,
    options: TrialOptions | None = None,
    executor=None,
    progress: Callable[[dict], None] | None = None,
    example_trials: int = 4,
    report: bool = True,
    resume: list[dict] | None = None,
) -> PunctureStudy:
    """Run the study and write ``out_dir/puncture.json`` (and ``puncture.html``).

    Parameters
    ----------
    out_dir : path-like
    trials : int
    seed : int
        Root seed; trial ``i`` uses the ``i``-th child of ``SeedSequence(seed)``.
    scenario : PunctureScenario, optional
    options : TrialOptions, optional
    executor : concurrent.futures.Executor, optional
        Runs the trials (default: one after another in this process).
    progress : callable, optional
        Called with each finished trial's outcome.
    example_trials : int
        Trials (the first ones: one per octant) whose time series are kept for the figures.
    report : bool
        Also write the report page.
    resume : list of dict, optional
        Trials an interrupted run finished (:func:`read_partial_puncture`): kept, and only
        the others run.

    Returns
    -------
    PunctureStudy

    Raises
    ------
    Interrupted
        Ctrl-C during the trials: the trials finished are written to ``puncture.partial.json``
        marked partial (no page), which ``resume`` carries on from.
    """
    from needlekit.control.controller import ControllerSettings
    from needlekit.control.em import EMSensorSpec
    from needlekit.control.procedure import ProcedureSettings

    if not isinstance(trials, int) or trials < 1:
        raise InvalidInputError("trials", f"expected a whole number >= 1, got {trials!r}")
    scenario = scenario or PunctureScenario()
    options = options or TrialOptions()
    out_dir = Path(out_dir)
    if out_dir.exists() and not out_dir.is_dir():
        raise InvalidInputError("out", f"{out_dir} exists and is not a folder")
    seeds = np.random.SeedSequence(seed).spawn(trials)
    # the guide-line filter on its own (no simulation: a few ms)
    filter_rates = redraw_filter_rates(scenario, seed=seed)
    t0 = time.perf_counter()
    head = _settings_record(trials, seed, scenario, options)
    done = collect_trials(
        list(range(trials)), {r["trial"]: r for r in resume or ()}, _run_job,
        lambda i: (scenario, options, i, seeds[i], i < example_trials), executor=executor,
        partial_path=out_dir / "puncture.json", head=head, done_key="per_trial",
        progress=progress,
    )  # fmt: skip
    wall = time.perf_counter() - t0
    completed = [r for r in done if trial_solved(r["status"])]
    cs, spec = ControllerSettings(), EMSensorSpec()
    bounds = _Bounds(
        cs.guide_radius_mm,
        math.degrees(cs.cone_angle_rad),
        cs.patient_radius_mm,
        0.0 if options.exact_sensors else spec.position_sigma_mm,
        0.0 if options.exact_sensors else spec.orientation_sigma_deg,
    )
    summary = {
        **{k: head[k] for k in ("needlekit_version", "trials", "seed")},
        "completed": len(completed),
        "aborted": {
            "count": trials - len(completed),
            "trials": [
                {"trial": r["trial"], "reason": r["reason"]}
                for r in done
                if not trial_solved(r["status"])
            ],
        },
        "position_error_mm": summary_stats(r["position_error_mm"] for r in completed),
        "angle_error_deg": summary_stats(r["angle_error_deg"] for r in completed),
        "constraint_violations": _violations(done, bounds),
        # judged on the robot's estimate and on the real tip (within the target tolerance)
        "reached_target": {
            "estimated": sum(bool(r.get("reached_estimated")) for r in done),
            "real": sum(bool(r.get("reached")) for r in done),
            "missed_by_real_tip": [
                {"trial": r["trial"], "position_error_mm": r["position_error_mm"]}
                for r in completed
                if not r.get("reached")
            ],
        },
        "guide_redraws": redraw_summary(done, scenario.redraw_guides),
        "redraw_filter": filter_rates,
        "paper": PAPER_RESULTS,
        "scenario": asdict(scenario),
        "options": asdict(options),
        # the adaptation off the control step (0: inline), as a time
        "adaptation_delay_ms": options.adaptation_delay_steps * ProcedureSettings().dt_s * 1e3,
        "wall_s": wall,
    }
    doc = dict(summary)
    doc["per_trial"] = done
    files = {"json": out_dir / "puncture.json"}
    text = json_text(doc, "puncture.json", indent=1) + "\n"
    with staged_outputs():  # both files or neither: a failed report keeps the old json
        write_text(files["json"], text)
        if report:
            from needlekit.report.puncture_report import write_puncture_report

            files["report"] = write_puncture_report(out_dir / "puncture.html", summary, done)
    return PunctureStudy(summary, done, files)


def _settings_record(trials: int, seed: int, scenario, options) -> dict:
    """What a partial record holds besides its trials, and a resumed run must share."""
    return {
        "needlekit_version": __version__,
        "trials": trials,
        "seed": seed,
        "scenario": asdict(scenario),
        "options": asdict(options),
    }


def read_partial_puncture(
    out_dir, *, trials: int, seed: int, scenario: PunctureScenario, options: TrialOptions
) -> list[dict]:
    """The trials an interrupted run finished (``puncture --resume``), from its
    ``puncture.partial.json`` (signed: :func:`needlekit.io.partial.read_partial`).

    Parameters
    ----------
    out_dir : path-like
    trials, seed, scenario, options
        This run's: the file's.

    Returns
    -------
    list of dict

    Raises
    ------
    InvalidInputError
        (named ``--resume``) No such file, not partial, changed since it was written, or
        other settings than this run's.
    """
    path = Path(out_dir) / "puncture.json"
    data = read_partial(path, "puncture", _settings_record(trials, seed, scenario, options))
    return list(data.get("per_trial") or [])
