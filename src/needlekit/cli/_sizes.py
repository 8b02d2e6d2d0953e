"""What each command's flags ask for in memory, estimated before the command runs.

A command whose flags (or scenario fields) size its arrays declares it beside its handler:
``set_defaults(sizes=<estimator>)``, one of the functions below, which reads the parsed
flags (and, where the size depends on it, the scenario or plan file: no anatomy, no
numba) and returns one :class:`~needlekit.memory.Size` per flag. The command line checks
them all with :func:`~needlekit.memory.refuse_sizes` after the paths and before the
handler (:func:`needlekit.cli.main`), so ``--resolution-deg 1e-6`` or ``--trials 1e12``
answers in one line naming the flag, at once, without allocating.

Each per-item figure below is a floor: what one item is certain to hold, never more, so
a request refused here could not have run.
"""

from __future__ import annotations

import argparse

from needlekit.memory import Size

__all__ = [
    "CFRW_BYTES_PER_CELL",
    "POINT_BYTES",
    "SWEEP_BYTES_PER_DIRECTION",
    "TRIAL_BYTES",
    "bench_sizes",
    "cells_sizes",
    "cfrw_sizes",
    "execute_lungs_sizes",
    "execute_sizes",
    "feng_lungs_sizes",
    "livers_sizes",
    "markups_sizes",
    "puncture_sizes",
    "slicer_sizes",
    "sweep_sizes",
]

#: One cell of a CFRW map: its float64 ray length and its feasibility, counts and angles
#: beside it (two float64s is far below all of them).
CFRW_BYTES_PER_CELL = 16
#: One swept direction per planner: its result (status, cost, statistics and the
#: primitives of a plan), far below what a solved one keeps; and the direction itself.
SWEEP_BYTES_PER_DIRECTION = 512
DIRECTION_BYTES = 24
#: One trial of a study: its number in the list of trials (an 8-byte slot and a 28-byte
#: int), its job tuple's slot, and its record's slot; the record itself is far larger.
TRIAL_BYTES = 64
#: One point (three float64s): a query, a curve point, a sampled arc point.
POINT_BYTES = 24
#: One value of a float64 array (a keyframe of the history, a guide sample).
VALUE_BYTES = 8


def _grid_size(flag: str, res, block: dict) -> list[Size]:
    """The CFRW grid of ``res`` degrees over the ranges of a ``straight`` block."""
    from needlekit.planning.straight import angle_grid as grid

    if not isinstance(res, (int, float)) or isinstance(res, bool) or not res > 0:
        return []  # the default, or a value the loader refuses with its own message
    m, k = grid.grid_shape(  # the whole grid is built (an approach cone only masks it)
        block.get("theta_range_deg", grid.DEFAULT_THETA_RANGE_DEG),
        block.get("phi_range_deg", grid.DEFAULT_PHI_RANGE_DEG),
        res,
    )
    cells = float(m) * float(k)
    return [Size(flag, cells, CFRW_BYTES_PER_CELL, f"a {res:g}-degree grid ({cells:.3g} cells)")]


def cfrw_sizes(args: argparse.Namespace) -> list[Size]:
    """``cfrw`` and ``multi``: ``--resolution-deg`` (or the scenario's
    ``straight.resolution_deg``) over the scenario's angle ranges, as the map builds them.

    Parameters
    ----------
    args : argparse.Namespace

    Returns
    -------
    list of Size
    """
    from needlekit.io.scenario_schema import read_scenario_document

    # kept for the command, which reads it once (its warnings said once)
    args.scenario_document = read_scenario_document(args.scenario)
    block = args.scenario_document.get("straight") or {}
    flag, res = "--resolution-deg", getattr(args, "resolution_deg", None)
    if res is None:
        flag, res = "straight.resolution_deg", block.get("resolution_deg")
    return _grid_size(flag, res, block)


def livers_sizes(args: argparse.Namespace) -> list[Size]:
    """``study livers``: one CFRW map of ``--resolution-deg`` over the study's angle
    ranges (every case builds at least one).

    Parameters
    ----------
    args : argparse.Namespace

    Returns
    -------
    list of Size
    """
    from needlekit.studies.liver_study import LIVER_SETTINGS

    return _grid_size("--resolution-deg", args.resolution_deg, LIVER_SETTINGS["straight"])


def _directions(flag: str, n: float, sweeps: int) -> Size:
    per = DIRECTION_BYTES + SWEEP_BYTES_PER_DIRECTION * sweeps
    return Size(flag, n, per, f"{n} directions")


def sweep_sizes(args: argparse.Namespace) -> list[Size]:
    """``sweep``: ``--directions`` (or ``--healpix``), one result per direction and
    planner asked for on the command line (at least one).

    Parameters
    ----------
    args : argparse.Namespace

    Returns
    -------
    list of Size
    """
    planners = len(dict.fromkeys(args.planner or ["?"]))
    if args.healpix is not None:
        return [_directions("--healpix", 12 * args.healpix**2, planners)]
    return [_directions("--directions", args.directions, planners)]


def feng_lungs_sizes(args: argparse.Namespace) -> list[Size]:
    """``study feng-lungs``: ``--directions`` swept for two targets by two planners.

    Parameters
    ----------
    args : argparse.Namespace

    Returns
    -------
    list of Size
    """
    n = getattr(args, "directions", None)
    return [] if n is None else [_directions("--directions", n, 2 * 2)]


def _trials(flag: str, n) -> list[Size]:
    return [] if n is None else [Size(flag, n, TRIAL_BYTES, f"{n} trials")]


def puncture_sizes(args: argparse.Namespace) -> list[Size]:
    """``puncture``: ``--trials``, and per trial ``--history`` keyframes and
    ``--guide-samples`` samples.

    Parameters
    ----------
    args : argparse.Namespace

    Returns
    -------
    list of Size
    """
    return [
        *_trials("--trials", args.trials),
        Size("--history", args.history, VALUE_BYTES, f"{args.history} keyframes"),
        Size("--guide-samples", args.guide_samples, VALUE_BYTES, f"{args.guide_samples} samples"),
    ]


def execute_sizes(args: argparse.Namespace) -> list[Size]:
    """``execute``: ``--trials`` (one trial with ``--replay-trial``).

    Parameters
    ----------
    args : argparse.Namespace

    Returns
    -------
    list of Size
    """
    return [] if getattr(args, "replay_trial", None) is not None else _trials("--trials", args.trials)


def execute_lungs_sizes(args: argparse.Namespace) -> list[Size]:
    """``study execute-lungs``: ``--trials`` and ``--pilot-trials`` per lung.

    Parameters
    ----------
    args : argparse.Namespace

    Returns
    -------
    list of Size
    """
    return [
        *_trials("--trials", getattr(args, "trials", None)),
        *_trials("--pilot-trials", getattr(args, "pilot_trials", None)),
    ]


def markups_sizes(args: argparse.Namespace) -> list[Size]:
    """``markups``: the curve points of the plan's path at ``--spacing-mm`` (a point is
    three float64s and about 80 characters of JSON: 100 bytes).

    Parameters
    ----------
    args : argparse.Namespace

    Returns
    -------
    list of Size
    """
    if args.spacing_mm is None or not args.spacing_mm > 0:
        return []  # the default, or a value the command refuses with its own message
    from needlekit.io.files import read_json_object
    from needlekit.planning.steerable.plan import plan_from_dict

    plan, _ = plan_from_dict(read_json_object(args.plan, "plan"), args.plan.name)
    if plan is None:
        return []  # no path: the command says so
    points = plan.length_mm / args.spacing_mm + 2
    return [Size("--spacing-mm", points, 100, f"{points:.3g} curve points")]


def slicer_sizes(args: argparse.Namespace) -> list[Size]:
    """``slicer``: ``--max-cells`` (:func:`cells_sizes`) and, for a steerable plan, the
    curve points of its path at ``--spacing-mm`` (:func:`markups_sizes`; the execution's
    paths are thinned from points the file already holds).

    Parameters
    ----------
    args : argparse.Namespace

    Returns
    -------
    list of Size
    """
    sizes = cells_sizes(args)
    if args.spacing_mm is None or not args.spacing_mm > 0:
        return sizes
    from needlekit.io.files import read_json_object

    if "needles" in read_json_object(args.plan, "plan"):
        return sizes  # a multi-needle plan: two points a needle, whatever the spacing
    return sizes + markups_sizes(args)


def _most(values) -> float:
    return max((v for v in values or () if v is not None), default=0)


def bench_sizes(args: argparse.Namespace) -> list[Size]:
    """``bench <suite>``: the sizes its suite's flags ask for (arcs and samples, grid and
    queries, trials, directions, replans, sampled targets).

    Parameters
    ----------
    args : argparse.Namespace

    Returns
    -------
    list of Size
    """
    a = vars(args)
    sizes = []
    if a.get("arcs") is not None:  # poses (4x4 float64) and three values per arc...
        sizes.append(Size("--arcs", a["arcs"], 128 + 3 * VALUE_BYTES, f"{a['arcs']} arcs"))
        if a.get("samples") is not None:  # ...and the points sampled along each
            n = float(a["arcs"]) * a["samples"]
            sizes.append(Size("--samples", n, POINT_BYTES, f"{n:.3g} arc points"))
    if a.get("grid") is not None:  # the test grids are float64 (a mask and an EDT beside)
        sizes.append(Size("--grid", a["grid"] ** 3, VALUE_BYTES, f"a {a['grid']}^3 grid"))
    if a.get("queries") is not None:
        sizes.append(Size("--queries", a["queries"], POINT_BYTES, f"{a['queries']} queries"))
    if a.get("sample_targets") is not None:
        n = a["sample_targets"]
        sizes.append(Size("--sample-targets", n, POINT_BYTES, f"{n} targets"))
    if a.get("replans") is not None:
        sizes.append(Size("--replans", a["replans"], TRIAL_BYTES, f"{a['replans']} re-plans"))
    trials, dirs = a.get("trials"), a.get("directions")
    if isinstance(trials, list):  # bench scale: the series' sizes
        trials = _most(trials)
    sizes += _trials("--trials", trials)
    if isinstance(dirs, list):  # bench scale
        sizes.append(_directions("--directions", _most(dirs), 1))
    return sizes


def cells_sizes(args: argparse.Namespace) -> list[Size]:
    """``scene render`` and ``approach``: ``--max-cells``, the samples along the longest
    axis of the grid a surface is drawn from (a float64 coordinate each, at least; the
    grid itself holds far more).

    Parameters
    ----------
    args : argparse.Namespace

    Returns
    -------
    list of Size
    """
    n = getattr(args, "max_cells", None)
    return [] if n is None else [Size("--max-cells", n, VALUE_BYTES, f"{n} samples per axis")]
