"""A run's planner settings: the scenario's ``planner`` block under the caller's flags,
checked once (names, families, option names) without importing a planner, and the planners
built once from them (:meth:`PlannerSettings.build`).

The module imports nothing heavy: the command line calls :func:`planner_settings` before
any planner module (numba) is loaded.
"""

from __future__ import annotations

from dataclasses import dataclass

from needlekit.constants import DEFAULT_TIME_LIMIT_S
from needlekit.errors import InvalidInputError
from needlekit.planning.interface import (
    Termination,
    check_planner_options,
    get_planner,
    seeded_options,
)

__all__ = ["PlannerSettings", "planner_settings"]


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

    def replanning(self) -> dict:
        """The main planner's settings as re-planning among moving obstacles takes them
        (:func:`needlekit.planning.steerable.dynamic.replan_among_moving`: its seed apart,
        since each cycle plans with a seed of its own).

        Returns
        -------
        dict
            ``planner``, ``time_limit_s``, ``max_iterations``, ``seed``, ``options``.
        """
        name = self.name
        return {
            "planner": name,
            "time_limit_s": self.time_limit_s,
            "max_iterations": self.max_iterations,
            "seed": self.seed_for(name),
            "options": {k: v for k, v in self.options[name].items() if k != "seed"},
        }

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
