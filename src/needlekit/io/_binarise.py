"""One pass from an integer image to a C-ordered boolean mask, checking that it is binary.

NIfTI stores volumes in Fortran order; the masks the toolkit works on are C-ordered bool.
Checking the two-value rule, thresholding and transposing with numpy took 5 to 6 passes
over each 170 MB Med-RAD mask (and two temporaries); this kernel reads the image once and
writes the mask once, in square tiles so that both stay in cache: about half the time of
the numpy passes on a Med-RAD mask, measured beside them in one process. :func:`binarise`
leaves floats to numpy, and the reader composes error messages with numpy too
(:func:`needlekit.io.volumes._binary`).
"""

from __future__ import annotations

import numba
import numpy as np

__all__ = ["STREAM_CHUNK_BYTES", "binarise", "binarise_stream"]

#: Bytes inflated per slab when a mask is streamed (a few dozen CT planes): large enough
#: that per-call costs vanish, small enough to stay out of the way of the memory peak.
STREAM_CHUNK_BYTES = 16 * 2**20

#: Side of the square tiles transposed together (32 x 32: 2 KB of int16 in, 1 KB of bools out).
_BLOCK = 32


@numba.njit(cache=True, nogil=True)
def _kernel(src, dst, k_offset, first, other, seen):  # pragma: no cover - compiled
    """``dst[:, :, k_offset + k] = src[k] != 0`` where ``src`` is C-ordered ``(k, j, i)``
    (a slab of a Fortran-ordered image seen through ``.T``) and ``dst`` is C-ordered
    ``(i, j, k)``, in square tiles of the ``(i, k)`` planes. Carries the two-value check
    across slabs: (first value, other value, values seen: 0 none yet, 1, 2, or 3 for more
    than two, where the pass stops); returns those and the slab's set count."""
    nk, nj, ni = src.shape
    if seen == 0:
        first = src[0, 0, 0]
        other = first
        seen = 1
    count = 0
    for j in range(nj):
        for k0 in range(0, nk, _BLOCK):
            k1 = min(k0 + _BLOCK, nk)
            for i0 in range(0, ni, _BLOCK):
                i1 = min(i0 + _BLOCK, ni)
                for k in range(k0, k1):
                    for i in range(i0, i1):
                        v = src[k, j, i]
                        if v != first:
                            if seen == 1:
                                other = v
                                seen = 2
                            elif v != other:
                                return first, other, 3, count
                        s = v != 0
                        dst[i, j, k_offset + k] = s
                        count += s
    return first, other, seen, count


class _Check:
    """The two-value check carried across slabs, and the set count."""

    def __init__(self, dtype) -> None:
        self.first = dtype.type(0)
        self.other = dtype.type(0)
        self.seen = 0
        self.count = 0

    def slab(self, src: np.ndarray, out: np.ndarray, k_offset: int) -> bool:
        """Binarise one slab; False once more than two values have been seen."""
        self.first, self.other, self.seen, n = _kernel(
            src, out, k_offset, self.first, self.other, self.seen
        )
        self.count += int(n)
        return self.seen != 3

    @property
    def ok(self) -> bool:
        return self.seen == 1 or (self.seen == 2 and (self.first == 0 or self.other == 0))


def binarise(data: np.ndarray) -> tuple[np.ndarray, bool, int] | None:
    """``data != 0`` as a C-ordered bool array, with the two-value check, in one pass.

    Parameters
    ----------
    data : ndarray, 3-D (shape (nx, ny, nz)), integer dtype (any memory layout)

    Returns
    -------
    (mask, ok, count) or None
        ``ok`` is False when ``data`` holds more than two values, or two of which neither
        is 0 (the caller composes the message); ``count`` is the number of set voxels.
        None when the kernel does not apply (not 3-D, not an integer type, empty).
    """
    if data.ndim != 3 or data.size == 0 or not np.issubdtype(data.dtype, np.integer):
        return None
    if data.dtype.byteorder not in ("=", "|"):  # big-endian files: native first
        data = data.astype(data.dtype.newbyteorder("="))
    src = data.T if data.flags.f_contiguous else np.ascontiguousarray(data.T)
    out = np.empty(data.shape, dtype=np.bool_)
    check = _Check(src.dtype)
    check.slab(src, out, 0)
    return out, check.ok, check.count


def binarise_stream(read_into, dtype: np.dtype, shape: tuple[int, int, int],
                    chunk_bytes: int = STREAM_CHUNK_BYTES) -> tuple[np.ndarray, bool, int] | None:  # fmt: skip
    """:func:`binarise` of a Fortran-ordered image read slab by slab (whole ``(i, j)``
    planes) into one reused buffer: the image is never held whole.

    Parameters
    ----------
    read_into : callable
        ``read_into(memoryview)`` fills the buffer from the stream and returns the number
        of bytes read (a file's ``readinto``).
    dtype : numpy dtype, integer, native byte order
    shape : (ni, nj, nk)
    chunk_bytes : int
        Buffer size (at least one plane).

    Returns
    -------
    (mask, ok, count) or None
        As :func:`binarise`; None when the stream ends early or the check fails at once
        (more than two values: the caller re-reads to compose the message).
    """
    ni, nj, nk = shape
    plane = ni * nj
    per = max(1, chunk_bytes // (plane * dtype.itemsize))
    buf = np.empty(per * plane, dtype=dtype)
    out = np.empty(shape, dtype=np.bool_)
    check = _Check(dtype)
    for k0 in range(0, nk, per):
        n = min(per, nk - k0)
        view = memoryview(buf[: n * plane]).cast("B")
        filled = 0
        while filled < len(view):
            got = read_into(view[filled:])
            if not got:
                return None
            filled += got
        if not check.slab(buf[: n * plane].reshape(n, nj, ni), out, k0):
            return None
    return out, check.ok, check.count
