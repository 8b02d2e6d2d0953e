"""Result files read back: which command wrote a JSON file, checked before any work.

The commands write their results as JSON (``plan.json``, ``sweep.json``, ``cfrw.json``,
``multi.json``, ``puncture.json``, the ``dynamic.json`` of ``plan --dynamic``, the
``execute.json`` of ``execute``, the ``scale.json`` of ``bench scale``, the
``approach.json`` of ``approach``, the ``feng_lungs.json`` of ``study feng-lungs``);
``needlekit report`` draws any of them again. Here, file handling only:
:func:`result_kind`, the kind of a result document from the fields that only that kind
has (:data:`KIND_FIELDS`), and :class:`ResultFile`, a file read and checked. Reading one
(every field checked by the result types' own ``from_dict``, its scenario located and
checked) is :func:`needlekit.scenario.results.read_result`, above planning.

A sweep file keeps each planner's best plan, not every direction's path; CFRW and
multi-needle files keep no blocking reason per direction nor entry points (the report
recomputes the maps from the scenario); a run among moving obstacles keeps the motions,
not the obstacles' shapes (the scenario gives them).
"""

from __future__ import annotations

import enum
import os
from dataclasses import dataclass
from pathlib import Path

from needlekit.errors import InvalidInputError

__all__ = [
    "FENG_GOAL_FILES",
    "KIND_FIELDS",
    "ResultFile",
    "ResultKind",
    "result_kind",
    "scenario_reference",
]


def scenario_reference(scenario: str | os.PathLike, result_path: str | os.PathLike) -> str:
    """How a result file names its scenario: the scenario's path relative to the folder the
    result is written to. A report resolves it there and nowhere else (not against the
    working folder it happens to run in), so the pair can be moved together.

    Parameters
    ----------
    scenario : path-like
        The scenario file, as the command was given it.
    result_path : path-like
        Where the result is written.

    Returns
    -------
    str
    """
    folder = os.path.dirname(os.path.abspath(result_path))
    return os.path.relpath(os.path.abspath(scenario), folder)


class ResultKind(enum.Enum):
    """What wrote a result file."""

    PLAN = "plan"  # needlekit plan, or sweep --plan
    GOALS = "goals"  # needlekit plan --goals
    SWEEP = "sweep"
    CFRW = "cfrw"
    MULTI = "multi"
    PUNCTURE = "puncture"
    DYNAMIC = "dynamic"  # needlekit plan --dynamic
    SCALE = "scale"  # needlekit bench scale
    EXECUTE = "execute"  # needlekit execute
    EXECUTE_MULTI = "execute-multi"  # needlekit execute SCENARIO multi.json
    APPROACH = "approach"  # needlekit approach
    FENG_LUNGS = "feng-lungs"  # needlekit study feng-lungs (its feng_lungs.json)

    @property
    def label(self) -> str:
        """The kind in words, with the command that writes it."""
        return _LABELS[self]

    @property
    def word(self) -> str:
        """The kind in a word or two (what ``needlekit report`` says it drew)."""
        return _WORDS[self]

    @property
    def needs_scenario(self) -> bool:
        """Whether drawing it needs the scenario it was made from (the Feng study reads
        the scenarios it wrote in its own folder)."""
        return self not in (ResultKind.PUNCTURE, ResultKind.SCALE, ResultKind.FENG_LUNGS)


_LABELS = {
    ResultKind.PLAN: "steerable-needle plan (needlekit plan)",
    ResultKind.GOALS: "plans to several targets (needlekit plan --goals)",
    ResultKind.SWEEP: "start-direction sweep (needlekit sweep)",
    ResultKind.CFRW: "collision-free reachable workspace (needlekit cfrw)",
    ResultKind.MULTI: "straight multi-needle plan (needlekit multi)",
    ResultKind.PUNCTURE: "puncture simulation study (needlekit puncture)",
    ResultKind.DYNAMIC: "re-planning among moving obstacles (needlekit plan --dynamic)",
    ResultKind.SCALE: "scaling curves (needlekit bench scale)",
    ResultKind.EXECUTE: "plan execution, open beside closed loop (needlekit execute)",
    ResultKind.EXECUTE_MULTI: "straight plan inserted by the robot (needlekit execute multi.json)",
    ResultKind.APPROACH: "approach analysis of a skin mesh (needlekit approach)",
    ResultKind.FENG_LUNGS: "Feng et al.'s protocol on a Med-RAD lung (needlekit study feng-lungs)",
}

_WORDS = {
    ResultKind.PLAN: "plan",
    ResultKind.GOALS: "plans to several targets",
    ResultKind.SWEEP: "sweep",
    ResultKind.CFRW: "CFRW map",
    ResultKind.MULTI: "multi-needle plan",
    ResultKind.PUNCTURE: "puncture study",
    ResultKind.DYNAMIC: "moving-obstacle run",
    ResultKind.SCALE: "scaling curves",
    ResultKind.EXECUTE: "execution",
    ResultKind.EXECUTE_MULTI: "multi-needle execution",
    ResultKind.APPROACH: "approach analysis",
    ResultKind.FENG_LUNGS: "Feng lung study",
}

#: The top-level fields that mark each kind, tried in this order (a sweep's best plans and
#: the targets of ``plan --goals`` hold plans, so those kinds come before the plan).
KIND_FIELDS: dict[ResultKind, tuple[str, ...]] = {
    ResultKind.PUNCTURE: ("per_trial", "paper", "options", "trials"),
    ResultKind.SWEEP: ("planners", "summary", "directions", "best_plans"),
    ResultKind.GOALS: ("targets", "mode", "planner"),
    ResultKind.MULTI: ("needles", "order", "gamma_mm"),
    ResultKind.CFRW: ("feasible", "theta_deg", "phi_deg", "world_T_sigma"),
    ResultKind.DYNAMIC: ("moving", "executed", "cycles", "settings"),
    ResultKind.EXECUTE: ("plan_primitives", "trials", "summary", "seed", "options"),
    ResultKind.EXECUTE_MULTI: ("plan_needles", "registration", "trials", "summary"),
    ResultKind.PLAN: ("status", "primitives", "start_pose", "goal_mm"),
    ResultKind.SCALE: ("benchmark", "planning", "sweep", "study", "machine"),
    ResultKind.APPROACH: ("paa", "needlekit", "blocked", "target_mm"),
    ResultKind.FENG_LUNGS: ("study", "case", "feng", "goals", "settings"),
}

#: What ``needlekit study feng-lungs`` writes per target beside its ``feng_lungs.json``
#: (in ``goal1/``, ``goal2/``), which drawing the record reads: the scenario, the sweep.
FENG_GOAL_FILES: tuple[str, str] = ("scenario.yaml", "sweep.json")

#: Other needlekit records, named in the error when one is given: no command draws a
#: page of them, so neither does ``needlekit report``.
_OTHER_RECORDS = (
    (
        ("study", "settings", "summary", "rows"),
        "a study of the Med-RAD livers (`needlekit study livers`), which has no page",
    ),
    (
        ("patients", "cases", "holds", "targets"),
        "a study of executions on Med-RAD lungs (`needlekit study execute-lungs`), which has no "
        "page (each lung's plan.json and execute.json have one)",
    ),
    (("machine", "versions"), "a benchmark record (`needlekit bench`), which has no page"),
)


def result_kind(data: dict, where: str) -> ResultKind:
    """The kind of a result document.

    Parameters
    ----------
    data : dict
        The document's top level.
    where : str
        Names it in messages (the file).

    Returns
    -------
    ResultKind

    Raises
    ------
    InvalidInputError
        No kind's fields are all there.

    Examples
    --------
    >>> result_kind({"status": "solved", "primitives": [], "start_pose": None,
    ...              "goal_mm": [0, 0, 0]}, "plan.json").value
    'plan'
    """
    for kind, keys in KIND_FIELDS.items():
        if all(k in data for k in keys):
            return kind
    known = ", ".join(k.value for k in ResultKind)
    for keys, what in _OTHER_RECORDS:
        if all(k in data for k in keys):
            raise InvalidInputError(where, f"is {what}; `needlekit report` reads {known} results")
    raise InvalidInputError(where, f"not a result of a known kind ({known})")


@dataclass(frozen=True)
class ResultFile:
    """A result file, read and checked.

    Attributes
    ----------
    path : Path
    kind : ResultKind
    data : dict
        The whole document.
    scenario : Path or None
        The scenario it was made from, located (None for kinds that need none). An
        execution names it in ``scenario_file`` (its ``scenario`` is the scenario's name);
        one written before it did takes the scenario of the plan drawn with it.
    """

    path: Path
    kind: ResultKind
    data: dict
    scenario: Path | None = None
