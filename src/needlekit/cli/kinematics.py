"""``needlekit kinematics forward|inverse``."""

from __future__ import annotations

import argparse
import math

from needlekit._numbers import MAX_ABS_MM, MAX_ABS_NUMBER, MAX_CURVATURE_PER_MM, Bounds
from needlekit.cli import _flags
from needlekit.cli._common import (
    EXIT_OK,
    _fmt_table,
    _numbers,
    _Parser,
    _positive,
    _positive_mm,
    _start_pose,
    number,
)
from needlekit.cli._paths import add_input
from needlekit.constants import MAX_TRAJECTORY_SAMPLES
from needlekit.errors import InvalidInputError, NeedlekitError, UnreachableTargetError
from needlekit.io.files import json_text

#: ``--kappa-per-mm``: a curvature, at most a radius of a micrometre.
_curvature = number(0.0, MAX_CURVATURE_PER_MM, unit="1/mm")
#: ``--segment u1,u2,T``: an insertion speed within a kilometre a second, a spin rate, and
#: a duration >= 0.
_segment = _numbers(
    3,
    "three numbers u1_mm_s,u2_rad_s,duration_s",
    (
        Bounds(-MAX_ABS_MM, MAX_ABS_MM, unit="mm/s"),
        Bounds(-MAX_ABS_NUMBER, MAX_ABS_NUMBER, unit="rad/s"),
        Bounds(0.0, MAX_ABS_NUMBER, unit="s"),
    ),
)


def _check_sample_count(durations_s, dt_s: float) -> None:
    """Refuse a sampling that would not fit in memory, before allocating anything."""
    # as simulate_bevel samples: ceil(T / dt) per segment (at least 1), plus the start
    total = 1.0 + sum(max(1.0, math.ceil(min(t / dt_s, 1e300))) for t in durations_s)
    if total > MAX_TRAJECTORY_SAMPLES:
        raise InvalidInputError(
            "--dt-s",
            f"{total:.3g} samples over {sum(durations_s):g} s of segments at {dt_s:g} s; "
            f"at most {MAX_TRAJECTORY_SAMPLES:,} (use a larger --dt-s or shorter segments)",
        )


def _cmd_forward(args: argparse.Namespace) -> int:
    import numpy as np

    segments = np.array(args.segment, dtype=float)
    if np.any(segments[:, 2] < 0):
        raise NeedlekitError("--segment: durations must be >= 0")
    if args.dt_s is not None:
        _check_sample_count(segments[:, 2].tolist(), args.dt_s)
    g0 = _start_pose(args.start_pose)  # a bad pose file is said before the kernels load
    from needlekit.needle.bevel3d import propagate_bevel, simulate_bevel

    if args.dt_s is None:
        ends = propagate_bevel(g0, segments, args.kappa_per_mm)
        times = np.concatenate([[0.0], np.cumsum(segments[:, 2])])
        poses = ends
    else:
        traj = simulate_bevel(g0, segments, args.kappa_per_mm, dt_s=args.dt_s)
        times, poses = traj.time_s, traj.world_T_tip
    if args.json:
        out = {
            "kappa_per_mm": args.kappa_per_mm,
            "segments": [
                {"u1_mm_s": float(a), "u2_rad_s": float(b), "duration_s": float(c)}
                for a, b, c in segments
            ],
            "time_s": times.tolist(),
            "points_mm": poses[:, :3, 3].tolist(),
            "directions": poses[:, :3, 2].tolist(),
            "final_pose": poses[-1].tolist(),
        }
        print(json_text(out, "--json", indent=2))
        return EXIT_OK
    rows = [
        [float(t), *(float(v) for v in g[:3, 3]), *(float(v) for v in g[:3, 2])]
        for t, g in zip(times, poses, strict=True)
    ]
    print(_fmt_table(["time_s", "x_mm", "y_mm", "z_mm", "dir_x", "dir_y", "dir_z"], rows))
    print("\nfinal pose (world_T_tip):")
    print(np.array2string(poses[-1], precision=6, suppress_small=True))
    return EXIT_OK


def _cmd_inverse(args: argparse.Namespace) -> int:
    import numpy as np

    from needlekit.needle.reachability import shortest_arc_line
    from needlekit.needle.transform_method import tm_inverse

    g0 = _start_pose(args.start_pose)
    targets = np.array(args.target, dtype=float)
    try:
        sol = tm_inverse(targets, g0, r_min_mm=args.r_min_mm)
    except UnreachableTargetError as exc:  # the library's names, as the flags say them
        reason = exc.reason.replace("below r_min_mm =", "below --r-min-mm")
        raise UnreachableTargetError("--target", reason) from None
    spin = sol.alpha_rad + 0.5 * np.pi  # twist-model spin, see needlekit.conventions
    spin = np.mod(spin + np.pi, 2 * np.pi) - np.pi
    arcline = shortest_arc_line(g0, targets, args.r_min_mm) if args.r_min_mm else None
    records = []
    for i, p in enumerate(targets):
        rec = {
            "target_mm": p.tolist(),
            "alpha_rad": float(sol.alpha_rad[i]),
            "spin_rad": float(spin[i]),
            "radius_mm": None if math.isinf(sol.radius_mm[i]) else float(sol.radius_mm[i]),
            "curvature_per_mm": float(sol.kappa_per_mm[i]),
            "phi_rad": float(sol.phi_rad[i]),
            "length_mm": float(sol.length_mm[i]),
        }
        if arcline is not None:
            rec["shortest_arc_line_mm"] = float(arcline.length_mm[i])
        records.append(rec)
    if args.json:
        print(json_text({"r_min_mm": args.r_min_mm, "arcs": records}, "--json", indent=2))
        return EXIT_OK
    headers = ["target", "alpha_deg", "spin_deg", "radius_mm", "phi_deg", "length_mm"]
    if arcline is not None:
        headers.append("arc+line_mm")
    rows = []
    for i, rec in enumerate(records):
        row: list[object] = [
            f"{i}",
            math.degrees(rec["alpha_rad"]),
            math.degrees(rec["spin_rad"]),
            float(sol.radius_mm[i]),
            math.degrees(rec["phi_rad"]),
            rec["length_mm"],
        ]
        if arcline is not None:
            row.append(rec["shortest_arc_line_mm"])
        rows.append(row)
    print(_fmt_table(headers, rows, why={
        "radius_mm": "the target lies on the needle's axis: a straight line (infinite radius)"
    }))  # fmt: skip
    return EXIT_OK


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``kinematics forward|inverse`` to the ``needlekit`` parser.

    Parameters
    ----------
    sub : argparse._SubParsersAction
        The top-level parser's sub-commands.

    Returns
    -------
    None
    """
    kin = sub.add_parser(
        "kinematics", help="bevel-tip needle kinematics: forward and inverse steering"
    )
    kin_sub = kin.add_subparsers(
        dest="kin_command", metavar="MODE", parser_class=_Parser, required=True
    )
    fwd = kin_sub.add_parser(
        "forward",
        help="tip trajectory of the 3D bevel-tip model for piecewise-constant inputs",
        description=(
            "Forward steering: propagate the tip pose exactly for segments of constant "
            "insertion speed u1 (mm/s) and spin rate u2 (rad/s)."
        ),
    )
    fwd.add_argument(
        "--kappa-per-mm", type=_curvature, required=True, help="needle curvature (1/mm)"
    )
    fwd.add_argument(
        "--segment",
        type=_segment,
        action="append",
        required=True,
        metavar="U1,U2,T",
        help="one input segment; repeat for several",
    )
    add_input(fwd, "--start-pose", help="4x4 start pose text file (RAS mm); default identity")
    fwd.add_argument(
        "--dt-s", type=_positive, default=None, help="sampling interval of the printed trajectory"
    )
    _flags.JSON.add(fwd, help="print JSON instead of a table")
    fwd.set_defaults(command_handler=_cmd_forward)

    inv = kin_sub.add_parser(
        "inverse",
        help="single-arc inverse steering from a tip pose to target points",
        description=(
            "Inverse steering with the transformation-matrix method: the arc (alpha, r, "
            "phi, l) from the tip through each target, and the shortest arc-then-line path "
            "when --r-min-mm is given."
        ),
    )
    inv.add_argument(
        "--target",
        type=_numbers(3, "three numbers x,y,z (mm)"),
        action="append",
        required=True,
        metavar="X,Y,Z",
        help="target point in the world frame (mm); repeat for several",
    )
    add_input(inv, "--start-pose", help="4x4 start pose text file (RAS mm); default identity")
    inv.add_argument(
        "--r-min-mm",
        type=_positive_mm,
        help="minimum radius of curvature; tighter arcs are an error",
    )
    _flags.JSON.add(inv, help="print JSON instead of a table")
    inv.set_defaults(command_handler=_cmd_inverse)
