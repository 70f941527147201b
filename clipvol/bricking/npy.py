"""Opening a ``.npy`` file as a read-only memory map, with its header checked first.

Why: ``np.load(mmap_mode="r")`` reports a file it cannot map in numpy's own words ("mmap length is
greater than file size", "Array can't be memory-mapped: Python objects in dtype", "EOF: reading
array header"), and a caller that does not catch ``ValueError`` ends in a traceback. Every reader of
a ``.npy`` (the brick input, the 4-D channel / time-series input, the numpy loader) opens it here,
so each fault is one :class:`~clipvol.errors.InputFormatError` naming the file and what is wrong
with it: not a ``.npy`` at all, a header cut short or malformed, Python objects instead of numbers,
or fewer data bytes than the header's shape and dtype need (a truncated copy).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ..errors import InputFormatError

__all__ = ["open_npy", "npy_header"]


def npy_header(path) -> tuple[tuple[int, ...], np.dtype, bool, int]:
    """``(shape, dtype, fortran_order, data_offset)`` of the ``.npy`` file ``path``, read and
    checked without mapping it (see the module docstring for what is refused)."""
    path = Path(path)
    try:
        with open(path, "rb") as f:
            try:
                version = np.lib.format.read_magic(f)
            except ValueError:
                raise InputFormatError(f"{path}: not a .npy file (its first bytes are not the .npy magic "
                                       "\\x93NUMPY)") from None
            try:
                if version == (1, 0):
                    shape, fortran, dtype = np.lib.format.read_array_header_1_0(f, max_header_size=1 << 20)
                else:
                    shape, fortran, dtype = np.lib.format.read_array_header_2_0(f, max_header_size=1 << 20)
            except (ValueError, EOFError, SyntaxError) as e:
                raise InputFormatError(f"{path}: the .npy header is cut short or malformed ({e})") from None
            offset = f.tell()
        size = os.stat(path).st_size
    except OSError as e:
        raise InputFormatError(f"{path}: cannot read the .npy file ({e.strerror or e})") from None
    dtype = np.dtype(dtype)
    if dtype.hasobject:
        raise InputFormatError(f"{path}: the .npy array holds Python objects (dtype {dtype}), not numbers; save it "
                               "with a numeric dtype (e.g. arr.astype('float32'))")
    need = int(np.prod(shape, dtype=np.int64)) * dtype.itemsize
    if size - offset < need:
        raise InputFormatError(f"{path}: truncated .npy file: its header says shape {tuple(shape)} {dtype}, "
                               f"{need} bytes of data, but it holds {max(0, size - offset)} after the {offset}-byte header")
    return tuple(int(n) for n in shape), dtype, bool(fortran), offset


def open_npy(path) -> np.ndarray:
    """The ``.npy`` file ``path`` as a read-only memory map, its header checked by :func:`npy_header`."""
    npy_header(path)
    try:
        return np.load(path, mmap_mode="r", allow_pickle=False)
    except (ValueError, OSError, EOFError) as e:
        raise InputFormatError(f"{path}: cannot read as a .npy array ({e})") from None
