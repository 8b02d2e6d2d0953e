"""What a first preparation of a patient says while it runs: what it does, about how long
it takes, where it is kept, and how far it is.

On a terminal (stderr a TTY) one live line on stderr, drawn by ``tqdm`` as the project's
other progress bars are::

    preparing Med-RAD lung 1 (first use; about 17 s, kept in ~/.cache/needlekit/medrad-lung1-4969643a...): masks 3/5 [00:04]

Otherwise (a pipe, a file, a notebook, a batch worker) the same lines are logged at INFO
(``needlekit -v`` shows them): the opening line, each stage, and the end. Nothing goes to
stdout, so JSON printed there is never mixed with it. A patient found in the cache says
nothing.

The estimate
    :func:`estimate_s` scales measured seconds per million voxels: reading a mask
    (:data:`READ_S_PER_MVOXEL`, per mask file), the free space and its signed distance
    field (:data:`FIELD_S_PER_MVOXEL`) and storing the entry
    (:data:`STORE_S_PER_MVOXEL`), both on the allowed region's grid. The voxel counts come
    from the files' headers (a few ms). The figures are Med-RAD lungs 1-3 prepared with
    ``python -m needlekit.benchmarks.prepare --patient N`` on the 2-core AMD EPYC with other
    work running (2026-12-06); a quiet machine is up to twice as fast.
"""

from __future__ import annotations

import gzip
import io
import logging
import os
import sys
import time
from pathlib import Path

__all__ = [
    "FIELD_S_PER_MVOXEL",
    "READ_S_PER_MVOXEL",
    "STORE_S_PER_MVOXEL",
    "ESTIMATE_BASIS",
    "PreparationProgress",
    "estimate_s",
    "header_voxels",
]

#: The loader's logger (the lines belong to loading a patient).
log = logging.getLogger("needlekit.io.medrad")

#: Seconds to read one mask file, per million voxels of its grid (lungs 1, 2, 3: 0.0168,
#: 0.0169, 0.0172; lung 1 is five masks of 84.2 M voxels, read in 7.1 s).
READ_S_PER_MVOXEL: float = 0.017
#: Seconds to build the free space and its signed distance field, per million voxels of
#: the allowed region's grid (lungs 1, 2, 3: 0.068, 0.122, 0.123; the mean).
FIELD_S_PER_MVOXEL: float = 0.104
#: Seconds to write and hash the entry, per million voxels of that grid (lungs 1, 2, 3:
#: 0.016, 0.014, 0.020).
STORE_S_PER_MVOXEL: float = 0.017
#: What the estimate rests on, as the docs say it.
ESTIMATE_BASIS: str = (
    "0.017 s per million voxels per mask read, 0.104 s for the free-space field and "
    "0.017 s for storing, measured on Med-RAD lungs 1-3 on a 2-core AMD EPYC"
)


def header_voxels(path: str | os.PathLike) -> int | None:
    """Voxels of a NIfTI image from its header alone (None when it cannot be read so).

    Parameters
    ----------
    path : path-like

    Returns
    -------
    int or None
    """
    import nibabel as nib

    p = Path(path)
    try:
        opener = gzip.open if p.name.lower().endswith(".gz") else open
        with opener(p, "rb") as f:
            head = f.read(540)
        size = int.from_bytes(head[:4], "little")
        cls = (
            nib.Nifti2Header if 540 in (size, int.from_bytes(head[:4], "big")) else nib.Nifti1Header
        )
        header = cls.from_fileobj(io.BytesIO(head[: cls.template_dtype.itemsize]))
        n = 1
        for d in header.get_data_shape()[:3]:
            n *= int(d)
        return n if n > 0 else None
    except Exception:  # any unreadable header: the estimate is left out, the reader says why
        return None


def estimate_s(mask_voxels: list[int], grid_voxels: int) -> float:
    """Seconds a first preparation takes (see the module's note on the estimate).

    Parameters
    ----------
    mask_voxels : list of int
        Voxels of each mask file read.
    grid_voxels : int
        Voxels of the allowed region's grid (the free space's).

    Returns
    -------
    float

    Examples
    --------
    >>> round(estimate_s([84_227_584] * 5, 84_227_584), 1)  # lung 1
    17.4
    """
    read = READ_S_PER_MVOXEL * sum(mask_voxels) / 1e6
    return read + (FIELD_S_PER_MVOXEL + STORE_S_PER_MVOXEL) * grid_voxels / 1e6


def _short(path: Path) -> str:
    """``~/.cache/needlekit/medrad-lung1-4969643a...``: home as ``~``, the key cut to 8."""
    text = str(path)
    home = str(Path.home())
    if text.startswith(home + os.sep):
        text = "~" + text[len(home) :]
    head, sep, key = text.rpartition("-")
    return f"{head}-{key[:8]}..." if sep and len(key) > 8 else text


def _columns(stream) -> int:
    """Width of the terminal ``stream`` is on (80 when it cannot be told)."""
    try:
        return os.get_terminal_size(stream.fileno()).columns or 80
    except (AttributeError, OSError, ValueError, io.UnsupportedOperation):
        return 80


class PreparationProgress:
    """The line of one first preparation. On a terminal narrower than the line, the
    opening words take a line of their own and the stages are drawn under them.

    Parameters
    ----------
    what : str
        ``"Med-RAD lung 1"``.
    where : path-like
        The entry's folder.
    estimate : float or None
        Seconds (None: unknown, not said).
    stream : file, optional
        Where the live line goes (default stderr); it is live only on a terminal.
    why : str
        Why it is prepared (``"first use"``, ``"its entry was damaged"``).
    """

    def __init__(self, what: str, where, estimate: float | None, stream=None,
                 why: str = "first use") -> None:  # fmt: skip
        self.what = what
        self.estimate = estimate
        about = "" if estimate is None else f"about {max(1, round(estimate))} s, "
        self.head = f"preparing {what} ({why}; {about}kept in {_short(Path(where))})"
        self._t0 = time.perf_counter()
        self._bar = None
        stream = sys.stderr if stream is None else stream
        isatty = getattr(stream, "isatty", None)
        if isatty is not None and isatty():
            from tqdm import tqdm

            self._lead = f"{self.head}: "
            if len(self._lead) + 40 > _columns(stream):  # too narrow: the stages below it
                stream.write(f"{self.head}\n")
                self._lead = "  "
            self._bar = tqdm(total=None, desc=f"{self._lead}starting", file=stream,
                             leave=True, bar_format="{desc} [{elapsed}]")  # fmt: skip
        else:
            log.info("%s", self.head)

    def __call__(self, stage: str) -> None:
        """A stage begins.

        Parameters
        ----------
        stage : str
            ``"masks 3/5"``, ``"free-space field"``, ``"storing 624 MB"``.

        Returns
        -------
        None
        """
        if self._bar is not None:
            self._bar.set_description_str(f"{self._lead}{stage}", refresh=True)
        else:
            log.info("preparing %s: %s (%.1f s so far)", self.what, stage,
                     time.perf_counter() - self._t0)  # fmt: skip

    def done(self, outcome: str) -> None:
        """The preparation ended.

        Parameters
        ----------
        outcome : str
            What became of it (``"624 MB kept in ..."``, ``"not stored"``).

        Returns
        -------
        None
        """
        took = time.perf_counter() - self._t0
        end = f"done in {took:.1f} s, {outcome}"
        if self._bar is not None:
            self._bar.set_description_str(f"{self._lead}{end}", refresh=True)
            self._bar.close()
            self._bar = None
        else:
            log.info("prepared %s: %s", self.what, end)

    def close(self) -> None:
        """Close the live line if a failure left it open.

        Returns
        -------
        None
        """
        if self._bar is not None:
            self._bar.close()
            self._bar = None
