"""The command line loses no work: paths are checked before any computation, outputs are
written as one unit, and bad input is answered before the heavy imports."""

import errno
import json
import logging
import os
import subprocess
import sys
from pathlib import Path

import pytest

import needlekit.cli
from needlekit.cli import main
from needlekit.cli._parser import (
    DEMO_FILES,
    FENG_LUNGS_FILES,
    PUNCTURE_FILES,
    REPRODUCE_FILES,
    REPRODUCE_PAPERS,
)
from needlekit.cli.execute import EXECUTE_FILES
from needlekit.cli.slicer import SLICER_FILES
from needlekit.cli.study import EXECUTE_LUNGS_FILES

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
TOY = str(EXAMPLES / "toy.yaml")
MULTI = str(EXAMPLES / "liver_phantom_multi.yaml")


def _tree(root):
    """Every path under root with its bytes and mode: to show that nothing changed."""
    out = {}
    for dirpath, dirnames, filenames in os.walk(root):
        for name in dirnames + filenames:
            p = os.path.join(dirpath, name)
            st = os.lstat(p)
            data = Path(p).read_bytes() if os.path.isfile(p) else None
            out[os.path.relpath(p, root)] = (data, st.st_mode)
    return out


@pytest.fixture
def no_work(monkeypatch):
    """Fail the test if any command starts (its module is imported and run)."""

    def started(command, args):
        raise AssertionError(f"{command} started before its paths were checked")

    monkeypatch.setattr(needlekit.cli, "_run", started)


@pytest.fixture
def places(tmp_path):
    """An empty folder, a read-only folder (refused for root too), a plain file and a
    read-only file; modes restored afterwards."""
    (tmp_path / "dir").mkdir()
    (tmp_path / "ro").mkdir()
    (tmp_path / "file.txt").write_text("a file\n")
    (tmp_path / "locked.json").write_text('{"old": true}\n')
    (tmp_path / "ro").chmod(0o555)
    (tmp_path / "locked.json").chmod(0o444)
    yield tmp_path
    (tmp_path / "ro").chmod(0o755)
    (tmp_path / "locked.json").chmod(0o644)


def _one_error_line(capsys, argv):
    try:
        code = main(argv)
    except SystemExit as exc:  # argparse's own errors
        code = exc.code
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) == 1, err
    assert lines[0].startswith("error: "), err
    return lines[0]


#: Every output file flag: the command before it, and the flag.
FILE_OUTPUTS = [
    (["plan", TOY], "--out"),
    (["plan", TOY], "--report"),
    (["sweep", TOY], "--out"),
    (["sweep", TOY], "--plan"),
    (["sweep", TOY], "--report"),
    (["scene", "render", TOY], "--out"),
    (["bench", "kinematics"], "--out"),
    (["bench", "fields"], "--out"),
    (["bench", "control"], "--out"),
    (["bench", "steerable"], "--out"),
    (["bench", "straight"], "--out"),
    (["cfrw", MULTI], "--out"),
    (["multi", MULTI], "--out"),
    (["multi", MULTI], "--report"),
    (["approach", MULTI], "--out"),
    (["approach", MULTI], "--report"),
    (["markups", TOY], "--out"),  # any existing file passes the input check
    (["slicer", TOY, TOY], "--out"),  # any existing files pass the input checks
    (["study", "livers"], "--out"),
    (["bench", "approach"], "--out"),
    (["bench", "scale"], "--out"),
    (["report", TOY], "--out"),  # the page is checked before any RESULT is read
    (["execute", TOY, TOY], "--report"),  # any existing file passes the input checks
    (["bench", "execute"], "--out"),
]
#: Every output folder flag, and the files the command writes in it.
FOLDER_OUTPUTS = [
    (["puncture"], "--out", PUNCTURE_FILES),
    (["demo"], "--out", DEMO_FILES),
    (["study", "feng-lungs"], "--out", FENG_LUNGS_FILES),
    (["reproduce", "lecture"], "--out", REPRODUCE_FILES),
    (["execute", TOY, TOY], "--out", EXECUTE_FILES),
    (["study", "execute-lungs"], "--out", EXECUTE_LUNGS_FILES),
    (["slicer", TOY, TOY], "--out-dir", SLICER_FILES),
]

#: Output flags the two tests above leave out, and why.
NOT_LISTED = {
    ("multi", "--markups"): "a folder of files named after the needles planned: the folder "
    "checks without a fixed file (read-only, a file) are the same code as puncture's",
}


def test_every_output_flag_is_tested():
    import argparse

    from needlekit.cli._parser import _build_parser
    from needlekit.cli._paths import _SPECS

    def walk(p, path=()):
        for spec in p.get_default(_SPECS) or ():
            if spec.output:
                yield (*path, spec.name)
        for a in p._actions:
            if isinstance(a, argparse._SubParsersAction):
                for name, sub in a.choices.items():
                    yield from walk(sub, (*path, name))

    def command(argv):  # the command's words: no scenario files, no paper names
        return tuple(a for a in argv if not a.endswith(".yaml") and a not in REPRODUCE_PAPERS)

    listed = {(*command(a), f) for a, f in FILE_OUTPUTS}
    listed |= {(*command(a), f) for a, f, _ in FOLDER_OUTPUTS}
    listed |= set(NOT_LISTED)
    assert set(walk(_build_parser())) == listed


#: Ways an output file cannot be written: the path, and the reason printed.
FILE_FAILURES = {
    "read-only folder": ("ro/out.json", "folder {root}/ro is read-only"),
    "folder under a file": ("file.txt/out.json", "cannot be created: {root}/file.txt is not a folder"),
    "a folder": ("dir", "is a folder, expected a file"),
    "read-only file": ("locked.json", "is read-only"),
}  # fmt: skip


@pytest.mark.parametrize("failure", list(FILE_FAILURES))
@pytest.mark.parametrize(
    ("argv", "flag"), FILE_OUTPUTS, ids=[" ".join(a[:2]) + f" {f}" for a, f in FILE_OUTPUTS]
)
def test_bad_output_file_is_one_error_line_before_any_work(capsys, places, no_work, argv, flag, failure):  # fmt: skip
    rel, reason = FILE_FAILURES[failure]
    before = _tree(places)
    line = _one_error_line(capsys, [*argv, flag, str(places / rel)])
    assert line == f"error: {flag}: {places / rel}: {reason.format(root=places)}"
    assert _tree(places) == before  # nothing written, created or left behind by the checks


@pytest.mark.parametrize(
    ("argv", "flag", "contents"), FOLDER_OUTPUTS, ids=[" ".join(a) for a, _, _ in FOLDER_OUTPUTS]
)
def test_bad_output_folder_is_one_error_line_before_any_work(capsys, places, no_work, argv, flag, contents):  # fmt: skip
    # a file inside the folder that cannot be replaced
    inner = places / "dir" / contents[0]
    inner.parent.mkdir(parents=True, exist_ok=True)
    inner.write_text("old results\n")
    inner.chmod(0o444)
    cases = [
        (places / "ro", "is read-only"),
        (places / "file.txt" / "out", f"cannot be created: {places}/file.txt is not a folder"),
        (places / "file.txt", "is a file, expected a folder"),
    ]
    before = _tree(places)
    for path, reason in cases:
        line = _one_error_line(capsys, [*argv, flag, str(path)])
        assert line == f"error: {flag}: {path}: {reason}"
    line = _one_error_line(capsys, [*argv, flag, str(places / "dir")])
    assert line == f"error: {flag}: {inner}: is read-only"
    assert _tree(places) == before
    inner.chmod(0o644)


def test_an_output_folder_holding_a_folder_where_a_file_goes(capsys, tmp_path, no_work):
    (tmp_path / "puncture.json").mkdir()
    line = _one_error_line(capsys, ["puncture", "--out", str(tmp_path)])
    assert line == f"error: --out: {tmp_path / 'puncture.json'}: is a folder, expected a file"


def test_one_path_for_two_outputs_or_an_output_over_an_input(capsys, tmp_path, no_work):
    same = tmp_path / "a.json"
    line = _one_error_line(
        capsys, ["sweep", TOY, "--out", str(same), "--report", str(tmp_path / "." / "a.json")]
    )
    assert line == f"error: --report: {tmp_path / 'a.json'}: also given to --out"
    scenario = tmp_path / "toy.yaml"
    scenario.write_text(Path(TOY).read_text())
    link = tmp_path / "link.yaml"
    link.symlink_to(scenario)
    line = _one_error_line(capsys, ["plan", str(scenario), "--out", str(link)])
    assert line == f"error: --out: {link}: is the input scenario; it would be overwritten"
    assert scenario.read_text() == Path(TOY).read_text()


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["plan", "{tmp}/missing.yaml"], "scenario: {tmp}/missing.yaml: not found"),
        (["scene", "info", "{tmp}"], "scenario: {tmp}: is a folder, expected a file"),
        (["verify", TOY, "{tmp}/plan.json"], "plan: {tmp}/plan.json: not found"),
        (["kinematics", "inverse", "--target", "1,2,3", "--start-pose", "{tmp}/g.txt"],
         "--start-pose: {tmp}/g.txt: not found"),
        (["bench", "steerable", "--medrad", "{tmp}/none"], "--medrad: {tmp}/none: not found"),
    ],
)  # fmt: skip
def test_bad_input_paths_are_one_error_line_before_any_work(capsys, tmp_path, no_work, argv, message):  # fmt: skip
    argv = [a.format(tmp=tmp_path) for a in argv]
    assert _one_error_line(capsys, argv) == "error: " + message.format(tmp=tmp_path)


@pytest.mark.parametrize(
    "argv",
    [
        ["plan", TOY, "--seed", "-1"],
        ["sweep", TOY, "--seed", "-1"],
        ["puncture", "--seed", "-1"],
        ["bench", "control", "--seed", "-1"],
    ],
    ids=["plan", "sweep", "puncture", "bench control"],
)
def test_negative_seed_is_an_input_error(capsys, no_work, argv):
    line = _one_error_line(capsys, argv)
    assert line == "error: argument --seed: expected a whole number in [0, 9.22e+18], got '-1'"


def test_forward_sampling_that_would_not_fit_in_memory_is_an_input_error(capsys, monkeypatch):
    import needlekit.needle.bevel3d as bevel3d

    def allocate(*args, **kwargs):
        raise AssertionError("the trajectory was allocated")

    monkeypatch.setattr(bevel3d, "simulate_bevel", allocate)
    argv = ["kinematics", "forward", "--kappa-per-mm", "0.02", "--segment", "5,0,4"]
    line = _one_error_line(capsys, [*argv, "--segment", "5,0,1e9", "--dt-s", "0.01"])
    assert line == (
        "error: --dt-s: 1e+11 samples over 1e+09 s of segments at 0.01 s; at most 1,000,000 "
        "(use a larger --dt-s or shorter segments)"
    )


def _imported_after(argv):
    """Run main(argv) in a fresh interpreter; its exit status and the heavy modules
    that were imported."""
    code = (
        "import sys\nfrom needlekit.cli import main\n"
        f"try:\n    rc = main({argv!r})\nexcept SystemExit as e:\n    rc = e.code\n"
        "heavy = [m for m in ('numpy', 'numba', 'scipy', 'plotly', 'matplotlib', 'yaml')"
        " if m in sys.modules]\n"
        "print(rc, ' '.join(heavy))\n"
    )
    done = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=120
    )
    return done.stdout.split("\n")[-2].split(" ", 1), done.stderr


def test_input_errors_and_help_need_no_heavy_import(tmp_path):
    (rc, heavy), err = _imported_after(["plan", str(tmp_path / "missing.yaml")])
    assert (rc, heavy) == ("2", "")
    assert err == f"error: scenario: {tmp_path}/missing.yaml: not found\n"
    (rc, heavy), err = _imported_after(["sweep", TOY, "--report", str(tmp_path)])
    assert (rc, heavy) == ("2", "") and "error: --report:" in err
    (rc, heavy), _ = _imported_after(["--help"])
    assert (rc, heavy) == ("0", "")


def test_a_failed_report_leaves_the_old_sweep_and_plan_as_they_were(capsys, tmp_path, monkeypatch):
    import needlekit.report.sweep_report as sweep_report

    out, plan, report = tmp_path / "sweep.json", tmp_path / "best.json", tmp_path / "report.html"
    out.write_text('{"an": "earlier sweep"}\n')
    plan.write_text('{"an": "earlier plan"}\n')
    before = _tree(tmp_path)
    written = []

    def disk_full(path, **kwargs):
        written.append(path)
        raise OSError(errno.ENOSPC, "No space left on device", str(path))

    monkeypatch.setattr(sweep_report, "write_report_html", disk_full)
    argv = ["sweep", TOY, "--directions", "12", "--max-iterations", "50", "--time-limit-s", "10"]
    argv += ["--out", str(out), "--plan", str(plan), "--report", str(report)]
    line = _one_error_line(capsys, argv)
    assert written == [report]  # the sweep ran and the report was being written
    assert line == f"error: {report}: No space left on device; no output was changed"
    assert _tree(tmp_path) == before  # both old files byte-identical; no temporary files
    # the same run with a working disk replaces all three
    monkeypatch.undo()
    assert main(argv) == 0
    assert json.loads(out.read_text())["planners"] == ["rcs_star"]
    assert json.loads(plan.read_text())["check"]["ok"] and report.stat().st_size > 0


TINY = """version: 1
structures:
  - {name: nodule, role: target, sphere: {center_mm: [0, 0, 0], radius_mm: 1}}
needle: {r_min_mm: %s}
"""


@pytest.mark.parametrize(
    ("radius", "r_min", "warnings"),
    [
        ("1", "50", ["tiny.yaml: the anatomy is only 2 mm across"]),
        ("10", "0.05", ["tiny.yaml: needle.r_min_mm is 0.05 mm"]),
        ("1", "0.05", ["needle.r_min_mm is 0.05 mm", "only 2 mm across"]),  # field first
        ("10", "1", []),
    ],
)
def test_scenario_in_other_units_gets_a_millimetre_warning(caplog, tmp_path, radius, r_min, warnings):  # fmt: skip
    from needlekit.scenario.loading import load_scenario

    path = tmp_path / "tiny.yaml"
    path.write_text(TINY.replace("radius_mm: 1", f"radius_mm: {radius}") % r_min)
    with caplog.at_level(logging.WARNING):
        load_scenario(path)
    loggers = ("needlekit.scenario.loading", "needlekit.units")  # the anatomy; each field
    got = [r.getMessage() for r in caplog.records if r.name in loggers]
    assert len(got) == len(warnings)
    for message, part in zip(got, warnings, strict=True):
        assert part in message and "are millimetres" in message


def test_the_toy_scenario_gets_no_warning(caplog):
    from needlekit.scenario.loading import load_scenario

    with caplog.at_level(logging.WARNING):
        load_scenario(TOY)
    assert not [r for r in caplog.records if r.levelno >= logging.WARNING]


def test_the_extent_check_builds_no_lazy_field():
    from needlekit.anatomy.fields import LazyField
    from needlekit.anatomy.primitives import Sphere
    from needlekit.anatomy.scene import Role, Scene, Structure
    from needlekit.scenario.loading import _cheap_extent_mm

    def build():
        raise AssertionError("a lazy field was built to find the extent")

    lazy = Structure("mask", Role.OBSTACLE, LazyField(build, "a big mask"))
    small = Structure("nodule", Role.TARGET, Sphere([0, 0, 0], 1.5))
    assert _cheap_extent_mm(Scene([lazy])) is None
    assert _cheap_extent_mm(Scene([lazy, small])) == pytest.approx(3.0)


def test_the_cli_shows_the_millimetre_warning_on_stderr(tmp_path):
    path = tmp_path / "tiny.yaml"
    path.write_text(TINY % "50")
    done = subprocess.run(
        [sys.executable, "-m", "needlekit.cli", "scene", "info", str(path)],
        capture_output=True,
        text=True,
        check=False,
        timeout=120,
    )
    assert done.returncode == 0
    assert done.stderr == (
        "WARNING needlekit.scenario.loading: tiny.yaml: the anatomy is only 2 mm across; lengths "
        "in scenario files are millimetres (was it written in cm or m?)\n"
    )


def test_a_plan_whose_verdict_fails_leaves_the_solved_plan_and_writes_beside_it(tmp_path, caplog):
    """The verdict rule: a run that fails (exit 1: infeasible, invalid, timeout; 2: an
    error; 130: interrupted) replaces no output that exists; its record goes beside."""
    plan = tmp_path / "plan.json"
    assert main(["plan", TOY, "--out", str(plan)]) == 0
    solved = plan.read_bytes()
    for goal, status in (("0,-40,0", "infeasible"), ("0,10,0", "invalid_input")):
        caplog.clear()
        assert main(["plan", TOY, "--goal", goal, "--out", str(plan)]) == 1
        assert plan.read_bytes() == solved
        failed = json.loads((tmp_path / "plan.failed.json").read_text())
        assert failed["status"] == status
        assert f"{plan}: an earlier output, kept; this run's result (it did not succeed) is in " \
            f"{tmp_path / 'plan.failed.json'}" in caplog.text  # fmt: skip
    fresh = tmp_path / "fresh.json"  # nothing there before: the record goes where asked
    assert main(["plan", TOY, "--goal", "0,-40,0", "--out", str(fresh)]) == 1
    assert json.loads(fresh.read_text())["status"] == "infeasible"
    assert not (tmp_path / "fresh.failed.json").exists()
