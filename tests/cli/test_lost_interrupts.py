"""A Ctrl-C that Python swallows is not lost.

A ``KeyboardInterrupt`` raised in a callback called from C (llvmlite's object-cache
callback while numba compiles; any ``ctypes`` callback) or in a finaliser cannot
propagate: Python reports it as "Exception ignored ..." and goes on. Seen in a clean-clone
run: a study signalled while numba compiled ran to its end and exited 0. Every command
runs with :func:`needlekit.cli._interrupts.interrupts_not_lost`, which delivers such an
interrupt again; these tests swallow one on purpose (a real ``ctypes`` callback and a real
finaliser) and check it still stops the work. The waits are iteration budgets: the work
loop runs at most 20,000 short sleeps (20 s), and the interrupt arrives within a few.
"""

from __future__ import annotations

import ctypes
import gc
import time
from pathlib import Path

import pytest

from needlekit.cli._interrupts import interrupts_not_lost

TOY = Path(__file__).resolve().parents[2] / "examples" / "toy.yaml"

#: The work after the swallowed interrupt: this many 1 ms sleeps at most.
BUDGET = 20_000


def _raise_keyboard_interrupt():
    raise KeyboardInterrupt


def _swallow_in_ctypes_callback() -> None:
    """Raise ``KeyboardInterrupt`` inside a ``ctypes`` callback (Python swallows it)."""
    callback = ctypes.CFUNCTYPE(None)(_raise_keyboard_interrupt)
    callback()


class _Finalised:
    def __del__(self):
        raise KeyboardInterrupt


def _swallow_in_finaliser() -> None:
    _Finalised()
    gc.collect()


def _work(budget: int = BUDGET) -> int:
    done = 0
    for _ in range(budget):
        time.sleep(0.001)
        done += 1
    return done


@pytest.mark.parametrize("swallow", [_swallow_in_ctypes_callback, _swallow_in_finaliser])
def test_a_swallowed_ctrl_c_is_delivered_again(swallow, capsys):
    with pytest.raises(KeyboardInterrupt):
        with interrupts_not_lost():
            swallow()  # returns: Python swallowed the interrupt
            _work()
    assert "Exception ignored" not in capsys.readouterr().err


def test_without_the_hook_python_swallows_it(monkeypatch):
    """The oracle for the tests above: the interrupt is indeed lost without the hook (it
    only reaches the unraisable hook, and the work after it runs to its end)."""
    seen = []
    monkeypatch.setattr("sys.unraisablehook", lambda u: seen.append(type(u.exc_value)))
    _swallow_in_ctypes_callback()
    assert _work(200) == 200
    assert seen == [KeyboardInterrupt]


def test_a_command_whose_ctrl_c_was_swallowed_ends_in_one_line_and_exit_130(
    tmp_path, monkeypatch, capsys
):
    import needlekit.cli as cli

    out = tmp_path / "plan.json"
    out.write_text("earlier\n")

    def handler(command, args):
        _swallow_in_ctypes_callback()
        _work()
        out.write_text("this run\n")  # not reached
        return 0

    monkeypatch.setattr(cli, "_run", handler)
    assert cli.main(["plan", str(TOY), "--out", str(out)]) == 130
    assert capsys.readouterr().err.splitlines() == [
        "interrupted: stopped before any result; no output was changed"
    ]
    assert out.read_text() == "earlier\n"
