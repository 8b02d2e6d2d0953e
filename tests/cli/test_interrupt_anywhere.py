"""Ctrl-C at any moment of any long command (issue "Fail safe", point 5).

Each long command runs to completion, then again with the same ``--out``, and gets a SIGINT
at a few seeded moments; the outcomes checked are those of ``interrupt_check``
(``tests/cli/conftest.py``): exit 130, one line on stderr, no worker left, the earlier
complete outputs byte-identical and nothing new but a partial record. The long studies on
real data: ``test_interrupt_studies.py``.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
TOY, MULTI = str(EXAMPLES / "toy.yaml"), str(EXAMPLES / "liver_phantom_multi.yaml")

#: Per long command: its arguments ({d}: its output folder; {plan}: a plan of the toy)
#: and how many moments it is interrupted at. Small phantom inputs: each runs in seconds.
COMMANDS = {
    "plan": (["plan", TOY, "--out", "{d}/plan.json"], 2),
    "sweep": (["sweep", TOY, "--directions", "200", "--max-iterations", "300",
               "--out", "{d}/sweep.json"], 3),
    "sweep-workers": (["sweep", TOY, "--directions", "200", "--max-iterations", "300",
                       "--workers", "2", "--out", "{d}/sweep.json"], 2),
    "puncture": (["puncture", "--trials", "1", "--out", "{d}"], 3),
    "puncture-workers": (["puncture", "--trials", "2", "--workers", "2", "--out", "{d}"], 1),
    "execute": (["execute", "--truth", "kinematic", TOY, "{plan}", "--trials", "3", "--out", "{d}"], 2),
    "multi": (["multi", MULTI, "--out", "{d}/multi.json"], 2),
    "cfrw": (["cfrw", MULTI, "--out", "{d}/cfrw.json"], 2),
    "bench": (["bench", "kinematics", "--arcs", "20000", "--samples", "8", "--repeat", "1",
               "--out", "{d}/bench.json"], 2),
}  # fmt: skip


def _args(name: str, out: Path, plan: Path) -> list[str]:
    return [a.replace("{d}", str(out)).replace("{plan}", str(plan)) for a in COMMANDS[name][0]]


@pytest.fixture(scope="module")
def toy_plan(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("toy-plan") / "plan.json"
    argv = [sys.executable, "-m", "needlekit.cli", "plan", TOY, "--out", str(out)]
    assert subprocess.run(argv, capture_output=True, timeout=600).returncode == 0
    return out


@pytest.mark.slow
@pytest.mark.parametrize("name", list(COMMANDS))
def test_ctrl_c_at_seeded_moments_ends_in_one_line_and_keeps_earlier_outputs(
    tmp_path, name, toy_plan, interrupt_check
):
    out = tmp_path / "out"
    interrupt_check(name, _args(name, out, toy_plan), out, COMMANDS[name][1])
