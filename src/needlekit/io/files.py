"""Atomic file output: a file is either written whole or left as it was.

- :func:`atomic_write` (and :func:`write_text`, :func:`write_json` on top of it) writes a
  temporary file beside the destination and renames it into place.
- :func:`staged_outputs` makes several files one unit: inside the block every
  :func:`atomic_write` is held back, and only when the whole block succeeds are all the
  files moved into place; on any error every destination is left as it was. A run that
  ends with a failing verdict (:meth:`Outputs.keep_earlier`) or is interrupted replaces
  no file that exists: its record goes beside it (:func:`beside`).
- :func:`output_path_problem` says, before any work, why a path could not be written.
"""

from __future__ import annotations

import contextvars
import json
import os
import re
import shutil
import stat
import tempfile
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from needlekit._numbers import check_document
from needlekit.errors import Interrupted, InvalidInputError
from needlekit.io.finite_json import json_text

__all__ = [
    "Outputs",
    "atomic_write",
    "beside",
    "json_text",
    "read_json_object",
    "output_path_problem",
    "staged_outputs",
    "write_bytes",
    "write_json",
    "write_text",
    "without_content",
]

#: What a parser's message may quote of a file: its syntax (a bracket, a comma, a colon,
#: a tab) and the parser's own markers (``<stream end>``); anything else quoted is the
#: file's text.
_QUOTABLE = re.compile(r"""(['"])(?:[^\w\s]{1,3}|<[a-z ]+>|\\t)\1""")
_QUOTED = re.compile(r"b?'[^']*'" + r'|b?"[^"]*"')


def _undecodable(exc: UnicodeDecodeError) -> str:
    """Where a file stops being UTF-8: the byte's value and offset, nothing around it."""
    return f"byte 0x{exc.object[exc.start]:02x} at offset {exc.start}"


def without_content(message: str) -> str:
    """A library's error message with the file's own text taken out, for an error line: a
    parser that quotes what it found (``found undefined alias 'X'``, ``Not a gzipped file
    (b'ro')``, ``could not convert string 'X' to float``) would print part of whatever
    file the user pointed at, perhaps by mistake. The punctuation it expected and its
    markers stay; other quoted text becomes ``'...'``.

    Parameters
    ----------
    message : str

    Returns
    -------
    str

    Examples
    --------
    >>> without_content("found undefined alias 'secret'")
    "found undefined alias '...'"
    >>> without_content("expected ',' or ']', but got '<stream end>'")
    "expected ',' or ']', but got '<stream end>'"
    """
    return _QUOTED.sub(
        lambda m: m.group(0) if _QUOTABLE.fullmatch(m.group(0)) else "'...'", str(message)
    )


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def beside(path: str | os.PathLike, tag: str) -> Path:
    """The file beside ``path`` that holds a run's record of kind ``tag`` (``"partial"``:
    an interrupted run's, ``"failed"``: a failing verdict's) instead of ``path``.

    Parameters
    ----------
    path : path-like
    tag : str

    Returns
    -------
    Path
        ``tag`` inserted before the last suffix.

    Examples
    --------
    >>> beside("out/sweep.json", "partial").as_posix(), beside("plan", "failed").name
    ('out/sweep.partial.json', 'plan.failed')
    """
    p = Path(path)
    return p.with_name(f"{p.stem}.{tag}{p.suffix}" if p.stem else f"{p.name}.{tag}")


def atomic_write(
    path: str | os.PathLike, write: Callable[[Path], None], *, partial: bool = False
) -> Path:
    """Call ``write(tmp_path)`` on a temporary file beside ``path``, then rename it over
    ``path``. On any error the temporary file is removed and ``path`` is untouched.

    Parameters
    ----------
    path : path-like
        Destination; its directory is created if missing.
    write : callable
        Writes the whole content to the path it is given.
    partial : bool
        The file is the record of an interrupted run (``X.partial.json``): inside
        :func:`staged_outputs` an interrupted block puts only such files in place. A
        complete file, once in place, removes the partial record beside it (now stale).

    Returns
    -------
    Path
        The destination.
    """
    dest = Path(path)
    stage = _STAGE.get()
    if stage is not None:
        stage._make_parents(dest)
    else:
        dest.parent.mkdir(parents=True, exist_ok=True)
    tmp = _temp_beside(dest, "tmp")
    try:
        write(tmp)
        # mkstemp creates 0600 files; give the result the mode a plain open() would.
        os.chmod(tmp, 0o666 & ~_umask())
        if stage is not None:
            stage._hold(dest, tmp, partial)
        else:
            os.replace(tmp, dest)
            if not partial:  # the complete result: an interrupted run's record is stale
                beside(dest, "partial").unlink(missing_ok=True)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return dest


def _temp_beside(dest: Path, kind: str) -> Path:
    fd, name = tempfile.mkstemp(prefix=f".{dest.name}.", suffix=f".{kind}", dir=dest.parent)
    os.close(fd)
    return Path(name)


class Outputs:
    """Files written inside one :func:`staged_outputs` block, not yet in place.

    What the block's end does with them:

    - the block ends normally: every file goes into place, and the record an interrupted
      run left beside each (``X.partial.json``, :func:`beside`) is removed, now stale;
    - the block ends normally after :meth:`keep_earlier` (a verdict that fails: a plan
      infeasible, a study whose checks fail): a file that does not exist yet goes into
      place, one that exists is left as it was and this run's version is written beside
      it (``X.failed.json``); the partial records the block itself wrote on the way to a
      complete file it wrote (a study's, between its cases) are dropped either way;
    - the block raises :class:`~needlekit.errors.Interrupted`: the partial records
      (``atomic_write(..., partial=True)``) go into place, and the complete files of
      the work finished (a study's finished case) where no file exists yet; a file that
      exists is left as it was;
    - the block raises anything else: nothing goes into place.
    """

    def __init__(self) -> None:
        self.pending: dict[Path, tuple[Path, bool]] = {}  # destination -> (temp, partial)
        self.new_dirs: list[Path] = []  # folders this block created, outermost first
        self.failed = False
        #: (destination kept, where this run's version went), after a failing verdict
        self.diverted: list[tuple[Path, Path]] = []

    def keep_earlier(self) -> None:
        """The run's verdict fails: it replaces no file that exists (see the class).

        Returns
        -------
        None
        """
        self.failed = True

    def _make_parents(self, dest: Path) -> None:
        missing = []
        d = dest.parent
        while not d.exists() and d != d.parent:
            missing.append(d)
            d = d.parent
        dest.parent.mkdir(parents=True, exist_ok=True)
        self.new_dirs.extend(reversed(missing))

    def _hold(self, dest: Path, tmp: Path, partial: bool = False) -> None:
        key = Path(os.path.abspath(dest))
        earlier = self.pending.pop(key, None)
        if earlier is not None:  # the same file written twice: the last version wins
            earlier[0].unlink(missing_ok=True)
        self.pending[key] = (tmp, partial)

    def _target(self, dest: Path, partial: bool) -> Path:
        if self.failed and not partial and os.path.lexists(dest):
            self.diverted.append((dest, beside(dest, "failed")))
            return beside(dest, "failed")
        return dest

    def _commit(self, *, interrupted: bool = False) -> None:
        """Move the files into place (when ``interrupted``, the partial records and the
        new files only); if one move fails, put back what was there."""
        if interrupted:
            for dest, (tmp, partial) in list(self.pending.items()):
                if not partial and os.path.lexists(dest):
                    tmp.unlink(missing_ok=True)
                    del self.pending[dest]
        complete = [d for d, (_, partial) in self.pending.items() if not partial]
        if not interrupted:  # the run finished: the partial records it wrote on the way
            # to a complete file are stale, whatever its verdict (an earlier run's stay
            # when the verdict fails: nothing earlier changes)
            for dest in complete:
                done = self.pending.pop(beside(dest, "partial"), None)  # keys: absolute
                if done is not None:
                    done[0].unlink(missing_ok=True)
        moved: list[tuple[Path, Path | None]] = []
        try:
            for dest, (tmp, partial) in list(self.pending.items()):
                target = self._target(dest, partial)
                backup = _keep_copy(target)
                try:
                    os.replace(tmp, target)
                except BaseException:
                    if backup is not None:
                        backup.unlink(missing_ok=True)
                    raise
                del self.pending[dest]
                moved.append((target, backup))
        except BaseException:
            for dest, backup in reversed(moved):
                if backup is not None:
                    os.replace(backup, dest)
                else:
                    dest.unlink(missing_ok=True)
            self._discard()
            raise
        for _, backup in moved:
            if backup is not None:
                backup.unlink(missing_ok=True)
        if not (interrupted or self.failed):  # the run finished: its partial records are stale
            for dest in complete:
                beside(dest, "partial").unlink(missing_ok=True)

    def _discard(self) -> None:
        """Remove the files not yet in place and the folders made for them (if empty)."""
        for tmp, _ in self.pending.values():
            tmp.unlink(missing_ok=True)
        self.pending.clear()
        for d in reversed(self.new_dirs):
            try:
                d.rmdir()
            except OSError:  # not empty (something else was written there) or gone
                pass
        self.new_dirs.clear()


def _keep_copy(dest: Path) -> Path | None:
    """A hard link (else a copy) of the file at ``dest``, to restore it; None if none."""
    if not os.path.lexists(dest):
        return None
    backup = _temp_beside(dest, "old")
    backup.unlink()
    try:
        os.link(dest, backup, follow_symlinks=False)
    except OSError:  # a file system without hard links
        shutil.copy2(dest, backup, follow_symlinks=False)
    return backup


_STAGE: contextvars.ContextVar[Outputs | None] = contextvars.ContextVar(
    "needlekit_output_stage", default=None
)


@contextmanager
def staged_outputs() -> Iterator[Outputs]:
    """Write several files as one unit: all of them, or none.

    Inside the block, every :func:`atomic_write` (and so :func:`write_text`,
    :func:`write_json` and every writer built on them) writes its temporary file beside
    the destination but does not rename it yet. When the block ends normally, all files
    are moved into place together; if the block raises (or a move fails), the temporary
    files and the folders made for them are removed and every file that was already
    there is left (or put back) as it was. Two outcomes replace no file that exists
    (:class:`Outputs`): a block that raises :class:`~needlekit.errors.Interrupted` puts
    only the partial record written for the stopped run in place (``X.partial.json``
    beside ``X.json``), and a block whose run called :meth:`Outputs.keep_earlier` (a
    failing verdict) writes its version of an existing file beside it
    (``X.failed.json``). Blocks nest: an inner block joins the outer one, whose end
    decides.

    Yields
    ------
    Outputs
        The files held (the outermost block's).

    Examples
    --------
    >>> import tempfile
    >>> from pathlib import Path
    >>> d = Path(tempfile.mkdtemp())
    >>> _ = write_text(d / "a.txt", "old")
    >>> try:
    ...     with staged_outputs():
    ...         _ = write_text(d / "a.txt", "new")
    ...         raise RuntimeError("the second file could not be made")
    ... except RuntimeError:
    ...     pass
    >>> (d / "a.txt").read_text(), sorted(p.name for p in d.iterdir())
    ('old', ['a.txt'])
    >>> with staged_outputs() as outputs:
    ...     _ = write_text(d / "a.txt", "infeasible")
    ...     outputs.keep_earlier()
    >>> (d / "a.txt").read_text(), (d / "a.failed.txt").read_text()
    ('old', 'infeasible')
    """
    outer = _STAGE.get()
    if outer is not None:  # an outer block commits
        yield outer
        return
    stage = Outputs()
    token = _STAGE.set(stage)
    try:
        yield stage
    except Interrupted:  # the partial record written for the stopped run is kept
        _STAGE.reset(token)
        stage._commit(interrupted=True)
        raise
    except BaseException:
        _STAGE.reset(token)
        stage._discard()
        raise
    _STAGE.reset(token)
    stage._commit()


def _read_only(mode: int) -> bool:
    # No write permission for anyone: refused even for root, who could write anyway,
    # because the owner marked it so (a rename would silently bypass the mark).
    return not mode & (stat.S_IWUSR | stat.S_IWGRP | stat.S_IWOTH)


def _folder_problem(d: Path, *, itself: bool = False) -> str | None:
    """Why new files cannot be made in the existing folder ``d`` (None if they can);
    ``itself``: the reason is about the path being checked, not one of its folders."""
    name = "" if itself else f"folder {d} "
    try:
        mode = d.stat().st_mode
    except OSError as exc:
        return f"{name}cannot be read ({exc.strerror})"
    if _read_only(mode):
        return f"{name}is read-only"
    if not os.access(d, os.W_OK | os.X_OK):
        return f"{name}is not writable (permission denied)"
    try:  # the real test (read-only file systems, ACLs, quotas): create a file and remove it
        probe = _temp_beside(d / "needlekit-probe", "probe")
    except OSError as exc:
        return f"{name}is not writable ({exc.strerror})"
    probe.unlink()
    return None


def _nearest_existing(p: Path) -> Path:
    d = p
    while not os.path.lexists(d) and d != d.parent:
        d = d.parent
    return d


def output_path_problem(path: str | os.PathLike, *, folder: bool = False) -> str | None:
    """Why an output could not be written at ``path``, checked before any work is done.

    Nothing is created or left behind: missing folders are only checked to be creatable
    (their nearest existing ancestor is a writable folder), and writability is tested by
    creating and removing a file.

    Parameters
    ----------
    path : path-like
        The output file, or folder when ``folder`` is true.
    folder : bool
        Whether an output folder (that files are written into) is meant.

    Returns
    -------
    str or None
        The reason, e.g. ``"is a folder, expected a file"`` or ``"folder /data is
        read-only"``; None when the path can be written.

    Examples
    --------
    >>> import tempfile
    >>> d = tempfile.mkdtemp()
    >>> output_path_problem(d)
    'is a folder, expected a file'
    >>> output_path_problem(d, folder=True) is None
    True
    """
    p = Path(path)
    if str(path) == "":
        return "the path is empty"
    if os.path.lexists(p):
        if p.is_dir():
            return _folder_problem(p, itself=True) if folder else "is a folder, expected a file"
        if folder:
            return "is a file, expected a folder"
        if not p.is_file() and not p.is_symlink():
            return "is not a regular file (a device, pipe or socket)"
        if p.is_file():
            mode = p.stat().st_mode
            if _read_only(mode):
                return "is read-only"
            if not os.access(p, os.W_OK):
                return "is not writable (permission denied)"
        return _folder_problem(p.parent if str(p.parent) else Path("."))
    base = _nearest_existing(p.parent)
    if not base.is_dir():
        return f"cannot be created: {base} is not a folder"
    return _folder_problem(base)


def write_text(path: str | os.PathLike, text: str, *, partial: bool = False) -> Path:
    """Write text atomically (UTF-8).

    Parameters
    ----------
    path : path-like
    text : str
    partial : bool
        An interrupted run's record (:func:`atomic_write`).

    Returns
    -------
    Path
    """
    return atomic_write(path, lambda p: p.write_text(text, encoding="utf-8"), partial=partial)


def write_bytes(path: str | os.PathLike, data: bytes) -> Path:
    """Write bytes atomically.

    Parameters
    ----------
    path : path-like
    data : bytes

    Returns
    -------
    Path
    """
    return atomic_write(path, lambda p: p.write_bytes(data))


def write_json(path: str | os.PathLike, data: Any, *, partial: bool = False) -> Path:
    """Write JSON atomically (UTF-8, indented, trailing newline).

    Parameters
    ----------
    path : path-like
    data : object
        JSON-serialisable; NaN and infinity are refused (:func:`json_text`) before anything
        is written.
    partial : bool
        An interrupted run's record (:func:`atomic_write`).

    Returns
    -------
    Path

    Raises
    ------
    OutputError
        A number in ``data`` is not finite (named by its field).
    """
    text = json_text(data, Path(path).name, indent=2, ensure_ascii=False) + "\n"
    return write_text(path, text, partial=partial)


def read_json_object(path: str | os.PathLike, what: str) -> dict:
    """Read a JSON file whose top level is an object, with one-line errors naming it.

    Parameters
    ----------
    path : path-like
    what : str
        What the file is, for messages (``"plan"``, ``"markups"``).

    Returns
    -------
    dict

    Raises
    ------
    InvalidInputError
        Missing file, not JSON, or not an object at the top level.
    """
    p = Path(path)
    if not p.is_file():
        raise InvalidInputError(str(p), f"{what} file not found")
    try:
        data = json.loads(p.read_text(encoding="utf-8"))
    except UnicodeDecodeError as exc:
        raise InvalidInputError(
            str(p), f"not a JSON {what} file (not UTF-8 text: {_undecodable(exc)})"
        ) from None
    except (OSError, json.JSONDecodeError) as exc:
        raise InvalidInputError(
            str(p), f"not a JSON {what} file ({without_content(exc)})"
        ) from None
    except RecursionError:
        raise InvalidInputError(str(p), "nested too deeply to be a needlekit file") from None
    if not isinstance(data, dict):
        raise InvalidInputError(str(p), "expected a JSON object at the top level")
    check_document(data, p.name)
    return data
