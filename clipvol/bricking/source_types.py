"""The kinds of level-0 input ``clipvol brick`` reads, behind one small interface (:class:`Source`).

A :class:`Source` only hands out regions ``read(start, stop)`` of level 0 (``(z, y, x)``, stop
exclusive), so bricking streams. This module holds the interface and the generic kinds (arrays,
files read by position, TIFF stacks and pages, zarr arrays, procedural volumes); the readers of
each field's formats (``formats/``) build on it, and :mod:`clipvol.bricking.sources` decides which
kind a path or URL is. Keeping the kinds apart from that decision is what lets ``formats/`` import
them while ``sources`` imports ``formats`` (no import cycle).
"""

from __future__ import annotations

import os
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

    def files(self) -> list[Path]:
        """The files whose size and modification time identify this input for a resumed build.

        Default: the file named by :attr:`key`, or a directory's own files (not its sub-folders:
        a zarr store's chunks are covered by the sampled-content hash instead); none for inputs
        without files (arrays, procedural, URLs). A source class may override it.
        """
        if not self.key or not os.path.exists(self.key):
            return []
        p = Path(self.key)
        if p.is_file():
            return [p]
        return sorted(c for c in p.iterdir() if c.is_file())

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

    def files(self) -> list[Path]:
        return list(self._files)

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
