"""``needlekit execute``'s plug points on the command line: ``--truth``, ``--sensor``,
``--estimator``, ``--feedback`` and ``--replanner`` (:mod:`needlekit.execute.plugins`),
each name checked before any work, a wrong one refused with the names known."""

from __future__ import annotations

import argparse

from needlekit.errors import InvalidInputError

__all__ = ["add_model_flags", "checked_models"]

#: The flags, by their argparse destination, and the default each has (today's loop).
MODEL_DEFAULTS = {"truth": "kinematic", "sensor": "em", "estimator": "kalman",
                  "feedback": "pure_pursuit", "replanner": "rcs_star"}  # fmt: skip


def add_model_flags(p: argparse.ArgumentParser) -> None:
    """Add the plug-point flags to ``execute``'s parser.

    Parameters
    ----------
    p : argparse.ArgumentParser

    Returns
    -------
    None
    """
    g = p.add_argument_group(
        "plug points: what the simulation believes and what runs the loop (docs/execute.md; "
        "others register under the needlekit.execute.* entry-point groups)"
    )
    g.add_argument("--truth", default="kinematic", metavar="NAME",
                   help="the needle and tissue simulated: kinematic (default), layered, or a "
                   "registered one")  # fmt: skip
    g.add_argument("--sensor", default="em", metavar="NAME",
                   help="the tip sensor: em (the simulated EM sensor, default), or a "
                   "registered one (--tip-from-igtl: the tracker)")  # fmt: skip
    g.add_argument("--estimator", default="kalman", metavar="NAME",
                   help="the tip estimator: kalman (default), unscented, or a registered one")  # fmt: skip
    g.add_argument("--feedback", default="pure_pursuit", metavar="NAME",
                   help="the feedback law: pure_pursuit (default), sliding_mode, or a "
                   "registered one")  # fmt: skip
    g.add_argument("--replanner", default="rcs_star", metavar="PLANNER",
                   help="the planner that re-plans: a steerable planner declaring "
                   "'warm_start' (rcs_star, the default, or rcs)")  # fmt: skip


def checked_models(args: argparse.Namespace):
    """The models the flags name, each checked (without importing a built-in's module).

    Parameters
    ----------
    args : argparse.Namespace

    Returns
    -------
    needlekit.execute.plugins.Models

    Raises
    ------
    InvalidInputError
        Named by the flag: an unknown name (with the nearest known), ``--sensor igtl``
        without the link, or a re-planner without the ``warm_start`` capability.
    """
    from needlekit.execute.plugins import Models, check_models
    from needlekit.planning.registry import check_replanner

    sensor = args.sensor
    if getattr(args, "tip_from_igtl", None) is not None:
        if sensor not in ("em", "igtl"):
            raise InvalidInputError(
                "--sensor", f"the tip comes from --tip-from-igtl: drop --sensor {sensor}"
            )
        sensor = "igtl"
    elif sensor == "igtl":
        raise InvalidInputError(
            "--sensor", "igtl reads a tracker over a live link: give --igtl and --tip-from-igtl"
        )
    models = Models(args.truth, sensor, args.estimator, args.feedback)
    check_models(models)
    if not args.no_replan:
        check_replanner(args.replanner)
    return models
