"""``needlekit cache list|clear|limit`` on a cache folder of small entries whose sizes and
last uses are known (written with :func:`needlekit.io.anatomy_cache.write_entry`)."""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
import pytest

from needlekit.cli import main
from needlekit.io.anatomy_cache import entry_key, write_entry
from needlekit.io.cache_entries import CACHE_LIMIT_ENV, list_entries, usage_record

DAY = 86400.0


@pytest.fixture(autouse=True)
def _no_limit_from_outside(monkeypatch):
    monkeypatch.delenv(CACHE_LIMIT_ENV, raising=False)


def _entry(root: Path, organ: str, patient: int, n_bytes: int, last_used: float) -> Path:
    label = f"medrad-{organ}{patient}"
    key = entry_key({"organ": organ, "patient": patient})
    usage = usage_record(f"Med-RAD {organ} {patient}", f"/data/{organ}/{patient}", now=last_used)
    arrays = {"a": (np.zeros(n_bytes, dtype=np.uint8), {})}
    return write_entry(root, label, key, {}, arrays, usage).path


def _size(path: Path) -> int:
    return sum(p.stat().st_size for p in path.iterdir() if p.is_file())


@pytest.fixture
def cache(tmp_path) -> dict[str, Path]:
    """Three entries: lung 1 used 10 days ago (2 MB), lung 2 an hour ago (1 MB), liver 3
    40 days ago (3 MB)."""
    now = time.time()
    root = tmp_path / "cache"
    return {
        "root": root,
        "lung1": _entry(root, "lung", 1, 2_000_000, now - 10 * DAY),
        "lung2": _entry(root, "lung", 2, 1_000_000, now - 3600),
        "liver3": _entry(root, "liver", 3, 3_000_000, now - 40 * DAY),
    }


def _run(capsys, *argv: str) -> tuple[int, str, str]:
    capsys.readouterr()
    code = main(list(argv))
    out = capsys.readouterr()
    return code, out.out, out.err


def test_list_shows_each_entry_the_total_and_the_limit(cache, capsys):
    root = cache["root"]
    code, out, err = _run(capsys, "cache", "list", "--cache-dir", str(root))
    assert code == 0 and err == ""
    lines = out.splitlines()
    assert lines[0] == f"prepared-anatomy cache: {root}"
    assert lines[1].split() == ["patient", "size_MB", "age", "last_used", "location"]
    rows = [line.split("  ") for line in lines[3:6]]
    rows = [[c.strip() for c in r if c.strip()] for r in rows]
    assert rows == [
        ["Med-RAD lung 2", "1", "1 h", "1 h ago", str(cache["lung2"])],
        ["Med-RAD lung 1", "2", "10 d", "10 d ago", str(cache["lung1"])],
        ["Med-RAD liver 3", "3", "40 d", "40 d ago", str(cache["liver3"])],
    ]
    total = sum(_size(cache[k]) for k in ("lung1", "lung2", "liver3"))
    assert total // 1_000_000 == 6
    assert lines[6] == "total: 3 entries, 6 MB, 0 % of the limit of 10 GB (the default)"


def test_list_json_gives_the_exact_bytes(cache, capsys):
    code, out, _ = _run(capsys, "cache", "list", "--cache-dir", str(cache["root"]), "--json")
    data = json.loads(out)
    assert code == 0 and data["limit_bytes"] == 10**10 and data["limit_source"] == "default"
    assert [e["patient"] for e in data["entries"]] == [
        "Med-RAD lung 2", "Med-RAD lung 1", "Med-RAD liver 3"]  # fmt: skip
    assert [e["bytes"] for e in data["entries"]] == [
        _size(cache["lung2"]), _size(cache["lung1"]), _size(cache["liver3"])]  # fmt: skip
    assert data["total_bytes"] == sum(e["bytes"] for e in data["entries"])
    assert data["entries"][0]["source"] == "/data/lung/2"


def test_an_empty_or_missing_cache_lists_nothing(tmp_path, capsys):
    code, out, _ = _run(capsys, "cache", "list", "--cache-dir", str(tmp_path / "none"))
    assert code == 0 and out.splitlines()[1:] == [
        "no entries", "total: 0 entries, 0 kB, 0 % of the limit of 10 GB (the default)"]  # fmt: skip


def test_clear_one_patient_by_any_of_its_names(cache, capsys):
    root = str(cache["root"])
    code, out, _ = _run(capsys, "cache", "clear", "--cache-dir", root, "--patient", "lung 1")
    assert code == 0 and not cache["lung1"].exists() and cache["lung2"].exists()
    assert out.splitlines() == [
        f"removed 1 entry (2 MB) from {root}", f"  Med-RAD lung 1: {cache['lung1']}"]  # fmt: skip
    key = cache["lung2"].name[-32:]
    code, out, _ = _run(capsys, "cache", "clear", "--cache-dir", root, "--patient", key[:8])
    assert code == 0 and not cache["lung2"].exists() and cache["liver3"].exists()
    code, out, _ = _run(capsys, "cache", "clear", "--cache-dir", root, "--patient", "medrad-liver3")
    assert code == 0 and list_entries(root) == []


def test_clear_older_than_removes_only_entries_not_used_since(cache, capsys):
    root = str(cache["root"])
    code, out, _ = _run(capsys, "cache", "clear", "--cache-dir", root, "--older-than-days", "30")
    assert code == 0 and out.startswith("removed 1 entry (3 MB)")
    assert [e.path for e in list_entries(root)] == [cache["lung2"], cache["lung1"]]
    code, out, _ = _run(capsys, "cache", "clear", "--cache-dir", root, "--older-than-days",
                        "5", "--patient", "lung2")  # fmt: skip
    assert code == 0 and out.startswith("removed 0 entries (0 kB)")
    code, out, _ = _run(capsys, "cache", "clear", "--cache-dir", root)
    assert code == 0 and out.startswith("removed 2 entries (3 MB)") and list_entries(root) == []


def test_clear_leaves_an_entry_being_written_alone(cache, capsys):
    root = cache["root"]
    temp = root / ".tmp-medrad-lung4-abc"
    temp.mkdir()
    (temp / "free_space.npy").write_bytes(b"\0" * 1000)
    code, out, _ = _run(capsys, "cache", "clear", "--cache-dir", str(root))
    assert code == 0 and out.startswith("removed 3 entries") and temp.is_dir()


def test_a_patient_not_held_is_one_error_naming_those_held(cache, capsys):
    root = cache["root"]
    code, out, err = _run(capsys, "cache", "clear", "--cache-dir", str(root), "--patient", "lung9")
    assert (
        code == 2
        and out == ""
        and err
        == (
            f"error: --patient: expected a patient or entry key held in {root} (have: "
            "Med-RAD liver 3, Med-RAD lung 1, Med-RAD lung 2), got 'lung9'\n"
        )
    )
    assert len(list_entries(root)) == 3


def test_limit_is_shown_stored_and_applied_at_once(cache, capsys, monkeypatch):
    root = cache["root"]
    code, out, _ = _run(capsys, "cache", "limit", "--cache-dir", str(root))
    assert code == 0 and out == "limit of 10 GB (the default)\n"
    # room for lung 2 and lung 1 (3 MB and their records), not liver 3, the least recently used
    limit = _size(cache["lung1"]) + _size(cache["lung2"]) + 1000
    code, out, err = _run(capsys, "cache", "limit", f"{limit}B", "--cache-dir", str(root))
    assert (
        code == 0
        and err == ""
        and out.splitlines()[:2]
        == [
            f"stored in {root / 'limit.json'}",
            f"limit of 3 MB (from {root / 'limit.json'})",
        ]
    )
    assert out.splitlines()[2].startswith(
        "prepared-anatomy cache over its limit of 3 MB: removed Med-RAD liver 3 (3 MB, last used "
    )
    assert json.loads((root / "limit.json").read_text()) == {"limit_bytes": limit}
    assert [e.path for e in list_entries(root)] == [cache["lung2"], cache["lung1"]]
    monkeypatch.setenv(CACHE_LIMIT_ENV, "1GB")
    code, out, _ = _run(capsys, "cache", "limit", "--cache-dir", str(root))
    assert out == "limit of 1 GB (from $NEEDLEKIT_CACHE_LIMIT)\n"
    monkeypatch.delenv(CACHE_LIMIT_ENV)
    code, out, _ = _run(capsys, "cache", "limit", "default", "--cache-dir", str(root))
    assert code == 0 and out.splitlines() == [
        f"removed {root / 'limit.json'}", "limit of 10 GB (the default)"]  # fmt: skip
    assert not (root / "limit.json").exists()


def test_a_bad_limit_from_the_environment_is_one_error(cache, capsys, monkeypatch):
    monkeypatch.setenv(CACHE_LIMIT_ENV, "banana")
    code, out, err = _run(capsys, "cache", "list", "--cache-dir", str(cache["root"]))
    assert (
        code == 2
        and out == ""
        and err
        == (
            "error: NEEDLEKIT_CACHE_LIMIT: expected a size such as 10GB, 500MB or 1.5TB "
            "(up to 1000TB), got 'banana'\n"
        )
    )


@pytest.mark.parametrize(
    ("argv", "line"),
    [
        (["cache", "limit", "banana"], "error: argument SIZE: expected a size such as 10GB, "
         "500MB or 1.5TB (up to 1000TB), got 'banana'"),
        (["cache", "clear", "--older-than-days", "-1"],
         "error: argument --older-than-days: expected a number in [0, 36500] days, got '-1'"),
        (["cache", "clear", "--older-than-days", "nan"],
         "error: argument --older-than-days: expected a number in [0, 36500] days, got 'nan'"),
    ],
)  # fmt: skip
def test_bad_arguments_are_one_line_and_exit_2(argv, line, capsys):
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2 and capsys.readouterr().err == line + "\n"
