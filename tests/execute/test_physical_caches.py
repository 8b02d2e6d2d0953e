"""What a physical run keeps between runs: the loop's calibrated needle model and the fast
key of the organ's precomputation, records in the prepared-anatomy cache
(:mod:`needlekit.io.record_cache`). A hit gives the same bits as computing; every input
the answer depends on is part of the key; a damaged record is recomputed."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

import needlekit.execute.physical_setup as physical_setup
from needlekit.execute.calibration import Calibration, calibrate_truth
from needlekit.execute.physical import MechanicsSettings
from needlekit.execute.run import ExecutionSettings
from needlekit.io import record_cache
from needlekit.planning.steerable.plan import SteerablePlan

POSE = np.eye(4)
POSE[:3, 3] = [1.5, -2.0, 3.25]
PLAN = SteerablePlan(POSE, np.array([[0.0, 0.0, 40.0]]))


def _settings(truth: str = "mechanics") -> ExecutionSettings:
    s = ExecutionSettings()
    return replace(s, models=replace(s.models, truth=truth))


def _physical(cache, mechanics=None, insertions=2, seed=0, r_min=50.0, use_cache=True):
    return physical_setup.physical_settings(
        _settings(), None, PLAN, [0.0, 0.0, 40.0], r_min,
        mechanics=mechanics or MechanicsSettings(), insertions=insertions, seed=seed,
        cache_dir=cache, use_cache=use_cache,
    ).model  # fmt: skip


def _counting(monkeypatch, calls=None, answer=None) -> list:
    """Count the calibrations into ``calls`` (a new list when None). ``answer``: given
    back in place of calibrating, where a test counts the misses and never looks at
    what they compute."""
    calls = [] if calls is None else calls

    def counted(*args, **kw):
        calls.append(args[2])
        return calibrate_truth(*args, **kw) if answer is None else answer

    monkeypatch.setattr(physical_setup, "calibrate_truth", counted)
    return calls


def test_a_second_calibration_of_the_same_needle_is_read_back_bit_for_bit(tmp_path, monkeypatch):
    calls = _counting(monkeypatch)
    first = _physical(tmp_path)
    again = _physical(tmp_path)
    assert isinstance(again, Calibration) and len(calls) == 1
    assert again.to_dict() == first.to_dict()  # every field, to the bit (JSON floats round-trip)
    assert [p.name.split("-")[0] for p in tmp_path.iterdir()] == ["calibration"]
    # each input the answer depends on misses: the seed, the insertions, the needle, the
    # tissue, the radius, the start pose (what is checked is that each calls the
    # calibration and is stored apart, so a stand-in gives the first answer back)
    _counting(monkeypatch, calls, answer=first)
    _physical(tmp_path, seed=1)
    _physical(tmp_path, insertions=3)
    _physical(tmp_path, mechanics=MechanicsSettings(needle="steel"))
    _physical(tmp_path, mechanics=MechanicsSettings(inhomogeneity=0.2))
    _physical(tmp_path, r_min=60.0)
    global PLAN
    saved, moved = PLAN, POSE.copy()
    moved[0, 3] += 1e-9
    PLAN = SteerablePlan(moved, np.array([[0.0, 0.0, 40.0]]))
    try:
        _physical(tmp_path)
    finally:
        PLAN = saved
    assert len(calls) == 7
    _counting(monkeypatch, calls)  # the calibration itself again
    assert _physical(tmp_path, use_cache=False).to_dict() == first.to_dict()
    assert len(calls) == 8 and len(list(tmp_path.iterdir())) == 7  # nothing read or written


def test_a_damaged_or_foreign_record_is_recomputed_not_read(tmp_path, monkeypatch, caplog):
    calls = _counting(monkeypatch)
    first = _physical(tmp_path)
    (entry,) = tmp_path.iterdir()
    data = entry / "record.npy"
    raw = bytearray(data.read_bytes())
    raw[-3] ^= 1  # one bit of the record's bytes
    data.write_bytes(bytes(raw))
    again = _physical(tmp_path)
    assert len(calls) == 2 and again.to_dict() == first.to_dict()
    assert "corrupt entry" in caplog.text
    # another build of needlekit (its source changed) does not read this one's answers
    # (counted: a stand-in gives the first answer back)
    _counting(monkeypatch, calls, answer=first)
    monkeypatch.setattr(record_cache, "source_digest", lambda: "0" * 32)
    _physical(tmp_path)
    assert len(calls) == 3


def test_a_registered_replacement_of_the_mechanics_truth_is_calibrated_every_time(tmp_path, monkeypatch):
    from needlekit.execute import plugins

    real = plugins.TRUTHS.get("mechanics")
    monkeypatch.setattr(plugins.TRUTHS, "get", lambda name: (lambda setup: real(setup)))
    calls = _counting(monkeypatch)
    _physical(tmp_path)
    _physical(tmp_path)
    assert len(calls) == 2 and list(tmp_path.iterdir()) == []


def test_records_round_trip_and_keep_their_inputs_apart(tmp_path):
    inputs = {"a": [1.0, 2.5], "b": "x"}
    assert record_cache.load_record(tmp_path, "thing", inputs) is None
    assert record_cache.store_record(tmp_path, "thing", inputs, {"v": 0.1 + 0.2}, "a thing")
    assert record_cache.load_record(tmp_path, "thing", inputs) == {"v": 0.1 + 0.2}
    assert record_cache.load_record(tmp_path, "thing", {**inputs, "b": "y"}) is None
    assert record_cache.load_record(tmp_path, "other", inputs) is None
    # a record that is not finite JSON is not stored, and says so in the log only
    assert not record_cache.store_record(tmp_path, "thing", {"n": 1}, {"v": float("nan")}, "nan")
    assert record_cache.load_record(tmp_path, "thing", {"n": 1}) is None
    (entry,) = tmp_path.iterdir()
    manifest = json.loads((entry / "manifest.json").read_text())
    assert manifest["inputs"] == inputs  # what it was made of, for a reader


@pytest.mark.realdata
@pytest.mark.slow
def test_a_second_run_opens_the_organs_precomputation_without_reading_a_mask(
    medrad_dir, tmp_path, monkeypatch
):
    import needlekit.execute.deforming as deforming
    from needlekit.execute.deforming import load_compliance
    from needlekit.scenario.loading import load_scenario
    from needlekit.studies.execute_lungs import lung_scenario_document

    sc = load_scenario("lung1.yaml", document=lung_scenario_document(1, 0.0, medrad_dir))
    start, goal = sc.start.world_T_tip, np.asarray(sc.goal.point_mm)
    # straight at the target, as test_physical_truth.py inserts it: the session's cache
    # holds its organ already when that ran first
    z = (goal - start[:3, 3]) / np.linalg.norm(goal - start[:3, 3])
    x = np.cross([0.0, 1.0, 0.0], z)
    pose = np.eye(4)
    pose[:3, :3] = np.column_stack([x / np.linalg.norm(x), np.cross(z, x / np.linalg.norm(x)), z])
    pose[:3, 3] = start[:3, 3]
    plan = SteerablePlan(pose, np.array([[0.0, 0.0, float(np.linalg.norm(goal - start[:3, 3]))]]))
    model = deforming.tissue_model_for(sc, plan, goal)
    cold = load_compliance(model)
    fast = record_cache.load_record(None, "tissue-key", deforming._fast_inputs(model))
    assert fast == {"label": "tissue-lung", "key": cold.info["cache_key"]}

    def no_masks(*args, **kw):
        raise AssertionError("read the masks")

    monkeypatch.setattr(deforming, "organ_inputs", no_masks)
    warm = load_compliance(model)
    for name in ("C", "B", "G", "H", "corridor_mm", "tracked_mm"):
        assert np.array_equal(getattr(warm, name), getattr(cold, name)), name
    assert warm.tracked_labels == cold.tracked_labels
    # another corridor is another key: the masks are read (and refused here)
    moved = replace(model, target_mm=tuple(v + 0.5 for v in model.target_mm))
    with pytest.raises(AssertionError, match="read the masks"):
        load_compliance(moved)
    # no cache: nothing read, so the masks are (the process's last masks forgotten: run
    # alone, this test's own cold call read them, and a model of the same organ and
    # corridor takes them from memory, as it should)
    deforming._organ_inputs_last.cache_clear()
    with pytest.raises(AssertionError, match="read the masks"):
        load_compliance(replace(model, use_cache=False))


def test_a_straight_needles_organ_goes_through_the_cache_it_was_given():
    # `execute --cache-dir D` / `--no-cache` on a multi plan: each needle's organ model
    # carries them to its precomputation (they had gone to the default cache)
    from needlekit.execute.straight_physics import StraightPhysics

    given = StraightPhysics("physical", MechanicsSettings(), "liver", "folder",
                            cache_dir="/elsewhere", use_cache=False)  # fmt: skip
    model = given.tissue_model([0.0, 0.0, 0.0], [0.0, 0.0, 30.0])
    assert (model.cache_dir, model.use_cache) == ("/elsewhere", False)
    default = StraightPhysics("physical", MechanicsSettings(), "liver", "folder")
    model = default.tissue_model([0.0, 0.0, 0.0], [0.0, 0.0, 30.0])
    assert (model.cache_dir, model.use_cache) == (None, True)
