"""The per-user secret that signs the prepared-anatomy cache, and the keyed hashes made with it.

Every record, manifest and array file of a cache entry carries a keyed BLAKE3 hash
(:func:`mac`, :func:`file_mac`) under a secret of 32 random bytes that only the user who
made the cache can read. Without the secret nobody can write a record that passes: a
record rewritten consistently by someone else (a new array and a new digest beside it) fails
like a changed byte does.

Where
    ``$NEEDLEKIT_CACHE_KEY_FILE``, else ``$XDG_CONFIG_HOME/needlekit/cache.key``, else
    ``~/.config/needlekit/cache.key``: beside the user's settings, not in the cache folder,
    so a cache folder shared with others (or copied from elsewhere) never carries it. A
    cluster whose workers share a home folder shares the key; workers with homes of their
    own each build and sign their own entries.

Made once
    When missing it is made with mode 0600 in a folder of mode 0700 and placed with one
    atomic link, so two processes that start together agree on one key. One that is not a
    regular file, belongs to another user, can be read or written by others, or does not
    hold 32 bytes is refused (:class:`CacheKeyError`, an ``OSError``): the caller goes on
    without the cache and says why in one line. Deleting the file invalidates every entry
    signed with it (they are rebuilt when next used).
"""

from __future__ import annotations

import hmac
import os
import secrets
import stat
import tempfile
from pathlib import Path

import blake3

__all__ = [
    "CACHE_KEY_ENV",
    "KEY_BYTES",
    "CacheKeyError",
    "cache_key",
    "cache_key_path",
    "file_mac",
    "hash_threads",
    "mac",
    "same_mac",
]

#: Environment variable naming the key file (tests, clusters with a shared settings folder).
CACHE_KEY_ENV: str = "NEEDLEKIT_CACHE_KEY_FILE"

#: Size of the secret: BLAKE3's key size.
KEY_BYTES: int = 32


class CacheKeyError(OSError):
    """The key file cannot be read or made safely; the cache is not used."""


def cache_key_path() -> Path:
    """Where the key is kept: ``$NEEDLEKIT_CACHE_KEY_FILE``, else
    ``$XDG_CONFIG_HOME/needlekit/cache.key``, else ``~/.config/needlekit/cache.key``.

    Returns
    -------
    Path
    """
    env = os.environ.get(CACHE_KEY_ENV)
    if env:
        return Path(env).expanduser()
    xdg = os.environ.get("XDG_CONFIG_HOME")
    base = Path(xdg).expanduser() if xdg else Path.home() / ".config"
    return base / "needlekit" / "cache.key"


def cache_key(path: str | os.PathLike | None = None) -> bytes:
    """The secret, read from its file (made there first when missing).

    Parameters
    ----------
    path : path-like, optional
        The key file (default :func:`cache_key_path`).

    Returns
    -------
    bytes
        :data:`KEY_BYTES` bytes.

    Raises
    ------
    CacheKeyError
        The file is not a regular file of this user's with mode 0600 (or stricter) holding
        32 bytes, or it cannot be made.
    """
    p = Path(path) if path is not None else cache_key_path()
    try:
        return _read(p)
    except FileNotFoundError:
        pass
    _make(p)
    try:
        return _read(p)
    except FileNotFoundError:
        raise CacheKeyError(f"cache key {p}: removed while it was being made") from None


def _read(p: Path) -> bytes:
    try:
        fd = os.open(p, os.O_RDONLY | getattr(os, "O_NOFOLLOW", 0))
    except FileNotFoundError:
        raise
    except OSError as exc:
        raise CacheKeyError(f"cache key {p}: {exc.strerror or exc}") from None
    st = os.fstat(fd)
    if not stat.S_ISREG(st.st_mode):
        os.close(fd)
        raise CacheKeyError(f"cache key {p}: not a regular file")
    with os.fdopen(fd, "rb") as f:
        if hasattr(os, "getuid") and st.st_uid != os.getuid():
            raise CacheKeyError(f"cache key {p}: belongs to another user")
        if st.st_mode & 0o077:
            raise CacheKeyError(
                f"cache key {p}: others may read or change it (mode {stat.S_IMODE(st.st_mode):o}); "
                "it must be 600"
            )
        data = f.read(KEY_BYTES + 1)
    if len(data) != KEY_BYTES:
        raise CacheKeyError(f"cache key {p}: holds {len(data)} bytes, not a needlekit key")
    return data


def _make(p: Path) -> None:
    """Write a new key beside ``p`` and link it into place (atomic; the first wins)."""
    try:
        p.parent.mkdir(mode=0o700, parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=".cache.key.", dir=p.parent)  # mode 0600
    except OSError as exc:
        raise CacheKeyError(f"cache key {p}: cannot be made ({exc.strerror or exc})") from None
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(secrets.token_bytes(KEY_BYTES))
            f.flush()
            os.fsync(f.fileno())
        try:
            os.link(tmp, p)
        except FileExistsError:
            pass  # another process made one first: use it
        except OSError as exc:
            raise CacheKeyError(
                f"cache key {p}: cannot be placed ({exc.strerror or exc})"
            ) from None
    finally:
        try:
            os.unlink(tmp)
        except OSError:
            pass


def mac(key: bytes, data: bytes) -> str:
    """Keyed BLAKE3 (256-bit, hex) of bytes.

    Parameters
    ----------
    key : bytes
        :data:`KEY_BYTES` bytes.
    data : bytes

    Returns
    -------
    str
    """
    return blake3.blake3(data, key=key).hexdigest()


#: Set in a process forked from another: BLAKE3's thread pool (Rayon's, started by the first
#: hash on many threads) does not survive a fork, and a child hashing on it would wait for
#: its threads forever. A forked child hashes on one thread instead.
_FORKED: list[bool] = [False]
os.register_at_fork(after_in_child=lambda: _FORKED.__setitem__(0, True))


def hash_threads() -> int:
    """The threads a BLAKE3 hash may use here: as many as there are cores, or one in a
    process forked from another (its thread pool does not survive the fork).

    Returns
    -------
    int
        ``blake3.blake3.AUTO`` or 1; every multi-threaded hash of needlekit takes it.
    """
    return 1 if _FORKED[0] else blake3.blake3.AUTO


def file_mac(key: bytes, path: str | os.PathLike) -> str:
    """Keyed BLAKE3 (256-bit, hex) of a whole file's bytes, read through a memory map on
    as many threads as there are cores (about 3 GB/s per core).

    Parameters
    ----------
    key : bytes
    path : path-like

    Returns
    -------
    str
    """
    h = blake3.blake3(key=key, max_threads=hash_threads())
    h.update_mmap(os.fspath(path))
    return h.hexdigest()


def same_mac(a: object, b: str) -> bool:
    """Whether a stored hash equals a computed one (constant time; False for non-text).

    Parameters
    ----------
    a : object
        What a record holds.
    b : str
        What was computed.

    Returns
    -------
    bool
    """
    return isinstance(a, str) and hmac.compare_digest(a.encode(), b.encode())
