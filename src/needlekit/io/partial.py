"""Partial results: what a long run stopped by Ctrl-C writes, and what ``--resume`` reads.

A sweep, a study or a puncture run that is interrupted writes the work it finished beside
its usual result file, never over it (``sweep.partial.json`` beside ``sweep.json``: a
complete result an earlier run wrote stays as it was), marked ``"partial": true``; the
same command with ``--resume`` reads it from there and plans or runs only the rest, and
a run that completes removes it (:func:`needlekit.io.files.staged_outputs`). The finished part is taken as it is: it is not recomputed, so a
resumed run trusts the partial file. That trust is earned the way the prepared-anatomy
cache earns it (:mod:`needlekit.io.cache_key`): the file carries a keyed BLAKE3 hash of
its whole content under the user's secret, and ``--resume`` refuses a file whose hash
does not match (any edited byte of the record, or a record written by someone else), and
a file written by another needlekit version or for other settings than the run asked for
(each setting is named).

Examples
--------
>>> import tempfile
>>> from pathlib import Path
>>> d = Path(tempfile.mkdtemp())
>>> p = write_partial(d / "run.json", {"seed": 1, "done": [3]}, key_file=d / "key")
>>> p.name, read_partial(d / "run.json", "run", {"seed": 1}, key_file=d / "key")["done"]
('run.partial.json', [3])
"""

from __future__ import annotations

import json
import os
from pathlib import Path

from needlekit import __version__
from needlekit.errors import InvalidInputError
from needlekit.io.cache_key import CacheKeyError, cache_key, mac, same_mac
from needlekit.io.files import beside, json_text, read_json_object, write_json

__all__ = ["PARTIAL_SIGNATURE", "partial_path", "read_partial", "write_partial"]

#: The field holding a partial record's keyed hash.
PARTIAL_SIGNATURE: str = "partial_signature"
#: The version that wrote a partial record: a resumed run must be made by the same one.
_VERSION = "needlekit_version"


def _canonical(data) -> bytes:
    return json_text(data, "partial record", sort_keys=True, separators=(",", ":")).encode()


def _signature(key: bytes, record: dict) -> str:
    return mac(key, b"needlekit partial result\0" + _canonical(record))


def partial_path(path: str | os.PathLike) -> Path:
    """Where an interrupted run whose complete result is ``path`` keeps its work.

    Parameters
    ----------
    path : path-like
        The complete result (``sweep.json``).

    Returns
    -------
    Path
        Beside it (``sweep.partial.json``).
    """
    return beside(path, "partial")


def write_partial(path: str | os.PathLike, record: dict, *, key_file=None) -> Path:
    """Write ``record`` marked ``"partial": true`` and signed (atomically), beside the
    complete result ``path`` (:func:`partial_path`), never over it.

    Parameters
    ----------
    path : path-like
        The complete result the run would have written.
    record : dict
        JSON-ready (NaN and infinity are refused, as by
        :func:`~needlekit.io.files.write_json`).
    key_file : path-like, optional
        The secret's file (default :func:`~needlekit.io.cache_key.cache_key_path`).

    Returns
    -------
    Path
        The file written (:func:`partial_path`).

    Notes
    -----
    Without a usable key (:class:`~needlekit.io.cache_key.CacheKeyError`) the file is
    written unsigned: it keeps the work for the user to read, and ``--resume`` refuses it
    with the reason.
    """
    # signed as it will read back (JSON turns tuples into lists, keys into text)
    data = json.loads(_canonical({**record, "partial": True, _VERSION: __version__}))
    data.pop(PARTIAL_SIGNATURE, None)
    try:
        data[PARTIAL_SIGNATURE] = _signature(cache_key(key_file), data)
    except CacheKeyError:
        data[PARTIAL_SIGNATURE] = None
    return write_json(partial_path(path), data, partial=True)


def read_partial(
    path: str | os.PathLike, what: str, expect: dict, flag: str = "--resume", *, key_file=None
) -> dict:
    """A partial record written by :func:`write_partial`, checked before use.

    Parameters
    ----------
    path : path-like
        The complete result; the record is read from beside it (:func:`partial_path`).
    what : str
        What the file is, for messages (``"sweep"``, ``"puncture"``).
    expect : dict
        Settings the record must hold as this run has them (compared as JSON).
    flag : str
        The option named in errors.
    key_file : path-like, optional
        The secret's file (default :func:`~needlekit.io.cache_key.cache_key_path`).

    Returns
    -------
    dict
        The record, without its signature.

    Raises
    ------
    InvalidInputError
        Not JSON (named by the path); missing, not partial, its signature missing or not
        matching, or a setting of ``expect`` different (named ``flag``).
    """
    path = partial_path(path)
    if not path.is_file():
        raise InvalidInputError(flag, f"no {path} to carry on from (an interrupted run writes it)")
    data = read_json_object(path, what)
    if data.get("partial") is not True:
        raise InvalidInputError(flag, f"{path} is not a partial {what}: nothing to carry on")
    stored = data.pop(PARTIAL_SIGNATURE, None)
    try:
        key = cache_key(key_file)
    except CacheKeyError as exc:
        raise InvalidInputError(flag, f"cannot check {path}: {exc}") from None
    try:
        ok = same_mac(stored, _signature(key, data))
    except ValueError:  # NaN or infinity: not a record write_partial made
        ok = False
    if not ok:
        raise InvalidInputError(
            flag,
            f"{path} is not as the interrupted run wrote it (its signature does not match): "
            "run again without --resume",
        )
    for name, value in [(_VERSION, __version__), *expect.items()]:
        if _canonical(data.get(name)) != _canonical(value):
            raise InvalidInputError(flag, f"{path} was written with other {name} than this run's")
    return data
