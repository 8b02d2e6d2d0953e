"""Small results in the prepared-anatomy cache: a record (JSON) slow to compute and small to
keep, under a key made of everything it was computed from.

Two kinds use it: the calibration of a needle model from simulated insertions (tens of
rod solves, 10-15 s, then the same answer for the same needle, tissue and start), and the
fast key of an organ's tissue precomputation (the file digests and settings a run knows
before it reads a mask, naming the entry that reading and binarising the masks would
key).

A record is an entry of :mod:`needlekit.io.anatomy_cache` with one array, the record's
canonical JSON as bytes: it is written atomically, signed under the user's secret and
checked in full when read, like the arrays of a patient. Its key holds, beside the
caller's inputs, the digest of needlekit's own source (:func:`source_digest`): a record is
a computed result, so a change to the code that computes it (within one version, as while
developing) must not read an old answer back. Failures never stop a run: a record that
cannot be read is recomputed, one that cannot be stored is logged and dropped.
"""

from __future__ import annotations

import functools
import json
import logging
import os
from pathlib import Path

import blake3
import numpy as np

import needlekit
from needlekit.errors import OutputError
from needlekit.io import anatomy_cache, cache_entries
from needlekit.io.files import json_text

__all__ = ["load_record", "source_digest", "store_record"]

log = logging.getLogger(__name__)

#: The array that holds a record's bytes.
_ARRAY = "record"


@functools.lru_cache(maxsize=1)
def source_digest() -> str:
    """BLAKE3 (128-bit, hex) of needlekit's Python source: every ``.py`` file of the
    package, by its path within the package and its bytes (about 10 ms, once per process).

    Returns
    -------
    str
    """
    root = Path(needlekit.__file__).resolve().parent
    h = blake3.blake3()
    for path in sorted(root.rglob("*.py")):
        rel = path.relative_to(root).as_posix().encode()
        h.update(len(rel).to_bytes(4, "little") + rel)
        data = path.read_bytes()
        h.update(len(data).to_bytes(8, "little") + data)
    return h.hexdigest(length=16)


def _key(inputs: dict) -> str:
    return anatomy_cache.entry_key({"record": inputs, "source": source_digest()})


def load_record(cache_dir: str | os.PathLike | None, label: str, inputs: dict) -> dict | None:
    """The record stored for ``inputs``, or None (none stored, or no readable cache).

    Parameters
    ----------
    cache_dir : path-like or None
        Cache root (None: the default, :func:`~needlekit.io.anatomy_cache.cache_root`).
    label : str
        Readable part of the entry's folder name (e.g. ``"calibration"``).
    inputs : dict
        JSON-serialisable: everything the record was computed from.

    Returns
    -------
    dict or None
    """
    try:
        entry = anatomy_cache.open_entry(cache_dir, label, _key(inputs))
    except (OSError, OutputError) as exc:  # no key file, an unreadable folder: compute it
        log.warning("record cache unavailable (%s); computing it", exc)
        return None
    if entry is None:
        return None
    try:
        record = json.loads(bytes(entry[_ARRAY].values).decode("utf-8"))
    except (KeyError, ValueError, UnicodeDecodeError) as exc:
        log.warning("record cache: entry %s unreadable (%s); computing it", entry.path.name, exc)
        return None
    if not isinstance(record, dict):
        return None
    cache_entries.mark_used(entry.path)
    return record


def store_record(cache_dir: str | os.PathLike | None, label: str, inputs: dict, record: dict,
                 what: str) -> bool:  # fmt: skip
    """Store ``record`` under ``inputs`` (a failure is logged, not raised).

    Parameters
    ----------
    cache_dir : path-like or None
    label : str
    inputs : dict
        As :func:`load_record`.
    record : dict
        JSON-serialisable (finite numbers).
    what : str
        What it is, for ``needlekit cache list``.

    Returns
    -------
    bool
        Whether it was stored.
    """
    try:
        data = np.frombuffer(json_text(record, label, sort_keys=True).encode("utf-8"), np.uint8)
        if not cache_entries.make_room(cache_dir, data.nbytes + 4096):
            return False
        usage = cache_entries.usage_record(what, "record")
        anatomy_cache.write_entry(cache_dir, label, _key(inputs), inputs, {_ARRAY: (data, {})}, usage)
    except (OSError, OutputError) as exc:
        log.warning("record cache: %s could not be stored: %s", what, exc)
        return False
    return True
