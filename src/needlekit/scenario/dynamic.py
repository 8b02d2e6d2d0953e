"""Re-planning among moving obstacles: the settings a scenario's ``dynamic`` block (or
the flags) gives, checked in two steps (what needs no planner module, then the values), and
the scenario split into its static problem and its moving obstacles.

The module imports nothing heavy at its top: the command line calls :func:`dynamic_block`
before any anatomy or planner module (numba) is loaded.
"""

from __future__ import annotations

import os
from dataclasses import replace
from pathlib import Path

from needlekit.errors import InvalidInputError
from needlekit.io.scenario_schema import read_scenario_document

__all__ = [
    "DYNAMIC_SETTINGS",
    "checked_dynamic_settings",
    "dynamic_block",
    "dynamic_settings",
    "moving_case",
]


#: The re-planning settings a scenario's ``dynamic`` block (or the flags) may give.
DYNAMIC_SETTINGS = ("insertion_speed_mm_s", "step_mm", "predict", "lookahead_s")


def dynamic_block(doc: dict, name: str, given: dict | None = None) -> dict:
    """What a scenario document gives for re-planning among moving obstacles, under
    ``given`` (flags win), checked for what needs no planner module: a structure that
    moves, and an insertion speed somewhere (the command line calls it before importing
    them; :func:`dynamic_settings` then checks the values).

    Parameters
    ----------
    doc : dict
        The scenario document (as :func:`needlekit.io.scenario_schema.read_scenario_document`
        returns it).
    name : str
        The document's name in messages.
    given : dict, optional
        Settings named as :data:`DYNAMIC_SETTINGS` (None values are ignored).

    Returns
    -------
    dict
        The settings given, by name.

    Raises
    ------
    InvalidInputError
        No structure moves, or no insertion speed anywhere.
    """
    if not any("moving" in s for s in doc.get("structures", [])):
        raise InvalidInputError("--dynamic", f"{name}: no structure has a moving block")
    kw = {k: v for k, v in doc.get("dynamic", {}).items() if k in DYNAMIC_SETTINGS}
    kw |= {k: v for k, v in (given or {}).items() if v is not None}
    if "insertion_speed_mm_s" not in kw:
        raise InvalidInputError(
            "--insertion-speed-mm-s",
            f"{name} has no dynamic.insertion_speed_mm_s; give the insertion speed",
        )
    return kw


def dynamic_settings(scenario_path: str | os.PathLike, given: dict | None = None) -> dict:
    """The re-planning settings of a scenario with moving obstacles, checked, before any
    anatomy is read: its ``dynamic`` block under ``given`` (flags win).

    Parameters
    ----------
    scenario_path : path-like
    given : dict, optional
        Settings named as :data:`DYNAMIC_SETTINGS` (None values are ignored).

    Returns
    -------
    dict
        ``insertion_speed_mm_s``, ``step_mm``, ``predict`` and, where given,
        ``lookahead_s``: the keyword arguments of
        :func:`needlekit.planning.steerable.dynamic.replan_among_moving`.

    Raises
    ------
    InvalidInputError
        No structure moves, no insertion speed anywhere, or a bad setting.
    """
    doc = read_scenario_document(scenario_path)
    return checked_dynamic_settings(dynamic_block(doc, Path(scenario_path).name, given))


def checked_dynamic_settings(given: dict) -> dict:
    """What :func:`dynamic_block` gave, with the defaults, every value checked.

    Parameters
    ----------
    given : dict
        From :func:`dynamic_block`.

    Returns
    -------
    dict
        As :func:`dynamic_settings`.

    Raises
    ------
    InvalidInputError
        A bad setting.
    """
    from needlekit.planning.steerable.dynamic import (
        DEFAULT_STEP_MM,
        PREDICTIONS,
        check_settings,
    )

    kw = dict(given)
    kw.setdefault("step_mm", DEFAULT_STEP_MM)
    kw.setdefault("predict", PREDICTIONS[0])
    check_settings(**kw)
    return kw


def moving_case(source, document=None):
    """A scenario with moving obstacles, split for re-planning.

    Parameters
    ----------
    source : needlekit.scenario.problems.ScenarioSource
    document : ScenarioDocument, optional
        The file's document, read and checked already (:meth:`ScenarioSource.load`).

    Returns
    -------
    scenario : Scenario
    static : SteerableProblem
        The problem among the structures that do not move.
    moving : list of MovingObstacle
        The moving structures, each with its motion (its shape as written is where it is at
        ``t = 0``).
    """
    from needlekit.planning.steerable.moving import Motion, MovingObstacle

    sc, problem = source.load(document)
    static = replace(problem, scene=sc.static_scene)
    moving = [
        MovingObstacle(name, sc.scene[name].field, Motion(**m), sc.scene[name].color)
        for name, m in sc.moving.items()
    ]
    return sc, static, moving
