"""Level-0 inputs of ``clipvol brick``: one small interface over every format we read.

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
import os
import re
from pathlib import Path
from typing import Sequence

import numpy as np

from ..errors import InputFormatError, InputNotFoundError, ParameterError
from .generators import parse_procedural
from .pyramid import validate_dtype
from .worldframe import WorldFrame

__all__ = [
    "Source",
    "ArraySource",
    "FileArraySource",
    "TiffStackSource",
    "TiffPagesSource",
    "ZarrSource",
    "ProceduralSource",
    "open_source",
    "tiff_spacing",
]

Int3 = tuple[int, int, int]
_TIFF_EXT = (".tif", ".tiff")


class Source:
    """A level-0 volume that can be read region by region.

    Attributes
    ----------
    shape : tuple of int
        ``(z, y, x)`` voxels, every axis >= 1.
    dtype : numpy.dtype
        Native-byte-order dtype of the values :meth:`read` returns.
    spacing : tuple of float or None
        ``(z, y, x)`` voxel size if the input records it (OME-Zarr, TIFF resolution), else None.
    frame : WorldFrame or None
        The input's voxel-to-world affine (NIfTI, DICOM, MRC, ...), else None.
    unit : str or None
        The unit of ``spacing`` and ``frame`` if the input says, else None.
    """

    shape: Int3
    dtype: np.dtype
    spacing: tuple[float, float, float] | None = None
    frame: "WorldFrame | None" = None
    unit: str | None = None
    name: str = "source"
    #: identifies the input across runs (absolute path or URL): a resumed build must match it
    key: str = ""

    def _init(self, shape, dtype, name: str) -> None:
        shape = tuple(int(s) for s in shape)
        if len(shape) != 3:
            raise InputFormatError(f"{name}: expected a 3-D volume (z, y, x), got shape {shape}")
        if any(s < 1 for s in shape):
            raise InputFormatError(f"{name}: expected every axis >= 1, got shape {shape}")
        try:
            dt = validate_dtype(dtype, f"{name}: dtype")
        except ParameterError as e:
            raise InputFormatError(str(e)) from None
        self.shape = shape  # type: ignore[assignment]
        self.dtype = dt.newbyteorder("=")
        self.name = name

    def read(self, start: Sequence[int], stop: Sequence[int]) -> np.ndarray:
        """Voxels ``start..stop`` of level 0 as a C-contiguous, native-order array."""
        start = tuple(int(v) for v in start)
        stop = tuple(int(v) for v in stop)
        if len(start) != 3 or len(stop) != 3 or any(not (0 <= a < b <= n) for a, b, n in zip(start, stop, self.shape)):
            raise ParameterError(f"{self.name}: region {start}..{stop} is outside the volume of shape {self.shape}")
        out = self._read(start, stop)
        return np.ascontiguousarray(out, dtype=self.dtype)

    def _read(self, start: Int3, stop: Int3) -> np.ndarray:  # pragma: no cover - abstract
        raise NotImplementedError

    def describe(self) -> str:
        """One line for people and for the store's ``source`` attribute."""
        z, y, x = self.shape
        return f"{self.name} ({z}x{y}x{x} {self.dtype})"

    def close(self) -> None:
        """Release file handles (sources opened per read hold none)."""

    def __enter__(self) -> "Source":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _squeeze3(shape: tuple[int, ...], name: str) -> tuple[int, ...]:
    """Drop leading singleton axes (t, c) so that three remain."""
    shape = tuple(shape)
    while len(shape) > 3 and shape[0] == 1:
        shape = shape[1:]
    if len(shape) == 2:
        shape = (1,) + shape
    if len(shape) != 3:
        raise InputFormatError(f"{name}: expected a 3-D volume (z, y, x), got shape {shape}")
    return shape


class ArraySource(Source):
    """Any array-like with numpy slicing (an in-memory array, a memory map, a zarr array)."""

    def __init__(self, array, name: str = "array", spacing=None) -> None:
        shape3 = _squeeze3(tuple(array.shape), name)
        self._arr = array
        self._lead = len(array.shape) - 3
        self._init(shape3, array.dtype, name)
        if len(array.shape) == 2:
            self._lead = -1
        self.spacing = spacing

    def _read(self, start, stop):
        sl = tuple(slice(a, b) for a, b in zip(start, stop))
        if self._lead == -1:
            return np.asarray(self._arr[sl[1:]])[None]
        return np.asarray(self._arr[(0,) * self._lead + sl])


class FileArraySource(Source):
    """A C-ordered array in a file at a byte ``offset`` (``.npy`` body or raw file).

    Whole z-slabs are one positional read; other regions read the covering z-y rows.
    """

    def __init__(self, path: Path, shape, dtype, offset: int, name: str) -> None:
        self._init(shape, dtype, name)
        self._file_dtype = np.dtype(dtype)
        self._path = Path(path)
        self._offset = int(offset)

    def _read(self, start, stop):
        z0, y0, x0 = start
        z1, y1, x1 = stop
        _, Y, X = self.shape
        it = self._file_dtype.itemsize
        if y0 == 0 and y1 == Y and x0 == 0 and x1 == X:
            rows = (z1 - z0, Y, X)
            first = z0 * Y * X
        else:  # read the z rows' (y0..y1) band, then cut x
            rows = None
            first = 0
        with open(self._path, "rb", buffering=0) as f:
            if rows is not None:
                buf = np.empty(rows, dtype=self._file_dtype)
                self._readinto(f, self._offset + first * it, buf)
                data = buf
            else:
                data = np.empty((z1 - z0, y1 - y0, X), dtype=self._file_dtype)
                for k, z in enumerate(range(z0, z1)):
                    self._readinto(f, self._offset + (z * Y + y0) * X * it, data[k])
                data = data[:, :, x0:x1]
        return data.astype(self.dtype, copy=False)  # byte-swaps a big-endian raw file

    def _readinto(self, f, pos: int, out: np.ndarray) -> None:
        view = memoryview(out.reshape(-1).view(np.uint8))
        f.seek(pos)
        got = 0
        while got < len(view):
            n = f.readinto(view[got:])
            if not n:
                raise InputFormatError(f"{self._path}: file ended early (expected {len(view)} bytes at offset {pos})")
            got += n


class TiffStackSource(Source):
    """A stack of 2-D TIFF files, one per z, sorted in natural order (``img2`` before ``img10``)."""

    def __init__(self, files: list[Path], name: str) -> None:
        import tifffile

        if not files:
            raise InputNotFoundError(f"{name}: no .tif/.tiff files found")
        self._files = files
        try:
            with tifffile.TiffFile(files[0]) as tf:
                page = tf.pages[0]
                yx = tuple(page.shape)
                dtype = page.dtype
        except (OSError, ValueError, tifffile.TiffFileError) as e:
            raise InputFormatError(f"{files[0]}: cannot read as TIFF ({e})") from None
        if len(yx) != 2:
            raise InputFormatError(f"{files[0]}: expected a 2-D grey image per slice, got page shape {yx}")
        self._yx = yx
        self._init((len(files),) + yx, dtype, name)

    def _read(self, start, stop):
        import tifffile

        out = np.empty(tuple(b - a for a, b in zip(start, stop)), dtype=self.dtype)
        for k, z in enumerate(range(start[0], stop[0])):
            try:
                img = tifffile.imread(self._files[z])
            except (OSError, ValueError, tifffile.TiffFileError) as e:
                raise InputFormatError(f"{self._files[z]}: cannot read as TIFF ({e})") from None
            if img.shape != self._yx:
                raise InputFormatError(f"{self._files[z]}: expected a {self._yx} slice like {self._files[0].name}, got {img.shape}")
            out[k] = img[start[1]:stop[1], start[2]:stop[2]]
        return out


class TiffPagesSource(Source):
    """A multi-page or 3-D TIFF read page by page (when it cannot be memory-mapped)."""

    def __init__(self, path: Path) -> None:
        import tifffile

        self._path = path
        with tifffile.TiffFile(path) as tf:
            series = tf.series[0]
            shape = _squeeze3(tuple(series.shape), str(path))
            self._npages = len(series.pages)
            self._init(shape, series.dtype, str(path))
        self._per_page = int(np.prod(self.shape)) // max(self._npages, 1)

    def _read(self, start, stop):
        import tifffile

        Y, X = self.shape[1:]
        if self._per_page != Y * X:  # one page holds the volume: read it (rare: 3-D TIFF, compressed)
            return tifffile.imread(self._path).reshape(self.shape)[tuple(slice(a, b) for a, b in zip(start, stop))]
        out = np.empty(tuple(b - a for a, b in zip(start, stop)), dtype=self.dtype)
        with tifffile.TiffFile(self._path) as tf:
            pages = tf.series[0].pages
            for k, z in enumerate(range(start[0], stop[0])):
                out[k] = pages[z].asarray().reshape(Y, X)[start[1]:stop[1], start[2]:stop[2]]
        return out


class ZarrSource(ArraySource):
    """A zarr array, or level 0 of the first multiscale of an OME-Zarr image (spacing from its scale)."""

    def __init__(self, path: Path) -> None:
        import zarr

        try:
            node = zarr.open(str(path), mode="r")
        except Exception as e:  # zarr raises many kinds for a non-store
            raise InputFormatError(f"{path}: cannot open as a zarr array or group ({type(e).__name__}: {e})") from None
        spacing = None
        name = str(path)
        if isinstance(node, zarr.Group):
            attrs = dict(node.attrs)
            ms = (attrs.get("ome") or attrs).get("multiscales")
            if not ms:
                raise InputFormatError(f"{path}: a zarr group without OME-Zarr 'multiscales' metadata; name the array inside it")
            try:
                ds = ms[0]["datasets"][0]
                arr = node[ds["path"]]
                for t in ds.get("coordinateTransformations", []):
                    if t.get("type") == "scale":
                        spacing = tuple(float(v) for v in t["scale"][-3:])
            except (KeyError, IndexError, TypeError, ValueError) as e:
                raise InputFormatError(f"{path}: malformed OME-Zarr 'multiscales' ({type(e).__name__}: {e})") from None
            name = f"{path}/{ds['path']}"
        else:
            arr = node
        super().__init__(arr, name=name, spacing=spacing)


class ProceduralSource(Source):
    """Level 0 of a ``procedural:NAME?size=N`` generator, evaluated region by region."""

    def __init__(self, url: str) -> None:

        self.generator = parse_procedural(url)
        self._init(self.generator.shape, self.generator.dtype, self.generator.url())

    def _read(self, start, stop):
        return self.generator.region(0, start, stop)


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
    from .formats import open_format  # NIfTI, DICOM, HDF5, MRC (each an optional extra)

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
    try:
        mm = np.load(path, mmap_mode="r", allow_pickle=False)
    except (ValueError, OSError, EOFError) as e:
        raise InputFormatError(f"{path}: cannot read as .npy ({e})") from None
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


def tiff_spacing(path: Path) -> tuple[float, float, float] | None:
    """``(z, y, x)`` voxel size of an ImageJ TIFF (its ``spacing`` and X/YResolution), else None.

    Only ImageJ files are trusted: their resolution is in pixels per unit of the ``unit`` they
    declare, and ``spacing`` is the z step. Other TIFFs' resolution is usually a print DPI.
    """
    import tifffile

    try:
        with tifffile.TiffFile(path) as tf:
            ij = tf.imagej_metadata
            if not ij or "spacing" not in ij:
                return None
            tags = tf.pages[0].tags
            xr, yr = tags.get("XResolution"), tags.get("YResolution")
            if xr is None or yr is None:
                return None
            sx = xr.value[1] / xr.value[0]
            sy = yr.value[1] / yr.value[0]
            sp = (float(ij["spacing"]), float(sy), float(sx))
    except (OSError, ValueError, KeyError, ZeroDivisionError, IndexError, TypeError, tifffile.TiffFileError):
        return None
    return sp if all(np.isfinite(sp)) and min(sp) > 0 else None


def _open_tiff(path: Path) -> Source:
    import tifffile

    src: Source
    try:
        mm = tifffile.memmap(path, mode="r")
        if any(s == 0 for s in mm.shape):
            raise InputFormatError(f"{path}: expected every axis >= 1, got shape {mm.shape}")
        src = ArraySource(mm, name=str(path))
    except InputFormatError:
        raise
    except (ValueError, OSError, tifffile.TiffFileError):
        try:  # compressed or tiled: read page by page
            src = TiffPagesSource(path)
        except (ValueError, OSError, tifffile.TiffFileError, IndexError) as e:
            raise InputFormatError(f"{path}: cannot read as TIFF ({e})") from None
    src.spacing = tiff_spacing(path)
    return src


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
