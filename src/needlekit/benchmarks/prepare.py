"""A Med-RAD lung made ready for a first plan, stage by stage, with the memory it took.

Each run is a fresh Python process (``python -m needlekit.benchmarks.prepare``), as a user's
``needlekit plan`` is: *cold* into an empty prepared-anatomy cache, then *warm* from it. The
process times every stage from the imports to the first planner call, and records memory
two ways: the kernel's high-water mark of the resident set (``VmHWM``, the figure to
hold against the 2 GiB goal; a sample above it is taken instead, as the kernel folds its
per-thread counters in lazily) and, per stage, the largest resident set a 2 ms sampler saw
while the stage ran (a lower bound: a spike shorter than the sampling step, or one while a
numpy call holds the GIL, can be missed).

Stages (``load_medrad``'s own timings split the load): ``import`` (numpy, scipy, numba,
needlekit, the scenario reader), ``hash`` (the mask files' digests, the cache key), then cold ``read``,
``align``, ``free_space``, ``free_field``, ``cache_write``, or warm ``cache_load``; then
``scene`` (the scene and the combined obstacle field), ``problem`` (start 1's problem: its
entry surface and normal, and the obstacle voxels of the ``voxel_centres`` model) and
``first_plan`` (one RCS* call with a one-iteration budget: the numba kernels loaded from
their cache and the validity checks' first calls).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

from needlekit.errors import NeedlekitError
from needlekit.io.files import json_text

__all__ = ["COLD_TARGET_S", "PEAK_TARGET_MB", "WARM_TARGET_S", "prepare_in_subprocess"]

#: The issue's goals for one lung on 2 cores: cold (empty cache), warm (from the cache),
#: and the peak resident memory (MiB).
COLD_TARGET_S: float = 10.0
WARM_TARGET_S: float = 1.0
PEAK_TARGET_MB: float = 2048.0

_LOAD_STAGES = ("hash", "read", "align", "free_space", "free_field", "cache_write", "cache_load")


def _status_kb(field: str) -> int | None:
    try:
        with open("/proc/self/status", encoding="ascii") as fh:
            for line in fh:
                if line.startswith(field + ":"):
                    return int(line.split()[1])
    except OSError:
        pass
    return None


class _RssSampler(threading.Thread):
    """The resident set (MiB) every ``interval_s``, with the time of each sample."""

    def __init__(self, interval_s: float = 0.002) -> None:
        super().__init__(daemon=True)
        self.interval_s = interval_s
        self.samples: list[tuple[float, float]] = []
        self._stop_event = threading.Event()
        self._page_mb = os.sysconf("SC_PAGE_SIZE") / 2**20

    def run(self) -> None:
        try:
            fh = open("/proc/self/statm", encoding="ascii")
        except OSError:
            return
        with fh:
            while not self._stop_event.is_set():
                fh.seek(0)
                rss = int(fh.read().split()[1]) * self._page_mb
                self.samples.append((time.perf_counter(), rss))
                self._stop_event.wait(self.interval_s)

    def stop(self) -> None:
        self._stop_event.set()
        self.join()

    def peak_between(self, t0: float, t1: float) -> float | None:
        vals = [rss for t, rss in self.samples if t0 <= t <= t1]
        return max(vals) if vals else None


def _run_stages(root: str | None, patient: int, cache_dir: str) -> dict[str, Any]:
    """Everything one process does to get a lung ready for a first plan (cold or warm by
    the state of ``cache_dir``)."""
    sampler = _RssSampler()
    sampler.start()
    spans: list[tuple[str, float, float]] = []
    t = time.perf_counter()

    # what ``needlekit plan SCENARIO`` has imported before it loads the anatomy: the
    # scenario reader too (it reads the file first), whose import the problem stage
    # would otherwise pay for, as it pays for no other import
    import needlekit.scenario.loading  # noqa: F401
    from needlekit.benchmarks.steerable import medrad_lung_problem
    from needlekit.io.medrad import load_medrad
    from needlekit.planning.steerable.solve import solve

    spans.append(("import", t, time.perf_counter()))
    t = time.perf_counter()
    case = load_medrad("lung", patient, root, cache_dir=cache_dir)
    t_end = time.perf_counter()
    # load_medrad's stages ran one after another from t: place them on the clock in order
    cursor = t
    for name in _LOAD_STAGES:
        dt = case.timings_s.get(f"{name}_s")
        if dt is not None:
            spans.append((name, cursor, cursor + dt))
            cursor += dt
    spans.append(("scene", cursor, t_end))  # the rest of load_medrad: scene and fields
    t = time.perf_counter()
    problem = medrad_lung_problem(case, "start1", 50.0)
    spans.append(("problem", t, time.perf_counter()))
    t = time.perf_counter()
    result = solve(problem, "rcs_star", max_iterations=1, time_limit_s=60.0)
    spans.append(("first_plan", t, time.perf_counter()))
    sampler.stop()
    stages = {}
    for name, a, b in spans:
        peak = sampler.peak_between(a, b)
        # rounded down to 0.1 MB: a stage's sampled peak never reads above the process's
        # exact high-water mark (VmHWM) because of the rounding
        mb = None if peak is None else math.floor(peak * 10.0) / 10.0
        stages[name] = {"s": b - a, "rss_peak_mb": mb}
    hwm = _status_kb("VmHWM")
    return {
        "patient": patient,
        "warm": "cache_load_s" in case.timings_s,
        "stages": stages,
        "total_s": spans[-1][2] - spans[0][1],
        "ready_s": spans[-2][2] - spans[0][1],  # through the problem, before the first plan
        # the kernel's high-water mark, or a sample above it: Linux keeps the resident
        # counters per thread and folds them in lazily (SPLIT_RSS_COUNTING), so a statm
        # sample can read a few hundred kB above VmHWM while memory-mapped files are read
        "peak_rss_mb": None
        if hwm is None
        else max(hwm / 1024, *(v["rss_peak_mb"] or 0.0 for v in stages.values())),
        "first_plan_status": result.status.value,
        "entry_surface": problem.entry_surface,
        "grid_shape": list(np.shape(case.free_space.data)),
    }


def prepare_in_subprocess(root, patient: int, cache_dir, *, timeout_s: float = 600.0) -> dict:
    """Run the stages in a fresh Python process and return its record.

    Parameters
    ----------
    root : path-like or None
        Med-RAD folder (None: :func:`needlekit.io.medrad.medrad_root`'s default).
    patient : int
    cache_dir : path-like
        Prepared-anatomy cache: empty for a cold run, holding the patient for a warm one.
    timeout_s : float

    Returns
    -------
    dict
        ``stages`` (name -> ``s`` and ``rss_peak_mb``), ``total_s``, ``ready_s``,
        ``peak_rss_mb``, ``warm``, ``first_plan_status``, ``entry_surface``,
        ``grid_shape``.
    """
    cmd = [sys.executable, "-m", "needlekit.benchmarks.prepare", "--patient", str(patient)]
    cmd += ["--cache-dir", str(cache_dir)]
    if root is not None:
        cmd += ["--medrad", str(root)]
    t0 = time.perf_counter()
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout_s, check=False)
    wall = time.perf_counter() - t0
    if done.returncode != 0:
        tail = (done.stderr or done.stdout).strip().splitlines()[-1:] or ["no output"]
        raise RuntimeError(f"preparing lung {patient} failed: {tail[0]}")
    record = json.loads(done.stdout.strip().splitlines()[-1])
    record["process_wall_s"] = wall  # with the interpreter's start and exit
    return record


def _main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m needlekit.benchmarks.prepare")
    ap.add_argument("--patient", type=int, required=True)
    ap.add_argument("--cache-dir", type=Path, required=True)
    ap.add_argument("--medrad", type=Path, default=None)
    args = ap.parse_args(argv)

    try:
        record = _run_stages(args.medrad, args.patient, str(args.cache_dir))
    except NeedlekitError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(json_text(record, "record"))
    return 0


if __name__ == "__main__":
    raise SystemExit(_main())
