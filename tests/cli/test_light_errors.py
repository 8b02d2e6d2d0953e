"""Input errors are answered before any heavy module is imported.

Each command's typical input errors run in a fresh interpreter (a small wrapper around
:func:`needlekit.cli.main`), which then reports which of the heavy modules (numba, scipy,
matplotlib, plotly, dask, dqrobotics, daqp) are in ``sys.modules``: every error must exit
with status 2, print exactly one ``error: ...`` line and import none of them. No clocks: the
times are measured by hand (docs/notes/real-time-and-scale-plan.md), never asserted.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from needlekit.cli import _GROUPS, _HANDLERS

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
TOY = str(EXAMPLES / "toy.yaml")
MULTI = str(EXAMPLES / "liver_phantom_multi.yaml")

HEAVY = ("numba", "scipy", "matplotlib", "plotly", "dask", "dqrobotics", "daqp")

#: Runs each argv of a JSON list through main() in this one interpreter, and prints per
#: argv its exit status, what it wrote on stderr, and the heavy modules imported so far.
#: The list is cumulative: once a case has imported a module, every later one shows it, so
#: the first case that shows a module is the one that imported it.
_WRAPPER = """
import contextlib, io, json, sys
from needlekit.cli import main
heavy = {heavy!r}
out = []
for argv in json.loads(sys.argv[1]):
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        try:
            rc = main(argv)
        except SystemExit as exc:
            rc = exc.code
    out.append({{"rc": rc, "stderr": err.getvalue(),
                "heavy": [m for m in heavy if m in sys.modules]}})
print(json.dumps(out))
"""


def _run(cases: list[list[str]]) -> list[dict]:
    done = subprocess.run(
        [sys.executable, "-c", _WRAPPER.format(heavy=HEAVY), json.dumps(cases)],
        capture_output=True,
        text=True,
        check=False,
        timeout=300,
    )
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout.splitlines()[-1])


TOY_STRUCTURES = """\
structures:
  - {name: lung, role: allowed_region, ellipsoid: {semi_axes_mm: [80, 60, 100]}}
  - {name: vessel, role: obstacle, capsule: {p0_mm: [-40, 10, -10], p1_mm: [40, 10, 5],
     radius_mm: 4}, moving: {velocity_mm_s: [0, 1, 0]}}
needle: {r_min_mm: 50}
start: {point_mm: [0, -12, 0], direction: [0, 1, 0.3]}
goal: {point_mm: [20, 30, 40]}
"""

FILES = {
    "malformed.yaml": "version: 1\nbase: {phantom: {name: lung\n",
    "invalid.yaml": "version: 1\nneedle: {r_min_mm: -3}\n",
    "version2.yaml": "version: 2\n",
    "list.yaml": "- version: 1\n",
    "block_planner.yaml": "version: 1\nplanner: {name: nope}\n",
    "block_option.yaml": "version: 1\nplanner: {name: rrt, options: {bogus: 1}}\n",
    "moving_no_speed.yaml": "version: 1\n" + TOY_STRUCTURES,
    "malformed.json": '{"x": 1',
    "list.json": "[1, 2]",
    "goal_only.json": '{"goal_mm": [0, 0, 0]}',
    "pose.txt": "1 0 0\n",
}


@pytest.fixture(scope="module")
def files(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("light")
    for name, text in FILES.items():
        (root / name).write_text(text)
    (root / "empty").mkdir()
    return root


#: Per command, its typical input errors; ``{d}`` is the folder of :data:`FILES`.
CASES = {
    "plan": [
        ["plan", "{d}/missing.yaml"],
        ["plan", "{d}/malformed.yaml"],
        ["plan", "{d}/invalid.yaml"],
        ["plan", "{d}/version2.yaml"],
        ["plan", "{d}/list.yaml"],
        ["plan", "{d}"],
        ["plan", TOY, "--planner", "nope"],
        ["plan", TOY, "--planner", "liu_cfrw"],
        ["plan", "{d}/block_planner.yaml"],
        ["plan", "{d}/block_option.yaml"],
        ["plan", TOY, "--goals", "1,2"],
        ["plan", TOY, "--goal", "1,2,x"],
        ["plan", TOY, "--goals", "1,2,3", "--goal", "1,2,3"],
        ["plan", TOY, "--goals", "1,2,3", "--multi", "one-tree", "--planner", "rcs"],
        ["plan", TOY, "--step-mm", "3"],
        ["plan", TOY, "--dynamic"],
        ["plan", TOY, "--dynamic", "--goals", "1,2,3"],
        ["plan", "{d}/moving_no_speed.yaml", "--dynamic"],
        ["plan", TOY, "--time-limit-s", "-1"],
        ["plan", TOY, "--seed", "x"],
        ["plan", TOY, "--max-iterations", "0"],
        ["plan", TOY, "--r-min-mm", "nan"],
        ["plan", TOY, "--rrt-connection", "nope"],
        ["plan", TOY, "--start-pose", "{d}/missing.txt"],
        ["plan", TOY, "--out", "{d}"],
        ["plan", TOY, "--out", "/proc/plan.json"],
        ["plan", TOY, "--out", "{d}/pose.txt/plan.json"],
        ["plan", TOY, "--out", TOY],
        ["plan", TOY, "--bogus"],
        ["plan", TOY, "--option", "bogus=1"],
        ["plan", TOY, "--option", "resolution.max_length_mm=x"],
        ["plan", TOY, "--option", "resolution=8"],
        ["plan", TOY, "--planner", "rrt", "--option", "seed=1.5"],
        ["plan", TOY, "--option", "novalue"],
    ],
    "sweep": [
        ["sweep", TOY, "--planner", "nope"],
        ["sweep", TOY, "--planner", "rrt", "liu_cfrw"],
        ["sweep", "{d}/malformed.yaml"],
        ["sweep", "{d}/invalid.yaml"],
        ["sweep", "{d}/block_option.yaml"],
        ["sweep", TOY, "--directions", "0"],
        ["sweep", TOY, "--healpix", "x"],
        ["sweep", TOY, "--report", "{d}/pose.txt/r.html"],
        ["sweep", TOY, "--out", "{d}/a.json", "--plan", "{d}/a.json"],
        ["sweep", TOY, "--executor", "serial", "--workers", "2"],
        ["sweep", TOY, "--planner", "rcs_star", "rrt", "--option", "nope=1"],
        ["sweep", TOY, "--planner", "rcs", "rrt", "--option", "seed=x"],
    ],
    "verify": [
        ["verify", TOY, "{d}/missing.json"],
        ["verify", TOY, "{d}/malformed.json"],
        ["verify", TOY, "{d}/list.json"],
        ["verify", "{d}/invalid.yaml", "{d}/goal_only.json"],
        ["verify", "{d}/malformed.yaml", "{d}/goal_only.json"],
    ],
    "scene": [
        ["schema", "--bogus"],
        ["scene", "info", "{d}/missing.yaml"],
        ["scene", "info", "{d}/malformed.yaml"],
        ["scene", "info", "{d}/invalid.yaml"],
        ["scene", "render", "{d}/invalid.yaml", "--out", "{d}/s.html"],
        ["scene", "render", TOY, "--out", "/proc/s.html"],
        ["scene", "render", TOY, "--out", "{d}/s.html", "--max-cells", "0"],
    ],
    "straight": [
        ["cfrw", "{d}/invalid.yaml"],
        ["cfrw", "{d}/malformed.yaml"],
        ["cfrw", TOY],
        ["cfrw", MULTI, "--target", "0"],
        ["cfrw", MULTI, "--target", "99"],
        ["multi", "{d}/invalid.yaml"],
        ["multi", TOY],
        ["multi", MULTI, "--planner", "nope"],
        ["multi", MULTI, "--order", "x"],
        ["approach", "{d}/invalid.yaml"],
        ["approach", TOY],
        ["approach", MULTI, "--report", "/proc/a.html"],
        ["approach", MULTI, "--target", "99"],
    ],
    "markups": [
        ["markups", "{d}/missing.json", "--out", "{d}/x.mrk.json"],
        ["markups", "{d}/malformed.json", "--out", "{d}/x.mrk.json"],
        ["markups", "{d}/list.json", "--out", "{d}/x.mrk.json"],
        ["markups", "{d}/goal_only.json", "--out", "{d}/x.txt"],
    ],
    "kinematics": [
        ["kinematics", "forward", "--kappa-per-mm", "0.02", "--segment", "1,2"],
        ["kinematics", "forward", "--kappa-per-mm", "x", "--segment", "1,2,3"],
        ["kinematics", "forward", "--kappa-per-mm", "0.02", "--segment", "1,2,-3"],
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
        ["kinematics", "inverse", "--kappa-per-mm", "0.02", "--target", "1,2"],
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
    ],
    "report": [
        ["report", "{d}/missing.json", "--out", "{d}/r.html"],
        ["report", "{d}/malformed.json", "--out", "{d}/r.html"],
        ["report", "{d}/list.json", "--out", "{d}/r.html"],
        ["report", "{d}/malformed.json", "--out", "{d}/malformed.json"],
        ["report", "{d}/malformed.json", "--out", "/proc/r.html"],
    ],
    "reproduce": [
        ["reproduce", "nope"],
        ["reproduce", "lecture", "--out", "/proc/reproduce"],
        ["reproduce", "lecture", "--out", "{d}/pose.txt"],
    ],
    "study": [
        ["study", "livers", "--medrad", "{d}/missing"],
        ["study", "livers", "--gamma", "-1"],
        ["study", "livers", "--livers", "0"],
        ["study", "feng-lungs", "--out", "{d}/feng", "--directions", "0"],
        ["study", "feng-lungs", "--out", "{d}/feng", "--medrad", "{d}/missing"],
        ["study", "feng-lungs", "--out", "{d}/pose.txt"],
        ["study", "feng-lungs", "--out", "{d}/feng", "--executor", "nope"],
        ["study", "feng-lungs", "--out", "{d}/feng", "--executor", "serial", "--workers", "2"],
    ],
    "puncture and bench": [
        ["puncture", "--trials", "0"],
        ["puncture", "--adaptation-delay-ms", "0.5"],
        ["puncture", "--out", "/proc/puncture"],
        ["puncture", "--qp-solver", "nope"],
        ["bench", "control", "--out", "/proc/x.json"],
        ["bench", "steerable", "--planners", "nope"],
        ["bench", "control", "--qp-solver", "nope"],
        ["bench", "steerable", "--planners", "liu_cfrw"],
        ["bench", "fields", "--out", "{d}/pose.txt/x.json"],
    ],
    "cache": [
        ["cache", "limit", "banana"],
        ["cache", "clear", "--older-than-days", "-1"],
        ["cache", "clear", "--cache-dir", "{d}", "--patient", "lung9"],
    ],
}

#: Errors whose checks moved ahead of heavy imports: the pose file (``_validation`` checks
#: small batches with numpy), the Med-RAD folder layout (``io.medrad_paths``), and
#: ``puncture --history`` (checked before the study's imports).
CASES["formerly heavy"] = [
    ["kinematics", "forward", "--kappa-per-mm", "0.02", "--segment", "1,2,3",
     "--start-pose", "{d}/pose.txt"],
    ["study", "livers", "--medrad", "{d}/empty"],
    ["study", "livers", "--livers", "9"],
    ["study", "feng-lungs", "--out", "{d}/feng", "--medrad", "{d}/empty"],
    ["puncture", "--history", "-1", "--out", "{d}/puncture"],
]  # fmt: skip


#: ``execute``'s plug points: a wrong name, a sensor without its link, a re-planner that
#: cannot warm-start; each refused before the plan is read.
CASES["execute plug points"] = [
    ["execute", TOY, "{d}/malformed.json", "--truth", "kinematik"],
    ["execute", "--truth", "kinematic", TOY, "{d}/malformed.json", "--estimator", "kalmann"],
    ["execute", "--truth", "kinematic", TOY, "{d}/malformed.json", "--feedback", "nope"],
    ["execute", "--truth", "kinematic", TOY, "{d}/malformed.json", "--sensor", "igtl"],
    ["execute", "--truth", "kinematic", TOY, "{d}/malformed.json", "--replanner", "rrt"],
    ["execute", "--truth", "kinematic", TOY, "{d}/malformed.json", "--replanner", "rcs_sta"],
]


#: ``execute``'s target sensing: a policy unknown or twice, a sensor's setting out of its
#: range, or given without its policy; each refused before the plan is read.
CASES["execute sensing"] = [
    ["execute", "--truth", "kinematic", TOY, "{d}/malformed.json", "--sensing", "em,sonar"],
    ["execute", "--truth", "kinematic", TOY, "{d}/malformed.json", "--sensing", "em,em"],
    ["execute", "--truth", "kinematic", TOY, "{d}/malformed.json", "--sensing", "tracking", "--tracking-rate-hz", "0"],
    ["execute", "--truth", "kinematic", TOY, "{d}/malformed.json", "--sensing", "tracking", "--tracking-latency-ms",
     "-1"],
    ["execute", "--truth", "kinematic", TOY, "{d}/malformed.json", "--sensing", "tracking", "--tracking-sigma-mm",
     "nan"],
    ["execute", "--truth", "kinematic", TOY, "{d}/malformed.json", "--sensing", "checkpoints", "--scan-s", "inf"],
    ["execute", "--truth", "kinematic", TOY, "{d}/malformed.json", "--sensing", "checkpoints", "--image-sigma-mm",
     "-0.1"],
    ["execute", "--truth", "kinematic", TOY, "{d}/malformed.json", "--sensing", "checkpoints",
     "--checkpoint-every-mm", "0"],
    ["execute", "--truth", "kinematic", TOY, "{d}/malformed.json", "--tracking-rate-hz", "5"],
    ["execute", "--truth", "kinematic", TOY, "{d}/malformed.json", "--retarget-mm", "1"],
]  # fmt: skip


#: A command group without its sub-command is a usage error (exit 2), not its help.
CASES["groups"] = [["bench"], ["study"], ["scene"], ["kinematics"], ["cache"]]


def _check(cases: list[list[str]], files: Path) -> None:
    argvs = [[a.replace("{d}", str(files)) for a in argv] for argv in cases]
    for argv, res in zip(argvs, _run(argvs), strict=True):
        lines = res["stderr"].splitlines()
        errors = [line for line in lines if line.startswith("error: ")]
        assert res["rc"] == 2, (argv, res)
        assert len(errors) == 1 and len(lines) == 1, (argv, res["stderr"])
        assert res["heavy"] == [], (argv, res["heavy"], errors[0])


@pytest.mark.parametrize("command", list(CASES))
def test_input_errors_exit_2_on_one_line_before_any_heavy_import(command, files):
    _check(CASES[command], files)


def test_help_of_every_command_imports_no_heavy_module():
    commands = [[], *([g] for g in _GROUPS), *(c.split() for c in _HANDLERS)]
    results = _run([[*c, "--help"] for c in commands])
    for argv, res in zip(commands, results, strict=True):
        assert res["rc"] == 0 and res["stderr"] == "", (argv, res)
    assert results[-1]["heavy"] == []  # cumulative: none imported by any of them


def test_the_dynamic_checks_say_what_dynamic_settings_says(files):
    """``plan --dynamic`` refuses a static scenario or a missing insertion speed before
    numba, in the words of :func:`needlekit.scenario.problems.dynamic_settings`."""
    from needlekit.errors import InvalidInputError
    from needlekit.scenario.problems import dynamic_settings

    for name in (TOY, str(files / "moving_no_speed.yaml")):
        with pytest.raises(InvalidInputError) as exc:
            dynamic_settings(name, {})
        (res,) = _run([["plan", name, "--dynamic", "--out", str(files / "p.json")]])
        assert res["stderr"] == f"error: {exc.value}\n" and res["heavy"] == []
