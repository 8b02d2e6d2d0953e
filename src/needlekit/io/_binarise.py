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

__all__ = ["binarise"]

#: Side of the square tiles transposed together (32 x 32: 2 KB of int16 in, 1 KB of bools out).
_BLOCK = 32


@numba.njit(cache=True, nogil=True)
def _kernel(src, dst):  # pragma: no cover - compiled
    """``dst = src != 0`` where ``src`` is C-ordered ``(k, j, i)`` (a Fortran-ordered image
    seen through ``.T``) and ``dst`` is C-ordered ``(i, j, k)``, in square tiles of the
    ``(i, k)`` planes; returns (values seen, first value, other value, set count): values
    seen is 3 when there are more than two (the pass stops there)."""
    nk, nj, ni = src.shape
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
                                return 3, first, other, count
                        s = v != 0
                        dst[i, j, k] = s
                        count += s
    return seen, first, other, count


def binarise(data: np.ndarray) -> tuple[np.ndarray, bool, int] | None:
    """``data != 0`` as a C-ordered bool array, with the two-value check, in one pass.

    Parameters
    ----------
    data : ndarray, 3-D, integer dtype (any memory layout)

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
    seen, first, other, count = _kernel(src, out)
    ok = seen == 1 or (seen == 2 and (first == 0 or other == 0))
    return out, bool(ok), int(count)
