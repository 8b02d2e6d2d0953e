"""The files and folders a command reads and writes, declared in the parser and checked
before any work starts.

Every path argument is added with :func:`add_output` or :func:`add_input`, which record
on the (sub)parser what the argument is: an output file or folder, an input file or
folder. :func:`check_paths` then checks all of them at once, before the command's module
is even imported, so a bad ``--report`` costs milliseconds, not a finished sweep:

- an input exists, is what was expected (file or folder) and can be read;
- an output can be written: it is not a folder where a file is expected (nor the
  reverse), an existing file is writable, and its folder exists and is writable or can be
  created (tested by creating and removing a file; nothing is left behind);
- no path is given to two output arguments, and no output would overwrite an input.
"""

from __future__ import annotations

import argparse
import os
from dataclasses import dataclass
from pathlib import Path

from needlekit.errors import InvalidInputError
from needlekit.io.files import output_path_problem

#: Namespace attribute under which each (sub)parser lists its path arguments.
_SPECS = "_path_specs"


@dataclass(frozen=True)
class PathArg:
    """One path argument of a command.

    Attributes
    ----------
    dest : str
        Its attribute in the parsed namespace.
    name : str
        How messages name it: the flag (``--report``) or the positional's name.
    output : bool
        Written (True) or read (False).
    folder : bool
        A folder rather than a file.
    contents : tuple of str
        For an output folder: the files the command writes in it (relative paths),
        each checked like an output file.
    """

    dest: str
    name: str
    output: bool
    folder: bool = False
    contents: tuple[str, ...] = ()


def _register(p: argparse.ArgumentParser, arg: PathArg) -> None:
    p.set_defaults(**{_SPECS: (*(p.get_default(_SPECS) or ()), arg)})


def add_output(
    p: argparse.ArgumentParser,
    flag: str,
    *,
    folder: bool = False,
    contents: tuple[str, ...] = (),
    **kwargs,
) -> argparse.Action:
    """Add an output file (or folder) argument, checked by :func:`check_paths`.

    Parameters
    ----------
    p : argparse.ArgumentParser
    flag : str
        E.g. ``"--out"``.
    folder : bool
        An output folder rather than a file.
    contents : tuple of str
        The files written in the folder.
    **kwargs
        Passed to ``add_argument`` (``type`` is always :class:`~pathlib.Path`).

    Returns
    -------
    argparse.Action
    """
    action = p.add_argument(flag, type=Path, **kwargs)
    _register(p, PathArg(action.dest, flag, True, folder, tuple(contents)))
    return action


def add_input(
    p: argparse.ArgumentParser, name: str, *, folder: bool = False, **kwargs
) -> argparse.Action:
    """Add an input file (or folder) argument, checked by :func:`check_paths`.

    Parameters
    ----------
    p : argparse.ArgumentParser
    name : str
        A positional's name (``"scenario"``) or a flag (``"--start-pose"``).
    folder : bool
        An input folder rather than a file.
    **kwargs
        Passed to ``add_argument`` (``type`` is always :class:`~pathlib.Path`).

    Returns
    -------
    argparse.Action
    """
    action = p.add_argument(name, type=Path, **kwargs)
    _register(p, PathArg(action.dest, name, False, folder))
    return action


def _input_problem(path: Path, folder: bool) -> str | None:
    if not path.exists():
        return "not found"
    if folder and not path.is_dir():
        return "is not a folder"
    if not folder and path.is_dir():
        return "is a folder, expected a file"
    if not folder and not path.is_file():
        return "is not a regular file"
    if not os.access(path, os.R_OK | (os.X_OK if folder else 0)):
        return "cannot be read (permission denied)"
    return None


def check_paths(args: argparse.Namespace) -> None:
    """Check every path argument of the parsed command (see the module's description).

    Parameters
    ----------
    args : argparse.Namespace
        As parsed by the ``needlekit`` parser.

    Returns
    -------
    None

    Raises
    ------
    InvalidInputError
        ``"<flag>: <path>: <reason>"`` for the first path at fault.
    """
    specs: tuple[PathArg, ...] = getattr(args, _SPECS, None) or ()
    given = [(s, Path(getattr(args, s.dest))) for s in specs if getattr(args, s.dest) is not None]
    for spec, path in given:
        if not spec.output:
            problem = _input_problem(path, spec.folder)
            if problem:
                raise InvalidInputError(spec.name, f"{path}: {problem}")
    inputs = {os.path.realpath(p): s.name for s, p in given if not s.output}
    outputs: dict[str, str] = {}
    for spec, path in given:
        if not spec.output:
            continue
        problem = output_path_problem(path, folder=spec.folder)
        if problem:
            raise InvalidInputError(spec.name, f"{path}: {problem}")
        for rel in spec.contents:
            problem = output_path_problem(path / rel)
            if problem:
                raise InvalidInputError(spec.name, f"{path / rel}: {problem}")
        key = os.path.realpath(path)
        if key in inputs:
            raise InvalidInputError(
                spec.name, f"{path}: is the input {inputs[key]}; it would be overwritten"
            )
        if key in outputs:
            raise InvalidInputError(spec.name, f"{path}: also given to {outputs[key]}")
        outputs[key] = spec.name
