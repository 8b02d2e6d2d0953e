"""The first preparation of Med-RAD lung 1 into an empty cache says what it does, with the
estimate from the masks' voxels; the second run, from the cache, says nothing; ``cache
list`` then shows the entry. Needs the Med-RAD data (skips without it)."""

from __future__ import annotations

import json
import logging

import pytest

from needlekit.cli import main
from needlekit.io.cache_entries import CACHE_LIMIT_ENV
from needlekit.io.medrad import load_medrad

pytestmark = [pytest.mark.realdata, pytest.mark.slow]

#: Lung 1's grid (497 x 331 x 512 voxels), five masks on it: the estimate's arithmetic.
LUNG1_VOXELS = 497 * 331 * 512


def test_lung1_first_preparation_says_so_and_a_hit_does_not(medrad_dir, tmp_path, caplog,
                                                            capsys, monkeypatch):  # fmt: skip
    from needlekit.io.prepare_progress import estimate_s

    monkeypatch.delenv(CACHE_LIMIT_ENV, raising=False)
    cache = tmp_path / "cache"
    with caplog.at_level(logging.INFO, logger="needlekit.io.medrad"):
        case = load_medrad("lung", 1, medrad_dir, cache_dir=cache)
    lines = [r.getMessage() for r in caplog.records if r.name == "needlekit.io.medrad"]
    seconds = round(estimate_s([LUNG1_VOXELS] * 5, LUNG1_VOXELS))
    assert seconds == 17
    assert lines[0] == (
        f"preparing Med-RAD lung 1 (first use; about {seconds} s, kept in "
        f"{cache}/medrad-lung1-{case.cache_entry.name[-32:][:8]}...)"
    )
    stages = [line.split(": ", 1)[1].split(" (")[0] for line in lines[1:-1]]
    assert stages[:6] == ["masks 1/5", "masks 2/5", "masks 3/5", "masks 4/5", "masks 5/5",
                          "free-space field"]  # fmt: skip
    assert stages[6].startswith("storing ") and lines[-1].endswith(" kept")
    caplog.clear()
    with caplog.at_level(logging.INFO, logger="needlekit.io.medrad"):
        again = load_medrad("lung", 1, medrad_dir, cache_dir=cache)
    assert "cache_load_s" in again.timings_s and caplog.records == []
    capsys.readouterr()
    assert main(["cache", "list", "--cache-dir", str(cache), "--json"]) == 0
    (entry,) = json.loads(capsys.readouterr().out)["entries"]
    on_disk = sum(p.stat().st_size for p in case.cache_entry.iterdir())
    assert entry["patient"] == "Med-RAD lung 1" and entry["bytes"] == on_disk
    assert entry["source"].endswith("Patient1")
