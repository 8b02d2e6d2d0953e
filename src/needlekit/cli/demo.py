"""``needlekit demo``: the main demonstration job.

On the built-in lung phantom it sweeps the effective puncture region with RCS*, RCS and
RRT (Feng et al. 2023), re-checks the best plan and writes ``lung/sweep.json``,
``lung/plan.json`` and the self-contained ``lung/report.html``; beside it, the needle
kinematics figures and the three phantoms. The files are written as one unit
(:func:`~needlekit.io.files.staged_outputs`): a demo that fails leaves an earlier
demo's files as they were.
"""

from __future__ import annotations

import argparse
import sys
from importlib import resources
from pathlib import Path

from needlekit.cli import _flags
from needlekit.cli._common import EXIT_OK, sweep_progress

#: What ``needlekit demo`` writes in its --out folder.
DEMO_FILES = (
    "lung/scenario.yaml",
    "lung/sweep.json",
    "lung/plan.json",
    "lung/report.html",
    "forward_steering_planar.png",
    "forward_steering_3d.png",
    "inverse_steering.png",
    "reachability.png",
    "demo.json",
    "phantoms.html",
    "phantoms.json",
)

#: Budgets of the demo sweep: iteration limits make its numbers the same on every machine.
DEMO_PLANNERS = ("rcs_star", "rcs", "rrt")
DEMO_TIME_LIMIT_S = 5.0
DEMO_MAX_ITERATIONS = 300


def _lung_sweep(out: Path) -> int:
    from needlekit.io.files import write_text
    from needlekit.scenario.problems import ScenarioSource
    from needlekit.studies.sweep_study import run_sweep_study

    case = out / "lung"
    print("lung phantom: loading the scene", file=sys.stderr)
    with (
        resources.as_file(resources.files("needlekit") / "data" / "lung_phantom.yaml") as src,
        sweep_progress() as progress,
    ):
        # the sweep reads the packaged file; its copy lands in lung/ with the results
        write_text(case / "scenario.yaml", Path(src).read_text(encoding="utf-8"))
        study = run_sweep_study(
            ScenarioSource.of(src),
            case / "sweep.json",
            plan_path=case / "plan.json",
            report_path=case / "report.html",
            planners=DEMO_PLANNERS,
            time_limit_s=DEMO_TIME_LIMIT_S,
            max_iterations=DEMO_MAX_ITERATIONS,
            progress=progress,
            title="needlekit demo: effective puncture region in the lung phantom",
        )
    for name, sw in study.sweeps.items():
        st = sw.stats
        best = "-" if st["best_cost_mm"] is None else f"{st['best_cost_mm']:.3f} mm"
        mean = "-" if st["mean_cost_mm"] is None else f"{st['mean_cost_mm']:.3f} mm"
        print(
            f"{name}: {st['n_solved']} of {st['n_effective']} effective directions solved, "
            f"best {best}, mean {mean}",
            file=sys.stderr,
        )
    for path in study.files.values():
        print(path)
    if study.check is not None and not study.check.ok:
        print("error: the best plan failed its check: " + "; ".join(study.check.violations))
        return 1
    return EXIT_OK


def _cmd_demo(args: argparse.Namespace) -> int:
    from needlekit.io.files import staged_outputs

    with staged_outputs():  # all of the demo's files, or none
        return _demo(Path(args.out))


def _demo(out: Path) -> int:
    import numpy as np

    from needlekit.anatomy.phantoms import PHANTOMS, make_phantom
    from needlekit.anatomy.summary import summarize_scene
    from needlekit.io.files import write_json
    from needlekit.report.kinematics import write_kinematics_figures
    from needlekit.report.scene3d import scene_figure, write_scenes_html

    code = _lung_sweep(out)
    paths = write_kinematics_figures(out)
    for p in paths:
        print(p)
    figures, summary = [], {}
    for name in PHANTOMS:  # the built-in default cases
        ph = make_phantom(name)
        print(f"{name} phantom: {len(ph.scene)} structures", file=sys.stderr)
        figures.append(
            (
                f"{name} phantom (seed {ph.seed})",
                scene_figure(
                    ph.scene, start_poses=ph.start_poses, targets_mm=ph.targets_mm, max_cells=110
                ),
            )
        )
        summary[name] = {
            "seed": ph.seed,
            "structures": [r.to_dict() for r in summarize_scene(ph.scene)],
            "start_poses": np.asarray(ph.start_poses).tolist(),
            "targets_mm": np.asarray(ph.targets_mm).tolist(),
        }
    print(write_scenes_html(figures, out / "phantoms.html", title="needlekit built-in phantoms"))
    print(write_json(out / "phantoms.json", summary))
    return code


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``demo`` to the ``needlekit`` parser.

    Parameters
    ----------
    sub : argparse._SubParsersAction
        The top-level parser's sub-commands.

    Returns
    -------
    None
    """
    demo = sub.add_parser("demo", help="run the main demonstration job and write its outputs")
    _flags.OUT.add(
        demo,
        folder=True,
        contents=DEMO_FILES,
        default="out/demo",
        help="output folder (default out/demo)",
    )
    _flags.PLOTLY.add(demo)
    demo.set_defaults(command_handler=_cmd_demo)
