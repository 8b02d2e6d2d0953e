"""``needlekit bench fields``' per-stage preparation of a Med-RAD lung in a fresh process
(needlekit.benchmarks.prepare): the record's stages, memory and first plan. No clocks are
judged here: the bench reports them."""

import os

import pytest

from needlekit.benchmarks.prepare import prepare_in_subprocess


@pytest.mark.realdata
@pytest.mark.slow
def test_a_warm_lung_is_prepared_stage_by_stage_in_a_fresh_process(medrad_dir, medrad_lung1):
    # medrad_lung1 has put lung 1 in the session's cache: this run is warm
    rec = prepare_in_subprocess(medrad_dir, 1, os.environ["NEEDLEKIT_CACHE_DIR"])
    assert rec["warm"] is True
    assert list(rec["stages"]) == ["import", "hash", "cache_load", "scene", "problem",
                                   "first_plan"]  # fmt: skip
    spent = sum(v["s"] for v in rec["stages"].values())
    assert 0 < spent <= rec["total_s"] + 1e-6 and rec["total_s"] <= rec["process_wall_s"]
    # ready: from the imports through the problem, before the first plan's call
    assert 0 < rec["ready_s"] <= rec["total_s"] - rec["stages"]["first_plan"]["s"] + 1e-9
    assert rec["peak_rss_mb"] >= max(v["rss_peak_mb"] or 0 for v in rec["stages"].values())
    assert rec["entry_surface"] == "bronchialTree"
    assert rec["first_plan_status"] in {"solved", "timeout", "infeasible"}
    assert rec["grid_shape"] == list(medrad_lung1.free_space.data.shape)


def test_a_failing_run_is_one_line(tmp_path):
    with pytest.raises(
        RuntimeError,
        match=r"preparing lung 1 failed: error: .*Med-RAD folder .*nowhere does not exist$",
    ):
        prepare_in_subprocess(tmp_path / "nowhere", 1, tmp_path / "cache")
