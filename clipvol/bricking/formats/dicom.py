"""A DICOM series (a folder of single-frame slices) read slice by slice with pydicom.

pydicom (Mason et al., *pydicom: An open source DICOM library*, 2024) reads each file; this module
does what a series reader must (NEMA, *DICOM PS3.3 Information Object Definitions*, C.7.6.2 Image
Plane Module): it reads only the headers first, refuses a folder that mixes series (two
``SeriesInstanceUID``), slice sizes or orientations, sorts slices by their position along the
slice normal (``ImagePositionPatient`` · (row × column direction), never by file name or
``InstanceNumber``), refuses duplicate positions and uneven gaps (more than :data:`GAP_TOLERANCE`,
1 %, from the median gap), slices off the stack's axis (shifted sideways, or a gantry-tilted
stack) and mixed ``PixelSpacing`` (:mod:`clipvol.bricking.formats.geometry`), and builds the affine from
``ImageOrientationPatient``, ``PixelSpacing`` and the first and last positions. DICOM's patient
frame is LPS+; the affine is stored in RAS+ like NIfTI's.

Voxels are read one slice (file) at a time when the bricker asks for a slab, with the modality
rescale (``RescaleSlope``/``RescaleIntercept``, e.g. CT Hounsfield units) applied: integer
rescales keep an integer type wide enough for every stored value, others give float32.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from ...errors import InputFormatError
from ..source_types import Source
from ..worldframe import LPS_TO_RAS, WorldFrame
from . import require
from .geometry import SIDEWAYS_TOLERANCE, SPACING_TOLERANCE, check_orthogonal_axes

__all__ = ["DicomSeriesSource", "find_dicom_files", "is_dicom_file"]

#: relative tolerance on the gaps between slice positions
GAP_TOLERANCE = 0.01


def is_dicom_file(path: Path) -> bool:
    """True for a DICOM Part-10 file (``DICM`` at byte 128) or a ``.dcm`` file."""
    if path.suffix.lower() == ".dcm":
        return True
    try:
        with open(path, "rb") as f:
            f.seek(128)
            return f.read(4) == b"DICM"
    except OSError:
        return False


def find_dicom_files(folder: Path) -> list[Path]:
    """The DICOM files directly inside ``folder`` (hidden files and sub-folders skipped)."""
    try:
        entries = sorted(p for p in folder.iterdir() if p.is_file() and not p.name.startswith("."))
    except OSError:
        return []
    return [p for p in entries if is_dicom_file(p)]


def _floats(ds, key: str, n: int, where: Path) -> np.ndarray:
    v = getattr(ds, key, None)
    if v is None:
        raise InputFormatError(f"{where}: DICOM slice without {key}; cannot place it in a volume")
    try:
        out = np.array([float(x) for x in v], dtype=np.float64)
    except (TypeError, ValueError):
        raise InputFormatError(f"{where}: DICOM {key} is not {n} numbers: {v!r}") from None
    if out.shape != (n,) or not np.all(np.isfinite(out)):
        raise InputFormatError(f"{where}: DICOM {key} is not {n} finite numbers: {v!r}")
    return out


def _check_on_axis(positions: np.ndarray, iop: np.ndarray, ps: np.ndarray, files: list, name: str) -> None:
    """Slices sorted along their normal must lie on one line along it: a position off that line
    (sideways, in the slice plane) by more than :data:`~.geometry.SIDEWAYS_TOLERANCE` of a pixel
    is a slice from elsewhere, or - when the offset grows steadily - a tilted (sheared) stack."""
    if len(positions) < 2:
        return
    row_dir, col_dir = iop[:3], iop[3:]
    rel = positions - positions[0]
    side = np.c_[rel @ row_dir, rel @ col_dir]  # (n, 2) mm in the slice plane
    tol = SIDEWAYS_TOLERANCE * float(ps.min())
    off = np.linalg.norm(side, axis=1)
    if off.max() <= tol:
        return
    k = np.arange(len(side), dtype=np.float64)
    slope = (side[-1] - side[0]) / k[-1]  # mm sideways per slice, if it is steady
    steady = np.linalg.norm(side - k[:, None] * slope, axis=1).max() <= tol
    along = rel @ np.cross(row_dir, col_dir)
    if steady and len(side) > 2:
        step = float(np.median(np.diff(along)))
        tilt = math.degrees(math.atan2(float(np.linalg.norm(slope)), step))
        raise InputFormatError(
            f"{name}: the slices advance {float(np.linalg.norm(slope)):.4g} mm sideways per {step:.4g} mm step: a stack "
            f"tilted by {tilt:.2f}° from the slice normal (gantry tilt), not an orthogonal grid (tolerance "
            f"{tol:.3g} mm, {SIDEWAYS_TOLERANCE:.0%} of a pixel); resample it onto an orthogonal grid first")
    i = int(np.argmax(off))
    raise InputFormatError(
        f"{name}: slice {files[i].name} lies {off[i]:.4g} mm sideways of the stack's axis through {files[0].name} "
        f"(row {side[i, 0]:+.4g} mm, column {side[i, 1]:+.4g} mm; tolerance {tol:.3g} mm, {SIDEWAYS_TOLERANCE:.0%} "
        "of a pixel); a shifted slice or mixed series, not one grid")


class DicomSeriesSource(Source):
    """One DICOM series: slices sorted along their normal, read one file per z."""

    def __init__(self, files: list[Path], name: str) -> None:
        pydicom = require("pydicom", "dicom")
        from pydicom.errors import InvalidDicomError

        heads = []
        for f in files:
            try:
                ds = pydicom.dcmread(f, stop_before_pixels=True)
            except (InvalidDicomError, OSError, ValueError, EOFError) as e:
                raise InputFormatError(f"{f}: cannot read as DICOM ({type(e).__name__}: {e})") from None
            heads.append((f, ds))
        if not heads:
            raise InputFormatError(f"{name}: no DICOM files")
        series: dict[str, int] = {}
        for _f, ds in heads:
            uid = str(getattr(ds, "SeriesInstanceUID", "?"))
            series[uid] = series.get(uid, 0) + 1
        if len(series) > 1:
            desc = ", ".join(f"{uid} ({n} files)" for uid, n in series.items())
            raise InputFormatError(f"{name}: expected one DICOM series, got {len(series)}: {desc}; put each series in its own folder")
        f0, d0 = heads[0]
        if int(getattr(d0, "NumberOfFrames", 1) or 1) > 1 and len(heads) > 1:
            raise InputFormatError(f"{f0}: a multi-frame DICOM file among others; brick it alone")
        rows, cols = int(d0.Rows), int(d0.Columns)
        iop = _floats(d0, "ImageOrientationPatient", 6, f0)
        ps = _floats(d0, "PixelSpacing", 2, f0)  # (between rows, between columns)
        if not np.all(ps > 0):
            raise InputFormatError(f"{f0}: DICOM PixelSpacing must be > 0, got {tuple(ps.tolist())}")
        check_orthogonal_axes(np.c_[iop[:3], iop[3:], np.cross(iop[:3], iop[3:])], str(f0),
                              "ImageOrientationPatient (row and column directions)")
        positions = []
        for f, ds in heads:
            if (int(ds.Rows), int(ds.Columns)) != (rows, cols):
                raise InputFormatError(f"{f}: slice of {int(ds.Rows)}x{int(ds.Columns)} pixels in a series of {rows}x{cols} ({f0.name})")
            if not np.allclose(_floats(ds, "ImageOrientationPatient", 6, f), iop, atol=1e-4):
                raise InputFormatError(f"{f}: ImageOrientationPatient differs from {f0.name}'s; not one volume")
            psf = _floats(ds, "PixelSpacing", 2, f)
            if np.any(np.abs(psf - ps) > SPACING_TOLERANCE * ps):
                raise InputFormatError(f"{f}: PixelSpacing {tuple(psf.tolist())} mm differs from {f0.name}'s "
                                       f"{tuple(ps.tolist())} (by more than {SPACING_TOLERANCE:.1%}); not one grid")
            if int(getattr(ds, "SamplesPerPixel", 1)) != 1:
                raise InputFormatError(f"{f}: expected grey slices (SamplesPerPixel 1), got {ds.SamplesPerPixel}")
            positions.append(_floats(ds, "ImagePositionPatient", 3, f))
        row_dir, col_dir = iop[:3], iop[3:]
        normal = np.cross(row_dir, col_dir)
        along = np.array([p @ normal for p in positions])
        order = np.argsort(along, kind="stable")
        along = along[order]
        self._files = [heads[i][0] for i in order]
        _check_on_axis(np.array([positions[i] for i in order]), iop, ps, self._files, name)
        if len(along) > 1:
            gaps = np.diff(along)
            k = int(np.argmin(gaps))
            if gaps[k] <= 1e-6 * max(1.0, abs(along).max()):
                raise InputFormatError(f"{name}: two slices at the same position {along[k]:g} "
                                       f"({self._files[k].name}, {self._files[k + 1].name}); mixed or duplicated series")
            step = float(np.median(gaps))
            bad = np.abs(gaps - step) > GAP_TOLERANCE * step
            if bad.any():
                i = int(np.argmax(bad))
                raise InputFormatError(f"{name}: uneven slice spacing ({gaps[i]:g} mm between {self._files[i].name} and "
                                       f"{self._files[i + 1].name}, expected {step:g}); a missing slice or mixed series")
            z_vec = (positions[order[-1]] - positions[order[0]]) / (len(along) - 1)
        else:
            thick = float(getattr(d0, "SliceThickness", 1.0) or 1.0)
            z_vec = normal * thick
        lps = np.eye(4)
        lps[:3, 0] = row_dir * ps[1]  # x: along a row (column index)
        lps[:3, 1] = col_dir * ps[0]  # y: down a column (row index)
        lps[:3, 2] = z_vec
        lps[:3, 3] = positions[order[0]]
        self.frame = WorldFrame(tuple(tuple(r) for r in LPS_TO_RAS @ lps), "RAS")
        self.spacing = self.frame.spacing
        self.unit = "millimeter"
        # rescale to modality values (CT: Hounsfield units)
        rescale = {(float(getattr(ds, "RescaleSlope", 1) or 1), float(getattr(ds, "RescaleIntercept", 0) or 0)) for _f, ds in heads}
        stored = self._stored_dtype(d0, f0)
        self._rescale = [
            (float(getattr(heads[i][1], "RescaleSlope", 1) or 1), float(getattr(heads[i][1], "RescaleIntercept", 0) or 0)) for i in order
        ]
        self._init((len(self._files), rows, cols), self._out_dtype(stored, d0, rescale), name)

    @staticmethod
    def _stored_dtype(ds, f: Path) -> np.dtype:
        bits = int(getattr(ds, "BitsAllocated", 16))
        signed = int(getattr(ds, "PixelRepresentation", 0)) == 1
        if bits not in (8, 16, 32):
            raise InputFormatError(f"{f}: unsupported BitsAllocated {bits} (expected 8, 16 or 32)")
        return np.dtype(f"{'i' if signed else 'u'}{bits // 8}")

    @staticmethod
    def _out_dtype(stored: np.dtype, ds, rescale: set) -> np.dtype:
        if rescale == {(1.0, 0.0)}:
            return stored
        if all(s.is_integer() and i.is_integer() for s, i in rescale):
            bits = int(getattr(ds, "BitsStored", stored.itemsize * 8))
            signed = stored.kind == "i"
            lo = -(2 ** (bits - 1)) if signed else 0
            hi = 2 ** (bits - 1) - 1 if signed else 2**bits - 1
            ends = [s * v + i for s, i in rescale for v in (lo, hi)]
            for dt in (np.int16, np.int32):
                if np.iinfo(dt).min <= min(ends) and max(ends) <= np.iinfo(dt).max:
                    return np.dtype(dt)
        return np.dtype(np.float32)

    def _read(self, start, stop):
        import pydicom

        out = np.empty(tuple(b - a for a, b in zip(start, stop)), dtype=self.dtype)
        for k, z in enumerate(range(start[0], stop[0])):
            f = self._files[z]
            try:
                px = pydicom.dcmread(f).pixel_array
            except Exception as e:  # compressed syntax without a decoder, truncated pixel data...
                raise InputFormatError(f"{f}: cannot decode the DICOM pixel data ({type(e).__name__}: {e})") from None
            if px.shape != self.shape[1:]:
                raise InputFormatError(f"{f}: pixel data of shape {px.shape}, expected {self.shape[1:]}")
            px = px[start[1]:stop[1], start[2]:stop[2]]
            slope, inter = self._rescale[z]
            if (slope, inter) == (1.0, 0.0):
                out[k] = px
            else:
                val = px.astype(np.float64) * slope + inter
                out[k] = np.rint(val) if self.dtype.kind in "iu" else val
        return out
