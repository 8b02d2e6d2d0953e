"""Problems built from scenario files, with overrides, and a picklable handle to rebuild
them in batch workers.

A scenario's anatomy (a patient's masks and distance fields, or a phantom) is heavy and
slow to ship; a :class:`ScenarioSource` is a path and a few numbers. Each worker of a
process pool or Dask cluster turns it into the problem once
(:func:`needlekit.batch.worker_cached`) and reuses it for every task it runs.

The module imports only numpy at its top: the command line calls :func:`dynamic_block` and
:func:`planner_settings` before any anatomy or planner module (numba) is loaded, so those
are imported by the functions that need them.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from needlekit.constants import DEFAULT_GOAL_TOLERANCE_MM
from needlekit.errors import InvalidInputError

__all__ = [
    "DYNAMIC_SETTINGS",
    "PlannerSettings",
    "ScenarioSource",
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
    return _with_overrides(sc, path.name, start_pose, goal_mm, r_min_mm, needle_diameter_mm)


def _with_overrides(sc, name: str, start_pose, goal_mm, r_min_mm, needle_diameter_mm):
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
    if sc.start is None and start_pose is None:
        raise InvalidInputError("start", f"{name}: the scenario gives no start; pass a start pose")
    if sc.goal is None and goal_mm is None:
        raise InvalidInputError("goal", f"{name}: the scenario gives no goal; pass a goal")
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
            ``start_pose``, ``goal_mm``, ``r_min_mm``, ``needle_diameter_mm`` (as :meth:`of`).

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
        import hashlib
        import json

        if not isinstance(document, dict):
            raise InvalidInputError(
                "document", f"expected a mapping, got {type(document).__name__}"
            )
        try:
            text = json.dumps(document, sort_keys=True, separators=(",", ":"), allow_nan=False)
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
        from needlekit.batch import worker_cached

        return worker_cached(
            ("ScenarioSource", self), lambda: self._load(share_base=True, document=document)
        )

    def _load(self, share_base: bool, document=None):
        import json

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
            sc, path.name, pose, self.goal_mm, self.r_min_mm, self.needle_diameter_mm
        )


@dataclass(frozen=True)
class PlannerSettings:
    """A run's planner settings: the scenario's ``planner`` block under the caller's
    overrides (the command line's flags), read the same way by ``plan``, ``sweep`` and the
    studies.

    Attributes
    ----------
    names : tuple of str
        Planners to run (the first is the main one).
    time_limit_s : float
    seed : int
    max_iterations : int or None
    options : dict
        Per planner name, its options (a mapping of the options dataclass's fields, the
        seed rule applied: :func:`needlekit.planning.interface.seeded_options`), their
        names checked; their values are checked when :meth:`build` builds the planners.
    """

    names: tuple[str, ...]
    time_limit_s: float
    seed: int
    max_iterations: int | None
    options: dict

    def seed_for(self, name: str) -> int:
        """The seed planner ``name`` runs with (its options' ``seed``, else the run's).

        Parameters
        ----------
        name : str

        Returns
        -------
        int
        """
        return int(self.options[name].get("seed", self.seed))

    def build(self) -> dict:
        """Every planner of the run, built once (the values of their options checked).

        Returns
        -------
        dict
            Planner name -> planner, in the order of :attr:`names`.

        Raises
        ------
        InvalidInputError
            An option's value out of range (naming the option).
        """
        from needlekit.planning.interface import get_planner

        return {name: get_planner(name, self.options[name]) for name in self.names}

    @property
    def name(self) -> str:
        """The main planner."""
        return self.names[0]

    def termination(self):
        """The budget.

        Returns
        -------
        needlekit.planning.interface.Termination
        """
        from needlekit.planning.interface import Termination

        return Termination(self.time_limit_s, self.max_iterations)


def planner_settings(
    block: dict | None,
    *,
    names=None,
    time_limit_s: float | None = None,
    seed: int | None = None,
    max_iterations: int | None = None,
    options: dict | None = None,
    family: str = "steerable",
) -> PlannerSettings:
    """Merge a scenario's ``planner`` block with overrides, and check the planners' names,
    families and option names once, without importing a planner (the values are checked
    when :meth:`PlannerSettings.build` builds them).

    Parameters
    ----------
    block : dict or None
        The scenario's ``planner`` block (``name``, ``time_limit_s``, ``seed``,
        ``max_iterations``, ``options`` of the named planner).
    names : str or sequence of str, optional
        Planners to run instead of the block's ``name`` (default ``rcs_star``).
    time_limit_s, seed, max_iterations : optional
        Override the block's values.
    options : dict, optional
        Per planner name, settings that override the block's (e.g.
        ``{"rrt": {"connection": "arc"}}``); a dict given for a dataclass-typed option
        (RCS's ``resolution``) replaces only the fields it names.
    family : str
        The planners' family (``steerable`` or ``straight``): others are refused.

    Returns
    -------
    PlannerSettings

    Raises
    ------
    InvalidInputError
        Unknown planner, one of another family, or an unknown option (naming it), before
        any work.
    """
    from needlekit.constants import DEFAULT_TIME_LIMIT_S
    from needlekit.planning.interface import check_planner_options, seeded_options

    block = dict(block or {})
    if names is None:
        names = [block.get("name") or "rcs_star"]
    elif isinstance(names, str):
        names = [names]
    names = tuple(dict.fromkeys(names))
    if not names:
        raise InvalidInputError("planner", "expected at least one planner")
    fallback = block.get("seed", 0)
    checked = {}
    for name in names:
        opts = _merged(
            block.get("options") if name == block.get("name") else None,
            (options or {}).get(name),
        )
        check_planner_options(name, opts, family=family)  # name, family, option names
        # the flag wins over the options (block's, then --option), which win over the block's seed
        checked[name] = dict(seeded_options(name, opts, seed, fallback=fallback))
    return PlannerSettings(
        names,
        float(
            time_limit_s
            if time_limit_s is not None
            else block.get("time_limit_s", DEFAULT_TIME_LIMIT_S)
        ),
        int(seed if seed is not None else fallback),
        max_iterations if max_iterations is not None else block.get("max_iterations"),
        checked,
    )


def _merged(block, overrides) -> dict:
    """A planner's options: the block's under the overrides, a field of a dataclass-typed
    option replacing only that field."""
    out = dict(block or {})
    for key, value in (overrides or {}).items():
        if isinstance(value, dict) and isinstance(out.get(key), dict):
            value = {**out[key], **value}
        out[key] = value
    return out


def multi_problem_from_scenario(scenario, *, targets_mm=None):
    """The straight multi-needle problem a scenario's ``straight`` block describes.

    The needle is the scenario's (radius half its diameter plus nothing: gamma is the
    block's safety distance; ``max_length_mm``). Sigma's z axis (``up``) defaults to the
    reverse of the start's z axis (the direction the needle comes from), else RAS +z; the
    approach cone, when given, is around that same direction.

    Parameters
    ----------
    scenario : needlekit.scenario.loading.Scenario or path-like
    targets_mm : array_like, shape (k, 3), optional
        Replace the block's targets.

    Returns
    -------
    problem : MultiNeedleProblem
    options : dict
        The planner settings of the block (``resolution_deg``, ``objective``, ``order``).

    Raises
    ------
    InvalidInputError
        No ``straight`` block, or a field out of range (named).
    """
    from needlekit.planning.straight.deformation import GridDeformation, NeedleDragDeformation
    from needlekit.planning.straight.planner import MultiNeedleProblem
    from needlekit.planning.straight.problem import StraightNeedle, StraightProblem
    from needlekit.scenario.loading import Scenario, load_scenario

    sc = scenario if isinstance(scenario, Scenario) else load_scenario(scenario)
    block = dict(sc.straight or {})
    if not block:
        raise InvalidInputError("straight", "the scenario has no straight block")
    if targets_mm is not None:
        targets = np.asarray(targets_mm, dtype=float)
    elif isinstance(block["targets"], str):  # coverage: chosen later; a stand-in till then
        field = sc.scene[block["coverage"]["structure"]].field
        targets = np.asarray(field.bounds(), dtype=float).reshape(2, 3).mean(axis=0)[None]
    else:
        targets = block["targets"]
    came_from = (
        None if sc.start is None or sc.start.world_T_tip is None else -sc.start.world_T_tip[:3, 2]
    )
    up = block.get("up", came_from if came_from is not None else np.array([0.0, 0.0, 1.0]))
    kw = {}
    for key in ("gamma_mm", "theta_range_deg", "phi_range_deg", "max_normal_angle_deg"):
        if key in block:
            kw[key] = block[key]
    if "approach_cone_deg" in block:
        if came_from is None:
            raise InvalidInputError(
                "straight.approach_cone_deg", "needs a start pose (its reversed z is the axis)"
            )
        kw["approach_direction"] = came_from
        kw["approach_cone_deg"] = block["approach_cone_deg"]
    needle = StraightNeedle(0.5 * sc.needle.diameter_mm, sc.needle.max_length_mm)
    scene = _body_with_targets(sc, block["entry_surface"])
    problem = StraightProblem(
        scene, np.asarray(targets)[0], block["entry_surface"], needle, up=up, **kw
    )
    deformation = block.get("deformation", "none")
    if deformation == "needle_drag":
        model = NeedleDragDeformation()
    elif isinstance(deformation, dict):
        model = GridDeformation(deformation["grid"])
    else:
        model = None
    options = {k: block[k] for k in ("resolution_deg", "objective", "order") if k in block}
    return MultiNeedleProblem(problem, targets, model), options


def _body_with_targets(sc, entry_surface: str):
    """The scene, with a Med-RAD organ's entry surface closed over its nodules.

    Med-RAD's liver (and lung) masks leave the nodules out: the organ's field is positive
    inside a nodule, so a target there would lie outside the body. The body is the organ
    together with its targets (their union); its outer surface is still the capsule.
    """
    from dataclasses import replace as _replace

    from needlekit.anatomy.fields import union
    from needlekit.anatomy.scene import Role, Scene
    from needlekit.io.medrad import MedradCase

    if not isinstance(sc.base, MedradCase) or entry_surface not in sc.scene:
        return sc.scene
    organ = sc.scene[entry_surface]
    nodules = [s.field for s in sc.scene.by_role(Role.TARGET)]
    if organ.role is not Role.ALLOWED_REGION or not nodules:
        return sc.scene
    body = _replace(organ, field=union(organ.field, *nodules))
    structures = [body if s.name == entry_surface else s for s in sc.scene.structures]
    return Scene(structures, name=sc.scene.name, obstacle_field=sc.scene.obstacle_field())


def coverage_region(scenario, problem):
    """The tumour-plus-margin region and zone of a scenario's ``straight.coverage`` block.

    The tumour is the block's ``structure``: its mask file when it has one (a Med-RAD
    nodule's NIfTI, on its own grid), else its field voxelised at ``voxel_mm``
    (``signed_distance <= 0``). With ``clip_to_body`` the margin counts only inside the
    problem's entry surface.

    Parameters
    ----------
    scenario : needlekit.scenario.loading.Scenario
    problem : StraightProblem
        From :func:`multi_problem_from_scenario` (its entry surface is the body).

    Returns
    -------
    region : TargetRegion
    settings : dict
        The block: ``zone`` (AblationZone), ``margin_mm``, ``max_needles``,
        ``coverage_goal``, ``structure``, ``voxel_mm``, ``clip_to_body``.
    """
    from needlekit.planning.straight.ablation import clip_region, voxelise
    from needlekit.planning.straight.coverage import target_region

    settings = dict((scenario.straight or {}).get("coverage") or {})
    if not settings:
        raise InvalidInputError("straight.targets", "expected targets: coverage")
    s = scenario.scene[settings["structure"]]
    src = Path(s.source) if s.source else None
    if src is not None and src.suffix in (".gz", ".nii", ".nrrd", ".mha") and src.is_file():
        from needlekit.io.volumes import read_mask

        m = read_mask(src)
        region = target_region(m.data, m.affine, settings["margin_mm"])
    else:
        mask, affine = voxelise(s.field, settings["voxel_mm"])
        region = target_region(mask, affine, settings["margin_mm"])
    if settings["clip_to_body"]:
        region = clip_region(region, problem.scene[problem.entry_surface].field)
    return region, settings


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
    from needlekit.io.scenario_schema import read_scenario_document

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


def moving_case(source: ScenarioSource, document=None):
    """A scenario with moving obstacles, split for re-planning.

    Parameters
    ----------
    source : ScenarioSource
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
