"""Problems built from scenario files, with overrides, and a picklable handle to rebuild
them in batch workers.

A scenario's anatomy (a patient's masks and distance fields, or a phantom) is heavy and
slow to ship; a :class:`ScenarioSource` is a path and a few numbers. Each worker of a
process pool or Dask cluster turns it into the problem once
(:func:`needlekit.batch.worker_cached`) and reuses it for every task it runs.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from needlekit.errors import InvalidInputError

__all__ = ["ScenarioSource", "load_problem"]


def load_problem(
    scenario_path: str | os.PathLike,
    *,
    start_pose=None,
    goal_mm=None,
    r_min_mm: float | None = None,
    needle_diameter_mm: float | None = None,
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

    Returns
    -------
    scenario : needlekit.io.scenario.Scenario
        With the start and goal filled in from the overrides where it lacked them.
    problem : SteerableProblem
    obstacles : VoxelObstacles or None
        The exact voxel-centre collision test for Med-RAD cases (the reference planner's
        model), else None (the scene's obstacle field is used).

    Raises
    ------
    InvalidInputError
        Missing start or goal, or a bad override.
    """
    from needlekit.io.scenario import GoalSpec, StartSpec, load_scenario
    from needlekit.planning.steerable.problem import SteerableProblem

    path = Path(scenario_path)
    sc = load_scenario(path)
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
        raise InvalidInputError(
            "start", f"{path.name}: the scenario gives no start; pass a start pose"
        )
    if sc.goal is None and goal_mm is None:
        raise InvalidInputError("goal", f"{path.name}: the scenario gives no goal; pass a goal")
    if sc.start is None or sc.goal is None:  # fill what the scenario lacks
        start = sc.start or StartSpec(
            overrides["start_pose"][:3, 3], overrides["start_pose"], "start_pose override"
        )
        goal = sc.goal or GoalSpec(overrides["goal_mm"], 1.0, "goal override")
        sc = type(sc)(
            sc.name, sc.description, sc.scene, sc.needle, start, goal, sc.planner, sc.path, sc.base
        )
    problem = SteerableProblem.from_scenario(sc, **overrides)
    obstacles = None
    if hasattr(sc.base, "voxel_obstacles"):  # Med-RAD: the reference's exact voxel-centre test
        obstacles = sc.base.voxel_obstacles(problem.needle_diameter_mm, problem.safety_margin_mm)
    return sc, problem, obstacles


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
    """

    scenario_path: str
    start_pose: tuple | None = None
    goal_mm: tuple | None = None
    r_min_mm: float | None = None
    needle_diameter_mm: float | None = None

    @classmethod
    def of(
        cls,
        scenario_path: str | os.PathLike,
        *,
        start_pose=None,
        goal_mm=None,
        r_min_mm: float | None = None,
        needle_diameter_mm: float | None = None,
    ) -> ScenarioSource:
        """A source from the same arguments as :func:`load_problem`.

        Parameters
        ----------
        scenario_path : str or path
        start_pose : array_like, shape (4, 4), optional
        goal_mm : array_like, shape (3,), optional
        r_min_mm, needle_diameter_mm : float, optional

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
        )

    def load(self):
        """Build the problem (no caching; see :meth:`cached`).

        Returns
        -------
        tuple
            ``(scenario, problem, obstacles)`` as from :func:`load_problem`.
        """
        pose = None if self.start_pose is None else np.reshape(self.start_pose, (4, 4))
        return load_problem(
            self.scenario_path,
            start_pose=pose,
            goal_mm=self.goal_mm,
            r_min_mm=self.r_min_mm,
            needle_diameter_mm=self.needle_diameter_mm,
        )

    def cached(self):
        """Build the problem once per process (batch workers reuse it across tasks).

        Returns
        -------
        tuple
            ``(scenario, problem, obstacles)``.
        """
        from needlekit.batch import worker_cached

        return worker_cached(("ScenarioSource", self), self.load)
