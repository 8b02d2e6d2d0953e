"""The Med-RAD case of Feng et al.'s protocol (:mod:`needlekit.studies.feng_lungs`): lung
patient 5, start 1, Feng's needle and limits, and the two targets (Med-RAD's, and goal 2
at Feng's offset from it) as scenario documents; the check that a target is in free space
and within reach, and the case's part of the study's record. Lengths in mm, patient RAS.
"""

from __future__ import annotations

import copy
from pathlib import Path

import numpy as np

from needlekit.errors import InvalidInputError
from needlekit.io.files import write_text
from needlekit.io.medrad_paths import patient_folder

__all__ = ["FENG_GOAL2_OFFSET_MM", "FENG_SCENARIO", "feng_lung_scenario", "feng_patient_folder"]


#: Feng's needle and limits (their Section 5; their "k_max = 50 mm^-1" read as r_min 50 mm),
#: the heading limit of their Algorithm 1 (no turn beyond 90 deg) and the reference
#: planner's 3 mm start exclusion (the needle leaves the airway through its wall).
FENG_SCENARIO: dict = {
    "version": 1,
    "base": {"medrad": {"organ": "lung", "patient": 5}},
    "needle": {
        "diameter_mm": 2.0,
        "r_min_mm": 50,
        "max_length_mm": 100,
        "max_heading_change_deg": 90,
        "min_puncture_angle_deg": 20,
        "start_exclusion_mm": 3,
    },
    "start": {"case_start": "start1"},
    "goal": {"case_target": "target", "tolerance_mm": 1.0},
    "collision_model": "field",
    "planner": {"name": "rcs_star", "time_limit_s": 1.0, "seed": 0},
}

#: Feng's goal 2 less their goal 1 (mm): the offset that makes goal 2 here.
FENG_GOAL2_OFFSET_MM: tuple[float, float, float] = (-10.0, -10.0, 10.0)


def feng_patient_folder(medrad_dir=None) -> Path:
    """The Med-RAD folder of Feng's case (lung 5), which must exist (light: no anatomy).

    Parameters
    ----------
    medrad_dir : path-like, optional

    Returns
    -------
    Path

    Raises
    ------
    InvalidInputError
        Named ``--medrad``: no Med-RAD folder, or no lung 5 in it.
    """
    return patient_folder("lung", FENG_SCENARIO["base"]["medrad"]["patient"], medrad_dir)


def _case_target_mm(medrad_dir=None) -> np.ndarray:
    """Med-RAD's target of the case (RAS mm), read from its text file alone."""
    from needlekit.io.medrad import _files, _starts_and_targets

    folder = feng_patient_folder(medrad_dir)
    _, targets = _starts_and_targets(_files(folder), folder)
    return np.asarray(targets[FENG_SCENARIO["goal"]["case_target"]], dtype=float)


def feng_lung_scenario(goal: int, *, medrad_dir=None) -> dict:
    """The scenario document of one target (``examples/medrad_lung_feng_goal{1,2}.yaml``).

    Parameters
    ----------
    goal : {1, 2}
        1: Med-RAD's target; 2: it moved by :data:`FENG_GOAL2_OFFSET_MM`.
    medrad_dir : path-like, optional
        Med-RAD folder (default ``$NEEDLEKIT_MEDRAD`` or ``../shared/data/med-rad``).

    Returns
    -------
    dict

    Raises
    ------
    InvalidInputError
        Another goal number, or no Med-RAD lung patient 5.
    """
    if goal not in (1, 2):
        raise InvalidInputError("goal", f"expected 1 or 2, got {goal!r}")
    doc = copy.deepcopy(FENG_SCENARIO)
    if medrad_dir is not None:
        doc["base"]["medrad"]["root"] = str(Path(medrad_dir).resolve())
    doc["name"] = f"Med-RAD lung 5, start 1, Feng's goal {goal}"
    if goal == 2:
        point = _case_target_mm(medrad_dir) + np.asarray(FENG_GOAL2_OFFSET_MM)
        tau = doc["goal"]["tolerance_mm"]
        doc["goal"] = {"point_mm": [float(v) for v in point], "tolerance_mm": tau}
    return doc


def _write_scenario(path, doc: dict, goal: str) -> Path:
    import yaml

    how = (
        "Med-RAD's target (in the nodule)"
        if goal == "goal1"
        else f"Med-RAD's target moved by Feng's goal offset {list(FENG_GOAL2_OFFSET_MM)} mm (RAS)"
    )
    head = (
        f"# Feng et al.'s protocol on Med-RAD lung 5, start 1: {goal}, {how}.\n"
        "# Written by `needlekit study feng-lungs`; sweep it with `needlekit sweep`.\n"
    )
    return write_text(path, head + yaml.safe_dump(doc, sort_keys=False))


def _case_record(p) -> dict:
    """The record's ``case``: the start, its normal, the collision model and goal 2's offset."""
    return {
        "medrad": "lung patient 5 (LIDC525), start1",
        "start_point_mm": [float(v) for v in p.start_point_mm],
        "puncture_normal": [float(v) for v in p.puncture_normal],
        "puncture_normal_source": p.metadata.get("puncture_normal_source"),
        "collision_model": p.collision_model,
        "field_error_bound_mm": float(p.scene.obstacle_field(0.0).error_bound_mm),
        "goal2_offset_mm": list(FENG_GOAL2_OFFSET_MM),
    }


def _check_goal(problem, goal: str) -> None:
    """A target must lie in free space and within l_max of the start (before any sweep)."""
    field = problem.scene.obstacle_field(0.0)  # certified: less the field's error bound
    clear = float(field.signed_distance(problem.goal_mm)) - field.error_bound_mm
    margin = problem.clearance_margin_mm
    if clear <= margin:
        raise InvalidInputError(
            goal, f"{np.round(problem.goal_mm, 3).tolist()} is {clear:.2f} mm from an obstacle; "
            f"the needle needs {margin:g} mm",
        )  # fmt: skip
    dist = float(np.linalg.norm(problem.goal_mm - problem.start_point_mm))
    if dist >= problem.max_length_mm:
        raise InvalidInputError(
            goal, f"{dist:.1f} mm from the start, beyond l_max = {problem.max_length_mm:g} mm"
        )
