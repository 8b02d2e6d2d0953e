"""The prepared-anatomy cache: content keys, atomic entries, corrupt entries rebuilt, and
cached patients that behave bit for bit as freshly built ones.

A small synthetic Med-RAD lung (48^3 voxels of 1 mm, written with nibabel into tmp_path)
stands in for the real data; every test uses a cache folder under tmp_path. The last two
use Med-RAD lung 1 itself (marked ``realdata``: they skip without it), planned and verified
without, into and from a cache once for both.
"""

import contextlib
import io
import json
import logging
import os
import pickle
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np
import pytest

import needlekit
from needlekit.anatomy.voxel import VoxelSDF
from needlekit.io import anatomy_cache, medrad, medrad_cache
from needlekit.io.anatomy_cache import (
    CACHE_DIR_ENV,
    cache_root,
    clear_cache,
    default_cache_dir,
    entry_key,
    file_digest,
    open_entry,
    write_entry,
)
from needlekit.io.cache_entries import CACHE_LIMIT_ENV
from needlekit.io.medrad import load_medrad
from needlekit.io.volumes import write_mask_nifti

N = 48  # voxels per axis, 1 mm, centred on the origin


def _masks() -> dict[str, np.ndarray]:
    x, y, z = (np.indices((N, N, N)) - N // 2).astype(float)
    return {
        "pleuralBoundary": x**2 + y**2 + z**2 <= 20**2,
        "bronchialTree": ((x + 8) ** 2 + y**2 <= 2.5**2) & (np.abs(z) <= 15),
        "vessels": ((x - 8) ** 2 + (z + 8) ** 2 <= 2**2) & (np.abs(y) <= 15),
        "fissures": (z == 10) & (x >= 0) & (x <= 12) & (np.abs(y) <= 12),
        "nodule": (x - 6) ** 2 + (y - 4) ** 2 + (z - 2) ** 2 <= 3**2,
    }


def _affine() -> np.ndarray:
    a = np.eye(4)
    a[:3, 3] = -N // 2
    return a


@pytest.fixture
def patient(tmp_path) -> Path:
    """A Med-RAD folder with one synthetic lung patient (start on the airway wall, pointing
    into the lung; target in the nodule) and a scenario file for it."""
    root = tmp_path / "med-rad"
    folder = root / "Lungs" / "TumorTargetEnvironments" / "Patient1"
    folder.mkdir(parents=True)
    for name, mask in _masks().items():
        write_mask_nifti(folder / f"{name}.nii.gz", mask, _affine())
    start = np.array([[0, 0, 1, -5.5], [1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 0, 1.0]])
    np.savetxt(folder / "start1.txt", start)
    np.savetxt(folder / "target.txt", [6.0, 4.0, 2.0])
    (tmp_path / "scenario.yaml").write_text(
        "version: 1\n"
        "name: synthetic lung\n"
        f"base: {{medrad: {{organ: lung, patient: 1, root: {root}}}}}\n"
        "needle: {diameter_mm: 0.5, r_min_mm: 10, max_length_mm: 60, start_exclusion_mm: 3}\n"
        "start: {case_start: start1}\n"
        "goal: {case_target: target, tolerance_mm: 1.0}\n"
        "planner: {name: rcs_star, time_limit_s: 30}\n"
    )
    return root


def _folder(root: Path) -> Path:
    return root / "Lungs" / "TumorTargetEnvironments" / "Patient1"


def _entries(cache: Path) -> list[Path]:
    return (
        sorted(p for p in cache.iterdir() if not p.name.startswith(".")) if cache.is_dir() else []
    )


def _debris(cache: Path) -> list[Path]:
    return sorted(p for p in cache.iterdir() if p.name.startswith(".")) if cache.is_dir() else []


def _same_sdf(a: VoxelSDF, b: VoxelSDF) -> None:
    assert a.values.dtype == b.values.dtype and a.values.shape == b.values.shape
    assert a.values.tobytes() == b.values.tobytes()
    assert a.affine.tobytes() == b.affine.tobytes()
    assert a.inv_affine.tobytes() == b.inv_affine.tobytes()
    assert (a.error_bound_mm, a.value_error_mm) == (b.error_bound_mm, b.value_error_mm)
    assert a.interpolation_error_mm == b.interpolation_error_mm
    np.testing.assert_array_equal(a.bounds(), b.bounds())
    np.testing.assert_array_equal(a.spacing_mm, b.spacing_mm)


# ----------------------------------------------------------------------------------------
# where


def test_default_cache_dir_follows_the_environment(monkeypatch, tmp_path):
    monkeypatch.setenv(CACHE_DIR_ENV, str(tmp_path / "mine"))
    assert default_cache_dir() == tmp_path / "mine"
    monkeypatch.delenv(CACHE_DIR_ENV)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert default_cache_dir() == tmp_path / "xdg" / "needlekit"
    monkeypatch.delenv("XDG_CACHE_HOME")
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    assert default_cache_dir() == tmp_path / "home" / ".cache" / "needlekit"
    assert cache_root(tmp_path / "given") == tmp_path / "given"


def test_the_test_session_never_uses_the_user_cache():
    home = Path.home() / ".cache" / "needlekit"
    assert default_cache_dir() != home
    assert os.environ[CACHE_DIR_ENV] == str(default_cache_dir())


# ----------------------------------------------------------------------------------------
# keys


def test_the_key_follows_content_not_modification_time(patient, tmp_path):
    cache = tmp_path / "cache"
    first = load_medrad("lung", 1, patient, cache_dir=cache)
    assert "cache_write_s" in first.timings_s
    mask = _folder(patient) / "vessels.nii.gz"
    os.utime(mask, (1e9, 1e9))  # touched, not changed
    again = load_medrad("lung", 1, patient, cache_dir=cache)
    assert again.cache_entry == first.cache_entry and "cache_load_s" in again.timings_s

    changed = _masks()["vessels"].copy()
    changed[20, 24, 16] = True  # one more vessel voxel, at (-4, 0, -8) mm
    write_mask_nifti(mask, changed, _affine())
    other = load_medrad("lung", 1, patient, cache_dir=cache)
    assert other.cache_entry != first.cache_entry and "cache_write_s" in other.timings_s
    assert len(_entries(cache)) == 2
    assert bool(other.scene["vessels"].field.signed_distance([-4.0, 0.0, -8.0]) < 0)


def test_the_key_follows_every_setting(patient, monkeypatch):
    folder = _folder(patient)
    paths = {name: folder / f"{name}.nii.gz" for name in _masks()}
    specs = [(name, medrad.Role.OBSTACLE, "", {}, name) for name in paths]

    def key():
        return entry_key(medrad_cache._cache_inputs("lung", paths, specs, "pleuralBoundary"))

    base = key()
    assert key() == base
    monkeypatch.setattr(medrad_cache, "DEFAULT_MASK_PADDING_MM", 12.0)
    padded = key()
    monkeypatch.setattr(medrad_cache, "MASK_OFFSET_MAX_FRACTION", 0.5)
    offset = key()
    monkeypatch.setattr(needlekit, "__version__", "0.0.0+other")
    version = key()
    monkeypatch.setattr(anatomy_cache, "CACHE_FORMAT_VERSION", 999)
    fmt = key()
    assert len({base, padded, offset, version, fmt}) == 5
    # roles count: the same files with another region give another entry
    assert entry_key(medrad_cache._cache_inputs("lung", paths, specs, "vessels")) != fmt


# ----------------------------------------------------------------------------------------
# the same anatomy, bit for bit


def test_a_cached_patient_equals_a_freshly_built_one(patient, tmp_path):
    cache = tmp_path / "cache"
    fresh = load_medrad("lung", 1, patient, use_cache=False)
    assert fresh.cache_entry is None and not cache.exists()
    cold = load_medrad("lung", 1, patient, cache_dir=cache)
    warm = load_medrad("lung", 1, patient, cache_dir=cache)
    assert cold.cache_entry == warm.cache_entry is not None
    assert "cache_load_s" in warm.timings_s and "load_s" not in warm.timings_s
    rng = np.random.default_rng(0)
    pts = rng.uniform(-30.0, 30.0, (2000, 3))
    for case in (cold, warm):
        assert case.free_space.data.tobytes() == fresh.free_space.data.tobytes()
        assert case.free_space.affine.tobytes() == fresh.free_space.affine.tobytes()
        _same_sdf(case.scene.obstacle_field().base, fresh.scene.obstacle_field().base)
        for s in fresh.scene.structures:
            _same_sdf(case.scene[s.name].field.get(), s.field.get())
            assert case.scene[s.name].role is s.role and case.scene[s.name].metadata == s.metadata
        a = case.scene.signed_distance(pts)
        b = fresh.scene.signed_distance(pts)
        assert all(a[n].tobytes() == b[n].tobytes() for n in b)
        g1 = case.scene.obstacle_field(0.25).gradient(pts)
        g2 = fresh.scene.obstacle_field(0.25).gradient(pts)
        assert g1.tobytes() == g2.tobytes()
        o1, o2 = case.voxel_obstacles(0.5, 0.1), fresh.voxel_obstacles(0.5, 0.1)
        assert o1.occupancy.tobytes() == o2.occupancy.tobytes()
        assert o1.min_distance_mm == o2.min_distance_mm
        start = case.starts[0].world_T_tip[:3, 3]
        assert np.array_equal(
            o1.collides(pts, exclude_near=start, exclusion_mm=3.0),
            o2.collides(pts, exclude_near=start, exclusion_mm=3.0),
        )
    # the structure fields the first run built are in the entry now, read-only
    stored = {p.stem for p in warm.cache_entry.glob("sdf_*.json")}
    assert stored == {"sdf_free_space"} | {f"sdf_{s.name}" for s in fresh.scene.structures}
    assert not warm.scene["vessels"].field.get().values.flags.writeable


def test_no_cache_reads_and_writes_nothing(patient, tmp_path):
    cache = tmp_path / "cache"
    case = load_medrad("lung", 1, patient, cache_dir=cache, use_cache=False)
    assert case.cache_entry is None and case.occupancy is None
    assert not cache.exists()


def _plan_json(path: Path) -> dict:
    def strip(d):
        if isinstance(d, dict):
            return {k: strip(v) for k, v in d.items() if not k.endswith("_s")}
        if isinstance(d, list):
            return [strip(v) for v in d]
        return d

    return strip(json.loads(path.read_text()))


def _plan_and_verify(scenario: Path, out: Path, *cache_flags: str):
    return (*_plan(scenario, out, *cache_flags), *_verify_quiet(scenario, out, *cache_flags))


def _plan(scenario: Path, out: Path, *cache_flags: str):
    from needlekit.cli import main

    with contextlib.redirect_stdout(io.StringIO()):
        code = main(["plan", str(scenario), "--out", str(out), *cache_flags])
    return code, _plan_json(out)


def _verify_quiet(scenario: Path, plan: Path, *cache_flags: str):
    from needlekit.cli import main

    printed = io.StringIO()
    with contextlib.redirect_stdout(printed):
        code = main(["verify", str(scenario), str(plan), "--json", *cache_flags])
    return code, json.loads(printed.getvalue())


def test_plan_and_verify_give_the_same_result_with_and_without_the_cache(patient, tmp_path):
    scenario = tmp_path / "scenario.yaml"
    cache = str(tmp_path / "cache")
    runs = [
        _plan_and_verify(scenario, tmp_path / "none.json", "--no-cache"),
        _plan_and_verify(scenario, tmp_path / "cold.json", "--cache-dir", cache),
        _plan_and_verify(scenario, tmp_path / "warm.json", "--cache-dir", cache),
    ]
    assert runs[0][0] == 0 and runs[0][1]["status"] == "solved" and runs[0][2] == 0
    for run in runs[1:]:
        assert run[0] == runs[0][0] and run[2] == runs[0][2]
        assert run[1] == runs[0][1]
        assert _plan_json_like(run[3]) == _plan_json_like(runs[0][3])
    assert len(_entries(Path(cache))) == 1


@pytest.mark.parametrize("damaged", ["sdf_free_space.npy", "occupancy.npy", "free_space.npy"])
def test_verify_on_a_damaged_cache_says_what_the_masks_say(
    patient, tmp_path, capsys, caplog, damaged
):
    # a few thousand bytes of the prepared fields changed in the middle of the file (where
    # format 1's sampled check did not look): the entry is rebuilt from the masks, with one
    # warning, and plan and verify answer as without any cache
    scenario = tmp_path / "scenario.yaml"
    cache = str(tmp_path / "cache")
    clean = _plan_and_verify(scenario, tmp_path / "none.json", "--no-cache")
    _plan_and_verify(scenario, tmp_path / "cold.json", "--cache-dir", cache)
    (entry,) = _entries(Path(cache))
    path = entry / damaged
    middle = path.stat().st_size // 2
    with open(path, "r+b") as f:
        f.seek(middle)
        block = bytearray(f.read(4000))
        f.seek(middle)
        f.write(bytes(b ^ 0x5A for b in block))
    with caplog.at_level(logging.WARNING, logger="needlekit.io.anatomy_cache"):
        code, report = _verify(capsys, scenario, tmp_path / "none.json", "--cache-dir", cache)
    assert [r.getMessage() for r in caplog.records if "corrupt entry" in r.getMessage()] != []
    assert len(caplog.records) == 1
    assert code == clean[2] and _plan_json_like(report) == _plan_json_like(clean[3])


def _verify(capsys, scenario: Path, plan: Path, *cache_flags: str):
    from needlekit.cli import main

    code = main(["verify", str(scenario), str(plan), "--json", *cache_flags])
    return code, json.loads(capsys.readouterr().out)


def _plan_json_like(report):
    return json.loads(
        json.dumps(report),
        object_hook=lambda d: {k: v for k, v in d.items() if not k.endswith("_s")},
    )


def test_a_scenario_source_carries_the_cache_settings(patient, tmp_path):
    from needlekit.scenario.problems import ScenarioSource

    src = ScenarioSource.of(tmp_path / "scenario.yaml", cache_dir=tmp_path / "c", use_cache=False)
    assert src.cache_dir == str((tmp_path / "c").resolve()) and src.use_cache is False
    again = pickle.loads(pickle.dumps(src))
    assert again == src and hash(again) == hash(src)
    assert ScenarioSource.of(tmp_path / "scenario.yaml").cache_dir is None


# ----------------------------------------------------------------------------------------
# damaged entries are rebuilt, with a warning


def _truncate(path: Path) -> None:
    with open(path, "r+b") as f:
        f.truncate(path.stat().st_size // 2)


def _scribble(path: Path) -> None:
    with open(path, "r+b") as f:
        f.seek(0)
        f.write(b"\x00" * 256)


@pytest.mark.parametrize(
    ("damaged", "how"),
    [
        ("sdf_free_space.npy", _truncate),
        ("occupancy.npy", _scribble),
        ("manifest.json", _truncate),
        ("free_space.json", lambda p: p.write_text('{"not": "a record"}')),
        ("mask_vessels.npy", lambda p: p.unlink()),
    ],
)
def test_a_corrupt_entry_is_rebuilt_with_a_warning(patient, tmp_path, caplog, damaged, how):
    cache = tmp_path / "cache"
    good = load_medrad("lung", 1, patient, cache_dir=cache)
    good.scene["vessels"].field.get()
    reference = good.scene.obstacle_field().base.values.tobytes()
    how(good.cache_entry / damaged)
    with caplog.at_level(logging.WARNING, logger="needlekit.io.anatomy_cache"):
        again = load_medrad("lung", 1, patient, cache_dir=cache)
    assert "corrupt entry" in caplog.text and "rebuilding" in caplog.text
    assert "cache_write_s" in again.timings_s  # built again, and stored again
    assert again.scene.obstacle_field().base.values.tobytes() == reference
    assert _entries(cache) == [again.cache_entry] and not _debris(cache)
    third = load_medrad("lung", 1, patient, cache_dir=cache)
    assert "cache_load_s" in third.timings_s


def test_a_corrupt_structure_field_is_rebuilt(patient, tmp_path, caplog):
    cache = tmp_path / "cache"
    first = load_medrad("lung", 1, patient, cache_dir=cache)
    reference = first.scene["vessels"].field.get().values.tobytes()
    _truncate(first.cache_entry / "sdf_vessels.npy")
    again = load_medrad("lung", 1, patient, cache_dir=cache)
    assert "cache_load_s" in again.timings_s  # the entry itself is sound
    with caplog.at_level(logging.WARNING, logger="needlekit.io.anatomy_cache"):
        rebuilt = again.scene["vessels"].field.get()
    assert "rebuilding" in caplog.text
    assert rebuilt.values.tobytes() == reference
    third = load_medrad("lung", 1, patient, cache_dir=cache)
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="needlekit.io.anatomy_cache"):
        assert third.scene["vessels"].field.get().values.tobytes() == reference
    assert caplog.text == ""


# ----------------------------------------------------------------------------------------
# atomic writes and concurrent writers


def test_a_write_that_fails_midway_leaves_no_entry_and_no_debris(patient, tmp_path, monkeypatch):
    cache = tmp_path / "cache"
    real = anatomy_cache._write_array
    calls = []

    def failing(folder, name, values, meta, secret):
        calls.append(name)
        if len(calls) == 3:
            raise KeyboardInterrupt  # the process is stopped while it writes
        real(folder, name, values, meta, secret)

    monkeypatch.setattr(anatomy_cache, "_write_array", failing)
    with pytest.raises(KeyboardInterrupt):
        load_medrad("lung", 1, patient, cache_dir=cache)
    assert cache.is_dir() and not _entries(cache) and not _debris(cache)


def test_an_unwritable_cache_is_skipped_with_a_warning(patient, tmp_path, caplog):
    blocked = tmp_path / "a file"
    blocked.write_text("not a folder")
    with caplog.at_level(logging.WARNING, logger="needlekit.io.medrad"):
        case = load_medrad("lung", 1, patient, cache_dir=blocked / "cache")
    assert "going on without it" in caplog.text
    assert case.cache_entry is None and "load_s" in case.timings_s
    fresh = load_medrad("lung", 1, patient, use_cache=False)
    _same_sdf(case.scene.obstacle_field().base, fresh.scene.obstacle_field().base)


def test_without_a_usable_key_the_cache_is_left_alone_with_a_warning(
    patient, tmp_path, monkeypatch, caplog
):
    from needlekit.io.cache_key import CACHE_KEY_ENV, KEY_BYTES

    cache = tmp_path / "cache"
    signed = load_medrad("lung", 1, patient, cache_dir=cache).cache_entry
    bad = tmp_path / "cache.key"
    bad.write_bytes(b"\x00" * KEY_BYTES)
    bad.chmod(0o644)  # anyone could read it, and sign entries with it
    monkeypatch.setenv(CACHE_KEY_ENV, str(bad))
    with caplog.at_level(logging.WARNING, logger="needlekit.io.medrad"):
        case = load_medrad("lung", 1, patient, cache_dir=cache)
    assert case.cache_entry is None and "cache_load_s" not in case.timings_s
    lines = caplog.text.strip().splitlines()
    assert len(lines) == 1 and "prepared-anatomy cache unavailable" in lines[0]
    assert "mode 644" in lines[0] and "going on without it" in lines[0]
    assert _entries(cache) == [signed]  # nothing removed: nothing could be checked
    fresh = load_medrad("lung", 1, patient, use_cache=False)
    _same_sdf(case.scene.obstacle_field().base, fresh.scene.obstacle_field().base)


def _arrays(seed: int = 0):
    rng = np.random.default_rng(seed)
    return {
        "a": (rng.normal(size=(30, 20, 10)).astype(np.float32), {"what": "values"}),
        "b": (rng.random((5, 6, 7)) < 0.5, {"affine": np.eye(4).tolist()}),
    }


def test_write_entry_stores_and_reopens_arrays_exactly(tmp_path):
    arrays = _arrays()
    key = entry_key({"test": 1})
    entry = write_entry(tmp_path, "test", key, {"test": 1}, arrays)
    assert entry.path == tmp_path / f"test-{key}"
    for name, (values, meta) in arrays.items():
        assert entry[name].values.tobytes() == values.tobytes() and entry[name].meta == meta
        assert not entry[name].values.flags.writeable
    again = open_entry(tmp_path, "test", key)
    assert again is not None and again["a"].values.tobytes() == arrays["a"][0].tobytes()
    assert open_entry(tmp_path, "test", entry_key({"test": 2})) is None
    assert again.get("missing") is None
    assert again.put("c", np.arange(5.0), {"n": 5}) is not None
    assert open_entry(tmp_path, "test", key).get("c").values.tolist() == [0, 1, 2, 3, 4]


def _flip(path: Path, offset: int) -> None:
    with open(path, "r+b") as f:
        f.seek(offset)
        byte = f.read(1)
        f.seek(offset)
        f.write(bytes([byte[0] ^ 0x01]))


@pytest.mark.parametrize("where", ["header", "middle", "last"])
def test_any_changed_byte_is_found(tmp_path, caplog, where):
    # one bit of one byte, anywhere: in the .npy header, in the middle of the values (off
    # the grid of blocks the sampled check of format 1 read), or the very last byte
    values = np.zeros((64, 64, 64), np.float32)
    key = entry_key({"test": "any byte"})
    entry = write_entry(tmp_path, "test", key, {}, {"a": (values, {})})
    path = entry.path / "a.npy"
    del entry
    size = path.stat().st_size
    offset = {"header": 20, "middle": size // 2 + 1234, "last": size - 1}[where]
    _flip(path, offset)
    with caplog.at_level(logging.WARNING, logger="needlekit.io.anatomy_cache"):
        assert open_entry(tmp_path, "test", key) is None
    assert "corrupt entry" in caplog.text and not (tmp_path / f"test-{key}").exists()
    assert len(caplog.records) == 1


def _forge(entry_path: Path, name: str, values: np.ndarray, secret: bytes) -> None:
    """Replace an array and rewrite its record consistently, signed with ``secret``."""
    from needlekit.io.cache_key import file_mac, mac

    npy = entry_path / f"{name}.npy"
    with open(npy, "wb") as f:
        np.lib.format.write_array(f, values, allow_pickle=False)
    rec = json.loads((entry_path / f"{name}.json").read_text())
    rec.update(bytes=npy.stat().st_size, blake3=file_mac(secret, npy), shape=list(values.shape))
    body = {k: v for k, v in rec.items() if k != "mac"}
    rec["mac"] = mac(secret, json.dumps(body, sort_keys=True, separators=(",", ":")).encode())
    (entry_path / f"{name}.json").write_text(json.dumps(rec))


def test_a_record_rewritten_consistently_without_the_key_is_refused(tmp_path, caplog):
    from needlekit.io.cache_key import cache_key

    key = entry_key({"test": "forged"})
    values = np.zeros((8, 8, 8), np.float32)
    forged = np.full_like(values, 50.0)  # "everything is far from every obstacle"
    path = write_entry(tmp_path, "test", key, {}, {"a": (values, {})}).path
    # someone without the user's key: a record that is right in every field but its signature
    _forge(path, "a", forged, b"\x07" * 32)
    with caplog.at_level(logging.WARNING, logger="needlekit.io.anatomy_cache"):
        assert open_entry(tmp_path, "test", key) is None
    assert "signature does not match" in caplog.text
    # the same rewrite signed with the user's key passes: the key is what decides
    path = write_entry(tmp_path, "test", key, {}, {"a": (values, {})}).path
    _forge(path, "a", forged, cache_key())
    assert open_entry(tmp_path, "test", key)["a"].values.tolist() == forged.tolist()


def test_a_writer_that_loses_the_race_uses_the_winners_entry(tmp_path, monkeypatch):
    key = entry_key({"race": 1})
    winner = {}
    real_rename = os.rename

    def rename(src, dst):
        if Path(dst).name == f"test-{key}" and not winner:
            # another process places the same entry just before this one
            winner["started"] = True
            winner["entry"] = write_entry(tmp_path, "test", key, {}, _arrays())
        return real_rename(src, dst)

    monkeypatch.setattr(anatomy_cache.os, "rename", rename)
    entry = write_entry(tmp_path, "test", key, {}, _arrays())
    assert entry.path == winner["entry"].path
    assert entry["a"].values.tobytes() == _arrays()["a"][0].tobytes()
    assert _entries(tmp_path) == [entry.path] and not _debris(tmp_path)


def _write_in_a_process(args):
    root, key = args
    entry = write_entry(root, "test", key, {}, _arrays())
    return entry["a"].values.tobytes() == _arrays()["a"][0].tobytes()


def test_processes_writing_the_same_entry_do_not_corrupt_it(tmp_path):
    key = entry_key({"race": 2})
    with ProcessPoolExecutor(2) as pool:
        ok = list(pool.map(_write_in_a_process, [(str(tmp_path), key)] * 6))
    assert all(ok)
    assert _entries(tmp_path) == [tmp_path / f"test-{key}"] and not _debris(tmp_path)
    assert open_entry(tmp_path, "test", key) is not None


def test_a_forked_child_hashes_after_its_parent_started_the_hash_thread_pool(tmp_path):
    """BLAKE3's thread pool does not survive a fork: a child forked after its parent hashed
    on many threads waited forever for the pool's threads (measured: the test above hung
    for 12 minutes under load, its workers blocked in ``file_mac``). A forked child hashes
    on one thread, to the same digests."""
    import multiprocessing

    from needlekit.io.cache_key import file_mac

    data = tmp_path / "big.bin"
    data.write_bytes(np.random.default_rng(0).bytes(8 << 20))  # hashed on many threads
    key = bytes(range(32))
    want = [file_mac(key, data), file_digest(data)]  # the parent starts the pool

    def child():
        (tmp_path / "child.json").write_text(json.dumps([file_mac(key, data), file_digest(data)]))

    proc = multiprocessing.get_context("fork").Process(target=child)
    proc.start()
    proc.join(120)
    hung = proc.is_alive()
    if hung:
        proc.kill()
        proc.join()
    assert not hung and proc.exitcode == 0
    assert json.loads((tmp_path / "child.json").read_text()) == want


def test_every_multi_threaded_hash_takes_the_fork_safe_thread_count():
    """The kind, not the case: a hash on many threads anywhere in needlekit asks
    ``hash_threads()`` how many it may use."""
    src = Path(needlekit.__file__).parent
    calls = [(f.relative_to(src), line) for f in src.rglob("*.py")
             for line in f.read_text().splitlines() if "max_threads=" in line]  # fmt: skip
    assert calls and all("max_threads=hash_threads()" in line for _, line in calls), calls


def test_stale_temporary_folders_are_removed_and_clear_cache_empties(tmp_path):
    stale = tmp_path / ".tmp-test-crashed"
    stale.mkdir()
    (stale / "a.npy").write_bytes(b"half")
    os.utime(stale, (0, 0))
    fresh = tmp_path / ".tmp-test-live"
    fresh.mkdir()
    write_entry(tmp_path, "test", entry_key({"x": 1}), {}, _arrays())
    assert not stale.exists() and fresh.exists()
    write_entry(tmp_path, "test", entry_key({"x": 2}), {}, _arrays())
    assert clear_cache(tmp_path) == 2
    assert list(tmp_path.iterdir()) == []


def test_values_that_cannot_be_stored_raise_and_leave_nothing(tmp_path):
    bad = {"ok": _arrays()["a"], "bad": (np.array([object()]), {})}
    with pytest.raises(ValueError):
        write_entry(tmp_path, "test", entry_key({"bad": 1}), {}, bad)
    assert list(tmp_path.iterdir()) == []


# ----------------------------------------------------------------------------------------
# the real data: Med-RAD lung 1 (skips, saying why, without the data: tests/conftest.py)

#: Lung 1's grid (497 x 331 x 512 voxels), five masks on it: the estimate's arithmetic.
LUNG1_VOXELS = 497 * 331 * 512


class _Records(logging.Handler):
    def __init__(self) -> None:
        super().__init__(logging.DEBUG)
        self.records: list[logging.LogRecord] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.records.append(record)


@pytest.fixture(scope="module")
def lung1_through_the_cache(medrad_dir, tmp_path_factory):
    """examples/medrad_lung1.yaml planned and verified three times, once per module:
    without the cache, into an empty cache (``cold``: the plan prepares lung 1 and stores
    it; what ``needlekit.io.medrad`` logs meanwhile at INFO is kept) and from that cache
    (``warm``). Returns the cache folder, those log records and the three runs."""
    d = tmp_path_factory.mktemp("lung1-cache")
    scenario = Path(__file__).resolve().parents[2] / "examples" / "medrad_lung1.yaml"
    cache = d / "cache"
    logger = logging.getLogger("needlekit.io.medrad")
    with pytest.MonkeyPatch.context() as mp:
        mp.delenv(CACHE_LIMIT_ENV, raising=False)
        none = _plan_and_verify(scenario, d / "none.json", "--no-cache")
        handler, level = _Records(), logger.level
        logger.addHandler(handler)
        logger.setLevel(logging.INFO)
        try:
            cold_plan = _plan(scenario, d / "cold.json", "--cache-dir", str(cache))
        finally:
            logger.removeHandler(handler)
            logger.setLevel(level)
        cold = (*cold_plan, *_verify_quiet(scenario, d / "cold.json", "--cache-dir", str(cache)))
        warm = _plan_and_verify(scenario, d / "warm.json", "--cache-dir", str(cache))
    return cache, handler.records, [none, cold, warm]


@pytest.mark.realdata
@pytest.mark.slow
def test_lung1_plans_and_verifies_the_same_through_the_cache(lung1_through_the_cache):
    _, _, runs = lung1_through_the_cache
    # RCS* certifies its plan (5 iterations, ~40 ms): the search ends each run, not the clock
    assert runs[0][1]["status"] == "solved" and runs[0][1]["stats"]["certified"]
    assert runs[0][1]["stats"]["reason"] == "search space exhausted"
    assert runs[0][1]["cost_mm"] == pytest.approx(58.25732192952233, abs=1e-6)
    for run in runs[1:]:
        assert run[0] == runs[0][0] and run[2] == runs[0][2]
        assert run[1] == runs[0][1]
        assert _plan_json_like(run[3]) == _plan_json_like(runs[0][3])


@pytest.mark.realdata
@pytest.mark.slow
def test_lung1_first_preparation_says_so_and_a_hit_does_not(lung1_through_the_cache, medrad_dir,
                                                            caplog, capsys, monkeypatch):  # fmt: skip
    """The first preparation of Med-RAD lung 1 into an empty cache (the cold plan above)
    says what it does, with the estimate from the masks' voxels; a later load from the
    cache says nothing; ``cache list`` then shows the entry."""
    from needlekit.cli import main
    from needlekit.io.prepare_progress import estimate_s

    cache, records, _ = lung1_through_the_cache
    monkeypatch.delenv(CACHE_LIMIT_ENV, raising=False)
    lines = [r.getMessage() for r in records if r.name == "needlekit.io.medrad"]
    with caplog.at_level(logging.INFO, logger="needlekit.io.medrad"):
        again = load_medrad("lung", 1, medrad_dir, cache_dir=cache)
    assert "cache_load_s" in again.timings_s and caplog.records == []
    # one entry: the one the first preparation stored, and the load found
    assert _entries(cache) == [again.cache_entry]
    seconds = round(estimate_s([LUNG1_VOXELS] * 5, LUNG1_VOXELS))
    assert seconds == 17
    assert lines[0] == (
        f"preparing Med-RAD lung 1 (first use; about {seconds} s, kept in "
        f"{cache}/medrad-lung1-{again.cache_entry.name[-32:][:8]}...)"
    )
    stages = [line.split(": ", 1)[1].split(" (")[0] for line in lines[1:-1]]
    assert stages[:6] == ["masks 1/5", "masks 2/5", "masks 3/5", "masks 4/5", "masks 5/5",
                          "free-space field"]  # fmt: skip
    assert stages[6].startswith("storing ") and lines[-1].endswith(" kept")
    capsys.readouterr()
    assert main(["cache", "list", "--cache-dir", str(cache), "--json"]) == 0
    (entry,) = json.loads(capsys.readouterr().out)["entries"]
    on_disk = sum(p.stat().st_size for p in again.cache_entry.iterdir())
    assert entry["patient"] == "Med-RAD lung 1" and entry["bytes"] == on_disk
    assert entry["source"].endswith("Patient1")
