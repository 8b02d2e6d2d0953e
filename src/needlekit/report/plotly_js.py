"""Where a page's plotly.js comes from: inlined in the page, or one shared file per folder.

Every page needlekit writes (:func:`needlekit.report.html_page.write_report_html`,
:func:`needlekit.report.scene3d.write_scene_html`, ...) asks :func:`plotly_script` for the
tag that loads plotly.js:

- ``inline`` (the default): the library (4.8 MB) inlined in the page, which then opens
  offline on its own, wherever it is copied;
- ``shared``: ``plotly.min.js`` written once beside the page (not again when the same
  library is already there) and loaded relatively: the pages of one folder share one copy,
  each page is then 4.8 MB lighter, and the folder is what opens offline.

The command line's ``--plotly inline|shared`` sets the mode for the whole command
(:func:`plotly_mode`). This module imports no plotly, numpy nor anything heavy: the
command line sets the mode before any handler runs.
"""

from __future__ import annotations

import contextlib
import contextvars
import os
from collections.abc import Iterator
from pathlib import Path

from needlekit.errors import InvalidInputError
from needlekit.io.files import atomic_write

__all__ = ["PLOTLY_FILE", "PLOTLY_MODES", "plotly_mode", "plotly_script"]

#: The modes, as ``--plotly`` spells them.
PLOTLY_MODES = ("inline", "shared")
#: The shared library's file name, beside the pages that load it.
PLOTLY_FILE = "plotly.min.js"

_MODE: contextvars.ContextVar[str] = contextvars.ContextVar("needlekit_plotly", default="inline")


@contextlib.contextmanager
def plotly_mode(mode: str) -> Iterator[None]:
    """Within the block, pages get plotly.js the way ``mode`` says.

    Parameters
    ----------
    mode : {"inline", "shared"}

    Yields
    ------
    None
    """
    if mode not in PLOTLY_MODES:
        raise InvalidInputError(
            "--plotly", f"expected one of {', '.join(PLOTLY_MODES)}, got {mode!r}"
        )
    token = _MODE.set(mode)
    try:
        yield
    finally:
        _MODE.reset(token)


def current_mode() -> str:
    """The mode in force (``inline`` outside any :func:`plotly_mode` block).

    Returns
    -------
    str
    """
    return _MODE.get()


def _library() -> str:
    from plotly.offline import get_plotlyjs

    return get_plotlyjs()


def plotly_script(page: str | os.PathLike, mode: str | None = None) -> str:
    """The ``<script>`` that loads plotly.js in the page ``page``; in ``shared`` mode,
    ``plotly.min.js`` is written beside it first unless the same library is there.

    Parameters
    ----------
    page : path-like
        The page being written.
    mode : {"inline", "shared"}, optional
        Default: the mode in force (:func:`plotly_mode`).

    Returns
    -------
    str
        HTML: the library inlined, or a relative ``<script src>``.
    """
    mode = current_mode() if mode is None else mode
    if mode not in PLOTLY_MODES:
        raise InvalidInputError(
            "plotly", f"expected one of {', '.join(PLOTLY_MODES)}, got {mode!r}"
        )
    js = _library()
    if mode == "inline":
        return f'<script type="text/javascript">{js}</script>'
    dest = Path(os.path.abspath(page)).parent / PLOTLY_FILE
    data = js.encode("utf-8")
    same = dest.is_file() and dest.stat().st_size == len(data) and dest.read_bytes() == data
    if not same:
        atomic_write(dest, lambda p: p.write_bytes(data))
    return f'<script type="text/javascript" charset="utf-8" src="{PLOTLY_FILE}"></script>'
