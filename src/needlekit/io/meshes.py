"""Triangle mesh files: STL, OBJ and PLY through trimesh, legacy VTK ``POLYDATA`` through
a small reader here (as 3D Slicer exports surfaces). Coordinates are taken as they are in
the file (mm); the scenario loader applies any frame change.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import trimesh

from needlekit._numbers import ANY_MM
from needlekit._validation import check_array
from needlekit.errors import InvalidInputError
from needlekit.io.files import atomic_write, without_content

__all__ = ["read_mesh", "write_mesh"]

_TRIMESH_TYPES = {".stl": "stl", ".obj": "obj", ".ply": "ply"}


# ----------------------------------------------------------------------------------------
# reading and writing


def _read_vtk_polydata(path: Path) -> trimesh.Trimesh:
    """Legacy VTK ASCII ``POLYDATA`` (versions 2 to 5.1): points and polygons/strips."""
    where = str(path)
    lines = path.read_text(encoding="utf-8", errors="replace").splitlines()
    if len(lines) < 4 or not lines[0].startswith("# vtk DataFile"):
        raise InvalidInputError(where, "not a legacy VTK file ('# vtk DataFile' header)")
    if lines[2].strip().upper() != "ASCII":
        raise InvalidInputError(where, f"only ASCII VTK is supported, got {lines[2].strip()!r}")
    body = [ln.split() for ln in lines[3:]]
    pos = 0

    def next_line():
        nonlocal pos
        while pos < len(body) and not body[pos]:
            pos += 1
        if pos >= len(body):
            return None
        pos += 1
        return body[pos - 1]

    def numbers(count, kind):
        nonlocal pos
        out = []
        while len(out) < count:
            line = next_line()
            if line is None:
                raise InvalidInputError(where, f"file ends inside a list of {count} numbers")
            out.extend(line)
        try:
            return np.array(out[:count], dtype=kind)
        except ValueError as exc:
            raise InvalidInputError(
                where, f"bad number in VTK data: {without_content(exc)}"
            ) from exc

    first = next_line()
    if first is None or [t.upper() for t in first] != ["DATASET", "POLYDATA"]:
        raise InvalidInputError(where, f"expected 'DATASET POLYDATA', got {first}")
    points = None
    triangles = []
    while (line := next_line()) is not None:
        key = line[0].upper()
        if key == "POINTS":
            points = numbers(3 * int(line[1]), np.float64).reshape(-1, 3)
        elif key in ("POLYGONS", "TRIANGLE_STRIPS", "VERTICES", "LINES"):
            n, size = int(line[1]), int(line[2])
            peek = pos
            nxt = next_line()
            if nxt is not None and nxt[0].upper() == "OFFSETS":  # version 5.1
                offsets = numbers(n, np.int64)
                conn_head = next_line()
                if conn_head is None or conn_head[0].upper() != "CONNECTIVITY":
                    raise InvalidInputError(where, "OFFSETS not followed by CONNECTIVITY")
                conn = numbers(size, np.int64)
                cells = [conn[offsets[c] : offsets[c + 1]] for c in range(n - 1)]
            else:
                pos = peek
                flat = numbers(size, np.int64)
                cells, at = [], 0
                for _ in range(n):
                    cells.append(flat[at + 1 : at + 1 + flat[at]])
                    at += 1 + flat[at]
            for cell in cells if key in ("POLYGONS", "TRIANGLE_STRIPS") else ():
                if len(cell) < 3:
                    raise InvalidInputError(where, f"a {key} cell has {len(cell)} < 3 points")
                for t in range(len(cell) - 2):
                    if key == "POLYGONS":  # fan (convex polygons)
                        triangles.append((cell[0], cell[t + 1], cell[t + 2]))
                    elif t % 2 == 0:  # strips alternate orientation
                        triangles.append((cell[t], cell[t + 1], cell[t + 2]))
                    else:
                        triangles.append((cell[t + 1], cell[t], cell[t + 2]))
        elif key == "METADATA":  # version 5.1: skip up to the next blank line
            while pos < len(body) and body[pos]:
                pos += 1
        elif key in ("POINT_DATA", "CELL_DATA"):
            break
        else:
            raise InvalidInputError(where, f"unsupported VTK section {line[0]!r}")
    if points is None or not triangles:
        raise InvalidInputError(where, "VTK file has no POINTS or no POLYGONS")
    faces = np.array(triangles, dtype=np.int64)
    if faces.min() < 0 or faces.max() >= len(points):
        raise InvalidInputError(where, f"polygon index out of range 0..{len(points) - 1}")
    return trimesh.Trimesh(points, faces, process=True)


def read_mesh(path: str | os.PathLike) -> trimesh.Trimesh:
    """Read a triangle mesh (coordinates in RAS mm) from STL, OBJ, PLY or legacy VTK.

    Parameters
    ----------
    path : path-like
        ``.stl``, ``.obj``, ``.ply`` (trimesh) or ``.vtk`` (ASCII ``POLYDATA``; polygons
        are fanned and strips split into triangles).

    Returns
    -------
    trimesh.Trimesh
        With duplicate vertices merged (STL stores each triangle's corners apart).

    Raises
    ------
    InvalidInputError
        Naming the file: missing, unsupported extension, unreadable, no triangles, or a
        coordinate that is not finite or past a kilometre (the numeric gate,
        :mod:`needlekit._numbers`).

    Examples
    --------
    >>> import tempfile
    >>> with tempfile.TemporaryDirectory() as tmp:
    ...     p = write_mesh(Path(tmp) / "ball.vtk", trimesh.creation.icosphere(1, 5.0))
    ...     mesh = read_mesh(p)
    >>> len(mesh.faces), mesh.is_watertight
    (80, True)
    """
    p = Path(path)
    ext = p.suffix.lower()
    if ext not in (*_TRIMESH_TYPES, ".vtk"):
        raise InvalidInputError(str(p), "unsupported extension; expected .stl, .obj, .ply or .vtk")
    if not p.is_file():
        raise InvalidInputError(str(p), "file not found")
    if ext == ".vtk":
        mesh = _read_vtk_polydata(p)
    else:
        mesh = _read_trimesh(p, _TRIMESH_TYPES[ext])
    if len(mesh.faces) == 0:
        raise InvalidInputError(str(p), "mesh has no triangles")
    check_array(mesh.vertices, f"{p}: vertex coordinates", ANY_MM)
    if ext != ".vtk":
        mesh.process()  # merge duplicate vertices (as trimesh.load does), now on finite data
    return mesh


#: What a file of each kind is, for the message when it is not one.
_FORMAT_NAMES = {"stl": "STL (ASCII or binary)", "obj": "Wavefront OBJ", "ply": "PLY"}


def _read_trimesh(p: Path, file_type: str) -> trimesh.Trimesh:
    """The triangles of an STL, OBJ or PLY file as trimesh reads them (not yet processed),
    or one error naming the file and the format expected."""
    expected = f"not a readable {_FORMAT_NAMES[file_type]} triangle mesh"
    try:
        mesh = trimesh.load(p, file_type=file_type, force="mesh", process=False)
    except (ValueError, EOFError, UnicodeDecodeError) as exc:  # a parser's own verdict
        why = without_content(str(exc)).strip().rstrip("!.")
        raise InvalidInputError(str(p), f"{expected} ({why})" if why else expected) from None
    except Exception:  # trimesh falls over in other ways on garbage (an import, an index)
        raise InvalidInputError(str(p), expected) from None
    if not isinstance(mesh, trimesh.Trimesh):
        raise InvalidInputError(str(p), f"{expected} (it holds no triangles)")
    return mesh


def _vtk_text(mesh: trimesh.Trimesh) -> str:
    v, f = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    out = ["# vtk DataFile Version 4.2", "needlekit mesh (RAS mm)", "ASCII", "DATASET POLYDATA"]
    out.append(f"POINTS {len(v)} double")
    out.extend(f"{x!r} {y!r} {z!r}" for x, y, z in v.tolist())
    out.append(f"POLYGONS {len(f)} {4 * len(f)}")
    out.extend(f"3 {a} {b} {c}" for a, b, c in f.tolist())
    return "\n".join(out) + "\n"


def write_mesh(path: str | os.PathLike, mesh: trimesh.Trimesh) -> Path:
    """Write a triangle mesh atomically (STL binary, OBJ, PLY binary or legacy VTK ASCII).

    Parameters
    ----------
    path : path-like
        Destination; the format follows the extension.
    mesh : trimesh.Trimesh

    Returns
    -------
    Path
        The destination.
    """
    dest = Path(path)
    ext = dest.suffix.lower()
    if ext == ".vtk":
        raw = _vtk_text(mesh).encode()
    elif ext in _TRIMESH_TYPES:
        raw = mesh.export(file_type=_TRIMESH_TYPES[ext])
        raw = raw.encode() if isinstance(raw, str) else raw
    else:
        raise InvalidInputError(
            str(dest), "unsupported extension; expected .stl, .obj, .ply or .vtk"
        )
    return atomic_write(dest, lambda p: p.write_bytes(raw))
