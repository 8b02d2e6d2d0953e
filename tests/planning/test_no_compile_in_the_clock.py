"""Budgets hold on a fresh machine: no numba compilation happens inside a planner's clock.

In a fresh process, every kernel a search calls must already be compiled (or loaded) by the
warm-up that runs before the clock starts: the dispatchers' signatures are counted when the
clock starts and when the search ends. A kernel first called inside the clock adds a
signature whether numba compiles it there or loads it from its on-disk cache, so the probe
uses the cache the suite already has (`make install` fills it): with an empty cache each
probe spent 10-25 s compiling every kernel again, for the same verdict.
"""

import json
import subprocess
import sys
from pathlib import Path

import pytest

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"

PROBE = r"""
import json, sys
import numba
from needlekit.scenario.problems import load_problem
from needlekit.planning.interface import Termination
from needlekit.planning.steerable.solve import solve


def compiled():
    out = {}
    for name, mod in list(sys.modules.items()):
        if not name.startswith("needlekit"):
            continue
        for attr, obj in list(vars(mod).items()):
            if isinstance(obj, numba.core.registry.CPUDispatcher):
                out[f"{name}.{attr}"] = len(obj.signatures)
    return out


at_start = {}


class Clock(Termination):
    def start(self):  # the planner starts its clock: count what is compiled by then
        at_start.update(compiled())
        return super().start()


if sys.argv[1] == "voxels":  # the voxel_centres model, read-only arrays as from the cache
    import numpy as np
    from needlekit.anatomy.occupancy import VoxelObstacles
    from needlekit.anatomy.primitives import Sphere
    from needlekit.anatomy.scene import Role, Scene, Structure
    from needlekit.planning.steerable.problem import SteerableProblem

    idx = np.arange(-30, 31)
    g = np.stack(np.meshgrid(idx, idx, idx, indexing="ij"), -1).astype(float)
    occ = np.hypot(g[..., 0] - 8.0, g[..., 2] - 10.0) <= 3.0  # a vessel across the way
    affine = np.eye(4)
    affine[:3, 3] = -30.0
    occ.flags.writeable = affine.flags.writeable = False
    scene = Scene([Structure("body", Role.ALLOWED_REGION, Sphere([0, 0, 0], 80.0))])
    start = np.eye(4)
    start[:3, 3] = [0.0, 0.0, -25.0]
    problem = SteerableProblem(
        scene, goal_mm=[5.0, 0.0, 25.0], start_pose=start, collision_model="voxel_centres",
        voxel_obstacles=VoxelObstacles(occ, affine, needle_diameter_mm=1.0),
    )
else:
    _, problem = load_problem(sys.argv[1])
report = {}
for planner in ("rcs_star", "rcs", "rrt"):
    at_start.clear()
    res = solve(problem, planner, termination=Clock(60.0, 300))
    after = compiled()
    report[planner] = {
        "status": res.status.value,
        "iterations": res.stats["iterations"],
        "compiled_in_clock": sorted(k for k, v in after.items() if v > at_start.get(k, 0)),
    }
print(json.dumps(report))
"""


@pytest.mark.slow
@pytest.mark.parametrize("scenario", ["toy.yaml", "lung_phantom.yaml", "voxels"])
def test_a_fresh_process_compiles_nothing_inside_the_planner_clock(scenario, tmp_path):
    proc = subprocess.run(
        [
            sys.executable,
            "-c",
            PROBE,
            scenario if scenario == "voxels" else str(EXAMPLES / scenario),
        ],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert proc.returncode == 0, proc.stderr
    report = json.loads(proc.stdout.strip().splitlines()[-1])
    for planner, r in report.items():
        assert r["iterations"] > 0, planner
        assert r["compiled_in_clock"] == [], (planner, r)
