"""MRC / CCP4 maps and tomograms (``.mrc``, ``.map``, ``.rec``, ``.st``), header by mrcfile.

mrcfile (Burnley, Palmer & Winn, *Recent developments in the CCP-EM software suite*, 2017)
validates the header (MRC2014: Cheng et al., *MRC2014: Extensions to the MRC format header for
electron cryo-microscopy and tomography*, 2015) and tells the data's dtype, byte order and offset;
the voxels are then read by positional reads of whole z-sections
(:class:`~clipvol.bricking.sources.FileArraySource`), never through a memory map whose pages would
count towards the bricker's memory.

Geometry: the voxel size is ``cella / (mx, my, mz)`` in ångström (a header without one, ``cella``
all 0, needs ``--spacing``; NaN, negative or partly-zero cell sizes are refused); voxel 0 sits at the header's
``origin`` when it is set, else at ``(nxstart, nystart, nzstart)`` voxels (both conventions are
in use). Only the standard axis order (``mapc, mapr, maps = 1, 2, 3``) is accepted.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ...errors import InputFormatError
from ..source_types import FileArraySource
from ..worldframe import WorldFrame
from . import require

__all__ = ["open_mrc"]


def open_mrc(path: Path) -> FileArraySource:
    """A :class:`FileArraySource` over the data block of the MRC file ``path``, with its geometry."""
    mrcfile = require("mrcfile", "mrc")
    from mrcfile.utils import data_dtype_from_header

    path = Path(path)
    try:
        with mrcfile.open(str(path), mode="r", header_only=True, permissive=False) as m:
            h = m.header.copy()
    except Exception as e:  # mrcfile raises ValueError for a bad header, OSError, ...
        raise InputFormatError(f"{path}: cannot read as MRC ({type(e).__name__}: {e})") from None
    order = (int(h.mapc), int(h.mapr), int(h.maps))
    if order != (1, 2, 3):
        raise InputFormatError(f"{path}: MRC axis order mapc,mapr,maps = {order}; only 1,2,3 (x fastest) is supported")
    try:
        dtype = data_dtype_from_header(h)
    except ValueError as e:
        raise InputFormatError(f"{path}: {e}") from None
    shape = (int(h.nz), int(h.ny), int(h.nx))
    if min(shape) < 1:
        raise InputFormatError(f"{path}: expected every axis >= 1, got nz, ny, nx = {shape}")
    offset = 1024 + int(h.nsymbt)
    need = offset + int(np.prod(shape)) * dtype.itemsize
    have = path.stat().st_size
    if have < need:
        raise InputFormatError(f"{path}: truncated MRC file (expected {need} bytes for {shape} {dtype.name}, got {have})")
    src = FileArraySource(path, shape, dtype, offset, str(path))
    vox = _voxel_size(path, h)
    unset = vox is None
    vox = np.ones(3) if unset else vox
    origin = np.array([float(h.origin.x), float(h.origin.y), float(h.origin.z)])
    if not np.any(origin) or not np.all(np.isfinite(origin)):
        origin = np.array([int(h.nxstart), int(h.nystart), int(h.nzstart)], dtype=np.float64) * vox
    src.frame = WorldFrame.from_spacing(vox[::-1], origin[::-1], frame="")
    src.spacing = src.frame.spacing
    src.unit = "angstrom"
    if unset:  # brick_volume refuses to guess: --spacing must say it
        src.spacing_required = (f"{path}: the MRC header records no voxel size (cell size cella = 0, 0, 0 Å); "
                                "pass --spacing z,y,x in Å")
    return src


def _voxel_size(path: Path, h) -> np.ndarray | None:
    """``(x, y, z)`` voxel size in Å from ``cella / (mx, my, mz)``; None when the header records
    none (``cella`` all 0, what writers leave by default). A cell size that is NaN, infinite,
    negative or 0 on some axes only, or a sampling grid ``mx, my, mz`` < 1 with a cell size, is no
    geometry at all: refused, naming the fields, instead of a silent 1 Å."""
    cella = np.array([float(h.cella.x), float(h.cella.y), float(h.cella.z)])
    grid = np.array([int(h.mx), int(h.my), int(h.mz)], dtype=np.float64)
    if np.all(cella == 0.0):
        return None
    if not np.all(np.isfinite(cella)) or np.any(cella <= 0.0):
        raise InputFormatError(f"{path}: expected an MRC cell size (cella) > 0 Å on every axis, got "
                               f"{tuple(float(v) for v in cella)}")
    if np.any(grid < 1):
        raise InputFormatError(f"{path}: expected an MRC sampling grid (mx, my, mz) >= 1 with cell size "
                               f"{tuple(float(v) for v in cella)}, got {tuple(int(v) for v in grid)}")
    vox = cella / grid
    if not np.all(np.isfinite(vox) & (vox > 0)):
        raise InputFormatError(f"{path}: MRC voxel size cella / (mx, my, mz) = {tuple(vox)} is not a size")
    return vox
