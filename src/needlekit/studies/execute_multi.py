"""A straight multi-needle plan inserted by the robot: each needle's line
is the guide line of Tang et al.'s controller on the simulated Panda, the needles go in in
the planned order, the needles already placed are vector-field-inequality obstacles, and
the plan's deformation model moves the remaining targets after each insertion.

One trial is the whole sequence. Needle ``k`` of trial ``i``:

1. Its real target is its planned target (tissue at rest) moved by the plan's deformation
   model for the needles *really* placed before it (where they ended, not where they were
   planned); the robot is given the plan's line (entry to aimed target), which the planner
   aimed at the target moved by the needles as *planned*. The two differ by what the
   placed needles' errors change in the deformation.
2. The line goes from the patient's frame (RAS) to the robot's through the registration
   (:func:`register_plan`). By default the robot knows it exactly; with
   ``registration_sd_mm`` the anatomy really lies offset from where the robot believes it
   by one random translation per trial (that SD per axis), the same for every needle.
3. A Tang trial (:func:`needlekit.control.procedure.run_trial`) with the paper's sensors,
   uncertainty box and procedure (as ``needlekit puncture``: a fresh estimate drawn in the
   box for each needle), the guide line given rather than measured, the start point the
   first of 300, 310, ... mm out along the line that the puncture study's filter accepts,
   and the needles placed before it as VFI obstacles where the robot believes it put them
   (its estimate of the tip pose at the end of each insertion).
4. Measured on the real arm: the tip's distance from the real target (the error Liu et al.
   report), the angle to the line, the constraints (guide cylinder, cone, plane; Tang et
   al.'s criterion, beyond the sensor noise, as ``needlekit puncture`` counts them), and
   the smallest real gap between the needle's shaft and every placed needle (touching:
   below 0).

After the sequence, the ablation coverage of the zones at the executed tips along the
executed axes (carried back to the tissue at rest), beside the plan's own.
"""

from __future__ import annotations

import math
import time
import traceback
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from needlekit import __version__
from needlekit.errors import raise_if_interrupt
from needlekit.execute.trial_runs import collect_trials
from needlekit.io.files import write_json
from needlekit.io.partial import read_partial
from needlekit.studies.puncture_study import PunctureScenario, TrialOptions, trial_settings
from needlekit.studies.puncture_summary import _Bounds, _violations
from needlekit.studies.robot_registration import place_patient

__all__ = [
    "LIU_IN_VITRO",
    "MultiExecution",
    "executed_coverage",
    "multi_summary",
    "multi_trial",
    "plan_lines",
    "run_multi_execution",
]

#: Liu et al. 2016, in vitro porcine liver: 10 runs with 2 to 4 needles, target error.
LIU_IN_VITRO = {
    "source": "Liu et al. 2016",
    "setting": "in vitro porcine liver, 10 runs of 2-4 needles (5-DOF robot, manual insertion)",
    "mean_mm": 2.1,
    "sd_mm": 0.6,
}
#: A gap below this (mm) is a touch: the needles' surfaces meet.
TOUCH_MM = 0.0


def plan_lines(record: dict) -> dict:
    """The needles of a ``multi.json`` record in their order, as arrays.

    Parameters
    ----------
    record : dict

    Returns
    -------
    dict
        ``order``, ``target_index`` (k,), ``rest_mm``, ``aimed_mm``, ``entry_mm`` (k, 3):
        the planned target (tissue at rest), the aimed (deformation-compensated) one, the
        entry.
    """
    rows = sorted((n for n in record["needles"] if n.get("entry_mm")), key=lambda n: n["order"])
    return {
        "order": [int(n["order"]) for n in rows],
        "target_index": [int(n["target_index"]) for n in rows],
        "rest_mm": np.array([n["planned_target_mm"] for n in rows], float),
        "aimed_mm": np.array([n["target_mm"] for n in rows], float),
        "entry_mm": np.array([n["entry_mm"] for n in rows], float),
    }


def _deformed(model, point, placed) -> np.ndarray:
    if model is None or not placed:
        return np.asarray(point, float).copy()
    return point + np.asarray(model.displacement(point[None], placed))[0]


def multi_trial(job: tuple) -> dict:
    """One trial: every needle of the plan inserted in order (see the module notes).

    Parameters
    ----------
    job : tuple
        ``(lines, deformation, radius_mm, registration, registration_sd_mm, starts,
        scenario, options, physics, seed, trial)``: :func:`plan_lines`, the plan's
        deformation model (or None), the needle radius, the :class:`Registration` and its
        error's SD per axis (mm), the start distances, the
        :class:`~needlekit.studies.puncture_study.PunctureScenario` and
        :class:`~needlekit.studies.puncture_study.TrialOptions`, the needle's
        :class:`~needlekit.execute.straight_physics.StraightPhysics` (None: the rigid
        needle goes where the robot holds it), the root seed and the trial's number.

    Returns
    -------
    dict
        ``trial``, ``seed``, ``needles`` (one row each) or ``error`` when it crashed.
    """
    lines, model, radius, reg, reg_sd, starts, scenario, options, physics, seed, trial = job
    head = {"trial": trial, "seed": seed, "seed_spawn_key": [trial]}
    try:
        # the first child draws the registration error, one more per needle
        first, *seeds = np.random.SeedSequence(seed, spawn_key=(int(trial),)).spawn(
            1 + len(lines["order"])
        )
        offset = np.random.default_rng(first).normal(0.0, 1.0, 3) * reg_sd
        pose = reg.world_T_ras.copy()
        pose[:3, 3] += offset
        truth = replace(reg, world_T_ras=pose)
        needles = _insert_all(lines, model, radius, reg, truth, starts, scenario, options, seeds,
                              physics)  # fmt: skip
        return {**head, "registration_error_mm": np.round(offset, 6).tolist(), "needles": needles}
    except Exception as exc:  # recorded with its seed; the other trials go on
        raise_if_interrupt(exc)  # Ctrl-C is no trial's failure
        last = traceback.extract_tb(exc.__traceback__)[-1]
        return {**head, "error": f"{type(exc).__name__}: {exc} ({Path(last.filename).name}:"
                f"{last.lineno})"}  # fmt: skip


def _insert_all(lines, model, radius, reg, truth, starts, scenario, options, seeds,
                physics=None) -> list:  # fmt: skip
    """The needles one after another: the robot works from ``reg``, the anatomy lies where
    ``truth`` puts it; with ``physics`` the needle bends and the organ is pushed
    (:mod:`needlekit.execute.straight_physics`)."""
    from needlekit.control.controller import ControllerSettings
    from needlekit.control.panda import PandaModel
    from needlekit.control.procedure import run_trial
    from needlekit.control.trial import TrialSetup
    from needlekit.planning.straight.deformation import PlacedNeedle

    k_all = len(lines["order"])
    nominal, spread = scenario.nominal_parameters, scenario.spread
    length = float(np.linalg.norm(nominal[6:9]))  # flange to tip
    cs = ControllerSettings(patient_axis=reg.patient_axis, needle_radius_mm=radius)
    known: list = []
    real: list = []
    placed_ras: list = []
    rows = []
    for k in range(k_all):
        rest, aimed, entry = lines["rest_mm"][k], lines["aimed_mm"][k], lines["entry_mm"][k]
        target = _deformed(model, rest, placed_ras)  # where the tissue really took it
        out = (entry - aimed) / np.linalg.norm(entry - aimed)
        draw, sensors, tissue = seeds[k].spawn(3)  # the first two as ever: a third for physics
        initial = nominal + np.random.default_rng(draw).uniform(-1.0, 1.0, 12) * spread
        setup = TrialSetup(
            PandaModel(), nominal, initial, np.asarray(scenario.q0, float), reg.point(aimed),
            reg.direction(out), guide_known=True,
            placed_needles=np.array(known) if known else None,
            placed_needles_true=np.array(real) if real else None,
        )  # fmt: skip
        adaptation, procedure, spec = trial_settings(scenario, options, initial)
        procedure = replace(procedure, start_distance_mm=starts[k])
        r = run_trial(
            setup, np.random.default_rng(sensors), procedure=procedure, controller=cs,
            adaptation=adaptation, needle_sensor=spec, scope_sensor=spec,
        )  # fmt: skip
        tip_w, axis_w = r.final_tip_pose[:3, 3], r.final_tip_pose[:3, 2]
        est = r.final_estimated_tip_pose
        real.append([tip_w, tip_w - length * axis_w])
        known.append([est[:3, 3], est[:3, 3] - length * est[:3, 2]])
        tip, axis = truth.to_ras(tip_w), axis_w @ truth.world_T_ras[:3, :3]  # the anatomy's
        depth = float(np.linalg.norm(entry - aimed))
        extra = {}
        if physics is not None:
            tip, axis, target, extra = _bent(physics, r.final_tip_pose, truth, tip, axis,
                                             (entry, aimed), target, tissue)  # fmt: skip
        placed_ras.append(PlacedNeedle(tip, tip - depth * axis, radius))
        rows.append({**_needle_row(k, lines, r, tip, axis, target, rest, aimed, starts[k]), **extra})
    return rows


def _bent(physics, final_pose, truth, tip, axis, planned, target, seed) -> tuple:
    """The rod's tip and axis where the robot held its base, and the target the organ
    pushed (:meth:`~needlekit.execute.straight_physics.StraightPhysics.insert`), with
    the figures beside the rigid needle's."""
    depth = float((tip - planned[0]) @ axis)
    start = np.eye(4)
    x = final_pose[:3, 0] @ truth.world_T_ras[:3, :3]
    x = x - (x @ axis) * axis
    start[:3, :3] = np.column_stack([x / np.linalg.norm(x), np.cross(axis, x / np.linalg.norm(x)), axis])
    start[:3, 3] = tip - depth * axis
    out = physics.insert(start, depth, planned, np.random.default_rng(seed))
    bent, pushed = tip + out["tip_offset_mm"], target + out["target_push_mm"]
    extra = {
        "robot_error_mm": float(np.linalg.norm(tip - target)),
        "needle_deflection_mm": float(np.linalg.norm(out["tip_offset_mm"])),
        "target_push_mm": float(np.linalg.norm(out["target_push_mm"])),
        "tip_force_n": out["tip_force_n"],
    }
    return bent, out["axis"], pushed, extra


def _finite(v):
    return float(v) if v is not None and math.isfinite(v) else None


def _needle_row(k, lines, r, tip, axis, target, rest, aimed, start) -> dict:
    return {
        "order": lines["order"][k],
        "target_index": lines["target_index"][k],
        "status": r.status.value,
        "reason": r.reason,
        "error_mm": float(np.linalg.norm(tip - target)),
        "error_to_aim_mm": float(np.linalg.norm(tip - aimed)),
        "angle_error_deg": r.angle_error_deg,
        "target_shift_mm": float(np.linalg.norm(target - rest)),
        "aim_off_target_mm": float(np.linalg.norm(aimed - target)),
        "min_needle_gap_mm": _finite(r.min_needle_gap_mm),
        "max_guide_distance_mm": r.max_guide_distance_mm,
        "max_cone_angle_deg": r.max_cone_angle_deg,
        "start_guide_distance_mm": _finite(r.start_guide_distance_mm),
        "start_cone_angle_deg": _finite(r.start_cone_angle_deg),
        "max_guide_distance_inside_mm": _finite(r.max_guide_distance_inside_mm),
        "max_cone_angle_inside_deg": _finite(r.max_cone_angle_inside_deg),
        "min_plane_distance_mm": _finite(r.min_plane_distance_mm),
        "min_patient_distance_mm": _finite(r.min_patient_distance_mm),
        "start_distance_mm": start,
        "qp_infeasible": int(r.counts.get("qp_infeasible", 0)),
        "tip_mm": np.round(tip, 4).tolist(),
        "axis": np.round(axis, 6).tolist(),
        "target_mm": np.round(target, 4).tolist(),
        "rest_mm": np.round(rest, 4).tolist(),
    }


@dataclass
class MultiExecution:
    """What :func:`run_multi_execution` wrote: the document and its path."""

    document: dict
    path: Path


def run_multi_execution(
    out_dir,
    record: dict,
    multi,
    *,
    trials: list[int],
    seed: int,
    coverage=None,
    scenario: PunctureScenario | None = None,
    options: TrialOptions | None = None,
    registration_sd_mm: float = 0.0,
    executor=None,
    progress=None,
    scenario_name: str = "",
    resume: bool = False,
    scenario_file: str | None = None,
    physics=None,
) -> MultiExecution:
    """Insert a checked multi-needle plan ``len(trials)`` times and write
    ``out_dir/execute.json`` (atomically; Ctrl-C writes the trials done, marked partial,
    to ``execute.partial.json`` beside it).

    Parameters
    ----------
    out_dir : path-like
    record : dict
        The ``multi.json`` document (checked by the caller against the scenario).
    multi : MultiNeedleProblem
        Its problem: the needle and the deformation model.
    trials : list of int
    seed : int
        Root seed: trial ``i`` uses ``SeedSequence(seed, spawn_key=(i,))``, one child per
        needle.
    coverage : tuple (TargetRegion, AblationZone), optional
        The coverage region and zone (``targets: coverage`` scenarios).
    scenario : PunctureScenario, optional
        The robot, its uncertainty and the workspace (default: Tang et al.'s).
    options : TrialOptions, optional
    registration_sd_mm : float
        SD per axis (mm) of the registration's error: one offset of the whole anatomy per
        trial (0: the robot knows where the patient lies).
    executor : concurrent.futures.Executor, optional
    progress : callable, optional
        Called with each finished trial.
    scenario_name : str
    resume : bool
        Carry on from the ``execute.partial.json`` an interrupted run with the same
        settings wrote (checked before any trial).
    scenario_file : str, optional
        The scenario's path relative to ``out_dir``, kept for ``needlekit report``.
    physics : StraightPhysics, optional
        The needle by mechanics and the organ that deforms
        (:mod:`needlekit.execute.straight_physics`; ``--truth mechanics|physical``).

    Returns
    -------
    MultiExecution

    Raises
    ------
    InvalidInputError
        A needle the robot cannot start
        (:func:`~needlekit.studies.robot_registration.start_distances`), or (named
        ``--resume``) no partial file of this run to carry on.
    Interrupted
        Ctrl-C.
    """
    scenario = scenario or PunctureScenario()
    options = options or TrialOptions()
    lines = plan_lines(record)
    radius = float(multi.problem.needle.radius_mm)
    reg, starts, cs = place_patient(lines, scenario, radius)
    head = {
        "kind": "multi",
        "needlekit_version": __version__,
        "scenario": scenario_name,
        "seed": seed,
        "trials_requested": list(trials),
        "registration": reg.to_dict(),
        "start_distance_mm": starts,
        "deformation": None if multi.deformation is None else repr(multi.deformation),
        "needle_radius_mm": radius,
        "needle_gap_mm": cs.needle_gap_mm,
        "registration_sd_mm": float(registration_sd_mm),
        "robot": {
            "nominal_base": list(scenario.nominal_base),
            "nominal_needle": list(scenario.nominal_needle),
        },
        "plan_needles": [
            {"order": o, "target_mm": a.tolist(), "entry_mm": e.tolist()}
            for o, a, e in zip(lines["order"], lines["aimed_mm"], lines["entry_mm"], strict=True)
        ],
    }
    path = Path(out_dir) / "execute.json"
    done: dict = {}
    if resume:
        want = {k: v for k, v in head.items() if k != "needlekit_version"}
        for r in read_partial(path, "execute", want).get("trials_done") or []:
            done[r["trial"]] = r
    if physics is not None:
        head["truth"] = physics.record()
    job = (lines, multi.deformation, radius, reg, float(registration_sd_mm), starts, scenario,
           options, physics, seed)  # fmt: skip

    def with_coverage(result: dict) -> dict:
        if coverage is not None and "needles" in result:
            result["coverage"] = executed_coverage(result["needles"], *coverage)
        return result

    t0 = time.perf_counter()
    records = collect_trials(
        list(trials), done, multi_trial, lambda k: (*job, k), executor=executor,
        partial_path=path, head=head, done_key="trials_done", progress=progress,
        finish=with_coverage,
    )  # fmt: skip
    planned = (record.get("coverage") or {}).get("planned")
    doc = {**head, "summary": multi_summary(records, cs, options, planned),
           "wall_s": time.perf_counter() - t0, "trials": records}  # fmt: skip
    if scenario_file is not None:
        doc["scenario_file"] = scenario_file
    write_json(path, doc)
    return MultiExecution(doc, path)


def executed_coverage(rows: list[dict], region, zone) -> dict:
    """The coverage of the zones at the executed tips along the executed axes, in the
    tissue at rest (each tip carried back by its target's shift).

    Parameters
    ----------
    rows : list of dict
        A trial's needle rows.
    region : TargetRegion
    zone : AblationZone

    Returns
    -------
    dict
        ``coverage``, ``tumour_coverage`` (fractions), ``uncovered_ml``.
    """
    from needlekit.planning.straight.coverage import evaluate_coverage

    tips = [np.subtract(r["tip_mm"], np.subtract(r["target_mm"], r["rest_mm"])) for r in rows]
    rep = evaluate_coverage(region, zone, np.array(tips), np.array([r["axis"] for r in rows]))
    return {
        "coverage": rep.coverage,
        "tumour_coverage": rep.tumour_coverage,
        "uncovered_ml": rep.uncovered_ml,
    }


#: A physical needle's figures beside the error (:func:`_bent`), summarised when present.
_PHYSICS = ("robot_error_mm", "needle_deflection_mm", "target_push_mm")


def _stats(values) -> dict:
    v = np.asarray([x for x in values if x is not None], dtype=float)
    if not len(v):
        return {"n": 0}
    return {
        "n": int(len(v)), "mean": float(v.mean()),
        "sd": float(v.std(ddof=1)) if len(v) > 1 else 0.0, "min": float(v.min()),
        "median": float(np.median(v)), "max": float(v.max()),
    }  # fmt: skip


def multi_summary(records: list[dict], cs, options: TrialOptions, planned=None) -> dict:
    """Per-needle and overall errors, touches, constraint violations and coverage.

    Parameters
    ----------
    records : list of dict
        The trials (:func:`multi_trial`, with ``coverage`` when there is a region).
    cs : ControllerSettings
        The guide cylinder and cone the constraints are judged by.
    options : TrialOptions
        The sensors (Tang et al.'s criterion allows their noise).
    planned : dict, optional
        The plan's own coverage report.

    Returns
    -------
    dict
    """
    from needlekit.control.em import EMSensorSpec

    ok = [r for r in records if "needles" in r]
    rows = [dict(n, trial=f"{r['trial']}/{n['order']}") for r in ok for n in r["needles"]]
    spec = EMSensorSpec()
    bounds = _Bounds(
        cs.guide_radius_mm, math.degrees(cs.cone_angle_rad), cs.patient_radius_mm,
        0.0 if options.exact_sensors else spec.position_sigma_mm,
        0.0 if options.exact_sensors else spec.orientation_sigma_deg,
    )  # fmt: skip
    gaps = [n["min_needle_gap_mm"] for n in rows if n["min_needle_gap_mm"] is not None]
    orders = sorted({n["order"] for n in rows})
    out = {
        "trials": len(records),
        "crashed": [{"trial": r["trial"], "error": r["error"]} for r in records if "error" in r],
        "needles": len(rows),
        "error_mm": _stats(n["error_mm"] for n in rows),
        "angle_error_deg": _stats(n["angle_error_deg"] for n in rows),
        "by_needle": {
            str(o): {
                "error_mm": _stats(n["error_mm"] for n in rows if n["order"] == o),
                "target_shift_mm": _stats(n["target_shift_mm"] for n in rows if n["order"] == o),
                **{key: _stats(n[key] for n in rows if n["order"] == o)
                   for key in _PHYSICS if rows and key in rows[0]},
            }
            for o in orders
        },
        **{key: _stats(n[key] for n in rows) for key in _PHYSICS if rows and key in rows[0]},
        "statuses": {
            s: sum(n["status"] == s for n in rows) for s in sorted({n["status"] for n in rows})
        },
        "touched": [
            n["trial"]
            for n in rows
            if n["min_needle_gap_mm"] is not None and n["min_needle_gap_mm"] < TOUCH_MM
        ],
        "min_needle_gap_mm": min(gaps) if gaps else None,
        "constraints": _violations(rows, bounds),
        "literature": [LIU_IN_VITRO],
    }
    with_cov = [r["coverage"] for r in ok if "coverage" in r]
    if with_cov:
        out["coverage"] = {
            "planned": planned,
            "coverage": _stats(c["coverage"] for c in with_cov),
            "tumour_coverage": _stats(c["tumour_coverage"] for c in with_cov),
            "fully_covered": sum(c["coverage"] >= 1.0 for c in with_cov),
        }
    return out
