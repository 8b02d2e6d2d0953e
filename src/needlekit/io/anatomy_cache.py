"""Prepared anatomy on disk: arrays that are slow to build (masks, signed distance grids,
obstacle voxels), kept between runs and keyed by the content of the files they came from.

Layout
    ``<cache root>/<label>-<key>/`` is one **entry** (e.g. ``medrad-lung1-3f9c...``).
    Every array in it is a pair: ``<name>.npy`` (uncompressed, read back as a read-only
    memory map, so batch workers share the pages) and ``<name>.json``, its record: dtype,
    shape, file size, the keyed hash of the whole file and the caller's metadata, with a
    keyed hash of the record itself. ``manifest.json`` (signed the same way) names the
    entry's key, the inputs the key was made of and the arrays every entry holds; arrays
    built later (fields a run needed) are added one by one beside them.

Key
    :func:`entry_key` hashes the inputs the caller gives (for Med-RAD: the BLAKE3 of the
    *bytes* of every mask file read, the structure table and every setting that changes
    the arrays) together with :data:`CACHE_FORMAT_VERSION` and the needlekit version. A
    file touched without being changed keeps its key; a changed byte gives a new entry.

Writes are atomic
    A new entry is written into a temporary folder beside the others and renamed into
    place in one step; if the rename finds the entry already there (another process built
    it meanwhile) the loser's copy is discarded. An array added to an existing entry is
    written to a temporary file and renamed, its record last, so an array without a record
    is never read. A crash therefore leaves no half entry; temporary folders of crashed
    writers are removed after :data:`STALE_TEMP_S`.

Reads are checked in full, and signed records cannot be forged
    Every hash of an entry is keyed BLAKE3 under the user's secret
    (:mod:`needlekit.io.cache_key`, a file of mode 0600 outside the cache folder).
    Opening an entry checks the manifest's hash, and for every array its record's hash,
    the file size, the hash of *every byte* of the file and the ``.npy`` header (dtype,
    shape): any changed byte, and any record rewritten consistently by someone without
    the secret, fails. A Med-RAD lung entry (0.6 GB) is hashed in about 0.1-0.2 s on two
    cores. A corrupt, partial or forged entry is logged in one warning line, moved aside
    and removed, and the caller rebuilds it: never planned on, never a traceback. The check
    is made when an array is opened; a change made to the files while a run holds them
    open is not seen by that run.

Where
    :func:`cache_root`: the folder given, else ``$NEEDLEKIT_CACHE_DIR``, else
    ``$XDG_CACHE_HOME/needlekit``, else ``~/.cache/needlekit``. ``needlekit cache
    list|clear|limit`` shows it, empties it and bounds its size
    (:mod:`needlekit.io.cache_entries`); :func:`clear_cache` removes every entry. Entries hold patient data, so they stay private to
    the user who made them (folders 0700, files 0600, as ``mkdtemp``/``mkstemp`` create
    them).
"""

from __future__ import annotations

import json
import logging
import os
import shutil
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import blake3
import numpy as np

import needlekit
from needlekit.io.cache_key import cache_key, file_mac, hash_threads, mac, same_mac
from needlekit.io.files import json_text

__all__ = [
    "CACHE_DIR_ENV",
    "CACHE_FORMAT_VERSION",
    "CacheEntry",
    "CachedArray",
    "cache_root",
    "clear_cache",
    "default_cache_dir",
    "entry_key",
    "file_digest",
    "open_entry",
    "write_entry",
]

log = logging.getLogger(__name__)

#: Version of the entry layout and of what the writers put in it. Raise it whenever a
#: change to the code would make an old entry differ from what would be built now (it is
#: part of every key, so old entries are simply no longer found). 2: keyed BLAKE3 of
#: whole files and of every record.
CACHE_FORMAT_VERSION: int = 2

#: Environment variable that moves the cache (batch clusters, tests, read-only homes).
CACHE_DIR_ENV: str = "NEEDLEKIT_CACHE_DIR"

#: Sub-folder of the user cache folder. The default root follows the XDG base-directory
#: rule (``$XDG_CACHE_HOME``, else ``~/.cache``): the place for data that can be rebuilt,
#: which backup tools skip and users know they may delete.
CACHE_SUBDIR: str = "needlekit"

#: Age (s) after which a temporary folder left by a crashed writer is removed. Writing a
#: lung takes seconds; an hour leaves any live writer alone.
STALE_TEMP_S: float = 3600.0

_WRITE_THREADS = 2
_TEMP_PREFIX = ".tmp-"
_TRASH_PREFIX = ".trash-"
_MANIFEST = "manifest.json"
#: An entry's unsigned usage record (patient, source, created, last used):
#: :mod:`needlekit.io.cache_entries`.
USAGE_FILE = "usage.json"


class CorruptEntryError(Exception):
    """An entry or array on disk is not what its records say (internal: never escapes)."""


# ----------------------------------------------------------------------------------------
# where, and keys


def default_cache_dir() -> Path:
    """The default cache root: ``$NEEDLEKIT_CACHE_DIR``, else ``$XDG_CACHE_HOME/needlekit``,
    else ``~/.cache/needlekit``.

    Returns
    -------
    Path
    """
    env = os.environ.get(CACHE_DIR_ENV)
    if env:
        return Path(env).expanduser()
    xdg = os.environ.get("XDG_CACHE_HOME")
    base = Path(xdg).expanduser() if xdg else Path.home() / ".cache"
    return base / CACHE_SUBDIR


def cache_root(cache_dir: str | os.PathLike | None = None) -> Path:
    """The cache root to use: ``cache_dir`` when given, else :func:`default_cache_dir`.

    Parameters
    ----------
    cache_dir : path-like, optional

    Returns
    -------
    Path
    """
    return Path(cache_dir).expanduser() if cache_dir is not None else default_cache_dir()


def file_digest(path: str | os.PathLike) -> str:
    """BLAKE3 (256-bit, hex) of a file's bytes (unkeyed: a content address).

    Parameters
    ----------
    path : path-like

    Returns
    -------
    str
    """
    h = blake3.blake3(max_threads=hash_threads())
    h.update_mmap(os.fspath(path))
    return h.hexdigest()


def _canonical(data: Any) -> bytes:
    return json_text(data, "cache key", sort_keys=True, separators=(",", ":")).encode()


def entry_key(inputs: dict) -> str:
    """The key of an entry: BLAKE3 (128-bit) of the inputs (canonical JSON), the cache
    format version and the needlekit version.

    Parameters
    ----------
    inputs : dict
        JSON-serialisable; everything that changes the arrays (file digests, settings).

    Returns
    -------
    str
        32 hex digits.

    Examples
    --------
    >>> entry_key({"a": 1, "b": [2, 3]}) == entry_key({"b": [2, 3], "a": 1})
    True
    >>> entry_key({"a": 1}) == entry_key({"a": 2})
    False
    """
    body = {"format": CACHE_FORMAT_VERSION, "needlekit": needlekit.__version__, **inputs}
    return blake3.blake3(_canonical(body)).hexdigest(length=16)


# ----------------------------------------------------------------------------------------
# arrays: <name>.npy and its record <name>.json


def _signed(record: dict, secret: bytes) -> dict:
    body = {k: v for k, v in record.items() if k != "mac"}
    return {**body, "mac": mac(secret, _canonical(body))}


def _checked(record: Any, where: Path, secret: bytes) -> dict:
    if not isinstance(record, dict) or "mac" not in record:
        raise CorruptEntryError(f"{where}: not a signed record")
    if not same_mac(record["mac"], _signed(record, secret)["mac"]):
        raise CorruptEntryError(f"{where}: its signature does not match its content")
    return record


def _temp_file(folder: Path, name: str) -> Path:
    fd, tmp = tempfile.mkstemp(prefix=f".{name}.", suffix=".part", dir=folder)
    os.close(fd)
    return Path(tmp)


def _replace_json(folder: Path, filename: str, data: dict) -> None:
    tmp = _temp_file(folder, filename)
    try:
        tmp.write_text(json_text(data, filename, indent=1), encoding="utf-8")
        os.replace(tmp, folder / filename)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def _write_array(folder: Path, name: str, values: np.ndarray, meta: dict, secret: bytes) -> None:
    """Write ``<name>.npy`` then its record ``<name>.json``, each by an atomic rename."""
    arr = np.ascontiguousarray(values)
    tmp = _temp_file(folder, f"{name}.npy")
    try:
        with open(tmp, "wb") as f:
            np.lib.format.write_array(f, arr, allow_pickle=False)
        size = tmp.stat().st_size
        record = _signed(
            {
                "name": name,
                "file": f"{name}.npy",
                "dtype": arr.dtype.str,
                "shape": list(arr.shape),
                "bytes": size,
                "blake3": file_mac(secret, tmp),
                "meta": meta,
            },
            secret,
        )
        os.replace(tmp, folder / f"{name}.npy")
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    _replace_json(folder, f"{name}.json", record)


@dataclass(frozen=True, eq=False)
class CachedArray:
    """An array read back from an entry.

    Attributes
    ----------
    values : ndarray
        Read-only (a memory map of the ``.npy`` file).
    meta : dict
        What the writer stored beside it.
    """

    values: np.ndarray
    meta: dict


def _read_array(folder: Path, name: str, secret: bytes) -> CachedArray:
    """An array and its metadata, every byte checked against its signed record;
    CorruptEntryError if not."""
    rec_path = folder / f"{name}.json"
    try:
        record = _checked(json.loads(rec_path.read_text(encoding="utf-8")), rec_path, secret)
        if record.get("file") != f"{name}.npy":
            raise CorruptEntryError(f"{rec_path}: names another file")
        path = folder / record["file"]
        size = path.stat().st_size
        if size != record["bytes"]:
            raise CorruptEntryError(f"{path}: {size} bytes, the record says {record['bytes']}")
        if not same_mac(record["blake3"], file_mac(secret, path)):
            raise CorruptEntryError(f"{path}: content does not match its record")
        values = np.load(path, mmap_mode="r", allow_pickle=False)
        if values.dtype.str != record["dtype"] or list(values.shape) != record["shape"]:
            raise CorruptEntryError(
                f"{path}: holds {values.dtype.str} {list(values.shape)}, the record says "
                f"{record['dtype']} {record['shape']}"
            )
        return CachedArray(np.asarray(values), record["meta"])
    except CorruptEntryError:
        raise
    except (OSError, EOFError, ValueError, KeyError, TypeError, RecursionError) as exc:
        raise CorruptEntryError(f"{folder / name}: {exc}") from exc


# ----------------------------------------------------------------------------------------
# entries


class CacheEntry:
    """One entry on disk, checked when opened (see :func:`open_entry`).

    Attributes
    ----------
    path : Path
        The entry's folder.
    manifest : dict
        ``key``, ``label``, ``inputs``, ``arrays`` (names every entry holds), ``format``,
        ``needlekit``, ``created_utc``.
    arrays : dict of str to CachedArray
        The arrays named in the manifest, checked and mapped.
    """

    def __init__(
        self, path: Path, manifest: dict, arrays: dict[str, CachedArray], secret: bytes
    ) -> None:
        self.path = path
        self.manifest = manifest
        self.arrays = arrays
        self._secret = secret

    @property
    def key(self) -> str:
        """The entry's key."""
        return self.manifest["key"]

    def __getitem__(self, name: str) -> CachedArray:
        return self.arrays[name]

    def get(self, name: str) -> CachedArray | None:
        """An array added after the entry was made (or one of its own), if present and
        sound; a corrupt one is logged and treated as absent.

        Parameters
        ----------
        name : str

        Returns
        -------
        CachedArray or None
        """
        if name in self.arrays:
            return self.arrays[name]
        if not (self.path / f"{name}.json").is_file():
            return None
        try:
            got = _read_array(self.path, name, self._secret)
        except CorruptEntryError as exc:
            log.warning("prepared-anatomy cache: %s; rebuilding it", exc)
            return None
        self.arrays[name] = got
        return got

    def put(self, name: str, values: np.ndarray, meta: dict) -> CachedArray | None:
        """Add (or replace) an array, atomically; a failure (entry removed meanwhile, disk
        full, read-only folder) is logged and the cache left as it was.

        Parameters
        ----------
        name : str
        values : ndarray, any shape
        meta : dict
            JSON-serialisable.

        Returns
        -------
        CachedArray or None
            The array as stored (memory-mapped), or None if it could not be stored.
        """
        try:
            _write_array(self.path, name, values, meta, self._secret)
            got = _read_array(self.path, name, self._secret)
        except (OSError, CorruptEntryError) as exc:
            log.warning(
                "prepared-anatomy cache: could not store %s in %s: %s", name, self.path, exc
            )
            return None
        self.arrays[name] = got
        return got


def _entry_dir(root: Path, label: str, key: str) -> Path:
    return root / f"{label}-{key}"


def _discard(path: Path) -> None:
    """Move a folder aside (one atomic step) and delete it; quiet if it is already gone."""
    trash = path.parent / f"{_TRASH_PREFIX}{path.name}-{os.getpid()}-{time.monotonic_ns()}"
    try:
        os.rename(path, trash)
    except OSError:
        return
    shutil.rmtree(trash, ignore_errors=True)


def _open_dir(path: Path, key: str, secret: bytes) -> CacheEntry:
    mpath = path / _MANIFEST
    try:
        manifest = _checked(json.loads(mpath.read_text(encoding="utf-8")), mpath, secret)
        if manifest.get("format") != CACHE_FORMAT_VERSION or manifest.get("key") != key:
            raise CorruptEntryError(f"{mpath}: made for another key or format")
        names = list(manifest["arrays"])
    except CorruptEntryError:
        raise
    except (OSError, ValueError, KeyError, TypeError, RecursionError) as exc:
        raise CorruptEntryError(f"{mpath}: {exc}") from exc
    arrays = {n: _read_array(path, n, secret) for n in names}
    return CacheEntry(path, manifest, arrays, secret)


def open_entry(cache_dir: str | os.PathLike | None, label: str, key: str) -> CacheEntry | None:
    """The entry of a key, every byte checked, or None when there is none (a corrupt or
    forged one is logged, removed, and reported as none).

    Parameters
    ----------
    cache_dir : path-like or None
        Cache root (None: :func:`default_cache_dir`).
    label : str
        Readable part of the folder name (e.g. ``"medrad-lung1"``).
    key : str
        From :func:`entry_key`.

    Returns
    -------
    CacheEntry or None

    Raises
    ------
    needlekit.io.cache_key.CacheKeyError
        The user's key cannot be read or made: nothing can be checked, nothing is removed.
    """
    path = _entry_dir(cache_root(cache_dir), label, key)
    if not path.is_dir():
        return None
    secret = cache_key()
    try:
        return _open_dir(path, key, secret)
    except CorruptEntryError as exc:
        log.warning("prepared-anatomy cache: corrupt entry %s (%s); rebuilding it", path.name, exc)
        _discard(path)
        return None


def _remove_stale_temps(root: Path) -> None:
    now = time.time()
    for p in root.iterdir():
        if p.name.startswith((_TEMP_PREFIX, _TRASH_PREFIX)):
            try:
                if now - p.stat().st_mtime > STALE_TEMP_S:
                    shutil.rmtree(p, ignore_errors=True)
            except OSError:
                pass


def write_entry(
    cache_dir: str | os.PathLike | None,
    label: str,
    key: str,
    inputs: dict,
    arrays: dict[str, tuple[np.ndarray, dict]],
    usage: dict | None = None,
) -> CacheEntry:
    """Store a new entry atomically and open it.

    Parameters
    ----------
    cache_dir : path-like or None
        Cache root (None: :func:`default_cache_dir`); created if missing.
    label : str
        Readable part of the folder name.
    key : str
        From :func:`entry_key` of ``inputs``.
    inputs : dict
        What the key was made of (kept in the manifest, for people reading it).
    arrays : dict of str to (ndarray, dict)
        Name -> (values of any shape, metadata). Names are file stems: letters, digits, ``_``, ``-``.
    usage : dict, optional
        The entry's usage record (:func:`needlekit.io.cache_entries.usage_record`),
        written with it.

    Returns
    -------
    CacheEntry
        Opened from disk: its arrays are read-only memory maps. If another process stored
        the same entry first, that one (the same content) is returned and this copy
        discarded.

    Raises
    ------
    OSError
        The cache folder cannot be written, or the user's key cannot be read or made
        (:class:`~needlekit.io.cache_key.CacheKeyError`): the caller goes on without the
        cache.
    """
    secret = cache_key()
    root = cache_root(cache_dir)
    root.mkdir(parents=True, exist_ok=True)
    _remove_stale_temps(root)
    final = _entry_dir(root, label, key)
    tmp = Path(tempfile.mkdtemp(prefix=f"{_TEMP_PREFIX}{label}-", dir=root))
    try:
        # two at a time, largest first: writing and hashing release the GIL, so two cores
        # share the work (about 0.7 GB for a lung)
        order = sorted(arrays, key=lambda n: -np.asarray(arrays[n][0]).nbytes)
        with ThreadPoolExecutor(max_workers=_WRITE_THREADS) as pool:
            jobs = [pool.submit(_write_array, tmp, n, *arrays[n], secret) for n in order]
            for job in jobs:
                job.result()
        manifest = _signed(
            {
                "format": CACHE_FORMAT_VERSION,
                "needlekit": _version(),
                "key": key,
                "label": label,
                "inputs": inputs,
                "arrays": list(arrays),
                "created_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
            },
            secret,
        )
        _replace_json(tmp, _MANIFEST, manifest)
        if usage is not None:
            _replace_json(tmp, USAGE_FILE, usage)
        for attempt in range(2):
            try:
                os.rename(tmp, final)
                break
            except OSError:
                if not final.exists():
                    raise
            existing = open_entry(root, label, key)  # another writer won: use its entry
            if existing is not None:
                shutil.rmtree(tmp, ignore_errors=True)
                return existing
            if attempt == 1:
                raise OSError(f"cannot place the prepared-anatomy entry {final}")
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    try:
        return _open_dir(final, key, secret)
    except CorruptEntryError as exc:  # changed under us (disk, another process): say so
        raise OSError(f"the prepared-anatomy entry just written is unreadable: {exc}") from exc


def _version() -> str:
    return needlekit.__version__  # read when called (tests change it)


def clear_cache(cache_dir: str | os.PathLike | None = None) -> int:
    """Remove every entry (and leftover temporary folder) under the cache root.

    Parameters
    ----------
    cache_dir : path-like, optional
        Cache root (default :func:`default_cache_dir`).

    Returns
    -------
    int
        Entries removed.
    """
    root = cache_root(cache_dir)
    if not root.is_dir():
        return 0
    n = 0
    for p in root.iterdir():
        if not p.is_dir():
            continue
        if (p / _MANIFEST).is_file():
            n += 1
            _discard(p)
        elif p.name.startswith((_TEMP_PREFIX, _TRASH_PREFIX)):
            shutil.rmtree(p, ignore_errors=True)
    return n
