"""``clipvol.open``: a store's voxels as numpy arrays, read through the verified loader.

A user who has bricked a scan wants to compute on it as well as look at it: take a region at some
level, hand a level to dask, map a world point to a voxel. :func:`open` gives a small read-only
:class:`Volume` for anything ``clipvol view`` opens (a store, the root of a channel set or time
series, a ``.npy``, a procedural URL, and a NIfTI / DICOM / HDF5 / MRC file, which is bricked once
into ``./NAME.zarr`` as ``view`` does, :mod:`clipvol.app.autobrick`).

Every voxel comes from the loader's ``read_brick`` (the custom-loader contract of
:mod:`clipvol.paging.loader`), never from zarr directly: a clipvol store's chunks are checked
against their crc32c and their statistics as they are when drawn, so a corrupt brick raises
:class:`~clipvol.errors.BrickIntegrityError` instead of returning wrong numbers. A region is read
brick by brick, so the memory a read takes is the region plus one brick.

Coordinates follow the rest of clipvol: arrays and voxel indices are ``(z, y, x)``, world points
``(x, y, z)``. :meth:`Volume.affine` is the store's voxel-to-world matrix in NIfTI's convention
(voxel index ``(x, y, z, 1)`` to world), the same one ``clipvol info`` prints; for a level ``L`` it
includes that level's scale and translation (the position of its voxel centres, docs/format.md).
"""

from __future__ import annotations

import sys
from itertools import product
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from ..bricking.pyramid import LevelInfo
from ..bricking.worldframe import WorldFrame
from ..errors import MissingExtraError, ParameterError
from ..paging.loader import check_brick
from .autobrick import bricked_source
from .session import open_loader

__all__ = ["open", "Volume", "LevelArray", "read_region"]


def read_region(loader, level: int, start: Sequence[int], stop: Sequence[int],
                out: np.ndarray | None = None) -> np.ndarray:
    """Voxels ``start..stop`` (``(z, y, x)``, stop exclusive) of ``level``, read brick by brick
    through ``loader.read_brick`` (each brick checked against the loader contract).

    ``out`` (shape ``stop - start``, the pyramid's dtype) receives the voxels when given (a memory
    map, for a region larger than memory); it is returned.
    """
    pyr = loader.pyramid
    shape = pyr.levels[level].shape
    start = tuple(int(v) for v in start)
    stop = tuple(int(v) for v in stop)
    if not all(0 <= a <= b <= n for a, b, n in zip(start, stop, shape)):
        raise ParameterError(f"region: expected 0 <= start <= stop <= {shape} at level {level}, got {start}..{stop}")
    size = tuple(b - a for a, b in zip(start, stop))
    if out is None:
        out = np.empty(size, dtype=pyr.dtype)
    elif out.shape != size:
        raise ParameterError(f"out: expected shape {size}, got {out.shape}")
    for index in bricks_of_region(pyr.brick_shape, start, stop):
        copy_brick(loader, level, index, start, stop, out)
    return out


def bricks_of_region(brick_shape, start, stop) -> list[tuple[int, int, int]]:
    """Indices ``(bz, by, bx)`` of the bricks that hold a voxel of ``start..stop`` (z-major order)."""
    if any(b <= a for a, b in zip(start, stop)):
        return []
    ranges = [range(a // s, (b - 1) // s + 1) for a, b, s in zip(start, stop, brick_shape)]
    return [tuple(i) for i in product(*ranges)]  # type: ignore[misc]


def copy_brick(loader, level: int, index, start, stop, out: np.ndarray) -> None:
    """Copy the part of brick ``index`` inside ``start..stop`` into ``out`` (indexed from ``start``)."""
    bs = loader.pyramid.brick_shape
    brick = check_brick(loader, level, index, loader.read_brick(level, index))
    lo = [max(a, i * s) for a, i, s in zip(start, index, bs)]
    hi = [min(b, (i + 1) * s) for b, i, s in zip(stop, index, bs)]
    src = tuple(slice(a - i * s, b - i * s) for a, b, i, s in zip(lo, hi, index, bs))
    dst = tuple(slice(a - o, b - o) for a, b, o in zip(lo, hi, start))
    out[dst] = brick[src]


def _normalize_key(key, shape: tuple[int, ...]) -> tuple[list[tuple[int, int, int]], tuple[bool, ...]]:
    """``(ranges, drop)``: per axis ``(start, stop, step)`` of the bounding box and whether the axis
    was indexed by an integer (and is dropped from the result)."""
    if not isinstance(key, tuple):
        key = (key,)
    if sum(k is Ellipsis for k in key) > 1:
        raise ParameterError("index: expected at most one '...'")
    if Ellipsis in key:
        i = key.index(Ellipsis)
        key = key[:i] + (slice(None),) * (len(shape) - len(key) + 1) + key[i + 1:]
    if len(key) > len(shape):
        raise ParameterError(f"index: expected at most {len(shape)} indices for shape {shape}, got {len(key)}")
    key = key + (slice(None),) * (len(shape) - len(key))
    ranges, drop = [], []
    for axis, (k, n) in enumerate(zip(key, shape)):
        if isinstance(k, slice):
            a, b, s = k.indices(n)
            if s < 1:
                raise ParameterError(f"index: axis {axis}: expected a positive step, got {s}")
            b = max(a, b)
            ranges.append((a, b, s))
            drop.append(False)
        elif isinstance(k, (int, np.integer)) and not isinstance(k, bool):
            i = int(k) + n if int(k) < 0 else int(k)
            if not 0 <= i < n:
                raise IndexError(f"index {int(k)} is out of bounds for axis {axis} with size {n}")
            ranges.append((i, i + 1, 1))
            drop.append(True)
        else:
            raise ParameterError(f"index: axis {axis}: expected an integer or a slice, got {type(k).__name__} "
                                 "(read a region first, then index it with numpy)")
    return ranges, tuple(drop)


class LevelArray:
    """One level of a :class:`Volume` as a lazy, read-only array: ``shape``, ``dtype``, ``ndim``, and
    ``[...]`` with integers and slices (positive steps), which reads the bricks it needs."""

    def __init__(self, volume: "Volume", level: int) -> None:
        self.volume = volume
        self.level = int(level)
        self.info: LevelInfo = volume.levels[self.level]
        self.shape: tuple[int, ...] = tuple(volume.lead_shape) + tuple(self.info.shape)
        self.dtype: np.dtype = volume.dtype
        self.ndim = len(self.shape)

    @property
    def chunks(self) -> tuple[int, ...]:
        """One chunk per brick (and per member along a channel or time axis)."""
        return (1,) * len(self.volume.lead_shape) + tuple(self.volume.brick_shape)

    def __len__(self) -> int:
        return self.shape[0]

    def __getitem__(self, key) -> np.ndarray:
        ranges, drop = _normalize_key(key, self.shape)
        nlead = len(self.volume.lead_shape)
        lead, space = ranges[:nlead], ranges[nlead:]
        start = [a for a, _, _ in space]
        stop = [b for _, b, _ in space]
        members = list(product(*[range(a, b, s) for a, b, s in lead]))
        box = tuple(b - a for a, b in zip(start, stop))
        out = np.empty((len(members),) + box, dtype=self.dtype)
        for m, idx in enumerate(members):
            read_region(self.volume.member(idx), self.level, start, stop, out[m])
        out = out.reshape(tuple(len(range(a, b, s)) for a, b, s in lead) + box)
        steps = tuple(slice(None) for _ in lead) + tuple(slice(None, None, s) for _, _, s in space)
        out = out[steps]
        squeeze = tuple(i for i, d in enumerate(drop) if d)
        out = out.reshape([n for i, n in enumerate(out.shape) if i not in squeeze])
        if out.ndim == 0:  # integers on every axis: a numpy scalar, as numpy's own a[z, y, x]
            return out[()]
        return np.ascontiguousarray(out)

    def __array__(self, dtype=None, copy=None) -> np.ndarray:
        a = self[...]
        return a if dtype is None else a.astype(dtype)

    def __repr__(self) -> str:
        return f"<LevelArray level {self.level} of {self.volume.source}: shape {self.shape} {self.dtype}>"


class Volume:
    """A read-only volume opened with :func:`open`.

    Attributes
    ----------
    source : str
        What was opened (the store a file format was bricked into, for those).
    axes : tuple of str
        ``("z", "y", "x")``, with ``"c"`` or ``"t"`` in front for a channel set or time series.
    shape : tuple of int
        Level-0 shape along ``axes``.
    levels : tuple of LevelInfo
        Per level: ``shape`` ``(z, y, x)``, ``scale`` and ``translation`` (world units, array axes).
    spacing : (float, float, float)
        Level-0 voxel size ``(z, y, x)``.
    dtype : numpy.dtype
    unit : str or None
        The unit of ``spacing`` and of world coordinates, when the store says.
    frame : WorldFrame
        Level 0's voxel-to-world affine (the store's own, or its spacing and origin).
    """

    def __init__(self, source: str, loader, members: dict | None = None, kwargs: dict | None = None) -> None:
        self.source = str(source)
        self._loader = loader
        self._kwargs = dict(kwargs or {})
        self._members: dict[tuple[int, ...], Any] = dict(members or {})
        self.lead_axes: tuple[str, ...] = tuple(getattr(loader, "axes", ()) or ())
        self.lead_shape: tuple[int, ...] = tuple(int(n) for n in (getattr(loader, "lead_shape", ()) or ()))
        pyr = loader.pyramid
        self.pyramid = pyr
        self.axes = self.lead_axes + ("z", "y", "x")
        self.levels: tuple[LevelInfo, ...] = tuple(pyr.levels)
        self.shape = self.lead_shape + tuple(pyr.shape)
        self.spacing = tuple(float(s) for s in pyr.spacing)
        self.dtype = np.dtype(pyr.dtype)
        self.brick_shape = tuple(pyr.brick_shape)
        self.value_range = tuple(pyr.value_range)
        self.unit = getattr(loader, "unit", None)
        #: False for a clipvol store whose manifest is missing or does not verify (``trust`` says why)
        self.verified: bool = bool(getattr(loader, "verified", True))
        self.trust: str = str(getattr(loader, "trust", "") or "")
        frame = getattr(loader, "frame", None)
        if frame is None:
            origin = getattr(loader, "origin", None) or (0.0, 0.0, 0.0)
            frame = WorldFrame.from_spacing(self.spacing, origin)
        self.frame: WorldFrame = frame

    # -- members of a set ------------------------------------------------------------------------
    def member(self, index: tuple[int, ...] = ()) -> Any:
        """The loader of one channel / time step (``index`` along ``lead_axes``; ``()`` for a 3-D volume)."""
        index = tuple(int(i) for i in index)
        if len(index) != len(self.lead_shape) or not all(0 <= i < n for i, n in zip(index, self.lead_shape)):
            raise ParameterError(f"member: expected an index along {self.lead_axes} within {self.lead_shape}, got {index}")
        if not index or all(i == 0 for i in index):
            return self._loader
        if index not in self._members:
            self._members[index] = open_loader(self.source, **self._kwargs, **dict(zip(self.lead_axes, index)))
        return self._members[index]

    # -- data --------------------------------------------------------------------------------------
    @property
    def num_levels(self) -> int:
        return len(self.levels)

    def _check_level(self, level: int, name: str = "level") -> int:
        if isinstance(level, bool) or int(level) != level or not 0 <= level < len(self.levels):
            raise ParameterError(f"{name}: expected 0..{len(self.levels) - 1} for {self.source}, got {level!r}")
        return int(level)

    def level(self, k: int = 0) -> LevelArray:
        """Level ``k`` (0 = finest) as a lazy array; ``vol.level(1)[10:20, :, 5]`` reads only the
        bricks that hold those voxels."""
        return LevelArray(self, self._check_level(k))

    def to_dask(self, level: int = 0):
        """Level ``level`` as a ``dask.array`` with one chunk per brick, read through the same
        verified loader (needs the ``dask`` extra: ``pip install 'clipvol[dask]'``)."""
        arr = self.level(level)
        try:
            import dask.array as da
        except ImportError:
            raise MissingExtraError("to_dask: needs dask; install the 'dask' extra: pip install 'clipvol[dask]'") from None
        return da.from_array(arr, chunks=arr.chunks, asarray=True, lock=False, fancy=False,
                             name=f"clipvol-{abs(hash((self.source, level))):x}")

    # -- geometry ----------------------------------------------------------------------------------
    def affine(self, level: int = 0) -> np.ndarray:
        """4x4 voxel-to-world matrix of ``level``: voxel index ``(x, y, z, 1)`` to world ``(X, Y, Z, 1)``
        (NIfTI's convention; level 0's is the store's :attr:`frame`)."""
        lv = self.levels[self._check_level(level)]
        sp = np.array(self.spacing[::-1])  # x, y, z
        to_level0 = np.eye(4)
        to_level0[:3, :3] = np.diag(np.array(lv.scale[::-1]) / sp)
        to_level0[:3, 3] = np.array(lv.translation[::-1]) / sp
        return self.frame.matrix @ to_level0

    def voxel_to_world(self, points=None, level: int = 0) -> np.ndarray:
        """World ``(..., 3)`` ``(x, y, z)`` of voxel indices ``points`` ``(..., 3)`` in array order
        ``(z, y, x)`` of ``level``; without ``points``, the 4x4 matrix of :meth:`affine`."""
        m = self.affine(level)
        if points is None:
            return m
        p = np.asarray(points, dtype=np.float64)
        if p.shape[-1:] != (3,):
            raise ParameterError(f"points: expected (..., 3) voxel indices (z, y, x), got shape {p.shape}")
        return p[..., ::-1] @ m[:3, :3].T + m[:3, 3]

    def world_to_voxel(self, points, level: int = 0) -> np.ndarray:
        """Fractional voxel indices ``(..., 3)`` in array order ``(z, y, x)`` of ``level`` for world
        points ``(..., 3)`` ``(x, y, z)``; a voxel's centre is at its integer index."""
        p = np.asarray(points, dtype=np.float64)
        if p.shape[-1:] != (3,):
            raise ParameterError(f"points: expected (..., 3) world points (x, y, z), got shape {p.shape}")
        inv = np.linalg.inv(self.affine(level))
        return (p @ inv[:3, :3].T + inv[:3, 3])[..., ::-1]

    def __repr__(self) -> str:
        axes = ", ".join(f"{a}={n}" for a, n in zip(self.axes, self.shape))
        return (f"<clipvol.Volume {self.source}: {axes} {self.dtype}, {len(self.levels)} levels, "
                f"spacing {self.spacing} {self.unit or ''}>")


def open(source: str | Path, *, store: str | Path | None = None, **kwargs) -> Volume:
    """Open anything ``clipvol view`` opens as a read-only :class:`Volume`.

    Parameters
    ----------
    source : str or Path
        A clipvol store or OME-Zarr image, the root of a channel set or time series (``clipvol brick``
        of a 4-D input), a ``.npy`` file, a ``procedural:NAME?...`` URL, a remote store URL, or a
        NIfTI / DICOM / HDF5 / MRC file (bricked once into ``store``, default ``./NAME.zarr``, and
        reused afterwards, as ``clipvol view`` does).
    store : str or Path, optional
        Where a file format is bricked (its progress bar shows on stderr while it is, and one line
        on stderr says which store is built or reused: ``bricking scan.nii.gz into /data/scan.zarr``).
    **kwargs
        Passed to the loader (``brick=32`` for ``.npy`` and procedural volumes; ``cache=``, ``storage_options=``
        for remote stores).

    Examples
    --------
    >>> vol = clipvol.open("scan.zarr")
    >>> block = vol.level(1)[10:40, 0:64, 0:64]   # numpy, (z, y, x)
    >>> vol.world_to_voxel([[12.5, -30.0, 4.0]])  # (z, y, x) of level 0
    """
    if isinstance(source, Path):
        source = str(source)
    for k in ("c", "t"):
        if k in kwargs:
            raise ParameterError(f"{k}: clipvol.open returns every channel and time step; index them with "
                                 f"vol.level(L)[k, ...] instead of {k}=")
    text = bricked_source(str(source), store, log=lambda line: print(line, file=sys.stderr))  # where its store is
    loader = open_loader(text, **kwargs)
    return Volume(text, loader, kwargs=kwargs)
