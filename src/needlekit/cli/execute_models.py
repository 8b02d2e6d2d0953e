"""``needlekit execute``'s plug points on the command line: ``--truth``, ``--sensor``,
``--estimator``, ``--feedback`` and ``--replanner`` (:mod:`needlekit.execute.plugins`),
each name checked before any work, a wrong one refused with the names known."""

from __future__ import annotations

import argparse
import math

from needlekit.errors import InvalidInputError

__all__ = ["add_model_flags", "check_physics_flags", "checked_models", "physics_options", "say_model", "say_pinned"]

#: The needle presets and the tissue presets of the mechanics (needlekit.mechanics.materials),
#: named here so that the parser refuses a wrong one without importing the mechanics.
NEEDLES = ("nitinol", "steel")
TISSUES = ("chicken", "gelatin", "liver", "lung", "plastisol")

#: The mechanics' flags, by their argparse destination, and their defaults: they apply to
#: ``--truth mechanics`` and ``physical`` (``--tissue-boundary`` to ``physical``) alone.
MECHANICS_DEFAULTS = {"needle": "nitinol", "tissue": None, "prebend_deg": 0.0,
                      "inhomogeneity": 0.1, "calibration_insertions": 24,
                      "tissue_boundary": "organ"}  # fmt: skip

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
    from needlekit.cli._common import number

    m = p.add_argument_group(
        "the needle and tissue of --truth mechanics and physical (docs/mechanics.md, "
        "docs/tissue.md); the loop's own model is then calibrated on the truth"
    )
    m.add_argument("--needle", choices=NEEDLES, default=MECHANICS_DEFAULTS["needle"],
                   help="the needle preset (default nitinol: a 0.83 mm wire, 30 deg bevel)")  # fmt: skip
    m.add_argument("--tissue", choices=TISSUES, default=MECHANICS_DEFAULTS["tissue"],
                   help="the tissue preset (default: the scenario's organ, lung otherwise)")  # fmt: skip
    m.add_argument("--prebend-deg", type=number(0.0, 89.0, unit="deg"),
                   default=MECHANICS_DEFAULTS["prebend_deg"],
                   help="a pre-bent tip: its bend toward the bevel over 5 mm (default 0)")  # fmt: skip
    m.add_argument("--inhomogeneity", type=number(0.0, 2.0),
                   default=MECHANICS_DEFAULTS["inhomogeneity"],
                   help="SD of the tissue's mm-to-mm variation of the tip load (default 0.1)")  # fmt: skip
    m.add_argument("--tissue-boundary", choices=("organ", "sliding"),
                   default=MECHANICS_DEFAULTS["tissue_boundary"],
                   help="--truth physical: the organ's boundary (docs/tissue.md): organ (its "
                   "held surfaces, default) or sliding (lung: the pleura slides, held along "
                   "its normal only)")  # fmt: skip
    m.add_argument("--calibration-insertions", type=number(2, 10_000, integer=True),
                   default=MECHANICS_DEFAULTS["calibration_insertions"], metavar="N",
                   help="curved insertions the loop's model is calibrated from (and N/2 "
                   "straight ones; default 24)")  # fmt: skip


def check_physics_flags(args: argparse.Namespace) -> None:
    """The mechanics' flags given only with a truth they apply to (else they would be
    ignored without a word).

    Parameters
    ----------
    args : argparse.Namespace

    Returns
    -------
    None

    Raises
    ------
    InvalidInputError
        Named by the flag given with another truth.
    """
    for dest, default in MECHANICS_DEFAULTS.items():
        wants = ("physical",) if dest == "tissue_boundary" else ("mechanics", "physical")
        if getattr(args, dest, default) != default and args.truth not in wants:
            raise InvalidInputError(
                "--" + dest.replace("_", "-"),
                f"applies to --truth {' or '.join(wants)}, not {args.truth}",
            )


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


def physics_options(args: argparse.Namespace, scenario, plan, problem, options):
    """The options with what a physical truth needs: the needle and tissue
    (``settings.mechanics``), the deforming organ for ``physical`` (``settings.tissue``),
    and the loop's model calibrated on the truth (``settings.model``). For the other truths
    (kinematic, layered, a registered one) the options are unchanged: their loop is given the
    simulator's radius and noise.

    Parameters
    ----------
    args : argparse.Namespace
    scenario : needlekit.scenario.loading.Scenario
    plan : SteerablePlan
    problem : SteerableProblem
    options : ExecuteOptions

    Returns
    -------
    ExecuteOptions
    """
    from dataclasses import replace

    from needlekit.execute.calibration import CalibrationSettings, calibrate_truth
    from needlekit.execute.physical import MechanicsSettings

    s = options.settings
    truth = s.models.truth
    if truth not in ("mechanics", "physical"):  # the simulator's own model (legacy)
        return options
    base = getattr(scenario, "base", None)
    tissue = args.tissue or {"liver": "liver"}.get(getattr(base, "organ", None), "lung")
    mech = MechanicsSettings(needle=args.needle, tissue=tissue, prebend_deg=args.prebend_deg,
                             inhomogeneity=args.inhomogeneity)  # fmt: skip
    s = replace(s, mechanics=mech)
    if truth == "physical":
        from needlekit.execute.deforming import tissue_model_for

        organ = getattr(base, "organ", None)
        if args.tissue_boundary == "sliding" and organ not in (None, "lung"):  # the flag named
            raise InvalidInputError(
                "--tissue-boundary", f"sliding is the lung's pleura; the scenario's organ is the {organ}"
            )
        model = tissue_model_for(scenario, plan, problem.goal_mm, args.tissue_boundary)
        if model is None:
            raise InvalidInputError(
                "--truth", "physical deforms the scenario's organ: it needs a Med-RAD scenario"
            )
        say_pinned(model)
        s = replace(s, tissue=model)
    n = args.calibration_insertions
    # calibrated on the needle alone: the organ's motion is the loop's to see, not its model's
    on = replace(s, models=replace(s.models, truth="mechanics")) if truth == "physical" else s
    cal = calibrate_truth(on, plan.start_pose, 1.0 / problem.kappa_max_per_mm,
                          CalibrationSettings(curved=n, straight=max(2, n // 2), seed=args.seed))  # fmt: skip
    return replace(options, settings=replace(s, model=cal))


def say_pinned(model) -> None:
    """One warning line when the organ model cannot move the target (it lies within a cell
    of a held surface, :meth:`~needlekit.execute.deforming.TissueModel.pinned`; recorded
    under ``truth.tissue.pinned_points`` too). Meshes the organ (cached) if it was not.

    Parameters
    ----------
    model : needlekit.execute.deforming.TissueModel

    Returns
    -------
    None
    """
    from needlekit.plausibility import warn

    if "target" not in model.pinned():
        return
    hint = "; --tissue-boundary sliding lets the pleura slide" if model.organ == "lung" else ""
    warn([f"the target lies within a cell of the {model.organ}'s held surface: the needle cannot "
          f"move it in this organ model (its displacement stays 0{hint})"])  # fmt: skip


def say_model(settings, problem) -> None:
    """One line on the loop's calibrated model beside the plan's needle.

    Parameters
    ----------
    settings : ExecutionSettings
    problem : SteerableProblem

    Returns
    -------
    None
    """
    cal = settings.model
    if cal is None:
        return
    r_plan = 1.0 / problem.kappa_max_per_mm
    line = (f"calibrated on {cal.curved + cal.straight} insertions of the {settings.models.truth} "
            f"truth: r {cal.r_min_mm:.1f} mm (the plan's needle {r_plan:.1f} mm), model replay "
            f"rms {cal.residual_rms_mm:.2f} mm")  # fmt: skip
    if cal.axis_slip_rad > 0.0:
        line += (f"; its tip's axis off its travel {math.degrees(cal.axis_slip_rad):.1f} deg RMS, "
                 f"correlated over {cal.axis_slip_mm:.1f} mm")  # fmt: skip
    if cal.r_min_mm > 1.05 * r_plan:
        line += "; the plan asks for tighter turns than this needle makes"
    print(line)
