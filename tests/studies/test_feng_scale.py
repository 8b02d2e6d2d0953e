"""Feng's protocol at scale: the six sweeps as one batch, on any
executor, with the same results; the executor flags of every command that has them.

The timings themselves are measured by the study (``feng_lungs.json``'s ``timing``), never
asserted here.
"""

import json
from pathlib import Path

import numpy as np
import pytest

from needlekit.batch import open_executor
from needlekit.cli import main
from needlekit.cli._parser import _build_parser
from needlekit.errors import InvalidInputError

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"

# -- the command line: --dask-workers, --scheduler, --workers, --executor ----------------

#: Every command with the shared executor flags, with what it needs besides them.
COMMANDS = {
    "sweep": ["sweep", str(EXAMPLES / "toy.yaml")],
    "puncture": ["puncture"],
    "reproduce": ["reproduce", "feng2023"],
    "study feng-lungs": ["study", "feng-lungs", "--out", "out-feng"],
}


def _parse(command, *flags):
    return _build_parser().parse_args([*COMMANDS[command], *flags])


@pytest.mark.parametrize("command", list(COMMANDS))
@pytest.mark.parametrize(
    ("flags", "expected"),
    [
        ([], ("serial", None, None)),
        (["--dask-workers", "3"], ("dask", 3, None)),
        (["--scheduler", "tcp://10.0.0.1:8786"], ("dask", None, "tcp://10.0.0.1:8786")),
        (["--workers", "2"], ("process", 2, None)),
        (["--workers", "2", "--executor", "dask"], ("dask", 2, None)),
        (["--executor", "dask", "--scheduler", "tcp://h:1"], ("dask", None, "tcp://h:1")),
        (["--executor", "process"], ("process", None, None)),
    ],
)
def test_the_executor_flags_read_as_one_choice(command, flags, expected):
    args = _parse(command, *flags)
    assert (args.executor, args.workers, args.scheduler) == expected


@pytest.mark.parametrize("command", list(COMMANDS))
@pytest.mark.parametrize(
    ("flags", "message"),
    [
        (["--scheduler", "tcp://h:1", "--dask-workers", "2"], "--scheduler uses a running"),
        (["--dask-workers", "2", "--scheduler", "tcp://h:1"], "--scheduler uses a running"),
        (["--scheduler", "tcp://h:1", "--workers", "2"], "--workers does not apply"),
        (["--dask-workers", "2", "--workers", "2"], "--dask-workers N or --workers N"),
        (["--executor", "process", "--scheduler", "tcp://h:1"], "contradicts --executor process"),
        (["--dask-workers", "2", "--executor", "serial"], "contradicts --executor serial"),
        (["--workers", "2", "--executor", "serial"], "contradicts --executor serial"),
        (["--scheduler", " "], "expected an address such as tcp://HOST:PORT"),
        (["--dask-workers", "0"], "expected a whole number in [1, "),
    ],
)
def test_contradicting_executor_flags_are_one_line_before_any_work(
    command, flags, message, capsys, tmp_path, monkeypatch
):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit) as stop:
        main([*COMMANDS[command], *flags])
    err = capsys.readouterr().err
    assert stop.value.code == 2
    assert err.startswith("error: ") and message in err and err.count("\n") == 1
    assert not any(tmp_path.iterdir())  # nothing written


def test_an_unreachable_scheduler_is_one_line_naming_the_flag(capsys, tmp_path, monkeypatch):
    pytest.importorskip("distributed")
    import needlekit.batch

    monkeypatch.setattr(needlekit.batch, "SCHEDULER_TIMEOUT_S", 0.5)
    out = tmp_path / "feng"
    code = main(["study", "feng-lungs", "--out", str(out), "--scheduler", "tcp://127.0.0.1:9"])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1
    assert err.startswith("error: --scheduler: no Dask scheduler answers at 'tcp://127.0.0.1:9'")
    assert not out.exists()
    with (
        pytest.raises(InvalidInputError, match="--scheduler"),
        open_executor("dask", address="no port here"),
    ):
        pass


# -- sweep_many: every sweep at once equals the sweeps one by one -------------------------


@pytest.fixture(scope="module")
def phantom_lung():
    from needlekit.scenario.problems import ScenarioSource

    return ScenarioSource.of(EXAMPLES / "lung_phantom.yaml").load()[1]


def _rows(result):
    return [
        None if r is None else (r.status.value, round(r.cost_mm, 9), r.stats.get("reason"))
        for r in result.results
    ]


def test_sweep_many_equals_the_sweeps_one_by_one(phantom_lung):
    from dataclasses import replace

    from needlekit.planning.steerable.sweep import sphere_directions, sweep
    from needlekit.planning.steerable.sweep_batch import (
        SweepJob,
        refused_before_search,
        sweep_many,
    )

    problem = phantom_lung
    other = replace(problem, goal_mm=problem.goal_mm + [4.0, -3.0, 2.0])  # a second target
    dirs = sphere_directions(64)
    kw = {"directions": dirs, "time_limit_s": 30.0, "max_iterations": 60}
    jobs = [
        SweepJob(p, name, options=opts, rank=int(name != "rcs_star"))
        for p in (problem, other)
        for name, opts in (("rcs_star", None), ("rrt", {"connection": "arc"}))
    ]
    done = []

    class Progress:
        def __init__(self):
            self.total = None

        def set_total(self, n):
            self.total = n

        def __call__(self, result):
            done.append(result.planner)

    progress = Progress()
    batch = sweep_many(jobs, progress=progress, **kw)
    assert len(batch.sweeps) == 4 and batch.workers == {}  # ran here, on the problems given
    for job, got in zip(jobs, batch.sweeps, strict=True):
        alone = sweep(job.problem, job.planner, options=job.options, **kw)
        assert _rows(got) == _rows(alone)
        assert np.array_equal(got.effective, alone.effective)
        for key in ("n_effective", "n_solved", "best_index", "best_cost_mm", "mean_cost_mm"):
            assert got.stats[key] == alone.stats[key], key
        # the guess of which directions the pre-checks refuse is the planners' own verdict
        eff = np.flatnonzero(got.effective)
        guess = refused_before_search(job.problem, dirs[eff])
        searched = [got.results[i].stats.get("iterations", 0) > 0 for i in eff]
        assert np.array_equal(guess, ~np.array(searched))
    assert sum(s.stats["n_solved"] for s in batch.sweeps) > 0
    assert progress.total == len(done) == sum(s.stats["n_effective"] for s in batch.sweeps)
    n_star = sum(s.stats["n_effective"] for s in batch.sweeps[::2])
    assert set(done[:n_star]) == {"rcs_star"} and set(done[n_star:]) == {"rrt"}  # rank order


def test_sweep_many_refuses_no_jobs():
    from needlekit.planning.steerable.sweep_batch import sweep_many

    with pytest.raises(InvalidInputError, match="jobs"):
        sweep_many([])


def test_an_inline_scenario_source_is_its_document(tmp_path):
    import pickle

    import yaml

    from needlekit.scenario.problems import ScenarioSource

    doc = yaml.safe_load((EXAMPLES / "toy.yaml").read_text())
    inline = ScenarioSource.of_document(doc, EXAMPLES, name="toy.yaml", goal_mm=[1, 2, 3])
    again = pickle.loads(pickle.dumps(inline))
    assert again == inline and hash(again) == hash(inline)
    swapped = dict(reversed(doc.items()))  # the same document: the same source
    assert inline == ScenarioSource.of_document(
        swapped, EXAMPLES, name="toy.yaml", goal_mm=[1, 2, 3]
    )
    assert inline != ScenarioSource.of_document({**doc, "name": "other"}, EXAMPLES, name="toy.yaml",
                                                goal_mm=[1, 2, 3])  # fmt: skip
    _, from_doc = inline.load()
    _, from_file = ScenarioSource.of(EXAMPLES / "toy.yaml", goal_mm=[1, 2, 3]).load()
    np.testing.assert_allclose(from_doc.goal_mm, [1, 2, 3])
    assert from_doc.r_min_mm == from_file.r_min_mm
    assert from_doc.scene.names == from_file.scene.names
    with pytest.raises(InvalidInputError, match="document"):
        ScenarioSource.of_document({"bad": float("nan")})


# -- the study on a Med-RAD lung: serial, process pool and a Dask cluster agree -----------


def _without_timings(value):
    """A record without what depends on the clock or the process: keys ending in ``_s``."""
    if isinstance(value, dict):
        return {k: _without_timings(v) for k, v in value.items() if not k.endswith("_s")}
    if isinstance(value, list):
        return [_without_timings(v) for v in value]
    return value


@pytest.mark.realdata
@pytest.mark.slow
def test_serial_process_and_dask_runs_agree(medrad_dir, tmp_path):
    pytest.importorskip("distributed")
    import logging

    from distributed import LocalCluster

    from needlekit.cli import main
    from needlekit.studies.feng_lungs import run_feng_lungs

    kw = {"directions": 24, "max_iterations": 100, "time_limit_s": 60.0, "report": False}
    runs = {}
    for kind in ("serial", "process", "dask"):
        with open_executor(kind, workers=2) as ex:
            executor = None if kind == "serial" else ex
            study = run_feng_lungs(tmp_path / kind, executor=executor, medrad_dir=medrad_dir, **kw)
        runs[kind] = study.record
    # an existing cluster, reached by its address as `--scheduler tcp://HOST:PORT` does
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                      dashboard_address=None, silence_logs=logging.WARNING) as cluster:  # fmt: skip
        argv = ["study", "feng-lungs", "--out", str(tmp_path / "scheduler"), "--directions",
                "24", "--max-iterations", "100", "--time-limit-s", "60", "--medrad",
                str(medrad_dir), "--scheduler", cluster.scheduler_address]  # fmt: skip
        assert main(argv) == 0
    runs["scheduler"] = json.loads((tmp_path / "scheduler" / "feng_lungs.json").read_text())
    sweeps = {
        kind: {g: json.loads((tmp_path / kind / g / "sweep.json").read_text()) for g in runs[kind]["goals"]}
        for kind in runs
    }  # fmt: skip
    assert sum(t["n_solved"] for t in runs["serial"]["goals"]["goal1"]["table4"].values()) > 0
    for kind in ("process", "dask", "scheduler"):
        assert _without_timings(sweeps[kind]) == _without_timings(sweeps["serial"]), kind
        assert _without_timings(runs[kind]["goals"]) == _without_timings(runs["serial"]["goals"])
        t = runs[kind]["timing"]
        assert t["workers"] == 2 and t["runs"] == 6 * runs[kind]["goals"]["goal1"]["table4"][
            "rcs_star"]["n_effective"]  # fmt: skip
        # each worker that ran tasks prepared the patient once, for both targets
        assert 1 <= len(t["built_by_worker"]) <= 2
        for built in t["built_by_worker"].values():
            assert built.get("MedradCase") == 1 and 1 <= built.get("ScenarioSource", 0) <= 2
        assert sum(t["tasks_by_worker"].values()) == t["runs"]
        assert set(t["prep_s_by_worker"]) == set(t["built_by_worker"])
    t = runs["serial"]["timing"]
    assert t["workers"] == 1 and set(t["prep_s_by_worker"]) == {"main"}
    for key in ("wall_s", "planner_s_sum", "setup_s_sum", "bound_s", "rcs_star_wall_s"):
        assert t[key] >= 0.0
    assert t["within_bound"] == (t["wall_s"] <= t["bound_s"])
