"""What the prepared-anatomy cache holds, and keeping it within a size limit.

Each entry (:mod:`needlekit.io.anatomy_cache`) carries beside its signed manifest a small
unsigned record, ``usage.json``: the patient it holds (``"Med-RAD lung 1"``), the folder
it was prepared from, when it was made and when it was last used. It is written into the
entry's temporary folder before the entry is renamed into place, and rewritten (to a
temporary file, then renamed) each time a run opens the entry: about 0.2 ms. It only
orders and names entries; nothing is planned from it, so it is not signed.

Size limit
    :func:`cache_limit`: ``$NEEDLEKIT_CACHE_LIMIT`` when set, else the limit stored in
    the cache folder (``limit.json``, by ``needlekit cache limit SIZE``), else
    :data:`DEFAULT_LIMIT_BYTES` (10 GB). Sizes are decimal: 1 GB = 10^9 bytes, 1 GiB =
    2^30. Before a new entry is stored, or an array added to one, :func:`make_room`
    removes the least recently used entries until the new bytes fit, in one log line;
    what would not fit even then is not stored (the run goes on from memory) and nothing
    is removed for it.

What eviction never removes
    The entries this process has opened or written (:func:`mark_used`); an entry still
    being written (its temporary ``.tmp-*`` folder, which is not an entry until the one
    rename that places it); an entry another process is adding an array to (a ``.part``
    file younger than :data:`~needlekit.io.anatomy_cache.STALE_TEMP_S` in it). An entry
    that another process has open and mapped is removed by one rename and then deleted:
    on POSIX systems that process keeps reading the mapped files; an array it adds later
    is not stored (a logged warning) and it builds it in memory instead.
"""

from __future__ import annotations

import json
import logging
import os
import re
import shutil
import time
from dataclasses import dataclass
from pathlib import Path

from needlekit.errors import InvalidInputError
from needlekit.io.anatomy_cache import (
    _MANIFEST,
    _TEMP_PREFIX,
    _TRASH_PREFIX,
    STALE_TEMP_S,
    USAGE_FILE,
    _discard,
    _replace_json,
    cache_root,
)

__all__ = [
    "CACHE_LIMIT_ENV",
    "DEFAULT_LIMIT_BYTES",
    "EntryInfo",
    "being_written",
    "cache_limit",
    "format_size",
    "list_entries",
    "make_room",
    "mark_used",
    "matches",
    "parse_size",
    "patient_name",
    "remove_entries",
    "remove_stale",
    "set_cache_limit",
    "usage_record",
]

log = logging.getLogger(__name__)

#: Environment variable that sets the size limit (over the one stored in the folder).
CACHE_LIMIT_ENV: str = "NEEDLEKIT_CACHE_LIMIT"

#: The limit when none is set: the five Med-RAD lungs with every structure's field built
#: (about 1.5 GB each) and the five livers fit.
DEFAULT_LIMIT_BYTES: int = 10 * 10**9

#: The largest limit taken (1 PB): a size past it is a typing mistake.
MAX_LIMIT_BYTES: int = 10**15

#: File of the cache folder holding the limit set by ``needlekit cache limit``.
LIMIT_FILE: str = "limit.json"

_UNITS = {
    "b": 1, "kb": 10**3, "mb": 10**6, "gb": 10**9, "tb": 10**12,
    "kib": 2**10, "mib": 2**20, "gib": 2**30, "tib": 2**40,
    "k": 10**3, "m": 10**6, "g": 10**9, "t": 10**12,
}  # fmt: skip
_SIZE = re.compile(r"^\s*(\d+(?:\.\d*)?|\.\d+)\s*([a-zA-Z]+)\s*$")
_EXPECTED_SIZE = "expected a size such as 10GB, 500MB or 1.5TB (up to 1000TB)"

#: Entries this process has opened or written: never evicted by it.
_IN_USE: set[str] = set()


# ----------------------------------------------------------------------------------------
# sizes


def parse_size(text: str, field: str = "SIZE") -> int:
    """Bytes of a size written with its unit (``10GB``, ``500 MB``, ``1.5TiB``).

    Parameters
    ----------
    text : str
    field : str
        What an error names.

    Returns
    -------
    int

    Raises
    ------
    InvalidInputError
        Not a positive size with a unit, or past 1000 TB.

    Examples
    --------
    >>> parse_size("10GB"), parse_size("1.5 GiB"), parse_size("500mb")
    (10000000000, 1610612736, 500000000)
    """
    m = _SIZE.match(str(text))
    unit = _UNITS.get(m.group(2).lower()) if m else None
    if unit is None:
        raise InvalidInputError(field, f"{_EXPECTED_SIZE}, got {text!r}")
    size = round(float(m.group(1)) * unit)
    if not 0 < size <= MAX_LIMIT_BYTES:
        raise InvalidInputError(field, f"{_EXPECTED_SIZE}, got {text!r}")
    return size


def format_size(n: int | float) -> str:
    """A size for people: ``624 MB``, ``1.52 GB``, ``2 kB`` (decimal units).

    Parameters
    ----------
    n : int or float
        Bytes.

    Returns
    -------
    str

    Examples
    --------
    >>> format_size(624_000_000), format_size(1_520_000_000), format_size(2_000)
    ('624 MB', '1.52 GB', '2 kB')
    >>> format_size(10**10)
    '10 GB'
    """
    if n >= 10**9:
        return f"{n / 1e9:.3g} GB"
    if n >= 10**6:
        return f"{n / 1e6:.0f} MB"
    return f"{n / 1e3:.0f} kB"


# ----------------------------------------------------------------------------------------
# the limit


def cache_limit(cache_dir: str | os.PathLike | None = None) -> tuple[int, str]:
    """The size limit and where it comes from.

    Parameters
    ----------
    cache_dir : path-like, optional
        Cache root (default :func:`~needlekit.io.anatomy_cache.default_cache_dir`).

    Returns
    -------
    (int, str)
        Bytes, and ``"$NEEDLEKIT_CACHE_LIMIT"``, the limit file's path or ``"default"``.

    Raises
    ------
    InvalidInputError
        The variable or the limit file holds no size.
    """
    env = os.environ.get(CACHE_LIMIT_ENV)
    if env is not None and env.strip():
        return parse_size(env, CACHE_LIMIT_ENV), f"${CACHE_LIMIT_ENV}"
    path = cache_root(cache_dir) / LIMIT_FILE
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except OSError:  # none there (or no readable folder: nothing will be stored anyway)
        return DEFAULT_LIMIT_BYTES, "default"
    except ValueError as exc:
        raise InvalidInputError(
            str(path), f"expected the cache's limit, unreadable: {exc}"
        ) from None
    size = data.get("limit_bytes") if isinstance(data, dict) else None
    if isinstance(size, bool) or not isinstance(size, int) or not 0 < size <= MAX_LIMIT_BYTES:
        raise InvalidInputError(
            str(path), f"limit_bytes: expected a whole number in [1, 1e15], got {size!r}"
        )
    return size, str(path)


def set_cache_limit(cache_dir: str | os.PathLike | None, size: int | None) -> Path:
    """Store the size limit in the cache folder (None: remove it, back to the default).

    Parameters
    ----------
    cache_dir : path-like or None
    size : int or None
        Bytes.

    Returns
    -------
    Path
        The limit file.
    """
    root = cache_root(cache_dir)
    path = root / LIMIT_FILE
    if size is None:
        path.unlink(missing_ok=True)
        return path
    root.mkdir(parents=True, exist_ok=True)
    _replace_json(root, LIMIT_FILE, {"limit_bytes": int(size)})
    return path


# ----------------------------------------------------------------------------------------
# entries and their usage records


def patient_name(label: str) -> str:
    """What an entry's label names: ``medrad-lung1`` -> ``Med-RAD lung 1``.

    Parameters
    ----------
    label : str

    Returns
    -------
    str

    Examples
    --------
    >>> patient_name("medrad-liver12"), patient_name("phantom-x")
    ('Med-RAD liver 12', 'phantom-x')
    """
    m = re.fullmatch(r"medrad-([a-z]+)(\d+)", label)
    return f"Med-RAD {m.group(1)} {int(m.group(2))}" if m else label


@dataclass(frozen=True)
class EntryInfo:
    """One entry as listed.

    Attributes
    ----------
    path : Path
    label : str
        ``medrad-lung1``.
    key : str
    patient : str
        ``Med-RAD lung 1``.
    source : str
        The folder it was prepared from ("" when unknown).
    bytes : int
        Sum of its files' sizes.
    created : float
        Unix time.
    last_used : float
        Unix time.
    writing : bool
        Another process is adding an array to it (never evicted then).
    """

    path: Path
    label: str
    key: str
    patient: str
    source: str
    bytes: int
    created: float
    last_used: float
    writing: bool

    def to_dict(self) -> dict:
        """The listing as ``needlekit cache list --json`` prints it.

        Returns
        -------
        dict
        """
        return {
            "patient": self.patient,
            "label": self.label,
            "key": self.key,
            "source": self.source,
            "bytes": self.bytes,
            "created_utc": _utc(self.created),
            "last_used_utc": _utc(self.last_used),
            "path": str(self.path),
            "being_written": self.writing,
        }


def _utc(t: float) -> str:
    return time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime(t))


def usage_record(patient: str, source: str, now: float | None = None) -> dict:
    """The usage record of a new entry (written by
    :func:`~needlekit.io.anatomy_cache.write_entry` with the entry).

    Parameters
    ----------
    patient : str
    source : str
    now : float, optional
        Unix time (default now).

    Returns
    -------
    dict
    """
    t = time.time() if now is None else float(now)
    return {"patient": patient, "source": source, "created": t, "last_used": t,
            "created_utc": _utc(t), "last_used_utc": _utc(t)}  # fmt: skip


def _read_usage(path: Path) -> dict:
    try:
        data = json.loads((path / USAGE_FILE).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return {}
    return data if isinstance(data, dict) else {}


def _number(value, fallback: float) -> float:
    ok = isinstance(value, (int, float)) and not isinstance(value, bool) and value == value
    return float(value) if ok else fallback


def mark_used(entry_path: str | os.PathLike, now: float | None = None) -> None:
    """Record that this process uses an entry: its last use is now, and this process will
    not evict it. A failure (read-only folder, entry removed meanwhile) changes nothing.

    Parameters
    ----------
    entry_path : path-like
    now : float, optional
        Unix time (default now).

    Returns
    -------
    None
    """
    path = Path(entry_path)
    _IN_USE.add(str(path.resolve()))
    t = time.time() if now is None else float(now)
    usage = _read_usage(path)
    if not usage:
        info = _info(path)
        if info is None:
            return
        usage = usage_record(info.patient, info.source, info.created)
    usage.update(last_used=t, last_used_utc=_utc(t))
    try:
        _replace_json(path, USAGE_FILE, usage)
    except OSError as exc:
        log.debug("prepared-anatomy cache: cannot record the use of %s: %s", path, exc)


def _fresh_part(path: Path, now: float) -> bool:
    for p in path.glob(".*.part"):
        try:
            if now - p.stat().st_mtime <= STALE_TEMP_S:
                return True
        except OSError:
            continue
    return False


def _info(path: Path, now: float | None = None) -> EntryInfo | None:
    """An entry's listing, or None if ``path`` is not an entry (any more)."""
    try:
        manifest = json.loads((path / _MANIFEST).read_text(encoding="utf-8"))
        files = [p.stat() for p in path.iterdir() if p.is_file()]
        mtime = (path / _MANIFEST).stat().st_mtime
    except (OSError, ValueError):  # not an entry, or removed meanwhile
        return None
    if not isinstance(manifest, dict):
        return None
    label = str(manifest.get("label", path.name.rsplit("-", 1)[0]))
    usage = _read_usage(path)
    created = _number(usage.get("created"), mtime)
    t = time.time() if now is None else now
    return EntryInfo(
        path=path,
        label=label,
        key=str(manifest.get("key", "")),
        patient=str(usage.get("patient") or patient_name(label)),
        source=str(usage.get("source", "")),
        bytes=sum(s.st_size for s in files),
        created=created,
        last_used=_number(usage.get("last_used"), created),
        writing=_fresh_part(path, t),
    )


def list_entries(cache_dir: str | os.PathLike | None = None) -> list[EntryInfo]:
    """The entries of the cache, most recently used first.

    Parameters
    ----------
    cache_dir : path-like, optional

    Returns
    -------
    list of EntryInfo
    """
    root = cache_root(cache_dir)
    if not root.is_dir():
        return []
    now = time.time()
    out = []
    for p in root.iterdir():
        if p.is_dir() and not p.name.startswith((_TEMP_PREFIX, _TRASH_PREFIX)):
            info = _info(p, now)
            if info is not None:
                out.append(info)
    return sorted(out, key=lambda e: (-e.last_used, e.path.name))


def being_written(cache_dir: str | os.PathLike | None = None) -> int:
    """Bytes in the temporary folders of entries being written now (not yet entries).

    Parameters
    ----------
    cache_dir : path-like, optional

    Returns
    -------
    int
    """
    root = cache_root(cache_dir)
    if not root.is_dir():
        return 0
    total = 0
    for p in root.glob(f"{_TEMP_PREFIX}*"):
        try:
            total += sum(f.stat().st_size for f in p.iterdir() if f.is_file())
        except OSError:
            continue
    return total


def _norm(text: str) -> str:
    return re.sub(r"[\s_-]+", "", text.lower())


def matches(info: EntryInfo, name: str) -> bool:
    """Whether ``--patient NAME`` names an entry: its patient (``"lung 1"``, ``lung1``,
    ``"Med-RAD lung 1"``), its label, its folder's name, or 6 or more leading digits of
    its key.

    Parameters
    ----------
    info : EntryInfo
    name : str

    Returns
    -------
    bool
    """
    n = _norm(name)
    if not n:
        return False
    names = {_norm(info.patient), _norm(info.label), _norm(info.path.name)}
    names |= {x.removeprefix("medrad") for x in names}
    return n in names or (len(n) >= 6 and info.key.startswith(n))


def remove_entries(entries: list[EntryInfo]) -> list[EntryInfo]:
    """Remove entries, each by one rename then deletion; those gone meanwhile are skipped.

    Parameters
    ----------
    entries : list of EntryInfo

    Returns
    -------
    list of EntryInfo
        The ones removed.
    """
    done = []
    for e in entries:
        if e.path.is_dir():
            _discard(e.path)
            if not e.path.exists():
                done.append(e)
    return done


def make_room(cache_dir: str | os.PathLike | None, need_bytes: int, *, limit: int | None = None,
              keep: str | os.PathLike | None = None, say=None) -> bool:  # fmt: skip
    """Remove least recently used entries until ``need_bytes`` more fit within the limit.

    Never removed: ``keep``, the entries this process uses (:func:`mark_used`), entries
    another process is adding an array to, and entries being written (not yet entries).
    What was removed is said in one log line.

    Parameters
    ----------
    cache_dir : path-like or None
    need_bytes : int
        The bytes about to be added.
    limit : int, optional
        Bytes (default :func:`cache_limit`).
    keep : path-like, optional
        The entry about to grow.
    say : callable, optional
        Given the line of what was removed instead of the log (a command prints it).

    Returns
    -------
    bool
        Whether the bytes fit now. False when they would not fit even after removing every
        entry it may remove: then it removes none, and the caller does not store them.
    """
    if limit is None:
        limit = cache_limit(cache_dir)[0]
    entries = list_entries(cache_dir)
    total = sum(e.bytes for e in entries)
    if total + need_bytes <= limit:
        return True
    protected = set(_IN_USE)
    if keep is not None:
        protected.add(str(Path(keep).resolve()))
    evict, left = [], total
    for e in sorted(entries, key=lambda e: (e.last_used, e.path.name)):  # oldest use first
        if left + need_bytes <= limit:
            break
        if e.writing or str(e.path.resolve()) in protected:
            continue
        evict.append(e)
        left -= e.bytes
    if left + need_bytes > limit:  # it would not fit even so: keep the others
        return False
    removed = remove_entries(evict)
    if removed:
        line = (
            f"prepared-anatomy cache over its limit of {format_size(limit)}: removed "
            + ", ".join(f"{e.patient} ({format_size(e.bytes)}, last used {_utc(e.last_used)})"
                        for e in removed)
            + ", least recently used (needlekit cache limit SIZE changes the limit)"
        )  # fmt: skip
        if say is None:
            log.warning("%s", line)
        else:
            say(line)
    return True


def remove_stale(cache_dir: str | os.PathLike | None = None) -> None:
    """Remove temporary folders left by crashed writers (older than
    :data:`~needlekit.io.anatomy_cache.STALE_TEMP_S`); live writers' folders stay.

    Parameters
    ----------
    cache_dir : path-like, optional

    Returns
    -------
    None
    """
    root = cache_root(cache_dir)
    if not root.is_dir():
        return
    now = time.time()
    for p in root.iterdir():
        if p.is_dir() and p.name.startswith((_TEMP_PREFIX, _TRASH_PREFIX)):
            try:
                if now - p.stat().st_mtime > STALE_TEMP_S:
                    shutil.rmtree(p, ignore_errors=True)
            except OSError:
                pass
