"""The cache made visible: entries' usage records, the size limit, eviction of the least
recently used entries (never one in use or being written), and the line a first
preparation says (and a hit does not).

Entries are written with :func:`needlekit.io.anatomy_cache.write_entry` from tiny arrays
whose sizes are known exactly; the preparation tests use a small synthetic Med-RAD lung
(32^3 voxels). Times are given explicitly (``now=``), never read off a clock.
"""

from __future__ import annotations

import io
import logging
import threading
from pathlib import Path

import numpy as np
import pytest

from needlekit.errors import InvalidInputError
from needlekit.io import anatomy_cache, cache_entries
from needlekit.io.anatomy_cache import entry_key, write_entry
from needlekit.io.cache_entries import (
    CACHE_LIMIT_ENV,
    DEFAULT_LIMIT_BYTES,
    cache_limit,
    list_entries,
    make_room,
    mark_used,
    parse_size,
    set_cache_limit,
    usage_record,
)
from needlekit.io.medrad import load_medrad
from needlekit.io.prepare_progress import (
    FIELD_S_PER_MVOXEL,
    READ_S_PER_MVOXEL,
    STORE_S_PER_MVOXEL,
    PreparationProgress,
    estimate_s,
    header_voxels,
)
from needlekit.io.volumes import write_mask_nifti

N = 32


@pytest.fixture(autouse=True)
def _no_limit_from_outside(monkeypatch):
    monkeypatch.delenv(CACHE_LIMIT_ENV, raising=False)


def fake_entry(root: Path, patient: int, n_bytes: int, last_used: float) -> Path:
    """An entry of one uint8 array of ``n_bytes`` bytes, made and last used at
    ``last_used`` (Unix time)."""
    label = f"medrad-lung{patient}"
    key = entry_key({"patient": patient, "n": n_bytes})
    arrays = {"a": (np.full(n_bytes, patient, dtype=np.uint8), {})}
    usage = usage_record(f"Med-RAD lung {patient}", f"/data/Patient{patient}", now=last_used)
    return write_entry(root, label, key, {"patient": patient}, arrays, usage).path


def _files_bytes(path: Path) -> int:
    return sum(p.stat().st_size for p in path.iterdir() if p.is_file())


# ----------------------------------------------------------------------------------------
# sizes and the limit


@pytest.mark.parametrize(
    ("text", "expected"),
    [("10GB", 10**10), ("500 MB", 5 * 10**8), ("1.5TB", 1.5e12), ("2GiB", 2 * 2**30),
     ("7k", 7000), ("3b", 3)],
)  # fmt: skip
def test_sizes_are_read_with_their_unit(text, expected):
    assert parse_size(text) == expected


@pytest.mark.parametrize("text", ["banana", "10", "-5GB", "0GB", "5 parsecs", "2000TB", ""])
def test_a_size_without_a_unit_or_out_of_range_is_refused(text):
    with pytest.raises(InvalidInputError, match=r"^SIZE: expected a size such as 10GB"):
        parse_size(text)


def test_the_limit_comes_from_the_variable_then_the_folder_then_the_default(tmp_path, monkeypatch):
    assert cache_limit(tmp_path) == (DEFAULT_LIMIT_BYTES, "default") == (10**10, "default")
    path = set_cache_limit(tmp_path, 5 * 10**9)
    assert cache_limit(tmp_path) == (5 * 10**9, str(path))
    monkeypatch.setenv(CACHE_LIMIT_ENV, "2GB")
    assert cache_limit(tmp_path) == (2 * 10**9, "$NEEDLEKIT_CACHE_LIMIT")
    monkeypatch.setenv(CACHE_LIMIT_ENV, "banana")
    with pytest.raises(InvalidInputError, match=r"^NEEDLEKIT_CACHE_LIMIT: expected a size"):
        cache_limit(tmp_path)
    monkeypatch.delenv(CACHE_LIMIT_ENV)
    set_cache_limit(tmp_path, None)
    assert cache_limit(tmp_path) == (DEFAULT_LIMIT_BYTES, "default")
    (tmp_path / "limit.json").write_text('{"limit_bytes": -3}')
    with pytest.raises(InvalidInputError, match=r"limit_bytes: expected a whole number"):
        cache_limit(tmp_path)


# ----------------------------------------------------------------------------------------
# listing and usage


def test_entries_are_listed_with_exact_sizes_most_recently_used_first(tmp_path):
    a = fake_entry(tmp_path, 1, 1000, last_used=1000.0)
    b = fake_entry(tmp_path, 2, 3000, last_used=3000.0)
    c = fake_entry(tmp_path, 3, 2000, last_used=2000.0)
    listed = list_entries(tmp_path)
    assert [e.path for e in listed] == [b, c, a]
    assert [e.patient for e in listed] == ["Med-RAD lung 2", "Med-RAD lung 3", "Med-RAD lung 1"]
    assert [e.bytes for e in listed] == [_files_bytes(b), _files_bytes(c), _files_bytes(a)]
    # the array's file is its bytes and a 128-byte .npy header
    assert (b / "a.npy").stat().st_size == 3000 + 128
    assert listed[0].source == "/data/Patient2" and listed[0].created == 3000.0
    assert not any(e.writing for e in listed)


def test_a_use_moves_an_entry_to_the_front_and_leaves_no_temporary_file(tmp_path):
    a = fake_entry(tmp_path, 1, 100, last_used=1000.0)
    fake_entry(tmp_path, 2, 100, last_used=2000.0)
    mark_used(a, now=5000.0)
    listed = list_entries(tmp_path)
    assert listed[0].path == a and listed[0].last_used == 5000.0 and listed[0].created == 1000.0
    assert sorted(p.name for p in a.iterdir()) == ["a.json", "a.npy", "manifest.json", "usage.json"]


def test_an_entry_without_a_usage_record_is_listed_from_its_manifest(tmp_path):
    a = fake_entry(tmp_path, 4, 100, last_used=1000.0)
    (a / "usage.json").unlink()
    (e,) = list_entries(tmp_path)
    assert e.patient == "Med-RAD lung 4" and e.last_used == e.created
    mark_used(a, now=7000.0)  # writes the record back
    (e,) = list_entries(tmp_path)
    assert e.last_used == 7000.0 and e.patient == "Med-RAD lung 4"


# ----------------------------------------------------------------------------------------
# eviction


def test_the_least_recently_used_entries_go_first_in_one_log_line(tmp_path, caplog):
    a = fake_entry(tmp_path, 1, 1000, last_used=1000.0)  # oldest use
    b = fake_entry(tmp_path, 2, 1000, last_used=3000.0)  # newest
    c = fake_entry(tmp_path, 3, 1000, last_used=2000.0)
    size = _files_bytes(a)
    # room for one more entry (and a byte) under a limit of three: a then c must go
    limit = 3 * size
    with caplog.at_level(logging.WARNING, logger="needlekit.io.cache_entries"):
        assert make_room(tmp_path, size + 1, limit=limit)
    assert [e.path for e in list_entries(tmp_path)] == [b]
    assert not a.exists() and not c.exists()
    (record,) = caplog.records
    assert "removed Med-RAD lung 1" in record.getMessage()
    assert record.getMessage().index("lung 1") < record.getMessage().index("lung 3")
    assert "lung 2" not in record.getMessage()


def test_nothing_is_removed_when_the_new_bytes_fit(tmp_path, caplog):
    a = fake_entry(tmp_path, 1, 1000, last_used=1000.0)
    with caplog.at_level(logging.WARNING):
        assert make_room(tmp_path, 10, limit=_files_bytes(a) + 10)
    assert a.exists() and caplog.records == []


def test_the_entry_in_use_is_never_removed_and_what_cannot_fit_is_said(tmp_path):
    a = fake_entry(tmp_path, 1, 1000, last_used=1000.0)
    b = fake_entry(tmp_path, 2, 1000, last_used=2000.0)
    size = _files_bytes(a)
    assert not make_room(tmp_path, 10**6, limit=10, keep=a)  # only b may go: not enough
    assert a.exists() and b.exists()  # so nothing is removed for it
    assert make_room(tmp_path, 10, limit=size + 10, keep=a)  # removing b is enough
    assert a.exists() and not b.exists()
    c = fake_entry(tmp_path, 3, 1000, last_used=500.0)
    mark_used(c, now=600.0)  # this process uses it (and its last use stays the oldest)
    assert not make_room(tmp_path, 10, limit=size + 10, keep=a)
    assert a.exists() and c.exists()


def test_an_entry_another_process_adds_an_array_to_is_not_removed(tmp_path):
    a = fake_entry(tmp_path, 1, 1000, last_used=1000.0)
    b = fake_entry(tmp_path, 2, 1000, last_used=2000.0)
    (a / ".sdf_x.npy.abc123.part").write_bytes(b"half an array")  # a writer's temporary
    assert [e.writing for e in list_entries(tmp_path)] == [False, True]
    assert not make_room(tmp_path, 1, limit=1)  # only b may go: not enough, none goes
    assert a.exists() and b.exists()
    assert make_room(tmp_path, 1, limit=_files_bytes(a) + 1)  # b, used later, goes
    assert a.exists() and not b.exists()


def test_eviction_leaves_an_entry_being_written_alone(tmp_path, monkeypatch):
    old = fake_entry(tmp_path, 1, 1000, last_used=1000.0)
    real = anatomy_cache._write_array
    started, release = threading.Event(), threading.Event()

    def slow(folder, name, values, meta, secret):  # another writer, stopped midway
        real(folder, name, values, meta, secret)
        started.set()
        assert release.wait(30)

    monkeypatch.setattr(anatomy_cache, "_write_array", slow)
    out = {}

    def writer():
        out["entry"] = fake_entry(tmp_path, 2, 5000, last_used=9000.0)

    t = threading.Thread(target=writer)
    t.start()
    assert started.wait(30)
    temps = [p for p in tmp_path.iterdir() if p.name.startswith(".tmp-")]
    assert len(temps) == 1 and (temps[0] / "a.npy").is_file()
    assert cache_entries.being_written(tmp_path) >= 5000
    assert make_room(tmp_path, 1, limit=1)  # evict everything it may
    assert not old.exists() and temps[0].is_dir() and (temps[0] / "a.npy").is_file()
    release.set()
    t.join(30)
    monkeypatch.setattr(anatomy_cache, "_write_array", real)
    (e,) = list_entries(tmp_path)
    assert e.path == out["entry"] and e.patient == "Med-RAD lung 2"
    reopened = anatomy_cache.open_entry(tmp_path, "medrad-lung2", e.key)
    assert reopened is not None and int(reopened["a"].values.sum()) == 2 * 5000


# ----------------------------------------------------------------------------------------
# a first preparation says so; a hit does not


def _masks() -> dict[str, np.ndarray]:
    x, y, z = (np.indices((N, N, N)) - N // 2).astype(float)
    return {
        "pleuralBoundary": x**2 + y**2 + z**2 <= 14**2,
        "bronchialTree": ((x + 5) ** 2 + y**2 <= 2**2) & (np.abs(z) <= 10),
        "vessels": ((x - 5) ** 2 + (z + 5) ** 2 <= 2**2) & (np.abs(y) <= 10),
        "fissures": (z == 7) & (x >= 0) & (x <= 8) & (np.abs(y) <= 8),
        "nodule": (x - 4) ** 2 + (y - 3) ** 2 + (z - 1) ** 2 <= 2**2,
    }


@pytest.fixture
def lung(tmp_path) -> Path:
    """A Med-RAD folder with one synthetic lung patient of 32^3 voxels."""
    root = tmp_path / "med-rad"
    folder = root / "Lungs" / "TumorTargetEnvironments" / "Patient1"
    folder.mkdir(parents=True)
    affine = np.eye(4)
    affine[:3, 3] = -N // 2
    for name, mask in _masks().items():
        write_mask_nifti(folder / f"{name}.nii.gz", mask, affine)
    np.savetxt(folder / "start1.txt", np.eye(4))
    np.savetxt(folder / "target.txt", [4.0, 3.0, 1.0])
    return root


def test_the_estimate_scales_the_voxels_of_the_headers(lung):
    folder = lung / "Lungs" / "TumorTargetEnvironments" / "Patient1"
    assert header_voxels(folder / "nodule.nii.gz") == N**3
    assert header_voxels(folder / "start1.txt") is None
    expected = (5 * READ_S_PER_MVOXEL + FIELD_S_PER_MVOXEL + STORE_S_PER_MVOXEL) * N**3 / 1e6
    assert estimate_s([N**3] * 5, N**3) == pytest.approx(expected, rel=1e-12)


def test_a_first_preparation_is_logged_with_its_stages_and_a_hit_says_nothing(
    lung, tmp_path, caplog
):
    cache = tmp_path / "cache"
    with caplog.at_level(logging.INFO, logger="needlekit.io.medrad"):
        first = load_medrad("lung", 1, lung, cache_dir=cache)
    lines = [r.getMessage() for r in caplog.records if r.name == "needlekit.io.medrad"]
    assert lines[0] == (
        "preparing Med-RAD lung 1 (first use; about 1 s, kept in "
        f"{cache}/medrad-lung1-{first.cache_entry.name[-32:][:8]}...)"
    )
    stages = [line.split(": ", 1)[1].split(" (")[0] for line in lines[1:-1]]
    assert stages == ["masks 1/5", "masks 2/5", "masks 3/5", "masks 4/5", "masks 5/5",
                      "free-space field", f"storing {stages[-1].split(' ', 1)[1]}"]  # fmt: skip
    assert lines[-1].startswith("prepared Med-RAD lung 1: done in ") and lines[-1].endswith(" kept")
    (e,) = list_entries(cache)
    assert e.patient == "Med-RAD lung 1" and e.source.endswith("Patient1")
    caplog.clear()
    with caplog.at_level(logging.DEBUG, logger="needlekit.io.medrad"):
        again = load_medrad("lung", 1, lung, cache_dir=cache)
    assert "cache_load_s" in again.timings_s
    assert not [r for r in caplog.records if r.levelno >= logging.INFO]
    assert list_entries(cache)[0].last_used >= e.last_used


class _Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_on_a_terminal_the_line_is_live_on_stderr_and_a_hit_draws_nothing(
    lung, tmp_path, monkeypatch, caplog
):
    cache = tmp_path / "cache"
    term = _Terminal()
    monkeypatch.setattr("sys.stderr", term)
    with caplog.at_level(logging.INFO, logger="needlekit.io.medrad"):
        load_medrad("lung", 1, lung, cache_dir=cache)
    text = term.getvalue()
    assert "preparing Med-RAD lung 1 (first use; about 1 s, kept in " in text
    for stage in ("masks 1/5", "masks 5/5", "free-space field", "storing", "done in"):
        assert stage in text, stage
    assert not [r for r in caplog.records if r.getMessage().startswith("prepar")]  # not twice
    term.seek(0)
    term.truncate()
    load_medrad("lung", 1, lung, cache_dir=cache)
    assert term.getvalue() == ""


@pytest.mark.parametrize(("columns", "lines"), [(400, 1), (80, 2)])
def test_on_a_narrow_terminal_the_stages_go_under_the_opening_words(
    tmp_path, monkeypatch, columns, lines
):
    from needlekit.io import prepare_progress

    monkeypatch.setattr(prepare_progress, "_columns", lambda stream: columns)
    term = _Terminal()
    p = PreparationProgress("Med-RAD lung 1", tmp_path / ("medrad-lung1-" + "0" * 32), 17.4,
                            stream=term)  # fmt: skip
    p("masks 3/5")
    p.done("624 MB kept")
    head = f"preparing Med-RAD lung 1 (first use; about 17 s, kept in {tmp_path}/medrad-lung1-00000000...)"
    last = term.getvalue().split("\r")[-2]  # the line as it is left
    if lines == 1:
        assert last.startswith(f"{head}: done in ") and "\n" not in term.getvalue()[:-1]
    else:
        assert term.getvalue().startswith(head + "\n") and last.startswith("  done in ")
    assert "624 MB kept [00:" in last


def test_progress_without_an_estimate_says_no_time(tmp_path):
    term = _Terminal()
    p = PreparationProgress("Med-RAD liver 2", tmp_path / ("medrad-liver2-" + "0" * 32), None,
                            stream=term)  # fmt: skip
    p("masks 1/3")
    p.done("not stored")
    assert (
        f"preparing Med-RAD liver 2 (first use; kept in {tmp_path}/medrad-liver2-00000000...)"
        in (term.getvalue())
    )


def test_a_new_patient_evicts_the_least_recently_used_entry(lung, tmp_path, caplog):
    cache = tmp_path / "cache"
    old = fake_entry(cache, 7, 50_000, last_used=1000.0)
    newer = fake_entry(cache, 8, 1000, last_used=2000.0)
    probe = load_medrad("lung", 1, lung, cache_dir=tmp_path / "probe")  # its entry's size
    need = sum(p.stat().st_size for p in probe.cache_entry.iterdir())
    # room for it (its estimate is a little larger) and `newer`, not for `old` too
    set_cache_limit(cache, need + _files_bytes(newer) + 25_000)
    with caplog.at_level(logging.WARNING):
        case = load_medrad("lung", 1, lung, cache_dir=cache)
    assert not old.exists() and newer.exists() and case.cache_entry.is_dir()
    (line,) = [r.getMessage() for r in caplog.records if "removed" in r.getMessage()]
    assert "removed Med-RAD lung 7" in line and "lung 8" not in line


def test_a_patient_larger_than_the_limit_is_not_stored(lung, tmp_path, caplog, monkeypatch):
    cache = tmp_path / "cache"
    keep = fake_entry(cache, 7, 1000, last_used=1000.0)
    monkeypatch.setenv(CACHE_LIMIT_ENV, "10kB")
    with caplog.at_level(logging.WARNING):
        case = load_medrad("lung", 1, lung, cache_dir=cache)
    assert case.cache_entry is None and "load_s" in case.timings_s
    assert "is not stored: it is larger than the prepared-anatomy cache's limit of" in caplog.text
    assert keep.exists()  # nothing is removed for what would not fit anyway


def test_a_bad_limit_is_one_error_before_any_preparation(lung, tmp_path, monkeypatch):
    monkeypatch.setenv(CACHE_LIMIT_ENV, "lots")
    with pytest.raises(InvalidInputError, match=r"^NEEDLEKIT_CACHE_LIMIT: expected a size"):
        load_medrad("lung", 1, lung, cache_dir=tmp_path / "cache")
    assert not (tmp_path / "cache").exists()
