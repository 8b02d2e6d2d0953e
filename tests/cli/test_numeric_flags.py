"""Every numeric flag of every command through the one gate (issue "Fail safe", point 3).

Each numeric flag's type is the gate (:class:`needlekit.cli._common._Number` over
:class:`needlekit._numbers.Bounds`); a hypothesis test per command drives its numeric flags
with huge (1e308), tiny (1e-308), negative, zero and non-finite values (nan, inf, -inf) and
whole numbers past any count. A value the gate refuses gives exit 2 and one line
``error: argument FLAG: expected ...``, from the parser, before any work; a value it takes
is run (on the cheap commands, with small examples), and so are the ends of each flag's
range: exit 0 or 1 with finite output, or exit 2 and one error line naming the flag.
"""

from __future__ import annotations

import argparse
import json
import math
import re
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from needlekit._numbers import MAX_ABS_MM, MAX_CURVATURE_PER_MM
from needlekit.cli import main
from needlekit.cli._common import _Number
from needlekit.cli._parser import _build_parser, walk_commands

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
TOY = str(EXAMPLES / "toy.yaml")
MULTI = str(EXAMPLES / "liver_phantom_multi.yaml")

#: What each numeric flag is driven with.
HOSTILE = (
    "1e308", "-1e308", "1e-308", "-1e-308", "-1", "0", "nan", "inf", "-inf", "1e999",
    "99999999999999999999999999",
)  # fmt: skip

#: Types that are not numbers: paths, planner options (typed by the planner, through the
#: same gate: tests/cli/test_flags.py), execute's sensing policies (names, comma-separated).
_NOT_NUMBERS = ("Path", "_option_pair", "_policies")


def _commands() -> dict[str, list[argparse.Action]]:
    out = {}
    for words, parser, dest in walk_commands(_build_parser()):
        if dest is None:
            out[" ".join(words)] = [
                a for a in parser._actions if a.type is not None and a.option_strings
            ]
    return out


COMMANDS = _commands()


def _numeric(command: str) -> list[argparse.Action]:
    return [a for a in COMMANDS[command] if isinstance(a.type, _Number)]


def test_every_typed_flag_is_a_number_through_the_gate_or_not_a_number():
    others = {
        f"{c} {a.option_strings[0]}": getattr(a.type, "__name__", repr(a.type))
        for c, actions in COMMANDS.items()
        for a in actions
        if not isinstance(a.type, _Number)
    }
    assert {k: v for k, v in others.items() if v not in _NOT_NUMBERS} == {}
    assert sum(len(_numeric(c)) for c in COMMANDS) >= 100


def test_every_length_flag_keeps_the_length_bound():
    for command in COMMANDS:
        for a in _numeric(command):
            if a.dest.endswith("_per_mm"):
                assert all(b.high <= MAX_CURVATURE_PER_MM for b in a.type.each), a.dest
            elif a.dest.endswith("_mm") or "(mm)" in a.type.what:
                assert all(b.high <= MAX_ABS_MM for b in a.type.each), (command, a.dest)
                assert all(b.unit in ("mm", "") for b in a.type.each), (command, a.dest)


def _gate_takes(action: argparse.Action, text: str) -> bool:
    try:
        action.type(text)
    except argparse.ArgumentTypeError:
        return False
    return True


def _one_line_naming(err: str, flag: str) -> bool:
    lines = err.strip().splitlines()
    return len(lines) == 1 and lines[0].startswith("error: ") and flag in lines[0]


def _run(capsys, argv):
    capsys.readouterr()
    try:
        code = main(argv)
    except SystemExit as exc:
        code = exc.code
    out = capsys.readouterr()
    return code, out.out, out.err


# -- refused at the parser: every command -----------------------------------------------------


@pytest.mark.parametrize("command", [c for c in COMMANDS if _numeric(c)])
def test_a_value_out_of_range_is_one_line_naming_the_flag_before_any_work(command, capsys):
    actions = _numeric(command)

    @settings(max_examples=30, deadline=None, derandomize=True,
              suppress_health_check=[HealthCheck.function_scoped_fixture])  # fmt: skip
    @given(st.sampled_from(actions), st.sampled_from(HOSTILE))
    def check(action, text):
        if _gate_takes(action, text):
            return  # taken: run below, on the commands cheap enough to run
        flag = action.option_strings[0]
        # the value alone: the parser refuses it before it looks at anything else
        code, out, err = _run(capsys, [*command.split(), flag, text])
        assert code == 2 and out == ""
        assert err.strip() == err.strip().splitlines()[0]  # one line
        assert re.match(rf"^error: argument {re.escape(flag)}(/\S+)?: expected ", err), err

    check()


# -- taken by the gate: run on the cheap commands --------------------------------------------


@pytest.fixture(scope="module")
def plan_file(tmp_path_factory) -> str:
    path = tmp_path_factory.mktemp("numbers") / "plan.json"
    assert main(["plan", TOY, "--out", str(path)]) == 0
    return str(path)


def _base(command: str, plan: str, tmp: Path) -> list[str]:
    return {
        "kinematics forward": ["kinematics", "forward", "--kappa-per-mm", "0.02",
                               "--segment", "1,0,10", "--json"],
        "kinematics inverse": ["kinematics", "inverse", "--target", "10,0,40", "--json"],
        "verify": ["verify", TOY, plan, "--json"],
        "markups": ["markups", plan, "--out", str(tmp / "m.mrk.json")],
        "plan": ["plan", TOY, "--out", str(tmp / "p.json"), "--max-iterations", "200"],
    }[command]  # fmt: skip


def _ends(action: argparse.Action) -> tuple[str, ...]:
    """The gate's own ends for a flag: its smallest and largest value (each number of a
    flag of several)."""
    each = action.type.each
    low = ",".join(f"{b.low:g}" if not b.low_open else f"{b.low + 1e-6:g}" for b in each)
    high = ",".join(f"{b.high:g}" for b in each)
    return low, high


def _finite_output(out: str, tmp: Path) -> bool:
    texts = [out, *(p.read_text() for p in tmp.glob("*.json"))]
    return not any(re.search(r"\b(nan|NaN|-?inf|-?Infinity)\b", t) for t in texts) and all(
        json.loads(p.read_text()) is not None for p in tmp.glob("*.json")
    )


@pytest.mark.parametrize(
    "command", ["kinematics forward", "kinematics inverse", "verify", "markups", "plan"]
)
def test_a_value_the_gate_takes_gives_a_finite_answer_or_one_line(
    command, plan_file, tmp_path_factory, capsys
):
    actions = _numeric(command)
    taken = [(a, t) for a in actions for t in (*HOSTILE, *_ends(a)) if _gate_takes(a, t)]
    assert taken

    @settings(max_examples=12 if command == "plan" else 25, deadline=None, derandomize=True,
              suppress_health_check=[HealthCheck.function_scoped_fixture])  # fmt: skip
    @given(st.sampled_from(taken))
    def check(case):
        action, text = case
        flag = action.option_strings[0]
        tmp = tmp_path_factory.mktemp("run")
        code, out, err = _run(capsys, [*_base(command, plan_file, tmp), flag, text])
        if code == 2:
            assert _one_line_naming(err, flag), (flag, text, err)
        else:
            assert code in (0, 1), (flag, text, code, err)
            assert "Traceback" not in err and _finite_output(out, tmp), (flag, text, out)

    check()


def test_the_kinds_reported_are_closed(tmp_path, capsys):
    """The campaign's cases: a 1e308 segment length or curvature is refused, not printed
    as overflowed poses; a plan edited to a 1e308 mm length is named when read."""
    for argv, flag in (
        (["--kappa-per-mm", "1e308", "--segment", "1,0,1"], "--kappa-per-mm"),
        (["--kappa-per-mm", "0.1", "--segment", "1e308,0,1"], "--segment"),
        (["--kappa-per-mm", "0.1", "--segment", "1,0,1e308"], "--segment"),
    ):
        code, out, err = _run(capsys, ["kinematics", "forward", *argv])
        assert code == 2 and out == "" and err.startswith(f"error: argument {flag}: expected ")
    plan = tmp_path / "plan.json"
    plan.write_text(json.dumps({"goal_mm": [1, 2, 3], "primitives": [{"length_mm": 1e308}]}))
    code, _, err = _run(capsys, ["verify", TOY, str(plan)])
    assert (code, err) == (
        2,
        "error: plan.json: primitives[0].length_mm: expected a number in [-1e+06, 1e+06] mm, "
        "got 1e+308\n",
    )
    assert math.isfinite(MAX_ABS_MM)


#: Runs each argv through main() in one fresh interpreter and reports, per argv, the exit
#: status, stderr and the heavy modules imported so far.
_WRAPPER = """
import contextlib, io, json, sys
from needlekit.cli import main
heavy = ("numba", "scipy", "matplotlib", "plotly", "dask", "trimesh", "nibabel")
out = []
for argv in json.loads(sys.argv[1]):
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        try:
            rc = main(argv)
        except SystemExit as exc:
            rc = exc.code
    out.append({"rc": rc, "stderr": err.getvalue(),
                "heavy": [m for m in heavy if m in sys.modules]})
print(json.dumps(out))
"""


def test_a_refused_number_loads_no_heavy_module():
    import subprocess
    import sys

    cases = [
        [*command.split(), _numeric(command)[0].option_strings[0], "nan"]
        for command in COMMANDS
        if _numeric(command)
    ]
    done = subprocess.run(
        [sys.executable, "-c", _WRAPPER, json.dumps(cases)],
        capture_output=True, text=True, check=True, timeout=300,
    )  # fmt: skip
    for argv, r in zip(cases, json.loads(done.stdout.splitlines()[-1]), strict=True):
        assert r["rc"] == 2 and r["heavy"] == [], (argv, r)
        assert r["stderr"].startswith(f"error: argument {argv[-2]}")
        assert r["stderr"].count("\n") == 1
