"""``needlekit markups``: a plan's tip path as a 3D Slicer Markups curve."""

from __future__ import annotations

import argparse

from needlekit.cli._common import EXIT_OK
from needlekit.errors import InvalidInputError


def _cmd_markups(args: argparse.Namespace) -> int:
    from needlekit.io.files import read_json_object

    out = args.out
    if not out.name.lower().endswith(".json"):
        # Slicer picks its reader by the extension: anything else would not open as markups.
        raise InvalidInputError("--out", f"{out}: expected a name ending in .mrk.json")
    data = read_json_object(args.plan, "plan")  # a malformed file is answered before numba
    from needlekit.io.markups import DEFAULT_CURVE_SPACING_MM, write_plan_curve
    from needlekit.planning.steerable.plan import plan_from_dict

    spacing = DEFAULT_CURVE_SPACING_MM if args.spacing_mm is None else args.spacing_mm
    plan, _ = plan_from_dict(data, args.plan.name)
    if plan is None:
        status = data.get("status", "unknown")
        raise InvalidInputError(
            str(args.plan), f"holds no path (status {status!r}): nothing to export"
        )
    planner = data.get("planner", "planner")
    write_plan_curve(
        out,
        plan,
        spacing_mm=spacing,
        description=f"{planner} plan from {args.plan.name} (status {data.get('status')})",
    )
    n = len(plan.points_mm(spacing))
    print(f"curve: {n} control points, {plan.length_mm:.4f} mm, LPS -> {out}")
    return EXIT_OK
