"""``needlekit execute``'s plug points on the command line: ``--truth``, ``--sensor``,
``--estimator``, ``--feedback`` and ``--replanner`` (:mod:`needlekit.execute.plugins`),
each name checked before any work, a wrong one refused with the names known."""

from __future__ import annotations

import argparse
import math

from needlekit.errors import InvalidInputError

__all__ = ["add_mechanics_flags", "add_model_flags", "check_physics_flags", "mechanics_from_flags", "checked_models", "physics_options", "resolve_truth",
           "say_model", "say_pinned"]

#: The needle presets and the tissue presets of the mechanics (needlekit.mechanics.materials),
#: named here so that the parser refuses a wrong one without importing the mechanics.
NEEDLES = ("nitinol", "steel")
TISSUES = ("chicken", "gelatin", "liver", "lung", "plastisol")

#: The mechanics' flags, by their argparse destination, and their defaults: they apply to
#: ``--truth mechanics`` and ``physical`` (``--tissue-boundary`` to ``physical``) alone.
#: ``prebend_deg`` None: :data:`STEERABLE_PREBEND_DEG` for a steerable plan, a straight tip
#: for a multi plan's needles.
MECHANICS_DEFAULTS = {"needle": "nitinol", "tissue": None, "prebend_deg": None,
                      "inhomogeneity": 0.1, "calibration_insertions": 24,
                      "tissue_boundary": "organ"}  # fmt: skip

#: The flags, by their argparse destination, and the default each has.
MODEL_DEFAULTS = {"truth": "physical", "sensor": "em", "estimator": "kalman",
                  "feedback": "pure_pursuit", "replanner": "rcs_star"}  # fmt: skip

#: A steerable plan's needle under the mechanics, unless ``--prebend-deg`` says otherwise:
#: a tip pre-bent by 20 degrees. A bevel alone barely steers in soft tissue (the rod turns
#: at 117 m in the ``lung`` preset, 53 m in ``liver``; Majewicz et al. found the same in
#: vivo), so a steerable needle is a pre-bent one (docs/mechanics.md).
STEERABLE_PREBEND_DEG: float = 20.0

#: The calibrated radius may exceed the plan's r_min by this factor before ``execute``
#: warns that the plan turns tighter than the needle can (the calibration's own spread).
R_MIN_SLACK: float = 1.05


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
    g.add_argument("--truth", default=None, metavar="NAME",
                   help="the needle and tissue simulated: physical (default: the needle bent by "
                   "mechanics in the scenario's organ, which deforms; mechanics where the "
                   "scenario has no organ to mesh), mechanics (the rod in still tissue), "
                   "kinematic (the planner's own needle with noise), layered, or a registered "
                   "one")  # fmt: skip
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
    add_mechanics_flags(p)


def add_mechanics_flags(p: argparse.ArgumentParser) -> None:
    """Add the needle's and tissue's flags of ``--truth mechanics`` and ``physical``.

    Parameters
    ----------
    p : argparse.ArgumentParser

    Returns
    -------
    None
    """
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
                   help="a pre-bent tip: its bend toward the bevel over 5 mm (default "
                   f"{STEERABLE_PREBEND_DEG:g} for a steerable plan, 0 for a multi plan's "
                   "straight needles)")  # fmt: skip
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


def resolve_truth(args: argparse.Namespace) -> None:
    """Set ``args.truth`` to its default when ``--truth`` was not given (``physical``),
    remembering in ``args.truth_given`` whether it was: a default ``physical`` becomes
    ``mechanics`` on a scenario with no organ to mesh (:func:`physics_options`), a given one
    is refused there.

    Parameters
    ----------
    args : argparse.Namespace

    Returns
    -------
    None
    """
    if getattr(args, "truth_given", None) is None:
        args.truth_given = args.truth is not None
    if args.truth is None:
        args.truth = MODEL_DEFAULTS["truth"]


def no_organ(args: argparse.Namespace, what: str) -> str:
    """``--truth physical`` on a scenario with no organ to mesh: refused when given, the rod
    in still tissue (``mechanics``, said in one line) when it was the default.

    Parameters
    ----------
    args : argparse.Namespace
    what : str
        The scenario, for the line.

    Returns
    -------
    str
        ``"mechanics"``.

    Raises
    ------
    InvalidInputError
        ``--truth physical`` given.
    """
    if args.truth_given:
        raise InvalidInputError(
            "--truth", "physical deforms the scenario's organ: it needs a Med-RAD scenario"
        )
    print(f"{what} has no organ to mesh: its needle bends by mechanics in still tissue "
          "(--truth mechanics; --truth kinematic for the planner's own needle)")  # fmt: skip
    args.truth = "mechanics"
    return "mechanics"


def mechanics_from_flags(args: argparse.Namespace, organ: str | None, straight: bool = False):
    """The needle and tissue the mechanics' flags ask for.

    Parameters
    ----------
    args : argparse.Namespace
    organ : str or None
        The scenario's organ: its tissue preset unless ``--tissue`` names one (``lung``
        for any organ but the liver).
    straight : bool
        A multi plan's straight needles (no pre-bend unless ``--prebend-deg`` asks).

    Returns
    -------
    needlekit.execute.physical.MechanicsSettings
    """
    from needlekit.execute.physical import MechanicsSettings

    prebend = args.prebend_deg
    if prebend is None:
        prebend = 0.0 if straight else STEERABLE_PREBEND_DEG
    tissue = args.tissue or ("liver" if organ == "liver" else "lung")
    return MechanicsSettings(needle=args.needle, tissue=tissue, prebend_deg=prebend,
                             inhomogeneity=args.inhomogeneity)  # fmt: skip


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
    resolve_truth(args)
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

    resolve_truth(args)
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

    from needlekit.execute.physical_setup import PHYSICAL_TRUTHS, physical_settings

    s = options.settings
    truth = s.models.truth
    if truth not in PHYSICAL_TRUTHS:  # the simulator's own model
        return options
    base = getattr(scenario, "base", None)
    organ = getattr(base, "organ", None)
    mech = mechanics_from_flags(args, organ)
    if truth == "physical":
        from needlekit.execute.deforming import tissue_model_for

        if args.tissue_boundary == "sliding" and organ not in (None, "lung"):  # the flag named
            raise InvalidInputError(
                "--tissue-boundary", f"sliding is the lung's pleura; the scenario's organ is the {organ}"
            )
        model = tissue_model_for(scenario, plan, problem.goal_mm, args.tissue_boundary,
                                 cache_dir=args.cache_dir, use_cache=not args.no_cache)  # fmt: skip
        if model is None:
            if args.tissue_boundary != MECHANICS_DEFAULTS["tissue_boundary"]:
                raise InvalidInputError("--tissue-boundary", "applies to a scenario's organ; "
                                        "this one has none to mesh")  # fmt: skip
            s = replace(s, models=replace(s.models, truth=no_organ(args, args.scenario.name)))
        else:
            say_pinned(model)
    s = physical_settings(s, scenario, plan, problem.goal_mm, 1.0 / problem.kappa_max_per_mm,
                          mechanics=mech, boundary=args.tissue_boundary,
                          insertions=args.calibration_insertions, seed=args.seed,
                          cache_dir=args.cache_dir, use_cache=not args.no_cache)  # fmt: skip
    return replace(options, settings=s)


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
    print(line)
    if cal.r_min_mm > R_MIN_SLACK * r_plan:
        from needlekit.plausibility import warn

        warn([f"the plan turns at r_min {r_plan:.1f} mm, tighter than this needle's "
              f"{cal.r_min_mm:.1f} mm: its tip will fall short of the plan's turns; plan for the "
              f"needle (needle.r_min_mm at least {math.ceil(cal.r_min_mm):d}; `needlekit sweep` "
              "finds start directions that reach) or carry the plan out with the planner's "
              "own needle (--truth kinematic)"])  # fmt: skip
