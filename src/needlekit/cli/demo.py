"""``needlekit demo``: the main demonstration job."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from needlekit.cli._common import EXIT_OK


def _cmd_demo(args: argparse.Namespace) -> int:
    from needlekit.anatomy.phantoms import PHANTOMS, make_phantom
    from needlekit.anatomy.summary import summarize_scene
    from needlekit.io.files import write_json
    from needlekit.report.kinematics import write_kinematics_figures
    from needlekit.report.scene3d import scene_figure, write_scenes_html

    out = Path(args.out)
    paths = write_kinematics_figures(out)
    for p in paths:
        print(p)
    print(out / "demo.json")
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
    return EXIT_OK
