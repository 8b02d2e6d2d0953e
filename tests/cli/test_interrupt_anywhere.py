"""Ctrl-C at any moment of any long command (issue "Fail safe", point 5).

Each long command runs to completion, then again with the same ``--out``, and gets a SIGINT
at a few seeded moments; the outcomes checked are those of ``interrupt_check``
(``tests/cli/conftest.py``): exit 130, one line on stderr, no worker left, the earlier
complete outputs byte-identical and nothing new but a partial record. ``plan``'s complete
run is the toy plan the module's fixture makes (``execute`` reads it); ``multi`` and
``cfrw`` plan on the liver phantom of ``examples/liver_phantom_multi.yaml`` baked on its
coarsest voxels. The long studies on real data: ``test_interrupt_studies.py``.
"""

from __future__ import annotations

from pathlib import Path

import pytest

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
TOY, MULTI = str(EXAMPLES / "toy.yaml"), str(EXAMPLES / "liver_phantom_multi.yaml")
#: The liver phantom's line in MULTI, and the same phantom baked on its coarsest voxels
#: (1.5 mm): the same stages (its layout, vessel trees and bake, then the CFRW maps), the
#: bake cheaper ({multi}: that scenario, written beside the runs).
MULTI_BASE = "base: {phantom: {name: liver, seed: 0}}"
COARSE_BASE = "base: {phantom: {name: liver, seed: 0, voxel_size_mm: 1.5}}"

#: Per long command: its arguments ({d}: its output folder; {plan}: a plan of the toy;
#: {multi}: MULTI on the coarse phantom) and how many moments it is interrupted at. Small
#: phantom inputs: each runs in seconds. ``puncture``'s seeded moments (0.31, 0.49) fall in
#: its trial's 1 kHz loop (the sensors, the controller's step, the adaptation), where a
#: third (0.487) fell too, 0.007 of the run from the second; ``cfrw`` draws one boundary
#: layer: its moments fall in building the phantom, before the map and the layers.
COMMANDS = {
    "plan": (["plan", TOY, "--out", "{d}/plan.json"], 2),
    "sweep": (["sweep", TOY, "--directions", "200", "--max-iterations", "300",
               "--out", "{d}/sweep.json"], 3),
    "sweep-workers": (["sweep", TOY, "--directions", "200", "--max-iterations", "300",
                       "--workers", "2", "--out", "{d}/sweep.json"], 2),
    "puncture": (["puncture", "--trials", "1", "--out", "{d}"], 2),
    "puncture-workers": (["puncture", "--trials", "2", "--workers", "2", "--out", "{d}"], 1),
    "execute": (["execute", "--truth", "kinematic", TOY, "{plan}", "--trials", "3", "--out", "{d}"], 2),
    "multi": (["multi", "{multi}", "--out", "{d}/multi.json"], 2),
    "cfrw": (["cfrw", "{multi}", "--layers", "150", "--out", "{d}/cfrw.json"], 2),
    "bench": (["bench", "kinematics", "--arcs", "20000", "--samples", "8", "--repeat", "1",
               "--out", "{d}/bench.json"], 2),
}  # fmt: skip


def _args(name: str, out: Path, inputs: dict[str, Path]) -> list[str]:
    words = COMMANDS[name][0]
    for key, value in {"d": out, **inputs}.items():
        words = [w.replace("{" + key + "}", str(value)) for w in words]
    return words


@pytest.fixture(scope="module")
def inputs(tmp_path_factory, interrupt_complete_run) -> tuple[dict[str, Path], float]:
    """What the commands read ({multi}: the coarse liver phantom's scenario; {plan}: the
    toy's plan, which ``execute`` reads), and the CPU of the ``plan`` row's complete run:
    the toy plan is that run (its folder ``{d}``), its outputs the earlier ones the
    ``plan`` row's interrupts keep byte-identical."""
    folder = tmp_path_factory.mktemp("inputs")
    multi = folder / "liver_phantom_multi.yaml"
    text = Path(MULTI).read_text()
    assert text.count(MULTI_BASE) == 1
    multi.write_text(text.replace(MULTI_BASE, COARSE_BASE))
    plan_folder = folder / "plan"
    cpu_s = interrupt_complete_run(_args("plan", plan_folder, {}))
    assert (plan_folder / "plan.json").is_file()
    return {"multi": multi, "plan": plan_folder / "plan.json"}, cpu_s


@pytest.mark.slow
@pytest.mark.parametrize("name", list(COMMANDS))
def test_ctrl_c_at_seeded_moments_ends_in_one_line_and_keeps_earlier_outputs(
    tmp_path, name, inputs, interrupt_check
):
    given, plan_cpu_s = inputs
    if name == "plan":  # the same command and arguments: the fixture's run is the earlier one
        out = given["plan"].parent
        interrupt_check(name, _args(name, out, given), out, COMMANDS[name][1], plan_cpu_s)
        return
    out = tmp_path / "out"
    interrupt_check(name, _args(name, out, given), out, COMMANDS[name][1])
