"""Shared by the tests of ``tests/cli``: Ctrl-C sent to a long command at seeded moments.

``interrupt_check(name, args, out, moments)`` runs ``needlekit ARGS`` to completion (its
complete outputs in ``out``: the "earlier run"; twice when the first filled a cache; a
module whose fixture already made that run, with the same arguments and ``out``, passes
its CPU instead), then again with the same arguments, and sends it a SIGINT at
``moments`` seeded moments: once the process (and its workers) have used a seeded fraction
of the CPU time the whole run took. Whatever it was doing then
(importing, loading the scene, inside a numba kernel, in a worker pool, writing), the
outcome must be the same: exit status 130, exactly one line on stderr and no traceback, no
worker left, the earlier complete outputs byte-identical and nothing else new but a
partial record (``X.partial.json``) beside them; a record the line says was written is
there.

Nothing here asserts a time: the moments are CPU fractions, the outcomes are checked.
"""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import tempfile
import time
import zlib
from pathlib import Path

import numpy as np
import pytest


def _descendants(pid: int) -> list[int]:
    """Every live descendant of ``pid`` (from /proc)."""
    parents = {}
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                fields = (entry / "stat").read_text().rsplit(")", 1)[1].split()
            except OSError:
                continue
            if fields[0] != "Z":
                parents[int(entry.name)] = int(fields[1])
    found, todo = [], [pid]
    while todo:
        p = todo.pop()
        kids = [c for c, pp in parents.items() if pp == p]
        found += kids
        todo += kids
    return found


def _cmdline(pid: int) -> bytes:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes()
    except OSError:
        return b""


def _left(family: list[int], workers: list[int]) -> list[int]:
    """The processes of ``family`` still alive: pool workers at once; multiprocessing's
    resource tracker ends by itself when it reads the end of its pipe (the main process
    gone), so it gets a few seconds to do so."""
    if [p for p in workers if _alive(p)]:
        return [p for p in workers if _alive(p)]
    for _ in range(100):
        left = [p for p in family if _alive(p)]
        if not left:
            break
        time.sleep(0.1)
    return left


def _alive(pid: int) -> bool:
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


def _cpu_s(pid: int) -> float:
    """CPU seconds of a process and its live descendants."""
    total = 0.0
    for p in [pid, *_descendants(pid)]:
        try:
            fields = Path(f"/proc/{p}/stat").read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        total += (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    return total


def _files(folder: Path) -> dict[str, bytes]:
    return {
        str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()
    }


def _default_sigint():
    # a run started in the background of a shell without job control inherits SIGINT
    # ignored: the command under test gets the default disposition, as a terminal gives it
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def _complete_run(argv: list[str]) -> tuple[float, bool]:
    """Run the command to its end (the earlier outputs): the CPU seconds it (and its own
    workers) took, and whether it compiled a numba kernel into the cache.

    The CPU is the command's own account, from ``wait4`` on its process: a difference of
    this process's ``RUSAGE_CHILDREN`` would also count any other child reaped meanwhile (a
    server or a cluster an earlier test of this worker left to end), and the moments, its
    fractions, would then fall after the command's result is decided. The compiling is the
    command's own account too (numba's ``NUMBA_DEBUG_CACHE`` lines, "data saved to",
    printed by the process that saved): the cache folders' mtimes would also move with
    what another test worker compiles meanwhile, and that makes no later run of this
    command faster."""
    env = os.environ | {"NUMBA_DEBUG_CACHE": "1"}
    with tempfile.TemporaryFile() as out, tempfile.TemporaryFile() as err:
        proc = subprocess.Popen(argv, stdout=out, stderr=err, env=env)
        _, status, usage = os.wait4(proc.pid, 0)
        proc.returncode = os.waitstatus_to_exitcode(status)
        err.seek(0)
        stderr = err.read().decode(errors="replace")
        out.seek(0)
        compiled = b"[cache] data saved to" in out.read()
    assert proc.returncode in (0, 1), stderr  # 1: a verdict (multi's plan may fail)
    return usage.ru_utime + usage.ru_stime, compiled


def _wait_for_cpu(proc: subprocess.Popen, cpu_s: float) -> None:
    """Return once ``proc`` and its live descendants have used ``cpu_s`` CPU seconds, or it
    has ended. Together they cannot use more than one CPU second per core and second of
    wall time: far from the moment it sleeps the time the rest needs at the least, and
    looks through /proc (milliseconds of this process's CPU each time, more on a busy
    machine) far less often than every 20 ms; near the moment, every 20 ms."""
    cores = os.cpu_count() or 1
    while proc.poll() is None:
        left = cpu_s - _cpu_s(proc.pid)
        if left <= 0:
            return
        time.sleep(max(0.02, left / cores))


def _interrupt_at(argv: list[str], cpu_s: float):
    proc = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                            preexec_fn=_default_sigint)  # fmt: skip
    _wait_for_cpu(proc, cpu_s)
    assert proc.poll() is None, "the command ended before the moment chosen"
    family = _descendants(proc.pid)
    workers = [p for p in family if b"spawn_main" in _cmdline(p)]
    proc.send_signal(signal.SIGINT)  # to the main process alone, as `timeout -s INT` does
    _, stderr = proc.communicate(timeout=300)
    return proc.returncode, stderr, _left(family, workers)


def _caches() -> dict[str, int]:
    """Every file other than numba's a run may add to what later runs find, with its
    mtime: the package's byte code and the prepared-anatomy cache's entries and arrays
    (files: a folder's mtime moves with any file written in it). Not the entries' usage
    records: every run that opens an entry rewrites its record
    (``cache_entries.mark_used``), and so does any other test worker reading the session's
    cache meanwhile; a rewritten record makes no later run faster, and counting it would
    run the complete command a second time for nothing. Numba's kernels: the run's own
    account (``_complete_run``)."""
    import needlekit
    from needlekit.io.anatomy_cache import USAGE_FILE, default_cache_dir

    found = {}
    for root in (Path(needlekit.__file__).parent, default_cache_dir()):
        pattern = "__pycache__/*.pyc" if root.name == "needlekit" else "*"
        for f in root.rglob(pattern):
            if f.name == USAGE_FILE or f.is_dir():
                continue
            try:
                found[str(f)] = f.stat().st_mtime_ns
            except OSError:
                continue
    return found


def complete_run(args: list[str]) -> float:
    """Run ``needlekit ARGS`` to its end (the earlier outputs; again when that run filled a
    cache): the CPU seconds of a warm run, whose fractions the moments are."""
    argv = [sys.executable, "-m", "needlekit.cli", *args]
    # the moments are fractions of a warm run, before its result is decided: a run that
    # filled a cache (compiled kernels, byte code, the prepared anatomy) the later runs find
    # is run again, and the warmer of the two counts
    before = _caches()
    total_cpu_s, compiled = _complete_run(argv)
    if compiled or _caches() != before:
        total_cpu_s = min(total_cpu_s, _complete_run(argv)[0])
    return total_cpu_s


def check_interrupts(
    name: str, args: list[str], out: Path, moments: int, total_cpu_s: float | None = None
) -> None:
    """Run ``needlekit ARGS`` to its end (writing in ``out``: :func:`complete_run`), then
    interrupt it at ``moments`` moments seeded by ``name`` and check each outcome (the
    module's text). ``total_cpu_s``: that complete run already made, by the caller, with
    the same arguments (its outputs in ``out``, its :func:`complete_run` CPU)."""
    argv = [sys.executable, "-m", "needlekit.cli", *args]
    if total_cpu_s is None:
        total_cpu_s = complete_run(args)
    earlier = _files(out)
    assert earlier, "the complete run wrote nothing"
    rng = np.random.default_rng(zlib.crc32(name.encode()))
    # at most half: the end of a run (its files put in place, the interpreter's shutdown)
    # takes up to a third of its CPU on a loaded machine, and a Ctrl-C there is ignored
    # by design (the result is decided)
    for moment in rng.uniform(0.1, 0.5, moments):
        code, stderr, left = _interrupt_at(argv, moment * total_cpu_s)
        lines = [ln for ln in stderr.splitlines() if ln.strip()]
        where = f"{name} at {moment:.2f} of {total_cpu_s:.1f} CPU s: {stderr}"
        assert code == 130, where
        assert len(lines) == 1 and lines[0].startswith("interrupted: "), where
        assert "Traceback" not in stderr and "SystemError" not in stderr, where
        assert left == [], where  # every worker stopped, nothing left behind
        now = _files(out)
        assert {k: now[k] for k in earlier} == earlier, where  # byte-identical
        new = sorted(set(now) - set(earlier))
        assert all(".partial." in Path(k).name for k in new), (new, where)
        said = re.search(r"written to (.+) marked partial", lines[0])
        for path in said.group(1).split(" and ") if said else ():  # the line tells the truth
            assert os.path.relpath(path, out) in new, (path, new, where)
        for k in new:  # a partial record, whole, then removed for the next moment
            assert json.loads(now[k])["partial"] is True
            (out / k).unlink()


@pytest.fixture
def interrupt_check():
    """``interrupt_check(name, args, out, moments[, total_cpu_s])``: see the module's text
    and :func:`check_interrupts`."""
    return check_interrupts


@pytest.fixture(scope="session")
def interrupt_complete_run():
    """``interrupt_complete_run(args)``: :func:`complete_run`, for a complete run a module
    shares (its CPU then given to ``interrupt_check``)."""
    return complete_run
