"""Level-0 inputs of ``clipvol brick``: which kind of :class:`Source` a path, URL or array is.

The kinds themselves live in :mod:`clipvol.bricking.source_types` (generic) and
:mod:`clipvol.bricking.formats` (each field's readers); :func:`open_source` picks one.
Bricking is streamed, so an input is never loaded whole: a :class:`Source` only has to hand out
regions ``read(start, stop)`` of level 0 (``(z, y, x)``, stop exclusive). The bricker asks for one
brick-row in z at a time (a slab), so formats stored z-slice by z-slice (TIFF stacks, C-order
``.npy`` and raw files) are read sequentially.

``.npy`` and raw files are read with positional file reads (``os.pread``-like, one handle per
call) rather than through a memory map: the pages of a memory map count towards the process's
resident memory until the kernel drops them, which would make the bricker's memory grow with the
volume. Fortran-ordered ``.npy`` files fall back to ``np.load(mmap_mode='r')`` slicing.

Everything a user can get wrong raises a :mod:`clipvol.errors` error naming the file or the
parameter: a missing input, a raw file whose size is not shape x dtype, an unsupported dtype, an
axis of size 0, an unknown procedural dataset.
"""

from __future__ import annotations

import glob
import hashlib
import os
import re
from pathlib import Path
from typing import Sequence

import numpy as np

from ..errors import InputFormatError, InputNotFoundError, ParameterError, SourceChangedError
from .formats import open_format  # NIfTI, DICOM, HDF5, MRC, OME-TIFF (each reader imported on use)
from .pyramid import validate_dtype
from .source_types import (
    _TIFF_EXT,
    ArraySource,
    FileArraySource,
    ProceduralSource,
    Source,
    TiffStackSource,
    ZarrSource,
    _open_tiff,
    _squeeze3,
)

# the Source kinds live in source_types (import them from there)
__all__ = ["open_source", "source_identity", "identity_changes"]


def _natural_key(p: Path):
    return [int(t) if t.isdigit() else t.lower() for t in re.split(r"(\d+)", p.name)]


def _is_zarr(p: Path) -> bool:
    return any((p / m).exists() for m in ("zarr.json", ".zarray", ".zgroup"))


def open_source(
    source,
    *,
    raw_shape: Sequence[int] | None = None,
    raw_dtype=None,
    byte_order: str = "little",
) -> Source:
    """Open a level-0 input for bricking.

    Parameters
    ----------
    source : str, Path or numpy.ndarray
        A ``.npy`` file; a raw binary file (with ``raw_shape`` and ``raw_dtype``); a directory or
        glob of 2-D TIFF files (one per z); a multi-page or 3-D TIFF; a zarr array or OME-Zarr
        image; ``procedural:NAME?size=N``; or an in-memory array.
    raw_shape, raw_dtype, byte_order
        Layout of a raw file (``(z, y, x)``, numpy dtype, ``'little'`` or ``'big'``).

    Returns
    -------
    Source

    Raises
    ------
    InputNotFoundError, InputFormatError, ParameterError
        Naming the file or the parameter.
    """
    if isinstance(source, np.ndarray):
        return ArraySource(source, name=f"array {source.shape} {source.dtype}")
    if isinstance(source, Source):
        return source
    if byte_order not in ("little", "big"):
        raise ParameterError(f"byte_order: expected 'little' or 'big', got {byte_order!r}")
    text = str(source)
    src = _open_path_or_url(text, raw_shape, raw_dtype, byte_order)
    src.key = text if text.startswith("procedural:") else os.path.abspath(text)
    return src


def _open_path_or_url(text: str, raw_shape, raw_dtype, byte_order: str) -> Source:
    if text.startswith("procedural:"):
        return ProceduralSource(text)
    if raw_shape is not None or raw_dtype is not None:
        return _open_raw(Path(text), raw_shape, raw_dtype, byte_order)
    if any(c in text for c in "*?[") and not Path(text).exists():
        files = sorted((Path(f) for f in glob.glob(text)), key=_natural_key)
        if not files:
            raise InputNotFoundError(f"{text}: no file matches this pattern")
        return TiffStackSource(files, text)
    src = open_format(text)
    if src is not None:
        return src
    path = Path(text)
    if not path.exists():
        raise InputNotFoundError(f"{path}: no such file or directory")
    if path.is_dir():
        if _is_zarr(path):
            return ZarrSource(path)
        files = sorted((p for p in path.iterdir() if p.suffix.lower() in _TIFF_EXT), key=_natural_key)
        if not files:
            raise InputFormatError(f"{path}: a directory that is neither a zarr store nor holds .tif/.tiff or DICOM files")
        return TiffStackSource(files, str(path))
    if not os.access(path, os.R_OK):
        raise InputNotFoundError(f"{path}: not readable (permission denied)")
    suffix = path.suffix.lower()
    if suffix == ".npy":
        return _open_npy(path)
    if suffix in _TIFF_EXT:
        return _open_tiff(path)
    raise InputFormatError(
        f"{path}: unknown input format {suffix or '(no extension)'!r}; expected .npy, .tif/.tiff, a TIFF directory "
        "or glob, a zarr store, .nii/.nii.gz, a DICOM folder, FILE.h5:/dataset, .mrc/.map, procedural:NAME?size=N, "
        "or a raw file with --shape and --dtype"
    )


def _open_npy(path: Path) -> Source:
    from .npy import open_npy

    mm = open_npy(path)
    if not isinstance(mm, np.memmap):  # pragma: no cover - np.load of a .npy with mmap gives a memmap
        raise InputFormatError(f"{path}: expected an .npy array, got {type(mm).__name__}")
    shape = _squeeze3(mm.shape, str(path))
    if any(s == 0 for s in mm.shape):
        raise InputFormatError(f"{path}: expected every axis >= 1, got shape {mm.shape}")
    if mm.flags.c_contiguous:
        src = FileArraySource(path, shape, mm.dtype, mm.offset, str(path))
        del mm
        return src
    return ArraySource(mm, name=str(path))


def _open_raw(path: Path, raw_shape, raw_dtype, byte_order: str) -> Source:
    if raw_shape is None or raw_dtype is None:
        raise ParameterError(f"{path}: a raw input needs both --shape Z,Y,X and --dtype")
    try:
        shape = tuple(int(s) for s in raw_shape)
    except (TypeError, ValueError):
        raise ParameterError(f"shape: expected three integers Z,Y,X, got {raw_shape!r}") from None
    if len(shape) != 3:
        raise ParameterError(f"shape: expected three integers Z,Y,X, got {raw_shape!r}")
    if any(s < 1 for s in shape):
        raise ParameterError(f"shape: expected every axis >= 1, got {shape}")
    dt = validate_dtype(raw_dtype, "dtype")
    dt = dt.newbyteorder("<" if byte_order == "little" else ">") if dt.itemsize > 1 else dt
    if not path.exists():
        raise InputNotFoundError(f"{path}: no such file")
    if path.is_dir():
        raise InputFormatError(f"{path}: expected a raw file, got a directory")
    size = path.stat().st_size
    need = int(np.prod(shape)) * dt.itemsize
    if size != need:
        raise InputFormatError(
            f"{path}: expected {need} bytes for shape {shape} of {np.dtype(raw_dtype).name}, got {size} bytes"
        )
    return FileArraySource(path, shape, dt, 0, str(path))


def source_identity(src: Source, samples: int = 9, edge: int = 16) -> dict:
    """What identifies ``src`` across runs, so a resumed build can refuse a different input.

    ``shape`` and ``dtype``; ``size`` (bytes) and ``mtime_ns`` (latest) of :meth:`Source.files`
    (None without files); and ``sample_sha256``, a SHA-256 of ``samples`` blocks of up to
    ``edge`` voxels per axis read through the source's own :meth:`Source.read` at fixed positions
    (the eight corners of the volume, then its centre), so it works for any source class,
    in-memory arrays and generators included, and catches a replaced file with the same size.
    """
    files = src.files()
    size = mtime = None
    if files:
        st = [os.stat(f) for f in files]
        size = int(sum(s.st_size for s in st))
        mtime = int(max(s.st_mtime_ns for s in st))
    shape = tuple(int(n) for n in src.shape)
    e = tuple(min(edge, n) for n in shape)
    corners = [tuple(0 if (c >> a) & 1 == 0 else n - k for a, (n, k) in enumerate(zip(shape, e))) for c in range(8)]
    centre = tuple((n - k) // 2 for n, k in zip(shape, e))
    starts = list(dict.fromkeys(corners + [centre]))[: max(1, samples)]
    h = hashlib.sha256()
    for s0 in starts:
        block = src.read(s0, tuple(a + k for a, k in zip(s0, e)))
        h.update(np.ascontiguousarray(block).tobytes())
    return {"shape": list(shape), "dtype": src.dtype.name, "size": size, "mtime_ns": mtime,
            "sample_sha256": h.hexdigest()}


def file_inodes(src: Source) -> dict[str, tuple[int, int]]:
    """``{path: (st_dev, st_ino)}`` of ``src``'s files: a file replaced by another one (``mv new
    old``, an editor's save) has a new inode even when its size, time and sampled blocks match.
    Kept in memory for one build only (not in the store: inodes do not survive a copy)."""
    out = {}
    for f in src.files():
        try:
            st = os.stat(f)
        except OSError:
            continue
        out[str(f)] = (int(st.st_dev), int(st.st_ino))
    return out


def check_source_unchanged(src: Source, identity: dict, inodes: dict, output) -> None:
    """Raise :class:`~clipvol.errors.SourceChangedError` when ``src`` differs from the ``identity``
    and ``inodes`` recorded when its build started. Called just before a store is marked complete,
    so a source rewritten during the build (slabs read before and after mixed in one pyramid) never
    yields a store that claims to be whole."""
    def changed(changes):
        return SourceChangedError(f"{output}: the input {src.name} changed while it was being bricked "
                                  f"({'; '.join(changes)}); the store is left incomplete: re-run with --overwrite "
                                  "once the input is stable")

    now_inodes = file_inodes(src)
    moved = sorted(p for p, ino in inodes.items() if now_inodes.get(p) != ino)
    if moved:
        more = f" and {len(moved) - 1} more" if len(moved) > 1 else ""
        raise changed([f"file replaced or removed: {moved[0]}{more}"])
    files = src.files()
    if files and isinstance(identity, dict):  # sizes and times first: reading a truncated memory map faults
        try:
            st = [os.stat(f) for f in files]
        except OSError as e:
            raise changed([f"{type(e).__name__}: {e}"]) from e
        size, mtime = int(sum(x.st_size for x in st)), int(max(x.st_mtime_ns for x in st))
        quick = identity_changes(identity, {**identity, "size": size, "mtime_ns": mtime})
        if quick:
            raise changed(quick)
    try:
        now = source_identity(src)
    except (OSError, ValueError) as e:  # truncated or removed meanwhile
        raise changed([f"{type(e).__name__}: {e}"]) from e
    changes = identity_changes(identity, now)
    if changes:
        raise changed(changes)


def identity_changes(old: dict | None, new: dict) -> list[str]:
    """What differs between two :func:`source_identity` records, one phrase each (empty: the same)."""
    if not isinstance(old, dict):
        return ["the interrupted build recorded no source identity"]
    out = []
    names = {"shape": "shape", "dtype": "dtype", "size": "size in bytes", "mtime_ns": "modification time (ns)",
             "sample_sha256": "content (hash of sampled blocks)"}
    for k, what in names.items():
        if old.get(k) != new.get(k):
            if k == "sample_sha256":
                out.append(f"{what} differs")
            else:
                out.append(f"{what} {old.get(k)!r} -> {new.get(k)!r}")
    return out
