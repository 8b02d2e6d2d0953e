"""Every allocation estimated (issue "Fail safe", point 4): each flag that sizes a command's
arrays, set absurdly, is refused in one line naming it, exit status 2, before the command
runs (its handler is replaced by one that fails the test: nothing was loaded or
allocated). The memory available is fixed here, so every line is known in full."""

from __future__ import annotations

from pathlib import Path

import pytest

from needlekit.cli import main
from needlekit.cli._parser import _build_parser, walk_commands

E = str(Path(__file__).resolve().parents[2] / "examples")

#: Per command line, the one error line (with 16 GiB available).
CASES = [
    (
        ["study","livers","--resolution-deg","1e-6"],
        'error: --resolution-deg: a 1e-06-degree grid (3.24e+16 cells) would need at least 460 PiB; this machine has 2 GiB available',
    ),
    (
        ["cfrw","{E}/liver_phantom_multi.yaml","--resolution-deg","1e-6","--out","{T}/c.json"],
        'error: --resolution-deg: a 1e-06-degree grid (2.16e+16 cells) would need at least 307 PiB; this machine has 2 GiB available',
    ),
    (
        ["multi","{E}/liver_phantom_multi.yaml","--resolution-deg","1e-6","--out","{T}/multi.json"],
        'error: --resolution-deg: a 1e-06-degree grid (2.16e+16 cells) would need at least 307 PiB; this machine has 2 GiB available',
    ),
    (
        ["sweep","{E}/toy.yaml","--directions","1000000000","--out","{T}/s.json"],
        'error: --directions: 1000000000 directions would need at least 499 GiB; this machine has 2 GiB available',
    ),
    (
        ["sweep","{E}/toy.yaml","--healpix","10000000","--planner","rcs_star","rrt","--out","{T}/s.json"],
        'error: --healpix: 1200000000000000 directions would need at least 1.12e+03 PiB; this machine has 2 GiB available',
    ),
    (
        ["study","feng-lungs","--directions","1000000000","--out","{T}/f"],
        'error: --directions: 1000000000 directions would need at least 1.88 TiB; this machine has 2 GiB available',
    ),
    (
        ["puncture","--trials","1000000000","--out","{T}/p"],
        'error: --trials: 1000000000 trials would need at least 59.6 GiB; this machine has 2 GiB available',
    ),
    (
        ["puncture","--history","1000000000","--out","{T}/p"],
        'error: --history: 1000000000 keyframes would need at least 7.45 GiB; this machine has 2 GiB available',
    ),
    (
        ["puncture","--guide-samples","1000000000","--out","{T}/p"],
        'error: --guide-samples: 1000000000 samples would need at least 7.45 GiB; this machine has 2 GiB available',
    ),
    (
        ["execute","{E}/toy.yaml","{T}/plan.json","--trials","1000000000","--out","{T}/e","--truth","kinematic"],
        'error: --trials: 1000000000 trials would need at least 59.6 GiB; this machine has 2 GiB available',
    ),
    (
        ["study","execute-lungs","--trials","1000000000","--out","{T}/el"],
        'error: --trials: 1000000000 trials would need at least 59.6 GiB; this machine has 2 GiB available',
    ),
    (
        ["study","execute-lungs","--pilot-trials","1000000000","--out","{T}/el","--truth","kinematic"],
        'error: --pilot-trials: 1000000000 trials would need at least 59.6 GiB; this machine has 2 GiB available',
    ),
    (
        ["bench","kinematics","--arcs","1000000000","--out","{T}/b.json"],
        'error: --arcs: 1000000000 arcs would need at least 142 GiB; this machine has 2 GiB available',
    ),
    (
        ["bench","kinematics","--samples","1000000000","--out","{T}/b.json"],
        'error: --samples: 2e+14 arc points would need at least 4.26 PiB; this machine has 2 GiB available',
    ),
    (
        ["bench","fields","--grid","100000","--out","{T}/b.json"],
        'error: --grid: a 100000^3 grid would need at least 7.11 PiB; this machine has 2 GiB available',
    ),
    (
        ["bench","fields","--queries","1000000000","--out","{T}/b.json"],
        'error: --queries: 1000000000 queries would need at least 22.4 GiB; this machine has 2 GiB available',
    ),
    (
        ["bench","control","--trials","1000000000","--out","{T}/b.json"],
        'error: --trials: 1000000000 trials would need at least 59.6 GiB; this machine has 2 GiB available',
    ),
    (
        ["bench","steerable","--sample-targets","1000000000","--out","{T}/b.json"],
        'error: --sample-targets: 1000000000 targets would need at least 22.4 GiB; this machine has 2 GiB available',
    ),
    (
        ["bench","execute","--trials","1000000000","--out","{T}/b.json"],
        'error: --trials: 1000000000 trials would need at least 59.6 GiB; this machine has 2 GiB available',
    ),
    (
        ["bench","execute","--replans","1000000000","--out","{T}/b.json"],
        'error: --replans: 1000000000 re-plans would need at least 59.6 GiB; this machine has 2 GiB available',
    ),
    (
        ["bench","scale","--directions","1000000000","--out","{T}/b.json"],
        'error: --directions: 1000000000 directions would need at least 499 GiB; this machine has 2 GiB available',
    ),
    (
        ["bench","scale","--trials","1000000000","--out","{T}/b.json"],
        'error: --trials: 1000000000 trials would need at least 59.6 GiB; this machine has 2 GiB available',
    ),
    (
        ["scene","render","{E}/toy.yaml","--max-cells","1000000000","--out","{T}/r.html"],
        'error: --max-cells: 1000000000 samples per axis would need at least 7.45 GiB; this machine has 2 GiB available',
    ),
    (
        ["approach","{E}/medrad_liver4.yaml","--max-cells","1000000000","--out","{T}/a.json"],
        'error: --max-cells: 1000000000 samples per axis would need at least 7.45 GiB; this machine has 2 GiB available',
    ),
]


@pytest.fixture
def refused_before_running(monkeypatch):
    import needlekit.cli as cli
    import needlekit.memory as memory

    def ran(command, args):
        raise AssertionError(f"{command} ran: its request was not refused first")

    monkeypatch.setattr(memory, "available_bytes", lambda: 2 * 2**30)
    monkeypatch.setattr(cli, "_run", ran)


@pytest.mark.parametrize(("argv", "line"), CASES, ids=[" ".join(a[:2]) + " " + next(
    x for x in a if x.startswith("--")) for a, _ in CASES])  # fmt: skip
def test_an_absurd_size_is_refused_naming_its_flag_before_the_command_runs(
    tmp_path, capsys, refused_before_running, argv, line
):
    (tmp_path / "plan.json").write_text("{}")
    argv = [a.replace("{E}", E).replace("{T}", str(tmp_path)) for a in argv]
    assert main(argv) == 2
    assert capsys.readouterr().err.splitlines() == [line]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["plan.json"]  # nothing written


#: The flags that size a command's arrays from its input.
SIZING_FLAGS = {"--resolution-deg", "--directions", "--healpix", "--trials", "--pilot-trials",
                "--history", "--guide-samples", "--arcs", "--samples", "--grid", "--queries",
                "--sample-targets", "--replans", "--max-cells", "--spacing-mm"}  # fmt: skip


def test_every_command_with_a_sizing_flag_declares_its_estimate():
    """A new command (or flag) that sizes arrays cannot skip the check: it must say what
    it asks for beside its handler (``set_defaults(sizes=...)``)."""
    missing = []
    for words, child, dest in walk_commands(_build_parser()):
        if dest is not None:
            continue
        flags = {s for a in child._actions for s in a.option_strings} & SIZING_FLAGS
        if flags and child.get_default("sizes") is None:
            missing.append((" ".join(words), sorted(flags)))
    assert missing == []
    covered = {next(x for x in a if x.startswith("--")) for a, _ in CASES}
    assert covered | {"--spacing-mm"} == SIZING_FLAGS  # markups: test_hostile_inputs


def test_a_mesh_voxel_size_too_small_for_memory_is_refused_naming_the_field(
    tmp_path, capsys, monkeypatch
):
    import trimesh

    import needlekit.memory as memory

    monkeypatch.setattr(memory, "available_bytes", lambda: 16 * 2**30)
    trimesh.creation.box((50, 50, 50)).export(tmp_path / "box.stl")
    scenario = tmp_path / "mesh.yaml"
    scenario.write_text(
        "version: 1\nname: a box\nstructures:\n  - {name: organ, role: obstacle, "
        "mesh: {path: box.stl, voxel_size_mm: 0.01}}\n"
    )
    assert main(["scene", "info", str(scenario)]) == 2
    assert capsys.readouterr().err.splitlines()[-1] == (
        "error: mesh.yaml: structures[0].mesh.voxel_size_mm: a 0.01 mm grid (3.43e+11 "
        "voxels) would need at least 320 GiB; this machine has 16 GiB available"
    )


def test_a_replayed_trial_is_one_trial_whatever_trials_says():
    """``execute --replay-trial K`` runs one trial: ``--trials`` (here 10^9, past any
    machine) only says which seeds K is among, and asks for no memory. Parsed by the real
    parser, so a renamed flag cannot leave the size rule reading a name that is gone."""
    from needlekit.cli._parser import _build_parser

    argv = ["execute", "--truth", "kinematic", "s.yaml", "p.json", "--trials", "1000000000", "--out", "o"]
    parser = _build_parser()
    args = parser.parse_args(argv)
    assert [s.flag for s in args.sizes(args)] == ["--trials"]
    args = parser.parse_args([*argv, "--replay-trial", "3"])
    assert args.sizes(args) == []


def test_every_size_rule_reads_flags_its_command_has():
    """Each command's size rule reads only its own flags (read off the parser): a flag
    renamed or dropped cannot leave a rule reading a name that ``getattr`` quietly
    defaults. ``scenario_document`` is the scenario the path check has already read."""
    import inspect
    import re

    from needlekit.cli import _sizes
    from needlekit.cli._parser import _build_parser, walk_commands

    def names(fn) -> set[str]:
        src = inspect.getsource(fn)
        found = set(re.findall(r'getattr\(args, "([a-z_]+)"', src))
        found |= set(re.findall(r"\bargs\.([a-z_]+)", src))
        for helper in re.findall(r"\b([a-z_]+_sizes)\(args\)", src):
            found |= names(getattr(_sizes, helper))
        return found

    checked = 0
    for words, parser, dest in walk_commands(_build_parser()):
        rule = None if dest is not None else parser.get_default("sizes")
        if rule is None:
            continue
        own = {a.dest for a in parser._actions} | {"sizes", "scenario_document"}
        assert names(rule) <= own, (" ".join(words), sorted(names(rule) - own))
        checked += 1
    assert checked >= 20
