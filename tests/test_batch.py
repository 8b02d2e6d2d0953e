"""Batch execution: serial, process-pool and Dask executors give the same study results."""

import pickle
from pathlib import Path

import numpy as np
import pytest

from needlekit.batch import (
    SerialExecutor,
    as_completed_indexed,
    clear_worker_cache,
    open_executor,
    worker_cached,
)
from needlekit.errors import InvalidInputError
from needlekit.planning.steerable.sweep import sphere_directions, sweep
from needlekit.scenario.problems import ScenarioSource, load_problem

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


def _square(x):
    return x * x


def _fail_on_three(x):
    if x == 3:
        raise ValueError("three")
    return x


def test_serial_executor_runs_at_submission_and_keeps_exceptions():
    ex = SerialExecutor()
    assert ex.submit(_square, 4).result() == 16
    fut = ex.submit(_fail_on_three, 3)
    assert fut.done() and isinstance(fut.exception(), ValueError)


@pytest.mark.parametrize("kind", ["serial", "process"])
def test_as_completed_indexed_returns_every_task_once(kind):
    with open_executor(kind, workers=2) as ex:
        got = dict(as_completed_indexed(ex, _square, range(10)))
    assert got == {i: i * i for i in range(10)}


def test_as_completed_indexed_propagates_a_task_error():
    with pytest.raises(ValueError, match="three"):
        dict(as_completed_indexed(SerialExecutor(), _fail_on_three, range(5)))


def _interrupt_at(x):
    if x == 2:
        raise KeyboardInterrupt
    return x


def test_ctrl_c_stops_a_serial_run_at_the_task_it_hits():
    """Ctrl-C is not a task's failure: the tasks after it never run, and the results taken
    before it are the ones done."""
    seen = []
    with pytest.raises(KeyboardInterrupt):
        for i, r in as_completed_indexed(SerialExecutor(), _interrupt_at, range(5)):
            seen.append((i, r))
    assert seen == [(0, 0), (1, 1)]


def test_stopping_a_pool_with_cancelled_tasks_leaves_no_thread_error(monkeypatch):
    """Ctrl-C while tasks wait in a pool: the waiting ones are cancelled, the workers
    stopped, and the pool's manager thread fails no cancelled task (Python 3.11 printed a
    thread traceback there)."""
    import threading
    import time

    from needlekit import batch

    errors = []
    monkeypatch.setattr(threading, "excepthook", lambda a: errors.append(a.exc_type))
    pool = batch.ProcessPoolExecutor(max_workers=1, initializer=batch._ignore_sigint,
                                     mp_context=batch.multiprocessing.get_context("spawn"))  # fmt: skip
    futures = [pool.submit(time.sleep, 60) for _ in range(4)]
    while not futures[0].running():
        time.sleep(0.01)
    assert all(f.cancel() for f in futures[2:])  # the ones still queued here
    manager = pool._executor_manager_thread
    procs = list(pool._processes.values())
    batch._stop_pool(pool)
    manager.join(10)
    assert not manager.is_alive() and not any(p.is_alive() for p in procs)
    assert errors == []


_CLOSED_PIPE_AT_EXIT = """
import time
from needlekit import batch

pool = batch.ProcessPoolExecutor(max_workers=1, initializer=batch._ignore_sigint,
                                 mp_context=batch.multiprocessing.get_context("spawn"))
future = pool.submit(time.sleep, 60)
while not future.running():
    time.sleep(0.01)
waker = pool._executor_manager_thread_wakeup
manager = pool._executor_manager_thread  # held: still registered at the exit, as one
batch._stop_pool(pool)                   # that had not ended by then would be
manager.join(60)
assert not manager.is_alive() and waker._closed  # it closed its pipe as it ended
# the interleaving a loaded machine gives: the exit hook checked ``_closed`` before the
# manager closed the pipe, and writes after
waker._closed = False
print("stopped")
"""


def test_a_stopped_pools_pipe_closed_under_the_exit_hook_prints_nothing(tmp_path):
    """The exit hook of concurrent.futures wakes every pool's manager; one whose pipe was
    closed between the hook's check and its write printed "Exception ignored ... Bad file
    descriptor" and a traceback after a Ctrl-C's one line: a stopped pool's waker takes a
    closed pipe as a manager that has ended."""
    import subprocess
    import sys

    script = tmp_path / "closed_pipe.py"
    script.write_text(_CLOSED_PIPE_AT_EXIT)
    done = subprocess.run([sys.executable, str(script)], capture_output=True, text=True,
                          timeout=120)  # fmt: skip
    assert done.returncode == 0 and done.stdout == "stopped\n", done.stderr
    assert done.stderr == ""


@pytest.mark.parametrize(
    ("kind", "workers", "field"),
    [("threads", None, "executor"), ("process", 0, "workers"), ("serial", 1.5, "workers")],
)
def test_open_executor_rejects_bad_arguments(kind, workers, field):
    with pytest.raises(InvalidInputError, match=field), open_executor(kind, workers=workers):
        pass


def test_worker_cache_builds_once_per_key():
    clear_worker_cache()
    calls = []

    def build():
        calls.append(1)
        return object()

    a = worker_cached("k", build)
    b = worker_cached("k", build)
    worker_cached("other", build)
    assert a is b and len(calls) == 2
    clear_worker_cache()
    assert worker_cached("k", build) is not a


def test_scenario_source_is_a_small_hashable_recipe():
    src = ScenarioSource.of(EXAMPLES / "toy.yaml", goal_mm=[1, 2, 3], r_min_mm=80)
    assert Path(src.scenario_path).is_absolute()
    assert hash(src) == hash(pickle.loads(pickle.dumps(src)))
    assert len(pickle.dumps(src)) < 1000
    _, problem = src.load()
    np.testing.assert_allclose(problem.goal_mm, [1, 2, 3])
    assert problem.r_min_mm == 80


def test_load_problem_errors_name_the_field(tmp_path):
    with pytest.raises(InvalidInputError, match="start_pose"):
        load_problem(EXAMPLES / "toy.yaml", start_pose=np.eye(3))


@pytest.fixture(scope="module")
def lung():
    src = ScenarioSource.of(EXAMPLES / "lung_phantom.yaml")
    _, problem = src.load()
    return src, problem


def _costs(result):
    return [None if r is None else (r.status.value, round(r.cost_mm, 9)) for r in result.results]


#: The sweep both executors run: 96 directions, the iteration budget ending each search.
SWEEP_KW = {"directions": sphere_directions(96), "time_limit_s": 30.0, "max_iterations": 150}


@pytest.fixture(scope="module")
def serial_sweep(lung):
    """The sweep run here, one direction after another: the reference of both executors
    (made once; the budget is iterations, so the serial run is the same each time)."""
    _, problem = lung
    return sweep(problem, "rcs_star", **SWEEP_KW)


@pytest.mark.slow
@pytest.mark.parametrize("kind", ["process", "dask"])
def test_parallel_sweep_equals_the_serial_sweep(lung, serial_sweep, kind, exact_clearance):
    src, problem = lung
    kw = SWEEP_KW
    serial = serial_sweep
    # the iteration budget ends each search: a fixed outcome, every plan of which clears
    # the phantom's exact anatomy
    assert (serial.stats["n_effective"], serial.stats["n_solved"]) == (30, 3)
    scenario, _ = src.load()
    plans = [r for r in serial.results if r is not None and r.plan is not None]
    assert len(plans) == 3
    for r in plans:
        exact_clearance(scenario.base, problem, r.plan, r.stats["certified_clearance_mm"])
    seen = []
    with open_executor(kind, workers=2) as ex:
        parallel = sweep(problem, "rcs_star", executor=ex, source=src, progress=seen.append, **kw)
    assert len(seen) == serial.stats["n_effective"] > 0
    assert _costs(parallel) == _costs(serial)
    assert parallel.stats["best_index"] == serial.stats["best_index"]


def test_remote_sweep_refuses_to_ship_a_heavy_scene(lung):
    _, problem = lung

    from concurrent.futures import ThreadPoolExecutor

    with (
        pytest.raises(InvalidInputError, match="source"),
        ThreadPoolExecutor(1) as ex,
    ):
        sweep(problem, "rcs_star", directions=sphere_directions(8), executor=ex)


# ---------------------------------------------------------------------------------------
# a local Dask cluster no one else can use

_INTRUDER = """
import os, signal, sys
from distributed import Client

def give_up(signum, frame):
    raise TimeoutError("no connection")

signal.signal(signal.SIGALRM, give_up)
address = sys.argv[1]
for label, target in (("tls", address), ("tcp", address.replace("tls://", "tcp://"))):
    signal.alarm(20)  # a client that can neither connect nor fail is refused too
    try:
        client = Client(target, timeout=5)
        print(label, "CONNECTED", client.submit(abs, -1).result(timeout=5), flush=True)
    except BaseException as exc:
        print(label, "refused", type(exc).__name__, flush=True)
    signal.alarm(0)
os._exit(0)  # Dask's threads of a failed client must not hold the interpreter open
"""


def _http_status(port: int, path: str) -> int | str:
    import urllib.error
    import urllib.request

    try:
        with urllib.request.urlopen(f"http://127.0.0.1:{port}{path}", timeout=5) as r:
            return r.status
    except urllib.error.HTTPError as exc:
        return exc.code
    except OSError as exc:
        return type(exc).__name__


def test_a_local_dask_cluster_refuses_other_processes_and_serves_no_page():
    import subprocess
    import sys

    pytest.importorskip("distributed")
    with open_executor("dask", workers=1) as ex:
        client = ex._client
        address = client.scheduler.address
        assert address.startswith("tls://127.0.0.1:")
        assert ex.submit(abs, -3).result() == 3  # this run's own client works
        info = client.scheduler_info()
        intruder = subprocess.run(
            [sys.executable, "-c", _INTRUDER, address],
            capture_output=True, text=True, timeout=120,
        )  # fmt: skip
        said = intruder.stdout.split("\n")
        assert [line.split()[:2] for line in said if line] == [
            ["tls", "refused"],
            ["tcp", "refused"],
        ], intruder.stdout + intruder.stderr
        # Dask starts an HTTP server on every node whatever it is told: none serves a page
        ports = [info["services"]["dashboard"]]
        ports += [w["services"]["dashboard"] for w in info["workers"].values()]
        for port in ports:
            for path in ("/", "/status", "/metrics", "/health", "/info/main/workers.html"):
                assert _http_status(port, path) == 404, (port, path)


def test_the_dashboard_is_served_only_when_asked():
    pytest.importorskip("distributed")
    with open_executor("dask", workers=1, dashboard=True) as ex:
        port = ex._client.scheduler_info()["services"]["dashboard"]
        assert _http_status(port, "/health") == 200
