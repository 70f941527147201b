"""NIfTI-1/2 volumes (``.nii``, ``.nii.gz``, ``.hdr``/``.img``) through nibabel's array proxy.

nibabel (Brett et al., *nipy/nibabel*, 2024) parses the header and the ``sform``/``qform``
affine (voxel ``(i, j, k)`` to RAS+ millimetres, Cox et al., *A (Sort of) New Image Data Format
Standard: NIfTI-1*, 2004) and its array proxy reads any region without loading the volume: the
bricker asks for z-slabs (``k`` ranges), which are contiguous in the file, so even a ``.nii.gz``
is decompressed once, front to back (the file handle is kept open between slabs).

nibabel's array order is ``(i, j, k)`` with ``i`` fastest on disk; clipvol's ``(z, y, x)`` is its
transpose, so the affine maps clipvol's ``(x, y, z)`` index unchanged. An affine whose axes are not
orthogonal (a sheared ``sform``) is refused (:mod:`clipvol.bricking.formats.geometry`); rotated
ones are kept as they are. A scaled image
(``scl_slope``/``scl_inter``) is read as float32 with the scaling applied, as nibabel defines it.
"""

from __future__ import annotations

import contextlib
from pathlib import Path

import numpy as np

from ...errors import InputFormatError
from ..source_types import Source
from ..worldframe import WorldFrame
from . import require
from .geometry import check_orthogonal_axes

__all__ = ["NiftiSource"]


def _affine_name(img) -> str:
    """Which of the header's affines nibabel chose (sform over qform), for messages."""
    hdr = img.header
    try:
        if int(hdr["sform_code"]) > 0:
            return "sform affine"
        if int(hdr["qform_code"]) > 0:
            return "qform affine"
    except (KeyError, TypeError, ValueError):
        pass
    return "voxel-to-world affine"


@contextlib.contextmanager
def _quiet_header_fixes():
    """nibabel logs the fixes it makes to a header as it loads it ("pixdim[1,2,3] should be non-zero;
    setting 0 dims to 1") on stderr; the one that matters here is refused by this class in its own
    words (:func:`_unset_voxel_size`), so the load does not print a second, contradicting line."""
    import logging

    log = logging.getLogger("nibabel.global")
    old = log.level
    log.setLevel(logging.ERROR)
    try:
        yield
    finally:
        log.setLevel(old)


def _unset_voxel_size(img) -> tuple[float, ...] | None:
    """The header's own ``pixdim[1:4]`` when it records no voxel size (a zero, negative or non-finite
    entry) and no ``sform``/``qform`` gives one instead; else None. nibabel replaces such a pixdim
    by 1 when it loads the header, so the header is read again as it is on disk."""
    hdr = img.header
    try:
        if int(hdr["sform_code"]) > 0 or int(hdr["qform_code"]) > 0:
            return None
        from nibabel.openers import ImageOpener

        fm = img.file_map
        with ImageOpener((fm.get("header") or fm["image"]).filename) as f:
            raw = type(hdr).from_fileobj(f, check=False)
        zooms = tuple(float(v) for v in raw["pixdim"][1:4])
    except Exception:  # noqa: BLE001 - a header nibabel has read once: anything odd keeps nibabel's reading
        return None
    return zooms if not all(np.isfinite(z) and z > 0 for z in zooms) else None


class NiftiSource(Source):
    """A 3-D NIfTI image (a 4-D one with a single volume is accepted)."""

    def __init__(self, path: Path) -> None:
        nib = require("nibabel", "nifti")
        self._path = Path(path)
        try:
            with _quiet_header_fixes():
                img = nib.load(str(path), keep_file_open=True)
        except Exception as e:  # nibabel raises ImageFileError, HeaderDataError, OSError, EOFError...
            raise InputFormatError(f"{path}: cannot read as NIfTI ({type(e).__name__}: {e})") from None
        shape = tuple(int(s) for s in img.shape)
        while len(shape) > 3 and shape[-1] == 1:
            shape = shape[:-1]
        if len(shape) == 2:
            shape = shape + (1,)
        if len(shape) != 3:
            raise InputFormatError(f"{path}: expected a 3-D NIfTI image (i, j, k), got shape {tuple(img.shape)}")
        self._ndim = len(img.shape)
        proxy = img.dataobj
        slope = float(getattr(proxy, "slope", 1.0))
        inter = float(getattr(proxy, "inter", 0.0))
        disk = np.dtype(img.get_data_dtype())
        dtype = disk if (slope == 1.0 and inter == 0.0) else np.dtype(np.float32)
        self._check_size(img, shape, disk)
        self._img = img
        self._proxy = proxy
        self._init(shape[::-1], dtype, str(path))
        affine = np.asarray(img.affine, dtype=np.float64)
        check_orthogonal_axes(affine, str(path), _affine_name(img))  # a sheared sform is refused
        self.frame = WorldFrame(tuple(tuple(r) for r in affine), "RAS")
        self.spacing = self.frame.spacing
        units = img.header.get_xyzt_units()[0] if hasattr(img.header, "get_xyzt_units") else None
        zooms = _unset_voxel_size(img)
        if zooms is not None:  # brick_volume refuses to guess: --spacing must say it
            self.spacing_required = (f"{path}: the NIfTI header records no voxel size (pixdim[1:4] = "
                                     f"{', '.join(f'{z:g}' for z in zooms)}, and neither an sform nor a qform); "
                                     "pass --spacing z,y,x")
        self.unit = {"mm": "millimeter", "micron": "micrometer", "meter": "meter"}.get(units or "", "millimeter")

    def _check_size(self, img, shape, disk: np.dtype) -> None:
        """An uncompressed file shorter than its header promises is refused before any brick is written."""
        name = self._path.name.lower()
        if name.endswith(".gz"):
            return  # the gzip stream's end is only known by decompressing; a short one fails on read
        data_file = self._path.with_suffix(".img") if name.endswith(".hdr") else self._path
        offset = int(getattr(img.dataobj, "offset", 0))
        need = offset + int(np.prod(shape)) * disk.itemsize
        try:
            have = data_file.stat().st_size
        except OSError as e:
            raise InputFormatError(f"{data_file}: cannot read the NIfTI data ({e})") from None
        if have < need:
            raise InputFormatError(f"{data_file}: truncated NIfTI file (expected {need} bytes for shape {shape} "
                                   f"{disk.name} at offset {offset}, got {have})")

    def _read(self, start, stop):
        (z0, y0, x0), (z1, y1, x1) = start, stop
        sl = (slice(x0, x1), slice(y0, y1), slice(z0, z1)) + (0,) * (self._ndim - 3)
        try:
            a = np.asarray(self._proxy[sl])
        except Exception as e:  # a truncated or corrupt .nii.gz fails here (EOFError, OSError, ValueError)
            raise InputFormatError(f"{self._path}: cannot read voxels {start}..{stop} ({type(e).__name__}: {e}); "
                                   "the file is truncated or corrupt") from None
        if a.ndim == 2:
            a = a[..., None]
        return a.transpose(2, 1, 0)

    def close(self) -> None:
        proxy = getattr(self, "_proxy", None)
        opener = getattr(proxy, "_opener", None)
        if opener is not None and not opener.closed:  # the handle keep_file_open=True holds
            opener.close_if_mine()
