"""A campaign of the project's own: bad inputs per command, each with
its expected exit status (2) and its one error line, exactly.

Each row runs :func:`needlekit.cli.main` in this process and compares what it printed on
stderr with the row's line: a new command adds its rows here. Placeholders: ``{d}`` the
folder of :data:`FILES`, ``{TOY}`` and ``{MULTI}`` two shipped examples, ``{M}`` the
Med-RAD folder (rows that name it need the data and skip without it). The lines were read
one by one when the table was written: each names the file, field or flag at fault and
what was expected, and quotes nothing of a file's content. The hypothesis side of the
campaign (random scenario documents: one clean error or a valid result, never a
traceback) is in tests/io/test_scenario.py.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from needlekit.cli import main

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"

TOY_BODY = """version: 1
structures:
  - {name: lung, role: allowed_region, ellipsoid: {semi_axes_mm: [80, 60, 100]}}
  - {name: vessel, role: obstacle, capsule: {p0_mm: [-40, 10, -10], p1_mm: [40, 10, 5], radius_mm: 4}}
"""
START_GOAL = (
    "start: {point_mm: [0, -12, 0], direction: [0, 1, 0.3]}\ngoal: {point_mm: [20, 30, 40]}\n"
)
STRAIGHT = """version: 1
base: {phantom: {name: liver, seed: 0}}
start: {case_start: 1}
goal: {case_target: 1}
straight:
  entry_surface: skin
  targets: [1, 2, 3]
"""

#: The files the table's cases read, by name (text, or bytes).
FILES = {
    "malformed.yaml": "version: 1\nbase: {phantom: {name: lung\n",
    "invalid.yaml": "version: 1\nneedle: {r_min_mm: -3}\n",
    "version2.yaml": "version: 2\n",
    "list.yaml": "- version: 1\n",
    "block_planner.yaml": "version: 1\nplanner: {name: nope}\n",
    "block_option.yaml": "version: 1\nplanner: {name: rrt, options: {bogus: 1}}\n",
    "malformed.json": '{"x": 1',
    "list.json": "[1, 2]",
    "goal_only.json": '{"goal_mm": [0, 0, 0]}',
    "pose.txt": "1 0 0\n",
    "moving_no_speed.yaml": "version: 1\n"
    + TOY_BODY.split("\n", 1)[1].replace(
        "radius_mm: 4}}", "radius_mm: 4}, moving: {velocity_mm_s: [0, 1, 0]}}"
    )
    + "needle: {r_min_mm: 50}\n"
    + START_GOAL,
    "nan.yaml": TOY_BODY + "start: {point_mm: [0, -12, .nan], direction: [0, 1, 0.3]}\n"
    "goal: {point_mm: [20, 30, 40]}\n",
    "huge_goal.yaml": TOY_BODY + "start: {point_mm: [0, -12, 0], direction: [0, 1, 0.3]}\n"
    "goal: {point_mm: [1e308, 30, 40]}\n",
    "deep.yaml": "version: 1\nname: " + "[" * 100 + "]" * 100 + "\n",
    "bomb.yaml": "a: &a [x, x, x, x, x, x, x, x, x]\n"
    + "".join(
        f"{c}: &{c} [{', '.join(['*' + p] * 9)}]\n"
        for p, c in zip("abcdefgh", "bcdefghi", strict=True)
    ),
    "latin1.yaml": "version: 1\nname: caf\xe9\n".encode("latin-1"),
    "binary.yaml": b"\x00\x01\x02\xff\xfe",
    "empty.yaml": "",
    "colour.yaml": "version: 1\ncolour: red\n",
    "no_name.yaml": "version: 1\nstructures:\n  - {role: obstacle, sphere: {center_mm: [0, 0, 0], radius_mm: 1}}\n",
    "duplicate.yaml": TOY_BODY
    + "  - {name: lung, role: obstacle, sphere: {center_mm: [0, 0, 0], radius_mm: 1}}\n"
    + START_GOAL,
    "zero_direction.yaml": TOY_BODY + "start: {point_mm: [0, -12, 0], direction: [0, 0, 0]}\n"
    "goal: {point_mm: [20, 30, 40]}\n",
    "two_sources.yaml": "version: 1\nstructures:\n  - {name: a, role: obstacle, sphere: "
    "{center_mm: [0, 0, 0], radius_mm: 1}, box: {half_extents_mm: [1, 1, 1]}}\n",
    "bad_role.yaml": "version: 1\nstructures:\n  - {name: a, role: wall, sphere: "
    "{center_mm: [0, 0, 0], radius_mm: 1}}\n",
    "neg_radius.yaml": "version: 1\nstructures:\n  - {name: a, role: obstacle, sphere: "
    "{center_mm: [0, 0, 0], radius_mm: -1}}\n",
    "string_radius.yaml": "version: 1\nstructures:\n  - {name: a, role: obstacle, sphere: "
    "{center_mm: [0, 0, 0], radius_mm: '5'}}\n",
    "bad_frame.yaml": "version: 1\nframe: XYZ\n",
    "mask_missing.yaml": "version: 1\nstructures:\n  - {name: a, role: obstacle, mask: {path: nowhere.nii.gz}}\n",
    "mesh_missing.yaml": "version: 1\nstructures:\n  - {name: a, role: obstacle, mesh: {path: nowhere.stl}}\n",
    "no_structures.yaml": "version: 1\n" + START_GOAL,
    "angle_95.yaml": TOY_BODY + "needle: {min_puncture_angle_deg: 95}\n" + START_GOAL,
    "heading_0.yaml": TOY_BODY + "needle: {max_heading_change_deg: 0}\n" + START_GOAL,
    "tolerance_0.yaml": TOY_BODY + "start: {point_mm: [0, -12, 0], direction: [0, 1, 0.3]}\n"
    "goal: {point_mm: [20, 30, 40], tolerance_mm: 0}\n",
    "bad_pose.yaml": TOY_BODY + "start: {pose: [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0]]}\n"
    "goal: {point_mm: [20, 30, 40]}\n",
    "sheared.txt": "1 0.5 0 0\n0 1 0 0\n0 0 1 0\n0 0 0 1\n",
    "nan_pose.txt": "1 0 0 nan\n0 1 0 0\n0 0 1 0\n0 0 0 1\n",
    "secret.txt": "root:SECRET:0:0\n",
    "string_numbers.json": '{"goal_mm": ["20", 30, 40]}',
    "deep.json": '{"goal_mm": ' + "[" * 5000 + "]" * 5000 + "}",
    "binary.json": b"\x00\x01\xff",
    "empty.json": "",
    "far_mask.yaml": "version: 1\nstructures:\n"
    "  - {name: body, role: allowed_region, sphere: {center_mm: [0, 0, 0], radius_mm: 60}}\n"
    "  - {name: far, role: obstacle, mask: {path: far.nii.gz}}\n",
    "straight_angle.yaml": STRAIGHT + "  max_normal_angle_deg: 200\n",
    "straight_order.yaml": STRAIGHT + "  order: [2, 3, 4]\n",
    "straight_up.yaml": STRAIGHT + "  up: [0, 0, 0]\n",
    "straight_cone.yaml": STRAIGHT + "  approach_cone_deg: 500\n",
    "unknown_kind.json": '{"hello": 1}',
}


def make_files(root):
    """Write :data:`FILES` and the few binary fixtures into ``root``."""
    import nibabel as nib
    import numpy as np

    for name, content in FILES.items():
        path = root / name
        if isinstance(content, bytes):
            path.write_bytes(content)
        else:
            path.write_text(content)
    (root / "empty").mkdir()
    mask = np.zeros((10, 10, 10), np.uint8)
    mask[3:7, 3:7, 3:7] = 1
    affine = np.eye(4)
    affine[:3, 3] = [1000.0, 0.0, 0.0]  # a metre from the body: another volume's mask
    nib.save(nib.Nifti1Image(mask, affine), str(root / "far.nii.gz"))
    plan = root / "moved_plan.json"  # a plan naming a scenario that is not beside it
    plan.write_text('{"goal_mm": [0, 0, 0], "scenario": "elsewhere/toy.yaml"}')


#: (argv, the one line on stderr); every row exits with status 2.
ROWS = [
    # -- plan
    (["plan", "{d}/missing.yaml"], "error: scenario: {d}/missing.yaml: not found"),
    (
        ["plan", "{d}/malformed.yaml"],
        "error: {d}/malformed.yaml: invalid YAML at line 3, column 1: expected ',' or '}', but got '<stream end>'",
    ),
    (
        ["plan", "{d}/invalid.yaml"],
        "error: invalid.yaml: needle.r_min_mm: expected a number >= 1e-06, got -3",
    ),
    (["plan", "{d}/version2.yaml"], "error: version2.yaml: version: expected 1, got 2"),
    (
        ["plan", "{d}/list.yaml"],
        "error: {d}/list.yaml: expected a mapping at the top level, got list",
    ),
    (["plan", "{d}"], "error: scenario: {d}: is a folder, expected a file"),
    (
        ["plan", "{TOY}", "--planner", "nope"],
        "error: --planner: unknown planner 'nope'; available: rcs_star, rcs, rrt, liu_cfrw",
    ),
    (
        ["plan", "{TOY}", "--planner", "liu_cfrw"],
        "error: --planner: 'liu_cfrw' plans straight needles; steerable planners: rcs_star, rcs, rrt",
    ),
    (
        ["plan", "{d}/block_planner.yaml"],
        "error: planner: unknown planner 'nope'; available: rcs_star, rcs, rrt, liu_cfrw",
    ),
    (
        ["plan", "{d}/block_option.yaml"],
        "error: planner.options: rrt takes connection, seed; unknown: bogus",
    ),
    (
        ["plan", "{TOY}", "--goals", "1,2"],
        "error: argument --goals: expected three numbers x,y,z (mm), each a number in [-1e+06, 1e+06] mm, got '1,2'",
    ),
    (
        ["plan", "{TOY}", "--goal", "1,2,x"],
        "error: argument --goal: expected three numbers x,y,z (mm), each a number in [-1e+06, 1e+06] mm, got '1,2,x'",
    ),
    (
        ["plan", "{TOY}", "--goal", "1e7,0,0"],
        "error: argument --goal: expected three numbers x,y,z (mm), each a number in [-1e+06, 1e+06] mm, got '1e7,0,0'",
    ),
    (
        ["plan", "{TOY}", "--r-min-mm", "1e300"],
        "error: argument --r-min-mm: expected a number in [1e-06, 1e+06] mm, got '1e300'",
    ),
    (
        ["study", "livers", "--gamma", "2e6"],
        "error: argument --gamma: expected a number in [0, 1e+06] mm, got '2e6'",
    ),
    (
        ["sweep", "{TOY}", "--out", "{d}/none.json", "--resume"],
        "error: --resume: no {d}/none.partial.json to carry on from (an interrupted run writes it)",
    ),
    (
        ["puncture", "--out", "{d}/nothing", "--resume"],
        "error: --resume: no {d}/nothing/puncture.partial.json to carry on from (an "
        "interrupted run writes it)",
    ),
    (
        ["plan", "{TOY}", "--goals", "1,2,3", "--goal", "1,2,3"],
        "error: --goals: give the targets with --goals or --goal, not both",
    ),
    (
        ["plan", "{TOY}", "--goals", "1,2,3", "--multi", "one-tree", "--planner", "rcs"],
        "error: --multi: one-tree grows an RRT tree; --planner is rcs",
    ),
    (["plan", "{TOY}", "--step-mm", "3"], "error: --step-mm: only goes with --dynamic"),
    (["plan", "{TOY}", "--dynamic"], "error: --dynamic: toy.yaml: no structure has a moving block"),
    (
        ["plan", "{TOY}", "--dynamic", "--goals", "1,2,3"],
        "error: --dynamic: plans to the scenario's goal; drop --goals",
    ),
    (
        ["plan", "{d}/moving_no_speed.yaml", "--dynamic"],
        "error: --insertion-speed-mm-s: moving_no_speed.yaml has no dynamic.insertion_speed_mm_s; give the insertion speed",
    ),
    (
        ["plan", "{TOY}", "--time-limit-s", "-1"],
        "error: argument --time-limit-s: expected a number in [1e-06, 1e+12], got '-1'",
    ),
    (
        ["plan", "{TOY}", "--seed", "x"],
        "error: argument --seed: expected a whole number in [0, 9.22e+18], got 'x'",
    ),
    (
        ["plan", "{TOY}", "--max-iterations", "0"],
        "error: argument --max-iterations: expected a whole number in [1, 1000000000], got '0'",
    ),
    (
        ["plan", "{TOY}", "--r-min-mm", "nan"],
        "error: argument --r-min-mm: expected a number in [1e-06, 1e+06] mm, got 'nan'",
    ),
    (
        ["plan", "{TOY}", "--rrt-connection", "nope"],
        "error: argument --rrt-connection: invalid choice: 'nope' (choose from 'arc_line', 'arc')",
    ),
    (
        ["plan", "{TOY}", "--start-pose", "{d}/missing.txt"],
        "error: --start-pose: {d}/missing.txt: not found",
    ),
    (["plan", "{TOY}", "--out", "{d}"], "error: --out: {d}: is a folder, expected a file"),
    (
        ["plan", "{TOY}", "--out", "/proc/plan.json"],
        "error: --out: /proc/plan.json: folder /proc is read-only",
    ),
    (
        ["plan", "{TOY}", "--out", "{d}/pose.txt/plan.json"],
        "error: --out: {d}/pose.txt/plan.json: cannot be created: {d}/pose.txt is not a folder",
    ),
    (
        ["plan", "{TOY}", "--out", "{TOY}"],
        "error: --out: {TOY}: is the input scenario; it would be overwritten",
    ),
    (["plan", "{TOY}", "--bogus"], "error: unrecognized arguments: --bogus"),
    (
        ["plan", "{TOY}", "--option", "bogus=1"],
        "error: --option bogus: unknown option (rcs_star takes resolution)",
    ),
    (
        ["plan", "{TOY}", "--option", "resolution.max_length_mm=x"],
        "error: --option resolution.max_length_mm: rcs_star: expected a number, got 'x'",
    ),
    (
        ["plan", "{TOY}", "--option", "resolution=8"],
        "error: --option resolution: rcs_star's resolution has fields: give resolution.FIELD=VALUE (max_length_mm, length_levels, spin_levels)",
    ),
    (
        ["plan", "{TOY}", "--planner", "rrt", "--option", "seed=1.5"],
        "error: --option seed: rrt: expected a whole number, got '1.5'",
    ),
    (
        ["plan", "{TOY}", "--option", "novalue"],
        "error: argument --option: expected NAME=VALUE, got 'novalue'",
    ),
    (
        ["plan", "{TOY}", "--goal", "nan,0,0"],
        "error: argument --goal: expected three numbers x,y,z (mm), each a number in [-1e+06, 1e+06] mm, got 'nan,0,0'",
    ),
    (
        ["plan", "{TOY}", "--goal", "1e400,0,0"],
        "error: argument --goal: expected three numbers x,y,z (mm), each a number in [-1e+06, 1e+06] mm, got '1e400,0,0'",
    ),
    (
        ["plan", "{TOY}", "--r-min-mm", "0"],
        "error: argument --r-min-mm: expected a number in [1e-06, 1e+06] mm, got '0'",
    ),
    (
        ["plan", "{TOY}", "--r-min-mm", "-5"],
        "error: argument --r-min-mm: expected a number in [1e-06, 1e+06] mm, got '-5'",
    ),
    (
        ["plan", "{TOY}", "--needle-diameter-mm", "0"],
        "error: argument --needle-diameter-mm: expected a number in [1e-06, 1e+06] mm, got '0'",
    ),
    (
        ["plan", "{TOY}", "--time-limit-s", "nan"],
        "error: argument --time-limit-s: expected a number in [1e-06, 1e+12], got 'nan'",
    ),
    (
        ["plan", "{TOY}", "--time-limit-s", "inf"],
        "error: argument --time-limit-s: expected a number in [1e-06, 1e+12], got 'inf'",
    ),
    (
        ["plan", "{TOY}", "--max-iterations", "1.5"],
        "error: argument --max-iterations: expected a whole number in [1, 1000000000], got '1.5'",
    ),
    (
        ["plan", "{TOY}", "--seed", "-1"],
        "error: argument --seed: expected a whole number in [0, 9.22e+18], got '-1'",
    ),
    (["plan", "{TOY}", "--goals"], "error: argument --goals: expected at least one argument"),
    (
        ["plan", "{TOY}", "--lookahead-s", "-1", "--dynamic"],
        "error: argument --lookahead-s: expected a number in [0, 1e+12], got '-1'",
    ),
    (
        ["plan", "{TOY}", "--insertion-speed-mm-s", "0", "--dynamic"],
        "error: argument --insertion-speed-mm-s: expected a number in [0.01, 1e+06] mm/s, got '0'",
    ),
    (
        ["plan", "{TOY}", "--predict", "nope"],
        "error: argument --predict: invalid choice: 'nope' (choose from 'arrival', 'swept', 'snapshot')",
    ),
    (["plan", "{TOY}", "--dashboard"], "error: unrecognized arguments: --dashboard"),
    (
        ["plan", "{d}/nan.yaml"],
        "error: nan.yaml: start.point_mm[2]: expected a number in [-1e+06, 1e+06] mm, got nan",
    ),
    (
        ["plan", "{d}/huge_goal.yaml"],
        "error: huge_goal.yaml: goal.point_mm[0]: expected a number in [-1e+06, 1e+06] mm, got 1e+308",
    ),
    (
        ["plan", "{d}/deep.yaml"],
        "error: {d}/deep.yaml: refused at line 2: the document is nested deeper than 64 levels",
    ),
    (
        ["plan", "{d}/bomb.yaml"],
        "error: {d}/bomb.yaml: refused at line 7: the document stands for more than 1,000,000 values once its aliases are expanded",
    ),
    (
        ["plan", "{d}/latin1.yaml"],
        "error: {d}/latin1.yaml: not UTF-8 text (byte 0xe9 at offset 20)",
    ),
    (["plan", "{d}/binary.yaml"], "error: {d}/binary.yaml: not UTF-8 text (byte 0xff at offset 3)"),
    (
        ["plan", "{d}/empty.yaml"],
        "error: {d}/empty.yaml: the file is empty: expected a scenario mapping",
    ),
    (
        ["plan", "{d}/colour.yaml"],
        "error: colour.yaml: (top level): unknown field 'colour' (allowed: version, name, description, frame, base, structures, needle, start, goal, planner, straight, dynamic, collision_model, collision_options)",
    ),
    (["plan", "{d}/no_name.yaml"], "error: no_name.yaml: structures[0]: 'name' is missing"),
    (
        ["plan", "{d}/duplicate.yaml"],
        "error: duplicate.yaml: structures[2].name: duplicate structure name 'lung'",
    ),
    (
        ["plan", "{d}/zero_direction.yaml"],
        "error: zero_direction.yaml: start.direction: expected a non-zero vector, got [0, 0, 0]",
    ),
    (
        ["plan", "{d}/two_sources.yaml"],
        "error: two_sources.yaml: structures[0]: needs exactly one source (mask, mesh, sphere, ellipsoid, capsule, cylinder, box, half_space, superquadric); got sphere, box",
    ),
    (
        ["plan", "{d}/bad_role.yaml"],
        "error: bad_role.yaml: structures[0].role: expected one of obstacle, target, entry_surface, allowed_region, context, got 'wall'",
    ),
    (
        ["plan", "{d}/neg_radius.yaml"],
        "error: neg_radius.yaml: structures[0].sphere.radius_mm: expected a number >= 1e-06, got -1",
    ),
    (
        ["plan", "{d}/string_radius.yaml"],
        "error: string_radius.yaml: structures[0].sphere.radius_mm: expected number, got str '5'",
    ),
    (
        ["plan", "{d}/bad_frame.yaml"],
        "error: bad_frame.yaml: frame: expected one of RAS, LPS, got 'XYZ'",
    ),
    (
        ["plan", "{d}/mask_missing.yaml"],
        "error: mask_missing.yaml: structures[0].mask.path: file {d}/nowhere.nii.gz not found",
    ),
    (
        ["plan", "{d}/mesh_missing.yaml"],
        "error: mesh_missing.yaml: structures[0].mesh.path: file {d}/nowhere.stl not found",
    ),
    (
        ["plan", "{d}/no_structures.yaml"],
        "error: no_structures.yaml: structures: the scenario has no structures (add some or a base)",
    ),
    (
        ["plan", "{d}/angle_95.yaml"],
        "error: angle_95.yaml: needle.min_puncture_angle_deg: expected a number < 90, got 95",
    ),
    (
        ["plan", "{d}/heading_0.yaml"],
        "error: heading_0.yaml: needle.max_heading_change_deg: expected a number > 0, got 0",
    ),
    (
        ["plan", "{d}/tolerance_0.yaml"],
        "error: tolerance_0.yaml: goal.tolerance_mm: expected a number >= 1e-06, got 0",
    ),
    (
        ["plan", "{d}/bad_pose.yaml"],
        "error: bad_pose.yaml: start.pose: expected 4 to 4 items, got 3",
    ),
    (
        ["plan", "{TOY}", "--start-pose", "{d}/sheared.txt"],
        "error: {d}/sheared.txt: rotation part of item 0 is not a proper rotation (|R^T R - I| = 5.00e-01, det = 1.000000)",
    ),
    (
        ["plan", "{TOY}", "--start-pose", "{d}/nan_pose.txt"],
        "error: {d}/nan_pose.txt: entry [0, 3]: expected a number in [-1e+06, 1e+06] mm, got nan",
    ),
    (
        ["plan", "{TOY}", "--start-pose", "{d}/secret.txt"],
        "error: {d}/secret.txt: line 1, item 1 is not a number (pose and point files hold whitespace-separated numbers)",
    ),
    (
        ["plan", "{TOY}", "--option", "=1"],
        "error: argument --option: expected NAME=VALUE, got '=1'",
    ),
    (
        ["plan", "{TOY}", "--planner", "rrt", "--option", "goal_bias=2"],
        "error: --option goal_bias: unknown option (rrt takes connection, seed)",
    ),
    # -- sweep
    (
        ["sweep", "{TOY}", "--planner", "nope"],
        "error: --planner: unknown planner 'nope'; available: rcs_star, rcs, rrt, liu_cfrw",
    ),
    (
        ["sweep", "{TOY}", "--planner", "rrt", "liu_cfrw"],
        "error: --planner: 'liu_cfrw' plans straight needles; steerable planners: rcs_star, rcs, rrt",
    ),
    (
        ["sweep", "{d}/malformed.yaml"],
        "error: {d}/malformed.yaml: invalid YAML at line 3, column 1: expected ',' or '}', but got '<stream end>'",
    ),
    (
        ["sweep", "{d}/invalid.yaml"],
        "error: invalid.yaml: needle.r_min_mm: expected a number >= 1e-06, got -3",
    ),
    (
        ["sweep", "{d}/block_option.yaml"],
        "error: planner.options: rrt takes connection, seed; unknown: bogus",
    ),
    (
        ["sweep", "{TOY}", "--directions", "0"],
        "error: argument --directions: expected a whole number in [1, 1000000000], got '0'",
    ),
    (
        ["sweep", "{TOY}", "--healpix", "x"],
        "error: argument --healpix: expected a whole number in [1, 1000000000], got 'x'",
    ),
    (
        ["sweep", "{TOY}", "--report", "{d}/pose.txt/r.html"],
        "error: --report: {d}/pose.txt/r.html: cannot be created: {d}/pose.txt is not a folder",
    ),
    (
        ["sweep", "{TOY}", "--out", "{d}/a.json", "--plan", "{d}/a.json"],
        "error: --plan: {d}/a.json: also given to --out",
    ),
    (
        ["sweep", "{TOY}", "--executor", "serial", "--workers", "2"],
        "error: --workers starts worker processes: it contradicts --executor serial",
    ),
    (
        ["sweep", "{TOY}", "--planner", "rcs_star", "rrt", "--option", "nope=1"],
        "error: --option nope: unknown option (rcs_star takes resolution; rrt takes connection, seed)",
    ),
    (
        ["sweep", "{TOY}", "--planner", "rcs", "rrt", "--option", "seed=x"],
        "error: --option seed: rrt: expected a whole number, got 'x'",
    ),
    (
        ["sweep", "{TOY}", "--directions", "-1"],
        "error: argument --directions: expected a whole number in [1, 1000000000], got '-1'",
    ),
    (
        ["sweep", "{TOY}", "--directions", "1000000000"],
        "error: --directions: 1000000000 directions would need at least 499 GiB; this machine has {AVAIL} available",
    ),
    (
        ["sweep", "{TOY}", "--healpix", "0"],
        "error: argument --healpix: expected a whole number in [1, 1000000000], got '0'",
    ),
    (
        ["sweep", "{TOY}", "--healpix", "100000"],
        "error: --healpix: 120000000000 directions would need at least 58.5 TiB; this machine has {AVAIL} available",
    ),
    (
        ["sweep", "{TOY}", "--time-limit-s", "0"],
        "error: argument --time-limit-s: expected a number in [1e-06, 1e+12], got '0'",
    ),
    (
        ["sweep", "{TOY}", "--dashboard"],
        "error: --dashboard: serves a local Dask cluster's dashboard: add --dask-workers N",
    ),
    (
        ["sweep", "{TOY}", "--scheduler", "a b"],
        "error: --scheduler: expected an address such as tcp://HOST:PORT, got 'a b'",
    ),
    (
        ["sweep", "{TOY}", "--dask-workers", "0"],
        "error: argument --dask-workers: expected a whole number in [1, 1000000000], got '0'",
    ),
    (
        ["sweep", "{TOY}", "--workers", "0"],
        "error: argument --workers: expected a whole number in [1, 1000000000], got '0'",
    ),
    (
        ["sweep", "{TOY}", "--scheduler", "tcp://127.0.0.1:1", "--dask-workers", "2"],
        "error: --scheduler uses a running Dask cluster, --dask-workers starts one: give one",
    ),
    (
        ["sweep", "{TOY}", "--scheduler", "tcp://127.0.0.1:1", "--dashboard"],
        "error: --dashboard: the cluster at --scheduler serves its own dashboard, if any",
    ),
    (
        ["sweep", "{TOY}", "--out", "{TOY}"],
        "error: --out: {TOY}: is the input scenario; it would be overwritten",
    ),
    (
        ["sweep", "{d}/nan.yaml"],
        "error: nan.yaml: start.point_mm[2]: expected a number in [-1e+06, 1e+06] mm, got nan",
    ),
    # -- verify
    (["verify", "{TOY}", "{d}/missing.json"], "error: plan: {d}/missing.json: not found"),
    (
        ["verify", "{TOY}", "{d}/malformed.json"],
        "error: {d}/malformed.json: not a JSON plan file (Expecting ',' delimiter: line 1 column 8 (char 7))",
    ),
    (
        ["verify", "{TOY}", "{d}/list.json"],
        "error: {d}/list.json: expected a JSON object at the top level",
    ),
    (
        ["verify", "{d}/invalid.yaml", "{d}/goal_only.json"],
        "error: invalid.yaml: needle.r_min_mm: expected a number >= 1e-06, got -3",
    ),
    (
        ["verify", "{d}/malformed.yaml", "{d}/goal_only.json"],
        "error: {d}/malformed.yaml: invalid YAML at line 3, column 1: expected ',' or '}', but got '<stream end>'",
    ),
    (
        ["verify", "{TOY}", "{d}/goal_only.json", "--goal", "x"],
        "error: argument --goal: expected three numbers x,y,z (mm), each a number in [-1e+06, 1e+06] mm, got 'x'",
    ),
    (
        ["verify", "{TOY}", "{d}/goal_only.json", "--start-pose", "{d}/missing.txt"],
        "error: --start-pose: {d}/missing.txt: not found",
    ),
    (
        ["verify", "{TOY}", "{d}/string_numbers.json"],
        "error: string_numbers.json: goal_mm: expected three finite numbers",
    ),
    (
        ["verify", "{TOY}", "{d}/deep.json"],
        "error: {d}/deep.json: nested too deeply to be a needlekit file",
    ),
    (
        ["verify", "{TOY}", "{d}/binary.json"],
        "error: {d}/binary.json: not a JSON plan file (not UTF-8 text: byte 0xff at offset 2)",
    ),
    (
        ["verify", "{TOY}", "{d}/empty.json"],
        "error: {d}/empty.json: not a JSON plan file (Expecting value: line 1 column 1 (char 0))",
    ),
    (
        ["verify", "{TOY}", "{d}/goal_only.json", "--r-min-mm", "0"],
        "error: argument --r-min-mm: expected a number in [1e-06, 1e+06] mm, got '0'",
    ),
    # -- scene
    (["schema", "--bogus"], "error: unrecognized arguments: --bogus"),
    (["scene", "info", "{d}/missing.yaml"], "error: scenario: {d}/missing.yaml: not found"),
    (
        ["scene", "info", "{d}/malformed.yaml"],
        "error: {d}/malformed.yaml: invalid YAML at line 3, column 1: expected ',' or '}', but got '<stream end>'",
    ),
    (
        ["scene", "info", "{d}/invalid.yaml"],
        "error: invalid.yaml: needle.r_min_mm: expected a number >= 1e-06, got -3",
    ),
    (
        ["scene", "render", "{d}/invalid.yaml", "--out", "{d}/s.html"],
        "error: invalid.yaml: needle.r_min_mm: expected a number >= 1e-06, got -3",
    ),
    (
        ["scene", "render", "{TOY}", "--out", "/proc/s.html"],
        "error: --out: /proc/s.html: folder /proc is read-only",
    ),
    (
        ["scene", "render", "{TOY}", "--out", "{d}/s.html", "--max-cells", "0"],
        "error: argument --max-cells: expected a whole number in [1, 1000000000], got '0'",
    ),
    (
        ["scene", "render", "{TOY}", "--out", "{d}/s.html", "--max-cells", "-1"],
        "error: argument --max-cells: expected a whole number in [1, 1000000000], got '-1'",
    ),
    (
        ["scene", "info", "{d}/bomb.yaml"],
        "error: {d}/bomb.yaml: refused at line 7: the document stands for more than 1,000,000 values once its aliases are expanded",
    ),
    (
        ["scene", "info", "{d}/deep.yaml"],
        "error: {d}/deep.yaml: refused at line 2: the document is nested deeper than 64 levels",
    ),
    (
        ["scene", "info", "{d}/nan.yaml"],
        "error: nan.yaml: start.point_mm[2]: expected a number in [-1e+06, 1e+06] mm, got nan",
    ),
    (
        ["scene", "info", "{d}/far_mask.yaml"],
        "error: far_mask.yaml: structures[1].mask.path: {d}/far.nii.gz: its set voxels span [[1002.5, 2.5, 2.5], [1006.5, 6.5, 6.5]] mm, outside the anatomy the other structures span [[-60.0, -60.0, -60.0], [60.0, 60.0, 60.0]] mm (a mask of another volume, or a wrong affine?)",
    ),
    (
        ["scene", "render", "{d}/missing.yaml", "--out", "{d}/s.html"],
        "error: scenario: {d}/missing.yaml: not found",
    ),
    (
        ["scene", "nope"],
        "error: argument ACTION: invalid choice: 'nope' (choose from 'info', 'render')",
    ),
    (["schema", "extra"], "error: unrecognized arguments: extra"),
    # -- straight
    (
        ["cfrw", "{d}/invalid.yaml"],
        "error: invalid.yaml: needle.r_min_mm: expected a number >= 1e-06, got -3",
    ),
    (
        ["cfrw", "{d}/malformed.yaml"],
        "error: {d}/malformed.yaml: invalid YAML at line 3, column 1: expected ',' or '}', but got '<stream end>'",
    ),
    (["cfrw", "{TOY}"], "error: toy.yaml: straight: the scenario has no straight block"),
    (
        ["cfrw", "{MULTI}", "--target", "0"],
        "error: argument --target: expected a whole number in [1, 1000000000], got '0'",
    ),
    (
        ["multi", "{d}/invalid.yaml"],
        "error: invalid.yaml: needle.r_min_mm: expected a number >= 1e-06, got -3",
    ),
    (["multi", "{TOY}"], "error: toy.yaml: straight: the scenario has no straight block"),
    (
        ["multi", "{MULTI}", "--planner", "nope"],
        "error: planner: unknown planner 'nope'; available: rcs_star, rcs, rrt, liu_cfrw",
    ),
    (
        ["multi", "{MULTI}", "--order", "x"],
        "error: argument --order: expected a whole number in [1, 1000000000], got 'x'",
    ),
    (
        ["approach", "{d}/invalid.yaml"],
        "error: invalid.yaml: needle.r_min_mm: expected a number >= 1e-06, got -3",
    ),
    (["approach", "{TOY}"], "error: toy.yaml: straight: the scenario has no straight block"),
    (
        ["approach", "{MULTI}", "--report", "/proc/a.html"],
        "error: --report: /proc/a.html: folder /proc is read-only",
    ),
    (
        ["cfrw", "{MULTI}", "--resolution-deg", "0"],
        "error: argument --resolution-deg: expected a number in [1e-06, 1e+12], got '0'",
    ),
    (
        ["cfrw", "{MULTI}", "--resolution-deg", "0.00001"],
        "error: --resolution-deg: a 1e-05-degree grid (2.16e+14 cells) would need at least 3.07 PiB; this machine has {AVAIL} available",
    ),
    (
        ["cfrw", "{MULTI}", "--layers", "x"],
        "error: argument --layers: expected a number in [1e-06, 1e+06] mm, got 'x'",
    ),
    (["cfrw", "{MULTI}", "--target", "99"], "error: --target: expected 1 to 3, got 99"),
    (
        ["cfrw", "{d}/straight_angle.yaml"],
        "error: straight_angle.yaml: straight.max_normal_angle_deg: expected a number <= 90, got 200",
    ),
    (
        ["cfrw", "{d}/straight_order.yaml"],
        "error: straight_order.yaml: straight.order: expected a permutation of 0..2 (the targets), got [2, 3, 4]",
    ),
    (
        ["multi", "{MULTI}", "--order", "0", "0"],
        "error: argument --order: expected a whole number in [1, 1000000000], got '0'",
    ),
    (
        ["multi", "{MULTI}", "--objective", "nope"],
        "error: argument --objective: invalid choice: 'nope' (choose from 'min_length', 'max_clearance', 'min_normal_angle')",
    ),
    (
        ["multi", "{MULTI}", "--resolution-deg", "-1"],
        "error: argument --resolution-deg: expected a number in [1e-06, 1e+12], got '-1'",
    ),
    (
        ["multi", "{MULTI}", "--time-limit-s", "0"],
        "error: argument --time-limit-s: expected a number in [1e-06, 1e+12], got '0'",
    ),
    (
        ["multi", "{d}/straight_up.yaml"],
        "error: straight_up.yaml: straight.up: expected a non-zero vector, got [0, 0, 0]",
    ),
    (
        ["multi", "{d}/straight_cone.yaml"],
        "error: straight_cone.yaml: straight.approach_cone_deg: expected a number <= 180, got 500",
    ),
    (
        ["approach", "{MULTI}", "--target", "0"],
        "error: argument --target: expected a whole number in [1, 1000000000], got '0'",
    ),
    (
        ["approach", "{MULTI}", "--max-cells", "0"],
        "error: argument --max-cells: expected a whole number in [1, 1000000000], got '0'",
    ),
    (
        ["approach", "{d}/nan.yaml"],
        "error: nan.yaml: start.point_mm[2]: expected a number in [-1e+06, 1e+06] mm, got nan",
    ),
    # -- markups
    (
        ["markups", "{d}/missing.json", "--out", "{d}/x.mrk.json"],
        "error: plan: {d}/missing.json: not found",
    ),
    (
        ["markups", "{d}/malformed.json", "--out", "{d}/x.mrk.json"],
        "error: {d}/malformed.json: not a JSON plan file (Expecting ',' delimiter: line 1 column 8 (char 7))",
    ),
    (
        ["markups", "{d}/list.json", "--out", "{d}/x.mrk.json"],
        "error: {d}/list.json: expected a JSON object at the top level",
    ),
    (
        ["markups", "{d}/goal_only.json", "--out", "{d}/x.txt"],
        "error: --out: {d}/x.txt: expected a name ending in .mrk.json",
    ),
    (
        ["markups", "{d}/goal_only.json", "--out", "{d}/x.mrk.json", "--spacing-mm", "0"],
        "error: argument --spacing-mm: expected a number in [0.001, 1e+06] mm, got '0'",
    ),
    (
        ["markups", "{d}/goal_only.json", "--out", "{d}/x.mrk.json", "--spacing-mm", "0.000000001"],
        "error: argument --spacing-mm: expected a number in [0.001, 1e+06] mm, got '0.000000001'",
    ),
    (
        ["markups", "{d}/deep.json", "--out", "{d}/x.mrk.json"],
        "error: {d}/deep.json: nested too deeply to be a needlekit file",
    ),
    (["markups", "{d}/goal_only.json"], "error: the following arguments are required: --out"),
    # -- slicer
    (
        ["slicer", "{TOY}", "{d}/missing.json", "--out", "{d}/x.mrb"],
        "error: plan: {d}/missing.json: not found",
    ),
    (
        ["slicer", "{TOY}", "{d}/malformed.json", "--out", "{d}/x.mrb"],
        "error: {d}/malformed.json: not a JSON plan file (Expecting ',' delimiter: line 1 column 8 (char 7))",
    ),
    (
        ["slicer", "{TOY}", "{d}/list.json", "--out", "{d}/x.mrb"],
        "error: {d}/list.json: expected a JSON object at the top level",
    ),
    (
        ["slicer", "{TOY}", "{d}/goal_only.json", "--out", "{d}/x.mrb"],
        "error: {d}/goal_only.json: not a result of a known kind (plan, goals, sweep, cfrw, multi, puncture, dynamic, scale, execute, execute-multi, approach, feng-lungs)",
    ),
    (
        ["slicer", "{TOY}", "{d}/deep.json", "--out", "{d}/x.mrb"],
        "error: {d}/deep.json: nested too deeply to be a needlekit file",
    ),
    (
        ["slicer", "{TOY}", "{d}/goal_only.json", "--out", "{d}/x.zip"],
        "error: --out: {d}/x.zip: expected a name ending in .mrb",
    ),
    (
        ["slicer", "{d}/nan.yaml", "{d}/goal_only.json", "--out", "{d}/x.mrb"],
        "error: nan.yaml: start.point_mm[2]: expected a number in [-1e+06, 1e+06] mm, got nan",
    ),
    (
        ["slicer", "{TOY}", "{d}/goal_only.json", "--execution", "{d}/missing.json", "--out", "{d}/x.mrb"],
        "error: --execution: {d}/missing.json: not found",
    ),
    (
        ["slicer", "{TOY}", "{d}/goal_only.json", "--out", "{d}/x.mrb", "--out-dir", "{d}/y"],
        "error: argument --out-dir: not allowed with argument --out",
    ),
    (
        ["slicer", "{TOY}", "{d}/goal_only.json", "--out", "{d}/x.mrb", "--max-cells", "2000"],
        "error: argument --max-cells: expected a whole number in [8, 1024], got '2000'",
    ),
    (
        ["slicer", "{TOY}", "{d}/goal_only.json"],
        "error: one of the arguments --out --out-dir is required",
    ),
    # -- kinematics
    (
        ["kinematics", "forward", "--kappa-per-mm", "0.02", "--segment", "1,2"],
        "error: argument --segment: expected three numbers u1_mm_s,u2_rad_s,duration_s (a number in [-1e+06, 1e+06] mm/s; a number in [-1e+12, 1e+12] rad/s; a number in [0, 1e+12] s), got '1,2'",
    ),
    (
        ["kinematics", "forward", "--kappa-per-mm", "x", "--segment", "1,2,3"],
        "error: argument --kappa-per-mm: expected a number in [0, 1000] 1/mm, got 'x'",
    ),
    (
        ["kinematics", "forward", "--kappa-per-mm", "0.02", "--segment", "1,2,-3"],
        "error: argument --segment: expected three numbers u1_mm_s,u2_rad_s,duration_s (a number in [-1e+06, 1e+06] mm/s; a number in [-1e+12, 1e+12] rad/s; a number in [0, 1e+12] s), got '1,2,-3'",
    ),
    (
        [
            "kinematics",
            "forward",
            "--kappa-per-mm",
            "0.02",
            "--segment",
            "1,0,1e15",
            "--dt-s",
            "0.01",
        ],
        "error: argument --segment: expected three numbers u1_mm_s,u2_rad_s,duration_s (a number in [-1e+06, 1e+06] mm/s; a number in [-1e+12, 1e+12] rad/s; a number in [0, 1e+12] s), got '1,0,1e15'",
    ),
    (
        ["kinematics", "inverse", "--kappa-per-mm", "0.02", "--target", "1,2"],
        "error: argument --target: expected three numbers x,y,z (mm), each a number in [-1e+06, 1e+06] mm, got '1,2'",
    ),
    (
        [
            "kinematics",
            "forward",
            "--kappa-per-mm",
            "0.02",
            "--segment",
            "1,2,3",
            "--start-pose",
            "{d}/missing.txt",
        ],
        "error: --start-pose: {d}/missing.txt: not found",
    ),
    (
        ["kinematics", "inverse", "--target", "1,2,3", "--r-min-mm", "0"],
        "error: argument --r-min-mm: expected a number in [1e-06, 1e+06] mm, got '0'",
    ),
    (
        ["kinematics", "forward", "--kappa-per-mm", "-1", "--segment", "1,2,3"],
        "error: argument --kappa-per-mm: expected a number in [0, 1000] 1/mm, got '-1'",
    ),
    (
        ["kinematics", "forward", "--kappa-per-mm", "0.02", "--segment", "1,2,3", "--dt-s", "0"],
        "error: argument --dt-s: expected a number in [1e-06, 1e+12], got '0'",
    ),
    (
        ["kinematics", "forward", "--kappa-per-mm", "0.02", "--segment", "nan,2,3"],
        "error: argument --segment: expected three numbers u1_mm_s,u2_rad_s,duration_s (a number in [-1e+06, 1e+06] mm/s; a number in [-1e+12, 1e+12] rad/s; a number in [0, 1e+12] s), got 'nan,2,3'",
    ),
    (
        ["kinematics", "inverse", "--target", "nan,2,3"],
        "error: argument --target: expected three numbers x,y,z (mm), each a number in [-1e+06, 1e+06] mm, got 'nan,2,3'",
    ),
    (
        ["kinematics", "nope"],
        "error: argument MODE: invalid choice: 'nope' (choose from 'forward', 'inverse')",
    ),
    # -- report
    (
        ["report", "{d}/missing.json", "--out", "{d}/r.html"],
        "error: RESULT: {d}/missing.json: not found",
    ),
    (
        ["report", "{d}/malformed.json", "--out", "{d}/r.html"],
        "error: {d}/malformed.json: not a JSON result file (Expecting ',' delimiter: line 1 column 8 (char 7))",
    ),
    (
        ["report", "{d}/list.json", "--out", "{d}/r.html"],
        "error: {d}/list.json: expected a JSON object at the top level",
    ),
    (
        ["report", "{d}/malformed.json", "--out", "{d}/malformed.json"],
        "error: --out: {d}/malformed.json: is the input RESULT; it would be overwritten",
    ),
    (
        ["report", "{d}/malformed.json", "--out", "/proc/r.html"],
        "error: --out: /proc/r.html: folder /proc is read-only",
    ),
    (["report", "--out", "{d}/r.html"], "error: the following arguments are required: RESULT"),
    (
        ["report", "{d}/goal_only.json", "--scenario", "{d}/missing.yaml", "--out", "{d}/r.html"],
        "error: --scenario: {d}/missing.yaml: not found",
    ),
    (
        ["report", "{d}/deep.json", "--out", "{d}/r.html"],
        "error: {d}/deep.json: nested too deeply to be a needlekit file",
    ),
    (
        ["report", "{d}/binary.json", "--out", "{d}/r.html"],
        "error: {d}/binary.json: not a JSON result file (not UTF-8 text: byte 0xff at offset 2)",
    ),
    (
        ["report", "{d}/unknown_kind.json", "--out", "{d}/r.html"],
        "error: {d}/unknown_kind.json: not a result of a known kind (plan, goals, sweep, cfrw, multi, puncture, dynamic, scale, execute, execute-multi, approach, feng-lungs)",
    ),
    (
        ["report", "{d}/moved_plan.json", "--out", "{d}/r.html"],
        "error: {d}/moved_plan.json: not a result of a known kind (plan, goals, sweep, cfrw, multi, puncture, dynamic, scale, execute, execute-multi, approach, feng-lungs)",
    ),
    # -- reproduce
    (
        ["reproduce", "nope"],
        "error: argument PAPER: invalid choice: 'nope' (choose from 'feng2023', 'liu2016', 'tang', 'lecture', 'all')",
    ),
    (
        ["reproduce", "lecture", "--out", "/proc/reproduce"],
        "error: --out: /proc/reproduce: folder /proc is read-only",
    ),
    (
        ["reproduce", "lecture", "--out", "{d}/pose.txt"],
        "error: --out: {d}/pose.txt: is a file, expected a folder",
    ),
    # -- study
    (["study", "livers", "--medrad", "{d}/missing"], "error: --medrad: {d}/missing: not found"),
    (
        ["study", "livers", "--gamma", "-1"],
        "error: argument --gamma: expected a number in [0, 1e+06] mm, got '-1'",
    ),
    (
        ["study", "livers", "--livers", "0"],
        "error: argument --livers: expected a whole number in [1, 1000000000], got '0'",
    ),
    (
        ["study", "feng-lungs", "--out", "{d}/feng", "--directions", "0"],
        "error: argument --directions: expected a whole number in [1, 1000000000], got '0'",
    ),
    (
        ["study", "feng-lungs", "--out", "{d}/feng", "--medrad", "{d}/missing"],
        "error: --medrad: {d}/missing: not found",
    ),
    (
        ["study", "feng-lungs", "--out", "{d}/pose.txt"],
        "error: --out: {d}/pose.txt: is a file, expected a folder",
    ),
    (
        ["study", "feng-lungs", "--out", "{d}/feng", "--executor", "nope"],
        "error: argument --executor: invalid choice: 'nope' (choose from 'serial', 'process', 'dask')",
    ),
    (
        ["study", "feng-lungs", "--out", "{d}/feng", "--executor", "serial", "--workers", "2"],
        "error: --workers starts worker processes: it contradicts --executor serial",
    ),
    (
        ["study", "livers", "--gamma", "x"],
        "error: argument --gamma: expected a number in [0, 1e+06] mm, got 'x'",
    ),
    (
        ["study", "feng-lungs", "--out", "{d}/feng", "--directions", "-5"],
        "error: argument --directions: expected a whole number in [1, 1000000000], got '-5'",
    ),
    (
        ["study", "livers", "--livers", "1", "--medrad", "{d}/missing"],
        "error: --medrad: {d}/missing: not found",
    ),
    (
        ["study", "feng-lungs", "--out", "{d}/feng", "--dashboard"],
        "error: --dashboard: serves a local Dask cluster's dashboard: add --dask-workers N",
    ),
    (
        ["study", "nope"],
        "error: argument STUDY: invalid choice: 'nope' (choose from 'livers', 'feng-lungs', 'execute-lungs')",
    ),
    # -- puncture and bench
    (
        ["puncture", "--trials", "0"],
        "error: argument --trials: expected a whole number in [1, 1000000000], got '0'",
    ),
    (
        ["puncture", "--adaptation-delay-ms", "0.5"],
        "error: argument --adaptation-delay-ms: expected a whole number >= 0 of control periods (1 ms), at most 1e+06 ms, got '0.5'",
    ),
    (
        ["puncture", "--out", "/proc/puncture"],
        "error: --out: /proc/puncture: folder /proc is read-only",
    ),
    (
        ["bench", "control", "--out", "/proc/x.json"],
        "error: --out: /proc/x.json: folder /proc is read-only",
    ),
    (
        ["bench", "fields", "--out", "{d}/pose.txt/x.json"],
        "error: --out: {d}/pose.txt/x.json: cannot be created: {d}/pose.txt is not a folder",
    ),
    # -- formerly heavy
    (
        [
            "kinematics",
            "forward",
            "--kappa-per-mm",
            "0.02",
            "--segment",
            "1,2,3",
            "--start-pose",
            "{d}/pose.txt",
        ],
        "error: {d}/pose.txt: expected a 4x4 matrix (16 numbers), got 3",
    ),
    (
        ["study", "livers", "--medrad", "{d}/empty"],
        "error: --medrad: no Med-RAD liver patients under {d}/empty",
    ),
    (
        ["study", "livers", "--livers", "9"],
        "error: --livers: no patient [9] under {M} (there: [1, 2, 3, 4, 5])",
    ),
    (
        ["study", "feng-lungs", "--out", "{d}/feng", "--medrad", "{d}/empty"],
        "error: --medrad: no Med-RAD lung patient 5 at {d}/empty/Lungs/TumorTargetEnvironments/Patient5",
    ),
    (
        ["puncture", "--history", "-1", "--out", "{d}/puncture"],
        "error: argument --history: expected a whole number in [0, 1000000000], got '-1'",
    ),
    # -- groups
    (["bench"], "error: the following arguments are required: SUITE"),
    (["study"], "error: the following arguments are required: STUDY"),
    (["scene"], "error: the following arguments are required: ACTION"),
    (["kinematics"], "error: the following arguments are required: MODE"),
    # -- reproduce and demo
    (
        ["reproduce", "lecture", "--out", "{TOY}"],
        "error: --out: {TOY}: is a file, expected a folder",
    ),
    (
        ["reproduce", "lecture", "--dashboard"],
        "error: --dashboard: serves a local Dask cluster's dashboard: add --dask-workers N",
    ),
    (
        ["reproduce", "lecture", "--workers", "0"],
        "error: argument --workers: expected a whole number in [1, 1000000000], got '0'",
    ),
    (["demo", "--out", "/proc/demo"], "error: --out: /proc/demo: folder /proc is read-only"),
    (["demo", "--out", "{TOY}"], "error: --out: {TOY}: is a file, expected a folder"),
    # -- puncture
    (
        ["puncture", "--trials", "-1"],
        "error: argument --trials: expected a whole number in [1, 1000000000], got '-1'",
    ),
    (
        ["puncture", "--seed", "x"],
        "error: argument --seed: expected a whole number in [0, 9.22e+18], got 'x'",
    ),
    # -- execute
    (
        ["execute", "--truth", "kinematic", "{TOY}", "{d}/malformed.json"],
        "error: {d}/malformed.json: not a JSON plan file (Expecting ',' delimiter: line 1 column 8 (char 7))",
    ),
    (
        ["execute", "--truth", "kinematic", "{TOY}", "{d}/malformed.json", "--trials", "0"],
        "error: argument --trials: expected a whole number in [1, 1000000000], got '0'",
    ),
    (
        ["execute", "--truth", "kinematic", "{TOY}", "{d}/malformed.json", "--trials", "2", "--replay-trial", "3"],
        "error: --replay-trial: expected a trial number below --trials (2), got 3",
    ),
    (
        ["execute", "--truth", "kinematic", "{TOY}", "{d}/malformed.json", "--igtl", "70000"],
        "error: --igtl: expected [HOST:]PORT with a port in 1-65535, got '70000'",
    ),
    (
        ["execute", "--truth", "kinematic", "{TOY}", "{d}/malformed.json", "--tip-from-igtl", "X"],
        "error: --tip-from-igtl: takes the tip from the --igtl link: give that too",
    ),
    (
        ["execute", "--truth", "kinematic", "{TOY}", "{d}/malformed.json", "--breathing", "lung", "--breathing-shape", "9"],
        "error: argument --breathing-shape: expected a whole number in [1, 6], got '9'",
    ),
    (
        ["execute", "--truth", "kinematic", "{TOY}", "{d}/malformed.json", "--orientation-noise-rad", "0.1"],
        "error: --orientation-noise-rad: expected at most 0.05, got 0.1",
    ),
    (
        ["execute", "--truth", "kinematic", "{TOY}", "{d}/malformed.json", "--sensing", "em,sonar"],
        "error: argument --sensing: expected policies among em, checkpoints, tracking "
        "(comma-separated), got 'sonar'",
    ),
    (
        ["execute", "--truth", "kinematic", "{TOY}", "{d}/malformed.json", "--sensing", "tracking",
         "--tracking-rate-hz", "0"],
        "error: argument --tracking-rate-hz: expected a number in (0, 1000] Hz, got '0'",
    ),
    (
        ["execute", "--truth", "kinematic", "{TOY}", "{d}/malformed.json", "--sensing", "tracking",
         "--tracking-latency-ms", "-5"],
        "error: argument --tracking-latency-ms: expected a number in [0, 10000] ms, got '-5'",
    ),
    (
        ["execute", "--truth", "kinematic", "{TOY}", "{d}/malformed.json", "--sensing", "checkpoints",
         "--checkpoint-every-mm", "0.5"],
        "error: argument --checkpoint-every-mm: expected a number in [1, 1000] mm, got '0.5'",
    ),
    (
        ["execute", "--truth", "kinematic", "{TOY}", "{d}/malformed.json", "--scan-s", "5"],
        "error: --scan-s: sets the checkpoints sensor: add checkpoints to --sensing",
    ),
    (
        ["execute", "--truth", "kinematic", "{TOY}", "{d}/malformed.json", "--registration-sd-mm", "1"],
        "error: --registration-sd-mm: applies to a multi plan (multi.json)",
    ),
    (
        ["study", "execute-lungs", "--out", "{d}/el", "--crossing-probability", "0.9"],
        "error: argument --crossing-probability: expected a number in (0, 0.5], got '0.9'",
    ),
    (
        ["bench", "execute", "--replans", "0"],
        "error: argument --replans: expected a whole number in [1, 1000000000], got '0'",
    ),
    (
        ["puncture", "--stability-radius-mm", "-1"],
        "error: argument --stability-radius-mm: expected a number in [0, 1e+06] mm, got '-1'",
    ),
    (
        ["puncture", "--guide-samples", "-1"],
        "error: argument --guide-samples: expected a whole number in [0, 1000000000], got '-1'",
    ),
    (
        ["puncture", "--qp-solver", "nope"],
        "error: --qp-solver: unknown QP solver 'nope'; available: daqp, quadprog",
    ),
    (
        ["puncture", "--workers", "0"],
        "error: argument --workers: expected a whole number in [1, 1000000000], got '0'",
    ),
    (
        ["puncture", "--dashboard"],
        "error: --dashboard: serves a local Dask cluster's dashboard: add --dask-workers N",
    ),
    # -- bench
    (
        ["bench", "fields", "--grid", "0"],
        "error: argument --grid: expected a whole number in [1, 1000000000], got '0'",
    ),
    (
        ["bench", "fields", "--grid", "100000"],
        "error: --grid: a 100000^3 grid would need at least 7.11 PiB; this machine has {AVAIL} available",
    ),
    (
        ["bench", "steerable", "--patients", "9"],
        "error: patient: no lung patient 9 in {M}/Lungs/TumorTargetEnvironments (have 1, 2, 3, 4, 5)",
    ),
    (
        ["bench", "straight", "--livers", "9"],
        "error: --livers: no Med-RAD liver patient 9 at {M}/Liver/Patient9",
    ),
    (
        ["bench", "control", "--trials", "0"],
        "error: argument --trials: expected a whole number in [1, 1000000000], got '0'",
    ),
    (
        ["bench", "scale", "--directions", "-1"],
        "error: argument --directions: expected a whole number in [0, 1000000000], got '-1'",
    ),
    (
        ["bench", "approach", "--repeat", "0"],
        "error: argument --repeat: expected a whole number in [1, 1000000000], got '0'",
    ),
    (
        ["bench", "steerable", "--reference-app", "{d}/missing-app"],
        "error: --reference-app: {d}/missing-app: not found",
    ),
    (
        ["bench", "steerable", "--radii", "-1"],
        "error: argument --radii: expected a number in [1e-06, 1e+06] mm, got '-1'",
    ),
    (
        ["bench", "steerable", "--planners", "nope"],
        "error: --planners: unknown planner 'nope'; available: rcs_star, rcs, rrt, liu_cfrw",
    ),
    (
        ["bench", "steerable", "--planners", "liu_cfrw"],
        "error: --planners: 'liu_cfrw' plans straight needles; steerable planners: rcs_star, rcs, rrt",
    ),
    (
        ["bench", "nope"],
        "error: argument SUITE: invalid choice: 'nope' (choose from 'kinematics', 'fields', 'control', 'steerable', 'execute', 'approach', 'straight', 'scale')",
    ),
    # -- cache
    (
        ["cache", "limit", "banana"],
        "error: argument SIZE: expected a size such as 10GB, 500MB or 1.5TB (up to 1000TB), got 'banana'",
    ),
    (
        ["cache", "limit", "5"],
        "error: argument SIZE: expected a size such as 10GB, 500MB or 1.5TB (up to 1000TB), got '5'",
    ),
    (
        ["cache", "clear", "--older-than-days", "-1"],
        "error: argument --older-than-days: expected a number in [0, 36500] days, got '-1'",
    ),
    (
        ["cache", "clear", "--cache-dir", "{d}", "--patient", "lung9"],
        "error: --patient: expected a patient or entry key held in {d} (have: none), got 'lung9'",
    ),
    (
        ["cache", "nope"],
        "error: argument ACTION: invalid choice: 'nope' (choose from 'list', 'clear', 'limit')",
    ),
]


@pytest.fixture(scope="module")
def folder(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("campaign")
    make_files(root)
    return root


def _medrad() -> str | None:
    from needlekit.errors import InvalidInputError
    from needlekit.io.medrad_paths import medrad_root

    try:
        return str(medrad_root())
    except InvalidInputError:
        return None


def test_the_table_is_a_campaign():
    assert len(ROWS) >= 150
    commands = {argv[0] for argv, _ in ROWS}
    from needlekit.cli import _GROUPS, _HANDLERS

    top = {c.split()[0] for c in _HANDLERS} | set(_GROUPS)
    assert top - {"schema"} <= commands | {"schema"}, top - commands  # every command has rows
    assert all(line.startswith("error: ") and "\n" not in line for _, line in ROWS)


@pytest.mark.parametrize(("argv", "line"), ROWS, ids=[" ".join(a)[:70] for a, _ in ROWS])
def test_bad_input_gets_its_one_line_and_exit_2(argv, line, folder, capsys):
    subs = {"{d}": str(folder), "{TOY}": str(EXAMPLES / "toy.yaml"),
            "{MULTI}": str(EXAMPLES / "liver_phantom_multi.yaml")}  # fmt: skip
    if "{M}" in line or argv[:2] in (["bench", "steerable"], ["bench", "straight"]):
        medrad = _medrad()
        if medrad is None:
            pytest.skip("Med-RAD data not found (set NEEDLEKIT_MEDRAD): the line names it")
        subs["{M}"] = medrad

    def fill(text: str) -> str:
        for k, v in subs.items():
            text = text.replace(k, v)
        return text

    capsys.readouterr()
    try:
        code = main([fill(a) for a in argv])
    except SystemExit as exc:  # argparse's own errors
        code = exc.code
    err = capsys.readouterr().err.splitlines()
    # the memory a machine has free varies from run to run: the rest of the line does not
    err = [
        re.sub(r"this machine has \S+ \S+ available", "this machine has {AVAIL} available", e)
        for e in err
    ]
    assert (code, err) == (2, [fill(line)])


# ---------------------------------------------------------------------------------------
# the same property on random documents, through the command line


def _fuzz_values():
    from hypothesis import strategies as st

    leaf = st.one_of(
        st.none(), st.booleans(), st.integers(-(10**6), 10**6),
        st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=12),
    )  # fmt: skip
    return st.recursive(
        leaf,
        lambda c: st.one_of(
            st.lists(c, max_size=4), st.dictionaries(st.text(max_size=8), c, max_size=4)
        ),
        max_leaves=10,
    )


def _places(node, prefix=()):
    yield prefix
    if isinstance(node, dict):
        for k, v in node.items():
            yield from _places(v, (*prefix, k))
    elif isinstance(node, list):
        for i, v in enumerate(node):
            yield from _places(v, (*prefix, i))


def test_fuzzed_scenario_files_give_one_clean_error_or_a_scene(tmp_path_factory):
    """Random edits of the toy scenario written as a file and run through ``needlekit
    scene info``: exit 0 with the scene's table, or exit 2 with exactly one ``error:``
    line; never a traceback, never any other status."""
    import contextlib
    import copy
    import io

    import yaml
    from hypothesis import HealthCheck, given, settings
    from hypothesis import strategies as st

    toy = yaml.safe_load((EXAMPLES / "toy.yaml").read_text())
    places = list(_places(toy))
    folder = tmp_path_factory.mktemp("fuzz")

    @settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
    @given(
        index=st.integers(0, 10**6),
        action=st.sampled_from(["replace", "delete", "add"]),
        value=_fuzz_values(),
        key=st.text(max_size=8),
    )
    def run(index, action, value, key):
        doc = copy.deepcopy(toy)
        path = places[index % len(places)]
        if not path:
            doc = value if action == "replace" else doc
        else:
            parent = doc
            for part in path[:-1]:
                parent = parent[part]
            if action == "replace":
                parent[path[-1]] = value
            elif action == "delete":
                del parent[path[-1]]
            elif isinstance(parent, dict):
                parent[key] = value
        f = folder / "fuzz.yaml"
        f.write_text(yaml.safe_dump(doc, allow_unicode=True))
        out, err = io.StringIO(), io.StringIO()
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            try:
                code = main(["scene", "info", str(f)])
            except SystemExit as exc:
                code = exc.code
        lines = [ln for ln in err.getvalue().splitlines() if not ln.startswith("WARNING ")]
        if code == 0:
            assert lines == [] and out.getvalue().strip(), err.getvalue()
        else:
            assert code == 2 and len(lines) == 1 and lines[0].startswith("error: "), (
                code,
                err.getvalue(),
            )

    run()
