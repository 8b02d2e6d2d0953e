"""Figures of the bevel-tip needle kinematics: forward and inverse steering, reachability.

:func:`write_kinematics_figures` computes fixed (seeded) examples with the library and
draws them with matplotlib's object API (``matplotlib.figure.Figure`` rendered by Agg: no
``pyplot``, no registry of open figures; the shared style is applied with a temporary
``matplotlib.rc_context``). Each figure is written atomically, then a
``demo.json`` lists the figures with the numbers they show and the round-trip errors
measured on the way, so the pictures can be checked against the library.

The computations (``_*_data``) and the drawings (``_plot_*``) are kept apart: the data
functions only call the library and return plain containers; the plot functions only
draw what they are given.

Figures, in the order they are returned:

1. ``forward_steering_planar.png``: the planar unicycle model, bevel side lambda = +1 and
   -1 and a bevel flip mid-insertion (S-curve), kappa0 = 1/50 per mm.
2. ``forward_steering_3d.png``: the SE(3) model under a few input sequences (arc, helix,
   S-curve, out-of-plane turn) with tip frames along the way.
3. ``inverse_steering.png``: transformation-matrix inverse steering from a tip pose to
   seeded random targets, and the planar way-point-wise steering of the lecture.
4. ``reachability.png``: single-arc reachability in the (radial, axial) half-plane for
   r_min = 50 mm, shortest arc-then-line paths and their length.
"""

from __future__ import annotations

import io
import os
from pathlib import Path
from typing import Any

import matplotlib
import numpy as np

from needlekit import __version__
from needlekit.errors import InvalidInputError
from needlekit.io.files import write_bytes, write_json
from needlekit.report._style import DEFAULT_DPI, _style
from needlekit.report.forward_figures import (
    _bevel_data,
    _bevel_json,
    _planar_data,
    _planar_json,
    _plot_bevel,
    _plot_planar,
)
from needlekit.report.inverse_figure import _inverse_data, _inverse_json, _plot_inverse
from needlekit.report.reachability_figure import _plot_reach, _reach_data, _reach_json

__all__ = ["FIGURE_NAMES", "kinematics_figures", "write_kinematics_figures"]

#: File names of the figures, in the order :func:`write_kinematics_figures` returns them.
FIGURE_NAMES: tuple[str, ...] = (
    "forward_steering_planar.png",
    "forward_steering_3d.png",
    "inverse_steering.png",
    "reachability.png",
)


def write_kinematics_figures(out_dir: str | os.PathLike, *, dpi: int = DEFAULT_DPI) -> list[Path]:
    """Write the kinematics figures as PNG files and a ``demo.json`` summary.

    Parameters
    ----------
    out_dir : path-like
        Folder to write into; created if missing. Existing files of the same names are
        replaced (each atomically: a file is either the old or the new one, never partial).
    dpi : int, default 150
        Resolution of the PNG files.

    Returns
    -------
    list of Path
        The figures, in the order of :data:`FIGURE_NAMES`. ``out_dir/demo.json`` (written
        last) lists them with the numbers they show: inputs and end states of the forward
        examples, the inverse-steering solutions (alpha, radius, phi, length per target),
        reachability counts and path lengths, and every round-trip error measured.

    Raises
    ------
    InvalidInputError
        ``dpi`` is not an integer in [30, 600].

    Notes
    -----
    Inputs are fixed and the random targets come from ``numpy.random.default_rng(0)``,
    so the output is the same on every run.

    Examples
    --------
    >>> import json, tempfile
    >>> from pathlib import Path
    >>> with tempfile.TemporaryDirectory() as d:
    ...     paths = write_kinematics_figures(d, dpi=60)
    ...     summary = json.loads((Path(d) / "demo.json").read_text())
    >>> len(paths), paths[0].name
    (4, 'forward_steering_planar.png')
    >>> summary["inverse"]["end_point_error_mm"] < 1e-9
    True
    """
    pngs, summary = kinematics_figures(dpi=dpi)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = [write_bytes(out / name, pngs[name]) for name in FIGURE_NAMES]
    write_json(out / "demo.json", summary)
    return paths


def kinematics_figures(*, dpi: int = DEFAULT_DPI) -> tuple[dict[str, bytes], dict[str, Any]]:
    """Draw the kinematics figures in memory.

    Parameters
    ----------
    dpi : int, default 150

    Returns
    -------
    pngs : dict of str to bytes
        Each figure's PNG, by its name in :data:`FIGURE_NAMES`.
    summary : dict
        What :func:`write_kinematics_figures` writes as ``demo.json``.

    Raises
    ------
    InvalidInputError
        ``dpi`` is not an integer in [30, 600].
    """
    if isinstance(dpi, bool) or not isinstance(dpi, (int, np.integer)) or not 30 <= dpi <= 600:
        raise InvalidInputError("dpi", f"expected an integer in [30, 600], got {dpi!r}")
    builders = (
        (_planar_data, _plot_planar, _planar_json, "forward_planar"),
        (_bevel_data, _plot_bevel, _bevel_json, "forward_3d"),
        (_inverse_data, _plot_inverse, _inverse_json, "inverse"),
        (_reach_data, _plot_reach, _reach_json, "reachability"),
    )
    pngs: dict[str, bytes] = {}
    summary: dict[str, Any] = {
        "needlekit_version": __version__,
        "figures": list(FIGURE_NAMES),
        "dpi": int(dpi),
    }
    with matplotlib.rc_context(_style()):
        for name, (data_fn, plot_fn, json_fn, key) in zip(FIGURE_NAMES, builders, strict=True):
            data = data_fn()
            buf = io.BytesIO()
            plot_fn(data).savefig(buf, format="png", dpi=int(dpi))
            pngs[name] = buf.getvalue()
            summary[key] = json_fn(data)
    return pngs, summary
