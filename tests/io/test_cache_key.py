"""The per-user key that signs the prepared-anatomy cache: made once, private, refused when
others could read or change it, the same for processes that start together."""

from __future__ import annotations

import os
import stat
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import pytest

from needlekit.io.cache_key import (
    CACHE_KEY_ENV,
    KEY_BYTES,
    CacheKeyError,
    cache_key,
    cache_key_path,
    file_mac,
    mac,
)


def test_the_session_never_uses_the_users_key():
    assert os.environ.get(CACHE_KEY_ENV)
    assert not str(cache_key_path()).startswith(str(Path.home() / ".config"))


def test_the_default_place_follows_xdg(monkeypatch, tmp_path):
    monkeypatch.delenv(CACHE_KEY_ENV)
    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path / "cfg"))
    assert cache_key_path() == tmp_path / "cfg" / "needlekit" / "cache.key"
    monkeypatch.delenv("XDG_CONFIG_HOME")
    assert cache_key_path() == Path.home() / ".config" / "needlekit" / "cache.key"


def test_a_key_is_made_once_private_and_then_read_back(tmp_path):
    path = tmp_path / "cfg" / "needlekit" / "cache.key"
    key = cache_key(path)
    assert len(key) == KEY_BYTES and cache_key(path) == key
    assert stat.S_IMODE(path.stat().st_mode) == 0o600
    assert stat.S_IMODE(path.parent.stat().st_mode) == 0o700
    assert [p.name for p in path.parent.iterdir()] == ["cache.key"]  # no temporary left
    assert cache_key(tmp_path / "other.key") != key


@pytest.mark.parametrize(
    ("spoil", "says"),
    [
        (lambda p: p.chmod(0o644), "others may read or change it (mode 644); it must be 600"),
        (lambda p: p.chmod(0o620), "others may read or change it (mode 620)"),
        (lambda p: p.write_bytes(b"short"), "holds 5 bytes, not a needlekit key"),
        (lambda p: (p.unlink(), p.mkdir()), "not a regular file"),
    ],
    ids=["readable", "writable", "short", "folder"],
)
def test_an_unsafe_key_file_is_refused(tmp_path, spoil, says):
    path = tmp_path / "cache.key"
    cache_key(path)
    spoil(path)
    with pytest.raises(CacheKeyError, match=r"cache key .*cache\.key: ") as err:
        cache_key(path)
    assert says in str(err.value)


def test_a_link_to_a_key_is_not_followed(tmp_path):
    real = tmp_path / "real.key"
    cache_key(real)
    link = tmp_path / "cache.key"
    link.symlink_to(real)
    with pytest.raises(CacheKeyError, match=r"cache\.key"):
        cache_key(link)


def test_an_unmakeable_key_is_refused_in_one_line(tmp_path):
    blocked = tmp_path / "a file"
    blocked.write_text("not a folder")
    with pytest.raises(CacheKeyError, match=r"cache\.key: Not a directory") as err:
        cache_key(blocked / "cache.key")
    assert "\n" not in str(err.value)


def _key_in_a_process(path):
    return cache_key(path)


def test_processes_that_make_the_key_together_agree(tmp_path):
    path = tmp_path / "cache.key"
    with ProcessPoolExecutor(2) as pool:
        keys = set(pool.map(_key_in_a_process, [path] * 8))
    assert keys == {cache_key(path)}


def test_keyed_hashes_depend_on_the_key_and_every_byte(tmp_path):
    a, b = b"\x01" * 32, b"\x02" * 32
    f = tmp_path / "data.bin"
    f.write_bytes(bytes(range(256)) * 4096)
    assert file_mac(a, f) == mac(a, f.read_bytes()) != file_mac(b, f)
    data = bytearray(f.read_bytes())
    data[123_457] ^= 0x80
    f.write_bytes(bytes(data))
    assert file_mac(a, f) != mac(a, bytes(range(256)) * 4096)
    empty = tmp_path / "empty.bin"
    empty.write_bytes(b"")
    assert file_mac(a, empty) == mac(a, b"")
