"""A whole 3D Slicer scene: surface models and markups in one ``.mrml`` scene, written as a
Slicer data bundle (``.mrb``) or as a folder.

Slicer opens a ``.mrb`` (a zip of a scene file and its data files) in one step: drag it
onto the window, or File > Add Data. This module writes it with numpy and the standard
library alone (no VTK, no Slicer): the scene file is MRML (XML), each surface a legacy
binary VTK ``POLYDATA`` file, each markup a Markups JSON file
(:mod:`needlekit.io.markups`).

Layout, inside the bundle (under one top folder, as Slicer saves bundles) or the folder::

    <name>.mrml
    Data/<model>.vtk          one per surface
    Data/<markup>.mrk.json    one per markup (fiducials, lines, curves)

Frames: needlekit works in RAS mm, as Slicer's scene does. Files store **LPS**, as
Slicer writes them: a model file's second header line says ``SPACE=LPS`` (Slicer >= 4.11
reads it and flips x and y back; a file without it is read as LPS too) and its points and
normals have x and y negated; markups files say ``"coordinateSystem": "LPS"``. Nodes get no
parent transform: what Slicer shows is in the patient RAS frame the masks and CT share.

Slicer names a node after the ``name`` in its markups file and after the MRML ``name`` of
a model; file names are those names made safe (letters, digits, ``-``, ``_``), unique.

Examples
--------
>>> import tempfile, zipfile
>>> from pathlib import Path
>>> d = Path(tempfile.mkdtemp())
>>> tetra = SlicerModel("vessel", [[0, 0, 0], [10, 0, 0], [0, 10, 0], [0, 0, 10]],
...                     [[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]], color=(1, 0, 0))
>>> out = write_slicer_scene(d / "case.mrb", [tetra], [])
>>> sorted(zipfile.ZipFile(out).namelist())
['case/Data/vessel.vtk', 'case/case.mrml']
"""

from __future__ import annotations

import io
import os
import re
import zipfile
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from xml.sax.saxutils import quoteattr

import numpy as np

from needlekit._validation import as_points
from needlekit.errors import InvalidInputError
from needlekit.io._markups_format import _flip_xy
from needlekit.io.files import staged_outputs, write_bytes
from needlekit.io.finite_json import json_text
from needlekit.io.markups import _color, _markup, _name, markups_document

__all__ = [
    "SCENE_FILE_KINDS",
    "SlicerMarkup",
    "SlicerModel",
    "model_vtk_bytes",
    "scene_files",
    "write_slicer_scene",
]

#: What ``--out`` may name: a Slicer data bundle, or a folder for the scene and its files.
SCENE_FILE_KINDS = (".mrb",)

#: The header's second line of a model file: Slicer reads the frame from ``SPACE=``.
_VTK_TITLE = "needlekit surface. SPACE=LPS"

#: The MRML element, node class and display node class of each markup type.
_MARKUP_NODES = {
    "Fiducial": ("MarkupsFiducial", "vtkMRMLMarkupsFiducialNode", "MarkupsFiducialDisplay",
                 "vtkMRMLMarkupsFiducialDisplayNode"),
    "Line": ("MarkupsLine", "vtkMRMLMarkupsLineNode", "MarkupsDisplay",
             "vtkMRMLMarkupsDisplayNode"),
    "Curve": ("MarkupsCurve", "vtkMRMLMarkupsCurveNode", "MarkupsDisplay",
              "vtkMRMLMarkupsDisplayNode"),
}  # fmt: skip


@dataclass
class SlicerModel:
    """A surface for the scene: a Slicer Model node.

    Attributes
    ----------
    name : str
        The node's name (e.g. the structure's).
    vertices_mm : array_like, shape (v, 3)
        RAS mm.
    faces : array_like of int, shape (f, 3)
        Triangles, counter-clockwise seen from outside (the normals point out).
    color : tuple of 3 float
        RGB in [0, 1].
    opacity : float
        In [0, 1].
    """

    name: str
    vertices_mm: np.ndarray
    faces: np.ndarray
    color: tuple = (0.8, 0.8, 0.8)
    opacity: float = 1.0

    def __post_init__(self) -> None:
        self.vertices_mm, _ = as_points(self.vertices_mm, f"{self.name}.vertices_mm")
        f = np.asarray(self.faces)
        if f.size == 0:
            f = f.reshape(0, 3)
        if f.ndim != 2 or f.shape[1] != 3 or not np.issubdtype(f.dtype, np.integer):
            raise InvalidInputError(
                f"{self.name}.faces", f"expected (f, 3) integers, got {f.shape}"
            )
        if f.size and (f.min() < 0 or f.max() >= len(self.vertices_mm)):
            raise InvalidInputError(f"{self.name}.faces", "an index is outside the vertices")
        self.faces = f.astype(np.int64)
        self.color = tuple(_unit_numbers(self.color, 3, f"{self.name}.color"))
        self.opacity = _unit_numbers([self.opacity], 1, f"{self.name}.opacity")[0]


@dataclass
class SlicerMarkup:
    """A markup for the scene: one item made by :func:`needlekit.io.markups.markups_line`,
    :func:`~needlekit.io.markups.markups_curve` or :func:`fiducials_markup`, and how the
    scene draws it.

    Attributes
    ----------
    item : dict
        The markup (``type`` Fiducial, Line or Curve; positions in LPS as those write them).
    curve_type : str
        For a curve: how Slicer joins the control points (``"spline"``, ``"linear"``).
    line_diameter_mm : float, optional
        Of lines and curves, in mm; else Slicer's default (a fifth of the glyph size,
        which follows the view's zoom).
    glyph_scale : float
        Size of the control points' glyphs (% of the view; Slicer's default 3).
    extra : dict
        More attributes of the display node.
    """

    item: dict
    curve_type: str = "spline"
    line_diameter_mm: float | None = None
    glyph_scale: float = 3.0
    extra: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        kind = self.item.get("type") if isinstance(self.item, dict) else None
        if kind not in _MARKUP_NODES:
            raise InvalidInputError(
                "item", f"expected a Fiducial, Line or Curve markup, got {kind!r}"
            )
        if self.curve_type not in ("linear", "spline", "polynomial", "shortestDistanceOnSurface"):
            raise InvalidInputError("curve_type", f"not a Slicer curve type: {self.curve_type!r}")


def fiducials_markup(points_mm, labels: Sequence[str], *, name: str, color=None) -> dict:
    """Points as a Slicer Markups **Point List** (type ``Fiducial``): one labelled control
    point each.

    Parameters
    ----------
    points_mm : array_like, shape (n, 3)
        RAS mm; n >= 1.
    labels : sequence of str
        One per point (Slicer shows them beside the points).
    name : str
    color : array_like, shape (3,), optional
        RGB in [0, 1].

    Returns
    -------
    dict
        One item of a markups document, positions in LPS.
    """
    pts, _ = as_points(points_mm, "points_mm")
    labels = list(labels)
    if len(pts) < 1 or len(labels) != len(pts):
        raise InvalidInputError(
            "labels", f"expected one label per point ({len(pts)}), got {len(labels)}"
        )
    item = _markup("Fiducial", _name(name), pts, labels, color=_color(color, "color"),
                   description="", point_labels=True)  # fmt: skip
    item.pop("measurements")  # a length means nothing for a point list
    return item


def _unit_numbers(values, n: int, name: str) -> list[float]:
    try:
        v = np.asarray(values, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        raise InvalidInputError(name, f"expected {n} numbers in [0, 1], got {values!r}") from None
    if v.shape != (n,) or not np.all(np.isfinite(v)) or np.any((v < 0) | (v > 1)):
        raise InvalidInputError(name, f"expected {n} numbers in [0, 1], got {values!r}")
    return [float(x) for x in v]


def _vertex_normals(v: np.ndarray, f: np.ndarray) -> np.ndarray:
    """Unit normals at the vertices: the faces' area-weighted normals summed."""
    n = np.zeros_like(v)
    if len(f):
        fn = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
        for k in range(3):
            np.add.at(n, f[:, k], fn)
    norm = np.linalg.norm(n, axis=1, keepdims=True)
    return np.divide(n, norm, out=np.zeros_like(n), where=norm > 0)


def model_vtk_bytes(vertices_mm, faces) -> bytes:
    """A surface as a legacy binary VTK ``POLYDATA`` file in LPS, as Slicer writes one.

    Points and normals are float32 (0.03 µm at 500 mm from the origin), big-endian as the
    format requires; the header's title says ``SPACE=LPS``.

    Parameters
    ----------
    vertices_mm : array_like, shape (v, 3)
        RAS mm.
    faces : array_like of int, shape (f, 3)

    Returns
    -------
    bytes
        The file: file version 4.2 (what Slicer 5 writes, read by every VTK), the points,
        the triangles and the point normals.
    """
    v = np.asarray(vertices_mm, dtype=np.float64).reshape(-1, 3)
    f = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    normals = _vertex_normals(v, f)
    out = io.BytesIO()
    head = f"# vtk DataFile Version 4.2\n{_VTK_TITLE}\nBINARY\nDATASET POLYDATA\n"
    out.write(head.encode())
    out.write(f"POINTS {len(v)} float\n".encode())
    out.write(_flip_xy(v).astype(">f4").tobytes())
    cells = np.hstack([np.full((len(f), 1), 3, dtype=np.int64), f]).astype(">i4")
    out.write(f"\nPOLYGONS {len(f)} {4 * len(f)}\n".encode())
    out.write(cells.tobytes())
    out.write(f"\nPOINT_DATA {len(v)}\nNORMALS Normals float\n".encode())
    out.write(_flip_xy(normals).astype(">f4").tobytes())
    out.write(b"\n")
    return out.getvalue()


def _safe(name: str, taken: set[str]) -> str:
    """A file name from a node name: letters, digits, ``-``, ``_``; unique in ``taken``."""
    base = re.sub(r"[^A-Za-z0-9_-]+", "_", name).strip("_") or "node"
    out, k = base, 1
    while out.lower() in taken:
        k += 1
        out = f"{base}_{k}"
    taken.add(out.lower())
    return out


def _attrs(**kv) -> str:
    return " ".join(f"{k}={quoteattr(str(v))}" for k, v in kv.items())


def _numbers(values) -> str:
    return " ".join(f"{float(x):.6g}" for x in values)


def _element(tag: str, **kv) -> str:
    return f" <{tag} {_attrs(**kv)}></{tag}>"


def scene_files(
    models: Sequence[SlicerModel], markups: Sequence[SlicerMarkup], *, name: str = "case"
) -> dict[str, bytes]:
    """Every file of the scene, by its path relative to the scene file's folder.

    Parameters
    ----------
    models : sequence of SlicerModel
    markups : sequence of SlicerMarkup
    name : str
        The scene file is ``<name>.mrml``.

    Returns
    -------
    dict
        ``{"<name>.mrml": ..., "Data/<file>": ...}``, the scene file first.
    """
    if not models and not markups:
        raise InvalidInputError("scene", "nothing to write: no model and no markup")
    taken: set[str] = set()
    lines = ['<?xml version="1.0" encoding="UTF-8"?>', '<MRML version="Slicer4.4.0" userTags="">']
    data: dict[str, bytes] = {}
    for i, m in enumerate(models, start=1):
        rel = f"Data/{_safe(m.name, taken)}.vtk"
        data[rel] = model_vtk_bytes(m.vertices_mm, m.faces)
        ids = (f"vtkMRMLModelNode{i}", f"vtkMRMLModelDisplayNode{i}", f"vtkMRMLModelStorageNode{i}")
        lines.append(_element("Model", id=ids[0], name=m.name,
                              references=f"display:{ids[1]};storage:{ids[2]};"))  # fmt: skip
        lines.append(_element(
            "ModelDisplay", id=ids[1], name="ModelDisplay", color=_numbers(m.color),
            opacity=f"{m.opacity:g}", visibility="true", visibility2D="true",
            visibility3D="true", sliceIntersectionThickness="2", backfaceCulling="false",
            scalarVisibility="false",
        ))  # fmt: skip
        lines.append(_element("ModelStorage", id=ids[2], name="ModelStorage", fileName=rel,
                              coordinateSystem="LPS"))  # fmt: skip
    for i, mk in enumerate(markups, start=1):
        item = mk.item
        tag, cls, display_tag, display_cls = _MARKUP_NODES[item["type"]]
        rel = f"Data/{_safe(item['name'], taken)}.mrk.json"
        data[rel] = (
            json_text(markups_document([item]), rel, indent=2, ensure_ascii=False) + "\n"
        ).encode()
        ids = (f"{cls}{i}", f"{display_cls}{i}", f"vtkMRMLMarkupsJsonStorageNode{i}")
        node = {"id": ids[0], "name": item["name"],
                "references": f"display:{ids[1]};storage:{ids[2]};", "locked": "true"}  # fmt: skip
        if item["type"] == "Curve":
            node["curveType"] = mk.curve_type
        lines.append(_element(tag, **node))
        shown = item.get("display", {})
        display = {"id": ids[1], "name": display_tag, "visibility": "true",
                   "glyphScale": f"{mk.glyph_scale:g}",
                   "pointLabelsVisibility": "true" if shown.get("pointLabelsVisibility") else "false",
                   "propertiesLabelVisibility": "true"}  # fmt: skip
        if mk.line_diameter_mm is not None:
            display["curveLineSizeMode"] = "UseLineDiameter"
            display["lineDiameter"] = f"{mk.line_diameter_mm:g}"
        if "color" in shown:
            display["color"] = display["selectedColor"] = _numbers(shown["color"])
        display.update(mk.extra)
        lines.append(_element(display_tag, **display))
        lines.append(_element("MarkupsJsonStorage", id=ids[2], name="MarkupsJsonStorage",
                              fileName=rel, coordinateSystem="LPS"))  # fmt: skip
    lines.append("</MRML>")
    return {f"{name}.mrml": ("\n".join(lines) + "\n").encode(), **data}


def _bundle(files: dict[str, bytes], top: str) -> bytes:
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", compression=zipfile.ZIP_DEFLATED, compresslevel=6) as z:
        for rel, raw in files.items():
            info = zipfile.ZipInfo(f"{top}/{rel}", date_time=(2020, 1, 1, 0, 0, 0))
            info.compress_type = zipfile.ZIP_DEFLATED
            info.external_attr = 0o644 << 16
            z.writestr(info, raw)
    return buf.getvalue()


def write_slicer_scene(
    out: str | os.PathLike,
    models: Sequence[SlicerModel],
    markups: Sequence[SlicerMarkup],
    *,
    name: str | None = None,
) -> Path:
    """Write a Slicer scene: a data bundle when ``out`` ends in ``.mrb``, else a folder.

    Parameters
    ----------
    out : path-like
        ``case.mrb`` (one zip file, opened by Slicer in one step), or a folder that gets
        ``<name>.mrml`` and ``Data/`` (open the ``.mrml`` file).
    models : sequence of SlicerModel
    markups : sequence of SlicerMarkup
    name : str, optional
        The scene's name (its ``.mrml`` file and, in a bundle, its top folder); default:
        the bundle's name without ``.mrb``, or ``case`` for a folder.

    Returns
    -------
    Path
        The bundle, or the scene file in the folder.
    """
    dest = Path(out)
    bundle = dest.suffix.lower() in SCENE_FILE_KINDS
    if name is None:
        name = dest.stem if bundle and dest.stem else "case"
    if not re.fullmatch(r"[A-Za-z0-9][A-Za-z0-9._-]*", name):
        raise InvalidInputError(
            "name", f"expected a plain file name (letters, digits, ._-), got {name!r}"
        )
    files = scene_files(models, markups, name=name)
    if bundle:
        return write_bytes(dest, _bundle(files, name))
    with staged_outputs():
        for rel, raw in files.items():
            write_bytes(dest / rel, raw)
    return dest / f"{name}.mrml"
