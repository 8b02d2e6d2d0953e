"""``needlekit schema`` and ``needlekit scene info|render``."""

from __future__ import annotations

import argparse

from needlekit.cli import _flags, _sizes
from needlekit.cli._common import EXIT_OK, _fmt_table, _Parser, _positive_int
from needlekit.cli._paths import add_input
from needlekit.errors import InvalidInputError
from needlekit.io.files import json_text


def _cmd_schema(args: argparse.Namespace | None = None) -> int:
    from needlekit.io.scenario_schema import SCENARIO_SCHEMA

    print(json_text(SCENARIO_SCHEMA, "schema", indent=2))
    return EXIT_OK


def _fmt_extent(extent) -> str:
    import numpy as np

    if not np.all(np.isfinite(extent)):
        return "unbounded"
    size = extent[1] - extent[0]
    return " x ".join(f"{v:.1f}" for v in size)


def _read_plan(args: argparse.Namespace):
    """``scene render --plan``: the plan file read and checked, before the anatomy loads."""
    if getattr(args, "plan", None) is None:
        return None
    from needlekit.scenario.results import read_plan_json

    plan, goal, data = read_plan_json(args.plan)
    if plan is None:
        status = data.get("status")
        raise InvalidInputError(
            "--plan", f"{args.plan.name} holds no path to draw (status {status})"
        )
    return plan, goal, data


def _cmd_scene(args: argparse.Namespace) -> int:
    from needlekit.io.scenario_schema import read_scenario_document

    doc = read_scenario_document(args.scenario)  # a bad file is answered before numba
    planned = _read_plan(args) if args.scene_command == "render" else None
    from needlekit.scenario.loading import load_scenario

    sc = load_scenario(args.scenario, document=doc)
    import numpy as np

    if args.scene_command == "info":
        from needlekit.anatomy.summary import summarize_scene

        rows = summarize_scene(sc.scene)
        if args.json:
            out = {
                "scenario": str(args.scenario),
                "name": sc.name,
                "structures": [r.to_dict() for r in rows],
            }
            print(json_text(out, "--json", indent=2))
            return EXIT_OK
        print(
            f"scene: {sc.scene.name or sc.name or args.scenario.name}  ({len(rows)} structures, RAS mm)"
        )
        table = [
            [
                r.name,
                r.role,
                r.kind,
                _fmt_extent(r.extent_mm),
                "-" if r.voxel_size_mm is None else " x ".join(f"{v:.2f}" for v in r.voxel_size_mm),
                None if not np.isfinite(r.volume_ml) else f"{r.volume_ml:.2f}",
                f"{r.error_bound_mm:.3f}",
            ]
            for r in rows
        ]
        print(
            _fmt_table(
                ["name", "role", "field", "extent_mm", "voxel_mm", "volume_ml", "error_mm"],
                table,
                why={
                    "voxel_mm": "an analytic shape, not a voxel grid",
                    "volume_ml": "an unbounded region (a half-space, an infinite cylinder)",
                },
            )
        )
        if sc.start is not None:
            print(f"start: {sc.start.name} at {np.round(sc.start.point_mm, 2).tolist()} mm")
        if sc.goal is not None:
            print(
                f"goal:  {sc.goal.name} at {np.round(sc.goal.point_mm, 2).tolist()} mm (tolerance {sc.goal.tolerance_mm:g} mm)"
            )
        return EXIT_OK
    from needlekit.report.scene3d import scene_figure, write_scene_html

    starts = None
    if sc.start is not None and sc.start.world_T_tip is not None:
        starts = sc.start.world_T_tip[None]
    elif sc.base is not None and getattr(sc.base, "start_poses", None) is not None:
        starts = sc.base.start_poses
    targets = None if sc.goal is None else sc.goal.point_mm[None]
    if planned is None:
        fig = scene_figure(
            sc.scene, start_poses=starts, targets_mm=targets, max_cells=args.max_cells
        )
        print(write_scene_html(fig, args.out))
        return EXIT_OK
    plan, goal, data = planned
    path = plan.points_mm(0.5)
    cost = data.get("cost_mm")
    label = f"{data.get('planner') or 'plan'}" + (f": {cost:.2f} mm" if cost is not None else "")
    fig = scene_figure(
        sc.scene,
        start_poses=np.asarray(plan.start_pose)[None],
        targets_mm=np.asarray(goal, dtype=float)[None],
        paths_mm=[path],
        path_names=[label],
        max_cells=args.max_cells,
        title=f"{sc.name or args.scenario.name}: {args.plan.name}",
        focus_mm=np.vstack([path, np.asarray(goal, dtype=float)[None]]),
    )
    print(f"drew {args.plan.name} ({data.get('status')}, {_plan_length(plan):.1f} mm path) -> "
          f"{write_scene_html(fig, args.out)}")  # fmt: skip
    return EXIT_OK


def _plan_length(plan) -> float:
    """The path's length (mm): the motions' lengths summed."""
    return float(sum(float(m[2]) for m in plan.primitives))


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``schema`` and ``scene info|render`` to the ``needlekit`` parser.

    Parameters
    ----------
    sub : argparse._SubParsersAction
        The top-level parser's sub-commands.

    Returns
    -------
    None
    """
    schema = sub.add_parser(
        "schema",
        help="print the JSON Schema of scenario files",
        description="Print the JSON Schema (draft 2020-12) that scenario files are validated against.",
    )
    schema.set_defaults(command_handler=_cmd_schema)
    scene = sub.add_parser("scene", help="inspect and render the anatomy of a scenario")
    scene_sub = scene.add_subparsers(
        dest="scene_command", metavar="ACTION", parser_class=_Parser, required=True
    )
    info = scene_sub.add_parser(
        "info", help="summarise the structures: role, extent, voxel size, volume"
    )
    add_input(info, "scenario", help="scenario file (YAML)")
    _flags.JSON.add(info, help="print JSON instead of a table")
    info.set_defaults(command_handler=_cmd_scene)
    render = scene_sub.add_parser(
        "render", help="write a self-contained interactive 3D view (HTML)"
    )
    add_input(render, "scenario", help="scenario file (YAML)")
    _flags.OUT.add(render, required=True, help="output HTML file")
    render.add_argument(
        "--max-cells",
        type=_positive_int,
        default=160,
        help="surface resolution: samples per axis (default 160)",
    )
    add_input(
        render,
        "--plan",
        help="a plan file (plan.json) to draw in the scene: the view is framed on its path",
    )
    _flags.PLOTLY.add(render)
    render.set_defaults(command_handler=_cmd_scene, sizes=_sizes.cells_sizes)
