"""Problems built from scenario files, with overrides, and a picklable handle to rebuild
them in batch workers.

A scenario's anatomy (a patient's masks and distance fields, or a phantom) is heavy and
slow to ship; a :class:`ScenarioSource` is a path and a few numbers. Each worker of a
process pool or Dask cluster turns it into the problem once
(:func:`needlekit.batch.worker_cached`) and reuses it for every task it runs.

The module imports only numpy at its top (the anatomy and the planners are imported by the
functions that need them). The planner settings (:mod:`needlekit.scenario.planners`), the
straight multi-needle problem (:mod:`needlekit.scenario.straight`) and the moving-obstacle
settings (:mod:`needlekit.scenario.dynamic`) have modules of their own, whose names this
module re-exports.
"""

from __future__ import annotations

import hashlib
import json
import os
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from needlekit.batch import worker_cached
from needlekit.constants import DEFAULT_GOAL_TOLERANCE_MM
from needlekit.errors import InvalidInputError, OutputError
from needlekit.io.files import json_text
from needlekit.scenario.dynamic import (  # re-exported (they lived here)
    DYNAMIC_SETTINGS,
    checked_dynamic_settings,
    dynamic_block,
    dynamic_settings,
    moving_case,
)
from needlekit.scenario.extent import anatomy_box, check_inside_anatomy
from needlekit.scenario.planners import PlannerSettings, planner_settings  # re-exported
from needlekit.scenario.straight import (  # re-exported
    coverage_region,
    multi_problem_from_scenario,
)

__all__ = [
    "DYNAMIC_SETTINGS",
    "PlannerSettings",
    "ScenarioSource",
    "checked_dynamic_settings",
    "coverage_region",
    "dynamic_block",
    "dynamic_settings",
    "load_problem",
    "moving_case",
    "multi_problem_from_scenario",
    "planner_settings",
    "problem_from_scenario",
]


def load_problem(
    scenario_path: str | os.PathLike,
    *,
    start_pose=None,
    goal_mm=None,
    r_min_mm: float | None = None,
    needle_diameter_mm: float | None = None,
    cache_dir: str | os.PathLike | None = None,
    use_cache: bool = True,
    safety_margin_mm: float | None = None,
):
    """Load a scenario file and build its steerable-needle problem.

    Parameters
    ----------
    scenario_path : str or path
        A scenario YAML file (``docs/scenarios.md``).
    start_pose : array_like, shape (4, 4), optional
        Replaces the scenario's start.
    goal_mm : array_like, shape (3,), optional
        Replaces the scenario's goal point (tolerance kept, default 1 mm).
    r_min_mm, needle_diameter_mm : float, optional
        Replace the scenario's needle values.
    cache_dir : path-like, optional
        Root of the prepared-anatomy cache (default: the user cache folder).
    use_cache : bool
        Load a Med-RAD base's prepared anatomy from that cache, or store it there.
    safety_margin_mm : float, optional
        Replaces the scenario's ``needle.safety_margin_mm``.

    Returns
    -------
    scenario : needlekit.scenario.loading.Scenario
        With the start and goal filled in from the overrides where it lacked them.
    problem : SteerableProblem
        With the scenario's collision model (:func:`problem_from_scenario`).

    Raises
    ------
    InvalidInputError
        Missing start or goal, or a bad override.
    """
    from needlekit.scenario.loading import load_scenario

    path = Path(scenario_path)
    sc = load_scenario(path, cache_dir=cache_dir, use_cache=use_cache)
    return _with_overrides(
        sc, path.name, start_pose, goal_mm, r_min_mm, needle_diameter_mm, safety_margin_mm
    )


def _with_overrides(
    sc, name: str, start_pose, goal_mm, r_min_mm, needle_diameter_mm, safety_margin_mm=None
):
    """:func:`load_problem`'s overrides applied to a loaded scenario."""
    from needlekit.scenario.loading import GoalSpec, StartSpec

    overrides: dict = {}
    if start_pose is not None:
        pose = np.asarray(start_pose, dtype=float)
        if pose.shape != (4, 4):
            raise InvalidInputError("start_pose", f"expected a 4x4 pose, got shape {pose.shape}")
        overrides["start_pose"] = pose
        overrides["start_point_mm"] = None
    if goal_mm is not None:
        overrides["goal_mm"] = np.asarray(goal_mm, dtype=float)
    if r_min_mm is not None:
        overrides["r_min_mm"] = r_min_mm
    if needle_diameter_mm is not None:
        overrides["needle_diameter_mm"] = needle_diameter_mm
    if safety_margin_mm is not None:
        overrides["safety_margin_mm"] = safety_margin_mm
    if sc.start is None and start_pose is None:
        raise InvalidInputError("start", f"{name}: the scenario gives no start; pass a start pose")
    if sc.goal is None and goal_mm is None:
        raise InvalidInputError("goal", f"{name}: the scenario gives no goal; pass a goal")
    if goal_mm is not None or start_pose is not None:  # where the anatomy is, before any search
        box = anatomy_box(sc.scene)
        if start_pose is not None:
            check_inside_anatomy(overrides["start_pose"][:3, 3], box, "start_pose")
        if goal_mm is not None:
            check_inside_anatomy(overrides["goal_mm"], box, "goal_mm")
    if sc.start is None or sc.goal is None:  # fill what the scenario lacks
        start = sc.start or StartSpec(
            overrides["start_pose"][:3, 3], overrides["start_pose"], "start_pose override"
        )
        goal = sc.goal or GoalSpec(overrides["goal_mm"], DEFAULT_GOAL_TOLERANCE_MM, "goal override")
        sc = replace(sc, start=start, goal=goal)
    return sc, problem_from_scenario(sc, **overrides)


def problem_from_scenario(scenario, **overrides):
    """The steerable-needle problem a scenario describes.

    Parameters
    ----------
    scenario : needlekit.scenario.loading.Scenario or path-like
        A loaded scenario or a scenario file.
    **overrides
        :class:`~needlekit.planning.steerable.problem.SteerableProblem` attributes to set
        instead of the scenario's (e.g. ``r_min_mm=100``, ``start_pose=...``).

    Returns
    -------
    SteerableProblem
        With the scenario's collision model; for ``voxel_centres`` its obstacle voxels are
        built from the scenario's base for the problem's needle.

    Raises
    ------
    InvalidInputError
        No start or goal, or a collision model the scenario's anatomy cannot give.
    """
    from needlekit.io.medrad import MedradCase
    from needlekit.planning.steerable.problem import CollisionModel, CostKind, SteerableProblem
    from needlekit.scenario.loading import Scenario, load_scenario

    sc = scenario if isinstance(scenario, Scenario) else load_scenario(scenario)
    if sc.start is None and "start_pose" not in overrides:
        raise InvalidInputError("start", "the scenario gives no start")
    if sc.goal is None and "goal_mm" not in overrides:
        raise InvalidInputError("goal", "the scenario gives no goal")
    n = sc.needle
    kw = {
        "scene": sc.scene,
        "goal_mm": None if sc.goal is None else sc.goal.point_mm,
        "start_pose": None if sc.start is None else sc.start.world_T_tip,
        "start_point_mm": None if sc.start is None else sc.start.point_mm,
        "r_min_mm": n.r_min_mm,
        "max_length_mm": n.max_length_mm,
        "needle_diameter_mm": n.diameter_mm,
        "safety_margin_mm": n.safety_margin_mm,
        "min_puncture_angle_deg": n.min_puncture_angle_deg,
        "max_heading_change_deg": n.max_heading_change_deg,
        "start_exclusion_mm": n.start_exclusion_mm,
        "collision_model": sc.collision_model,
        "collision_options": dict(sc.collision_options) or None,
    }
    if sc.goal is not None:
        kw["goal_tolerance_mm"] = sc.goal.tolerance_mm
    cost = (sc.planner or {}).get("cost")
    if cost:
        kw["cost"] = cost.get("kind", CostKind.PATH_LENGTH.value)
        for key, name in (("weight", "cost_weight"), ("reach_mm", "cost_reach_mm")):
            if key in cost:
                kw[name] = cost[key]
    kw.update(overrides)
    if kw.get("start_pose") is not None and "start_point_mm" not in overrides:
        kw["start_point_mm"] = None
    # the built-in voxel model's data comes from the scenario's base (a user's checker
    # takes what it needs from its setup: scene, needle, start, options)
    if kw["collision_model"] == CollisionModel.VOXEL_CENTRES and kw.get("voxel_obstacles") is None:
        if not isinstance(sc.base, MedradCase):
            raise InvalidInputError(
                "collision_model",
                "voxel_centres needs obstacle voxels: a scenario with a medrad base "
                "(use collision_model: field for phantoms and shapes)",
            )
        margin = float(kw["safety_margin_mm"])
        kw["voxel_obstacles"] = sc.base.voxel_obstacles(float(kw["needle_diameter_mm"]), margin)
    return SteerableProblem(**kw)


def _frozen(value):
    if value is None:
        return None
    a = np.asarray(value, dtype=float)
    return tuple(a.ravel().tolist()) if a.ndim else float(a)


@dataclass(frozen=True)
class ScenarioSource:
    """A picklable, hashable recipe for :func:`load_problem`.

    Attributes
    ----------
    scenario_path : str
        Absolute path of the scenario file (workers may run in other directories).
    start_pose : tuple of 16 floats or None
    goal_mm : tuple of 3 floats or None
    r_min_mm, needle_diameter_mm : float or None
    cache_dir : str or None
        Root of the prepared-anatomy cache (None: the user cache folder).
    use_cache : bool
    document : str or None
        The scenario itself as canonical JSON (:meth:`of_document`); None: read the file.
    document_sha256 : str or None
        Its digest, which identifies the source in place of the text.
    safety_margin_mm : float or None
        Replaces the scenario's safety margin (``--safety-margin-mm``).
    """

    scenario_path: str
    start_pose: tuple | None = None
    goal_mm: tuple | None = None
    r_min_mm: float | None = None
    needle_diameter_mm: float | None = None
    cache_dir: str | None = None
    use_cache: bool = True
    document: str | None = field(default=None, compare=False, repr=False)
    document_sha256: str | None = None
    safety_margin_mm: float | None = None

    @classmethod
    def of(
        cls,
        scenario_path: str | os.PathLike,
        *,
        start_pose=None,
        goal_mm=None,
        r_min_mm: float | None = None,
        needle_diameter_mm: float | None = None,
        cache_dir: str | os.PathLike | None = None,
        use_cache: bool = True,
        safety_margin_mm: float | None = None,
    ) -> ScenarioSource:
        """A source from the same arguments as :func:`load_problem`.

        Parameters
        ----------
        scenario_path : str or path
        start_pose : array_like, shape (4, 4), optional
        goal_mm : array_like, shape (3,), optional
        r_min_mm, needle_diameter_mm : float, optional
        cache_dir : str or path, optional
        use_cache : bool
        safety_margin_mm : float, optional

        Returns
        -------
        ScenarioSource
        """
        return cls(
            str(Path(scenario_path).resolve()),
            _frozen(start_pose),
            _frozen(goal_mm),
            None if r_min_mm is None else float(r_min_mm),
            None if needle_diameter_mm is None else float(needle_diameter_mm),
            None if cache_dir is None else str(Path(cache_dir).expanduser().resolve()),
            bool(use_cache),
            safety_margin_mm=None if safety_margin_mm is None else float(safety_margin_mm),
        )

    @classmethod
    def of_document(
        cls,
        document: dict,
        base_dir: str | os.PathLike = ".",
        *,
        name: str = "scenario.yaml",
        cache_dir: str | os.PathLike | None = None,
        use_cache: bool = True,
        **overrides,
    ) -> ScenarioSource:
        """A source that carries the scenario document itself: workers on other machines,
        which cannot read a file written here, build the problem from it.

        The document travels as canonical JSON (sorted keys) and the source is identified
        by its SHA-256, so equal documents share a worker's cached problem. Files the
        document names (a Med-RAD ``root``, point files) must exist at the same paths on
        the workers; relative ones are read against ``base_dir``.

        Parameters
        ----------
        document : dict
            The scenario (``docs/scenarios.md``), checked when a worker builds it.
        base_dir : str or path
            Folder that relative paths in the document are resolved against.
        name : str
            Name of the document in error messages.
        cache_dir : str or path, optional
        use_cache : bool
        **overrides
            ``start_pose``, ``goal_mm``, ``r_min_mm``, ``needle_diameter_mm``,
            ``safety_margin_mm`` (as :meth:`of`).

        Returns
        -------
        ScenarioSource

        Raises
        ------
        InvalidInputError
            A document JSON cannot hold (not a mapping, a non-finite number, an object).

        Examples
        --------
        >>> doc = {"version": 1, "structures": []}
        >>> a = ScenarioSource.of_document(doc, "/tmp")
        >>> a == ScenarioSource.of_document(dict(reversed(doc.items())), "/tmp")
        True
        """
        if not isinstance(document, dict):
            raise InvalidInputError(
                "document", f"expected a mapping, got {type(document).__name__}"
            )
        try:
            text = json_text(document, "document", sort_keys=True, separators=(",", ":"))
        except OutputError as exc:  # NaN or infinity: named by its field
            raise InvalidInputError(exc.field, "expected a finite number") from None
        except (TypeError, ValueError) as exc:
            raise InvalidInputError("document", f"not a JSON document ({exc})") from None
        path = Path(base_dir).expanduser().resolve() / name
        src = cls.of(path, cache_dir=cache_dir, use_cache=use_cache, **overrides)
        return replace(
            src, document=text, document_sha256=hashlib.sha256(text.encode()).hexdigest()
        )

    def load(self, document=None):
        """Build the problem (no caching; see :meth:`cached`).

        Parameters
        ----------
        document : ScenarioDocument, optional
            The scenario file's document as this process read and checked it already
            (:func:`needlekit.io.scenario_schema.read_scenario_document`): not read again.

        Returns
        -------
        tuple
            ``(scenario, problem)`` as from :func:`load_problem`.
        """
        return self._load(share_base=False, document=document)

    def cached(self, document=None):
        """Build the problem once per process (batch workers reuse it across tasks), and a
        Med-RAD base once per process for every source of that patient.

        Parameters
        ----------
        document : ScenarioDocument, optional
            As for :meth:`load` (workers read the file themselves).

        Returns
        -------
        tuple
            ``(scenario, problem)``.
        """
        return worker_cached(
            ("ScenarioSource", self), lambda: self._load(share_base=True, document=document)
        )

    def without_margin(self):
        """The scenario's problem without its safety margin, built once per process: the
        anatomy and collision model that ``needlekit execute`` judges executed paths by.

        Returns
        -------
        SteerableProblem
        """
        sc, _ = self.cached()
        return worker_cached(("ScenarioSource without margin", self),
                             lambda: problem_from_scenario(sc, safety_margin_mm=0.0))  # fmt: skip

    def _load(self, share_base: bool, document=None):
        from needlekit.scenario.loading import load_scenario

        path = Path(self.scenario_path)
        inline = self.document is not None
        if inline:
            document = json.loads(self.document)
        sc = load_scenario(
            path,
            cache_dir=self.cache_dir,
            use_cache=self.use_cache,
            document=document,
            share_base=share_base,
        )
        if inline:  # no file stands behind it
            sc = replace(sc, path=None)
        pose = None if self.start_pose is None else np.reshape(self.start_pose, (4, 4))
        return _with_overrides(
            sc, path.name, pose, self.goal_mm, self.r_min_mm, self.needle_diameter_mm,
            self.safety_margin_mm,
        )  # fmt: skip
