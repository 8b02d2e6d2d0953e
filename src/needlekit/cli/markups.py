"""``needlekit markups``: a plan's tip path as a 3D Slicer Markups curve."""

from __future__ import annotations

import argparse

from needlekit.cli import _flags, _sizes
from needlekit.cli._common import (
    EXIT_OK,
    _step_mm,
)
from needlekit.cli._paths import add_input
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


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``markups`` to the ``needlekit`` parser.

    Parameters
    ----------
    sub : argparse._SubParsersAction
        The top-level parser's sub-commands.

    Returns
    -------
    None
    """
    mk = sub.add_parser(
        "markups",
        help="export a plan's tip path as a 3D Slicer Markups curve (.mrk.json, LPS)",
        description="Write the tip path of plan.json as a Slicer Markups Curve: control points "
        "at most --spacing-mm apart along the path, in LPS mm. Open it in Slicer with "
        "File > Add Data.",
    )
    add_input(mk, "plan", help="plan file (plan.json, as `needlekit plan` writes it)")
    _flags.OUT.add(mk, required=True, help="markups file to write (.mrk.json)")
    mk.add_argument(
        "--spacing-mm",
        type=_step_mm,
        help="largest spacing of the curve's control points along the path (default 2 mm)",
    )
    mk.set_defaults(command_handler=_cmd_markups, sizes=_sizes.markups_sizes)
