"""``needlekit slicer``: the whole case as one 3D Slicer scene (docs/export.md)."""

from __future__ import annotations

import argparse

from needlekit.cli import _flags, _sizes
from needlekit.cli._common import EXIT_OK, _positive_int, _step_mm, number
from needlekit.cli._paths import add_input, add_output
from needlekit.errors import InvalidInputError

#: ``--out-dir``: the scene file the folder gets (the models and markups go in its Data/).
SLICER_FILES = ("case.mrml",)

#: ``--max-cells``: marching cubes samples per axis, at least 8 (a coarser surface is no
#: use) and at most 1024 (a 1024^3 float32 grid is 4 GiB).
_max_cells = number(8, 1024, integer=True)


def _cmd_slicer(args: argparse.Namespace) -> int:
    import time

    from needlekit.io.files import read_json_object
    from needlekit.io.results import ResultKind, result_kind
    from needlekit.io.scenario_schema import read_scenario_document

    t0 = time.perf_counter()
    if args.out is not None and not args.out.name.lower().endswith(".mrb"):
        # Slicer opens a bundle by its extension: anything else would not load as a scene.
        raise InvalidInputError("--out", f"{args.out}: expected a name ending in .mrb")
    read_scenario_document(args.scenario)  # a bad scenario is answered before any work
    plan_data = read_json_object(args.plan, "plan")
    kind = result_kind(plan_data, str(args.plan))
    if kind not in (ResultKind.PLAN, ResultKind.MULTI):
        raise InvalidInputError(
            str(args.plan),
            f"is a {kind.label}; expected a plan.json (needlekit plan) or multi.json (needlekit multi)",
        )
    execution = None
    if args.execution is not None:
        execution = read_json_object(args.execution, "execution")
    from needlekit.io.slicer_scene import write_slicer_scene
    from needlekit.report.slicer_case import case_markups, execution_markups, structure_models

    spacing = 2.0 if args.spacing_mm is None else args.spacing_mm
    # the plan and the execution checked and turned into markups before the anatomy loads
    markups = case_markups(plan_data, str(args.plan), spacing_mm=spacing)
    if execution is not None:
        markups += execution_markups(
            plan_data, execution, str(args.execution), trials=args.trials, spacing_mm=spacing
        )
    from needlekit.scenario.loading import load_scenario

    scenario = load_scenario(args.scenario, cache_dir=args.cache_dir, use_cache=not args.no_cache)
    models = structure_models(scenario.scene, max_cells=args.max_cells)
    out = write_slicer_scene(args.out if args.out is not None else args.out_dir, models, markups)
    names = ", ".join(m.item["name"] for m in markups)
    print(f"{len(models)} models ({', '.join(m.name for m in models)})")
    meshed = {m.name for m in models}
    missed = [s.name for s in scenario.scene.structures if s.name not in meshed]
    if missed:
        print(
            f"no surface at --max-cells {args.max_cells} (thinner than a cell?): {', '.join(missed)}"
        )
    print(f"{len(markups)} markups ({names})")
    print(f"RAS scene, files in LPS -> {out} ({time.perf_counter() - t0:.1f} s)")
    return EXIT_OK


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``slicer`` to the ``needlekit`` parser.

    Parameters
    ----------
    sub : argparse._SubParsersAction
        The top-level parser's sub-commands.

    Returns
    -------
    None
    """
    sl = sub.add_parser(
        "slicer",
        help="export the whole case as one 3D Slicer scene (.mrb): anatomy, points, plan, execution",
        description="Write a 3D Slicer scene of the case: one model per structure of the "
        "scenario, the target and entry points, the plan (a curve, or one line per needle of "
        "a multi-needle plan) and, with --execution, the tip paths of the first --trials "
        "trials. --out case.mrb writes one bundle (drag it onto Slicer's window); --out-dir "
        "DIR writes DIR/case.mrml and DIR/Data/. Scene in RAS, files in LPS (as Slicer "
        "writes them).",
    )
    add_input(sl, "scenario", help="scenario file (YAML) the plan was made for")
    add_input(
        sl, "plan", help="plan file: plan.json (needlekit plan) or multi.json (needlekit multi)"
    )
    add_input(
        sl, "--execution", metavar="EXECUTE_JSON",
        help="execute.json of this plan (needlekit execute --out DIR writes DIR/execute.json)",
    )  # fmt: skip
    where = sl.add_mutually_exclusive_group(required=True)
    _flags.OUT.add(where, help="Slicer data bundle to write (.mrb)")
    add_output(
        where, "--out-dir", folder=True, contents=SLICER_FILES, metavar="DIR",
        help="folder to write the scene in (case.mrml and Data/)",
    )  # fmt: skip
    sl.add_argument(
        "--trials",
        type=_positive_int,
        default=10,
        help="with --execution: how many trials to draw, the first ones (default 10)",
    )
    sl.add_argument(
        "--spacing-mm",
        type=_step_mm,
        help="largest spacing of a curve's control points (default 2 mm)",
    )
    sl.add_argument(
        "--max-cells",
        type=_max_cells,
        default=256,
        help="surface resolution: marching cubes samples per axis (default 256)",
    )
    _flags.add_cache_options(sl)
    sl.set_defaults(command_handler=_cmd_slicer, sizes=_sizes.slicer_sizes)
