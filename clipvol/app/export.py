"""Take a region out of a volume: a box at one level, written as ``.npy``, ``.tif``, ``.nii(.gz)`` or ``.zarr``
with its place in the world.

The region is read brick by brick through the loader (:func:`clipvol.app.volume_access.read_region`:
checksums and statistics checked as when drawn) straight into a memory-mapped output file, one
z-slab of bricks at a time; after each slab the written pages are flushed and handed back to the
kernel, so the process holds one brick and one slab's dirty pages whatever the region's size.

Geometry travels with the data, in each format's own terms:

* ``.nii`` / ``.nii.gz``: the sform and qform are the region's voxel-to-world affine (the store's
  affine, the level's scale and translation, and the box's corner), code ``scanner`` for an
  anatomical (RAS) store and ``aligned`` otherwise; voxel ``(0, 0, 0)`` of the file is the box's
  first voxel. NIfTI stores ``(x, y, z)`` in Fortran order, which is clipvol's C-order ``(z, y, x)``
  byte for byte, so the voxels are written without a transpose (``.nii.gz`` gzips the finished
  ``.nii`` in a stream).
* ``.zarr``: a clipvol store bricked by the usual pipeline (:func:`clipvol.bricking.pipeline.brick_volume`)
  with the region's affine, so its OME ``scale`` is the level's voxel size and its ``translation``
  the box's corner.
* ``.tif``: a multi-page TIFF (``ZYX``) whose JSON description holds ``spacing``, ``unit`` and
  ``affine`` (read back with ``tifffile.TiffFile(...).shaped_metadata``) and whose resolution tags
  hold the in-plane voxel size.
* ``.npy``: the array, with the same geometry in a ``.npy.json`` sidecar.

Nothing half-written is left as if complete: the output is built under a hidden temporary name
beside it and renamed at the end; an error or Ctrl-C removes the temporary. A full disk is an error
before the first voxel, not a crash in the middle: the region's size is checked against the
folder's free space, and each memory-mapped file's blocks are reserved (``posix_fallocate``) before
it is written, since a mapped write that the file system cannot back ends the process with SIGBUS
(no handler runs, the temporary stays). ``--overwrite`` replaces only what
:mod:`clipvol.bricking.output_guard` allows (a file of the output's kind, a clipvol store, an empty
folder; never the input).
"""

from __future__ import annotations

import errno
import json
import mmap
import os
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

from ..bricking.worldframe import WorldFrame
from ..bricking.output_guard import check_not_input, check_overwrite, exists_error, remove_output
from ..errors import (OPERATIONAL_ERRNOS, ClipvolError, MissingExtraError, OutputWriteError, ParameterError,
                      describe_os_error)
from ..units import format_bytes
from .volume_access import Volume, bricks_of_region, copy_brick

__all__ = ["FORMATS", "Region", "output_format", "region_from_voxels", "region_from_world", "export_region"]

#: output suffixes and the format each names
FORMATS = {".npy": "npy", ".tif": "tif", ".tiff": "tif", ".nii": "nii", ".nii.gz": "nii.gz", ".zarr": "zarr"}


@dataclass(frozen=True, slots=True)
class Region:
    """A box ``start..stop`` (``(z, y, x)``, stop exclusive) of voxels of ``level``."""

    level: int
    start: tuple[int, int, int]
    stop: tuple[int, int, int]

    def __post_init__(self) -> None:
        start = tuple(int(v) for v in self.start)
        stop = tuple(int(v) for v in self.stop)
        if int(self.level) < 0 or len(start) != 3 or len(stop) != 3 or not all(0 <= a <= b for a, b in zip(start, stop)):
            raise ParameterError(f"Region: expected level >= 0 and 0 <= start <= stop (z, y, x), got level "
                                 f"{self.level}, {self.start}..{self.stop}")
        object.__setattr__(self, "level", int(self.level))
        object.__setattr__(self, "start", start)
        object.__setattr__(self, "stop", stop)

    @property
    def shape(self) -> tuple[int, int, int]:
        return tuple(b - a for a, b in zip(self.start, self.stop))  # type: ignore[return-value]


def output_format(out: str | Path) -> str:
    """``"npy"``, ``"tif"``, ``"nii"``, ``"nii.gz"`` or ``"zarr"`` from the output's name."""
    name = Path(out).name.lower()
    for suffix in sorted(FORMATS, key=len, reverse=True):
        if name.endswith(suffix) and len(name) > len(suffix):
            return FORMATS[suffix]
    raise ParameterError(f"--out: expected a name ending in {', '.join(FORMATS)}, got {str(out)!r}")


def _check_level(volume: Volume, level: int) -> int:
    if isinstance(level, bool) or int(level) != level or not 0 <= level < volume.num_levels:
        raise ParameterError(f"--level: expected 0..{volume.num_levels - 1} for {volume.source}, got {level!r}")
    return int(level)


def region_from_voxels(volume: Volume, start0: Sequence[int], stop0: Sequence[int], level: int = 0) -> Region:
    """The voxels of ``level`` that overlap the level-0 box ``start0..stop0`` (``(z, y, x)``): a
    coarse voxel ``i`` covers level-0 voxels ``i * f .. (i + 1) * f`` with ``f`` the level's factor."""
    level = _check_level(volume, level)
    shape0 = volume.levels[0].shape
    start0 = tuple(int(v) for v in start0)
    stop0 = tuple(int(v) for v in stop0)
    if len(start0) != 3 or len(stop0) != 3 or not all(0 <= a < b <= n for a, b, n in zip(start0, stop0, shape0)):
        raise ParameterError(f"--box: expected 0 <= start < stop <= {shape0} (z, y, x voxels of level 0) for "
                             f"{volume.source}, got {start0}..{stop0}")
    lv = volume.levels[level]
    f = [max(1, round(s / s0)) for s, s0 in zip(lv.scale, volume.levels[0].scale)]
    start = tuple(a // k for a, k in zip(start0, f))
    stop = tuple(min(n, -(-b // k)) for b, k, n in zip(stop0, f, lv.shape))
    return Region(level, start, stop)  # type: ignore[arg-type]


def region_from_world(volume: Volume, corner_a, corner_b, level: int = 0) -> Region:
    """The voxels of ``level`` whose centres lie in the world box with corners ``corner_a`` and
    ``corner_b`` (``(x, y, z)`` in the store's world frame; for an oblique frame, the bounding box in
    the array's axes of that world box)."""
    level = _check_level(volume, level)
    a = np.asarray(corner_a, dtype=np.float64)
    b = np.asarray(corner_b, dtype=np.float64)
    if a.shape != (3,) or b.shape != (3,) or not (np.all(np.isfinite(a)) and np.all(np.isfinite(b))):
        raise ParameterError(f"--box-world: expected two finite corners x,y,z, got {corner_a} and {corner_b}")
    lo, hi = np.minimum(a, b), np.maximum(a, b)
    corners = np.array([[(lo, hi)[i][0], (lo, hi)[j][1], (lo, hi)[k][2]] for i in (0, 1) for j in (0, 1) for k in (0, 1)])
    vox = volume.world_to_voxel(corners, level)
    shape = volume.levels[level].shape
    eps = 1e-6
    start = np.maximum(np.ceil(vox.min(axis=0) - eps), 0).astype(int)
    stop = np.minimum(np.floor(vox.max(axis=0) + eps) + 1, shape).astype(int)
    if np.any(stop <= start):
        w0 = volume.voxel_to_world([0, 0, 0], level)
        w1 = volume.voxel_to_world([n - 1 for n in shape], level)
        raise ParameterError(f"--box-world: the box {lo.tolist()}..{hi.tolist()} holds no voxel centre of level {level} of "
                             f"{volume.source} (its voxel centres span {np.round(w0, 4).tolist()}..{np.round(w1, 4).tolist()}, x, y, z)")
    return Region(level, tuple(int(v) for v in start), tuple(int(v) for v in stop))  # type: ignore[arg-type]


def region_affine(volume: Volume, region: Region) -> np.ndarray:
    """4x4 affine of the exported array: its voxel ``(x, y, z, 1)`` (NIfTI order) to world."""
    shift = np.eye(4)
    shift[:3, 3] = region.start[::-1]
    return volume.affine(region.level) @ shift


# -- streaming into a memory map -------------------------------------------------------------------
def _release(mm: np.ndarray, lo: int, hi: int) -> None:
    """Flush bytes ``lo..hi`` of memory map ``mm`` and let the kernel drop their pages (they are in the
    file): the memory an export holds stays one slab, not the region. Best effort."""
    base = getattr(mm, "_mmap", None)
    if base is None or not hasattr(base, "madvise") or not hasattr(mmap, "MADV_DONTNEED"):
        return
    try:
        mm.flush()
        delta = mm.ctypes.data - np.frombuffer(base, dtype=np.uint8).ctypes.data
        page = mmap.PAGESIZE
        a = (delta + lo) // page * page
        b = (delta + hi) // page * page
        if b > a:
            base.madvise(mmap.MADV_DONTNEED, a, b - a)
    except (ValueError, OSError, BufferError):
        pass


def _stream(loader, region: Region, mm: np.ndarray, progress: bool, desc: str) -> None:
    """Read ``region`` brick by brick into ``mm`` (its shape), z-slab by z-slab of bricks."""
    from tqdm import tqdm

    bs = loader.pyramid.brick_shape
    bricks = bricks_of_region(bs, region.start, region.stop)
    row = mm.shape[1] * mm.shape[2] * mm.dtype.itemsize
    with tqdm(total=len(bricks), desc=desc, unit="brick", disable=not progress, leave=False) as bar:
        slab = None
        for index in bricks:
            if slab is not None and index[0] != slab:
                z1 = min(region.stop[0], (slab + 1) * bs[0]) - region.start[0]
                _release(mm, 0, z1 * row)
            slab = index[0]
            copy_brick(loader, region.level, index, region.start, region.stop, mm)
            bar.update(1)
    if hasattr(mm, "flush"):
        mm.flush()


def _temp_name(out: Path) -> Path:
    return out.with_name(f".{out.name}.partial-{os.getpid()}")


def _remove(p: Path) -> None:
    if p.is_dir() and not p.is_symlink():
        shutil.rmtree(p, ignore_errors=True)
    else:
        try:
            p.unlink()
        except FileNotFoundError:
            pass


def _check_free(folder: Path, nbytes: int, out: Path) -> None:
    """Refuse an export that cannot fit: ``nbytes`` more than the free space of ``folder``
    (:func:`shutil.disk_usage`), before a byte is written."""
    try:
        free = shutil.disk_usage(folder).free
    except OSError:
        return  # the size cannot be asked: the reservation of each file still catches a full disk
    if nbytes > free:
        err = OutputWriteError(f"--out {out}: the export needs {format_bytes(nbytes)} in {folder}, which has "
                               f"{format_bytes(free)} free; nothing was written")
        err.errno = errno.ENOSPC
        raise err


def _reserve(path: Path) -> None:
    """Allocate the disk blocks of the (sparse) file ``path`` that a memory map will fill
    (:func:`os.posix_fallocate`), so a full disk is an ``ENOSPC`` here and not a SIGBUS at the
    first mapped write to a page the file system cannot back. A file system that cannot
    reserve (``EOPNOTSUPP``, ``EINVAL``) is written as before, after the free-space check."""
    if not hasattr(os, "posix_fallocate"):
        return
    fd = os.open(path, os.O_RDWR)
    try:
        size = os.fstat(fd).st_size
        if size > 0:
            os.posix_fallocate(fd, 0, size)
    except OSError as e:
        if e.errno not in (errno.EOPNOTSUPP, errno.ENOSYS, errno.EINVAL):
            raise
    finally:
        os.close(fd)


def _geometry(volume: Volume, region: Region, affine: np.ndarray) -> dict:
    return {"source": volume.source, "level": region.level, "box_start_zyx": list(region.start),
            "box_stop_zyx": list(region.stop), "spacing_zyx": list(WorldFrame(affine, volume.frame.frame).spacing),
            "unit": volume.unit, "world_frame": volume.frame.frame, "affine": [list(map(float, r)) for r in affine]}


def _write_npy(loader, region, tmp: Path, geom: dict, progress: bool, dtype) -> list[Path]:
    mm = np.lib.format.open_memmap(tmp, mode="w+", dtype=dtype, shape=region.shape)
    _reserve(tmp)
    _stream(loader, region, mm, progress, "export")
    del mm
    side = tmp.with_name(tmp.name + ".json")
    side.write_text(json.dumps(geom, indent=2))
    return [side]


def _write_tif(loader, region, tmp: Path, geom: dict, progress: bool, dtype) -> list[Path]:
    import tifffile

    sz, sy, sx = geom["spacing_zyx"]
    meta = {"axes": "ZYX", "spacing": [sz, sy, sx], "unit": geom["unit"] or "", "affine": geom["affine"],
            "world_frame": geom["world_frame"], "level": geom["level"], "box_start_zyx": geom["box_start_zyx"]}
    mm = tifffile.memmap(tmp, shape=region.shape, dtype=dtype, photometric="minisblack", metadata=meta,
                         resolution=(1.0 / sx, 1.0 / sy))
    _reserve(tmp)
    _stream(loader, region, mm, progress, "export")
    del mm
    return []


_NIFTI_UNITS = {"millimeter": "mm", "micrometer": "micron", "meter": "meter"}


def _nifti_header(region: Region, affine: np.ndarray, frame: str, unit: str | None, dtype, out: Path):
    try:
        import nibabel as nib
    except ImportError:
        raise MissingExtraError(f"--out {out}: NIfTI output needs nibabel; install the 'nifti' extra: "
                                "pip install 'clipvol[nifti]'") from None
    hdr = nib.Nifti1Header()
    try:
        hdr.set_data_dtype(np.dtype(dtype))
    except Exception:
        raise ParameterError(f"--out {out}: NIfTI cannot hold dtype {np.dtype(dtype)}; write .npy, .tif or .zarr") from None
    hdr.set_data_shape(region.shape[::-1])  # (x, y, z)
    code = "scanner" if frame == "RAS" else "aligned"
    hdr.set_sform(affine, code=code)
    hdr.set_qform(affine, code=code)
    hdr.set_xyzt_units(xyz=_NIFTI_UNITS.get(unit or "", "unknown"))
    hdr.set_data_offset(352)
    return hdr


def _write_nii(loader, region, tmp: Path, geom: dict, progress: bool, dtype, out: Path, gz: bool) -> list[Path]:
    hdr = _nifti_header(region, np.asarray(geom["affine"]), geom["world_frame"], geom["unit"], dtype, out)
    raw = tmp.with_name(tmp.name + ".nii") if gz else tmp
    disk_dtype = hdr.get_data_dtype()  # the header's byte order
    nbytes = int(np.prod(region.shape)) * disk_dtype.itemsize
    with open(raw, "wb") as f:
        hdr.write_to(f)  # 348 bytes and the 4-byte "no extensions" flag of a single-file NIfTI
        if f.tell() != 352:
            raise ParameterError(f"--out {out}: unexpected NIfTI header length {f.tell()}")
        f.truncate(352 + nbytes)
    try:
        _reserve(raw)
        mm = np.memmap(raw, dtype=disk_dtype, mode="r+", offset=352, shape=region.shape)  # (z, y, x) C = NIfTI's F
        _stream(loader, region, mm, progress, "export")
        del mm
        if gz:
            import gzip

            with open(raw, "rb") as src, gzip.open(tmp, "wb", compresslevel=6) as dst:
                shutil.copyfileobj(src, dst, 4 << 20)
    finally:
        if gz:
            _remove(raw)
    return []


def _write_zarr(loader, region, tmp: Path, geom: dict, progress: bool, dtype, volume: Volume) -> list[Path]:
    from ..bricking.pipeline import brick_volume
    from ..bricking.pyramid import FILTERS
    from ..bricking.source_types import ArraySource

    scratch = tmp.with_name(tmp.name + ".npy")
    try:
        mm = np.lib.format.open_memmap(scratch, mode="w+", dtype=dtype, shape=region.shape)
        _reserve(scratch)
        _stream(loader, region, mm, progress, "export")
        mm.flush()
        src = ArraySource(mm, name=f"{volume.source} level {region.level} box {region.start}..{region.stop}")
        src.frame = WorldFrame(np.asarray(geom["affine"]), volume.frame.frame)
        src.unit = volume.unit
        src.spacing = src.frame.spacing
        filt = volume.pyramid.filter if volume.pyramid.filter in FILTERS else "mean"
        edge = volume.brick_shape[0]
        brick = edge if edge % 2 == 0 and 8 <= edge <= 256 and len(set(volume.brick_shape)) == 1 else 64
        brick_volume(src, tmp, brick=brick, filter=filt, progress=progress, summary=True)
        del src, mm
    finally:
        _remove(scratch)
    return []


def export_region(volume: Volume, region: Region, out: str | Path, *, member: Sequence[int] = (),
                  overwrite: bool = False, progress: bool = False, inputs: Sequence[str | Path] = ()) -> dict:
    """Write ``region`` of ``volume`` (member ``member`` of a channel set or time series) to ``out``.

    Parameters
    ----------
    volume : Volume
        From :func:`clipvol.open`.
    region : Region
        From :func:`region_from_voxels` or :func:`region_from_world`.
    out : str or Path
        ``.npy``, ``.tif``/``.tiff``, ``.nii``, ``.nii.gz`` or ``.zarr`` (see the module docstring).
    member : sequence of int
        Index along the volume's channel / time axes (``()`` for a 3-D volume).
    overwrite : bool
        Replace an existing ``out`` (only once the new one is complete), and only when it is one
        file of the output's kind or, for ``.zarr``, a clipvol store or an empty folder
        (:func:`clipvol.bricking.output_guard.check_overwrite`); ``out`` is never the volume's
        source, a folder holding it, or a path inside it.
    progress : bool
        A tqdm progress bar on stderr.
    inputs : sequence of str or Path
        Other paths ``out`` must not touch (the file a store was bricked from), besides the
        volume's source.

    Returns
    -------
    dict
        The region's geometry: ``level``, ``box_start_zyx``, ``box_stop_zyx``, ``spacing_zyx``,
        ``unit``, ``world_frame``, ``affine`` (voxel ``(x, y, z, 1)`` to world) and ``path``.
    """
    out = Path(out)
    fmt = output_format(out)
    kind = "store" if fmt == "zarr" else fmt
    inputs = [volume.source, *inputs]
    check_not_input(out, inputs, "--out")
    if out.exists() or out.is_symlink():
        if not overwrite:
            raise exists_error(out, kind, "--out")
        check_overwrite(out, inputs, kind, "--out")  # refused before anything is read or written
    if not out.parent.is_dir():
        raise ParameterError(f"--out {out}: the folder {out.parent} does not exist")
    shape = volume.levels[_check_level(volume, region.level)].shape
    if not all(b <= n for b, n in zip(region.stop, shape)):
        raise ParameterError(f"--box: the region {region.start}..{region.stop} reaches past level {region.level}'s "
                             f"shape {shape} (z, y, x)")
    if any(b <= a for a, b in zip(region.start, region.stop)):
        raise ParameterError(f"--box: the region {region.start}..{region.stop} at level {region.level} is empty")
    loader = volume.member(tuple(member))
    affine = region_affine(volume, region)
    geom = _geometry(volume, region, affine)
    dtype = volume.dtype
    nbytes = int(np.prod(region.shape)) * np.dtype(dtype).itemsize
    # a .nii.gz is written as .nii first, a .zarr is bricked from a scratch .npy: both hold the region twice
    _check_free(out.parent, nbytes * (2 if fmt in ("nii.gz", "zarr") else 1), out)
    tmp = _temp_name(out)
    _remove(tmp)
    extras: list[Path] = []
    try:
        if fmt == "npy":
            extras = _write_npy(loader, region, tmp, geom, progress, dtype)
        elif fmt == "tif":
            extras = _write_tif(loader, region, tmp, geom, progress, dtype)
        elif fmt in ("nii", "nii.gz"):
            extras = _write_nii(loader, region, tmp, geom, progress, dtype, out, fmt == "nii.gz")
        else:
            extras = _write_zarr(loader, region, tmp, geom, progress, dtype, volume)
        if out.exists() or out.is_symlink():
            check_overwrite(out, inputs, kind, "--out")  # what is there now, not what was there at the start
            remove_output(out)
        for e in extras:  # a sidecar first: the data file's name appears last, complete
            os.replace(e, out.with_name(out.name + e.name[len(tmp.name):]))
        os.replace(tmp, out)
    except BaseException as e:
        _remove(tmp)
        _remove(tmp.with_name(tmp.name + ".json"))  # a .npy's sidecar, should its own write have failed
        for x in extras:
            _remove(x)
        if isinstance(e, OSError) and not isinstance(e, ClipvolError) and e.errno in OPERATIONAL_ERRNOS:
            err = OutputWriteError(f"--out {out}: cannot write the export ({describe_os_error(e)}); nothing was "
                                   "written")
            err.errno = e.errno
            raise err from e
        raise
    geom["path"] = str(out)
    return geom

