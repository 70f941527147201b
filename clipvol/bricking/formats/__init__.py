"""Readers for the files people hold: NIfTI, DICOM series, HDF5 datasets, MRC maps, OME-TIFF geometry.

Each reader is a :class:`clipvol.bricking.sources.Source` in its own module, built on the
library of its field (nibabel, pydicom, h5py, mrcfile) rather than a parser of our own, and each
library is an optional extra: a missing one raises :class:`~clipvol.errors.MissingExtraError`
naming the ``pip install 'clipvol[...]'`` that brings it. Every reader streams (NIfTI through
nibabel's array proxy, DICOM slice by slice, HDF5 by chunks, MRC by positional reads) and records
the file's geometry as a :class:`~clipvol.bricking.worldframe.WorldFrame`.

:func:`open_format` is the one hook :func:`~clipvol.bricking.sources.open_source` calls: it
recognises a path by its suffix (or, for a folder, by the DICOM files inside it) and returns None
for anything else, so the older formats keep their own code path.
"""

from __future__ import annotations

import importlib
from pathlib import Path

from ...errors import MissingExtraError

__all__ = ["open_format", "require", "NIFTI_SUFFIXES", "HDF5_SUFFIXES", "MRC_SUFFIXES", "readable_formats"]

NIFTI_SUFFIXES = (".nii", ".nii.gz", ".hdr", ".img")
HDF5_SUFFIXES = (".h5", ".hdf5", ".hdf", ".he5", ".nxs")
MRC_SUFFIXES = (".mrc", ".map", ".mrcs", ".rec", ".st")


def require(module: str, extra: str):
    """Import ``module`` or raise :class:`MissingExtraError` naming the extra that installs it."""
    try:
        return importlib.import_module(module)
    except ImportError:
        raise MissingExtraError(
            f"reading this input needs the optional package {module!r}: pip install 'clipvol[{extra}]'"
        ) from None


def _has_suffix(name: str, suffixes) -> bool:
    low = name.lower()
    return any(low.endswith(s) for s in suffixes)


def _split_hdf5(text: str) -> tuple[str, str | None] | None:
    """``FILE.h5:/path/in/file`` -> (FILE.h5, /path/in/file); ``FILE.h5`` -> (FILE.h5, None)."""
    for suf in HDF5_SUFFIXES:
        i = text.lower().find(suf + ":")
        if i >= 0:
            return text[: i + len(suf)], text[i + len(suf) + 1:] or "/"
    if _has_suffix(text, HDF5_SUFFIXES):
        return text, None
    return None


def readable_formats() -> str:
    """The inputs a drawing command (``render``, ``view``, ``slice``, ``export``) opens, for an error
    that must tell a newcomer what to give instead: stores and the files bricked on first use."""
    from .ometiff import OME_SUFFIXES

    return ("a clipvol / OME-Zarr store directory, a .npy file, a URL (procedural:fractal?size=256, https://, s3://), "
            f"or a file bricked on first use: NIfTI ({', '.join(NIFTI_SUFFIXES)}), a DICOM series folder, "
            f"HDF5 FILE{HDF5_SUFFIXES[0]}:/dataset ({', '.join(HDF5_SUFFIXES)}), MRC ({', '.join(MRC_SUFFIXES)}), "
            f"OME-TIFF ({', '.join(OME_SUFFIXES)}); other TIFF stacks and raw files: `clipvol brick` first")


def open_format(text: str):
    """The reader for ``text`` if it names a NIfTI, DICOM, HDF5 or MRC input, else None."""
    h5 = _split_hdf5(text)
    if h5 is not None:
        from .hdf5 import Hdf5Source

        return Hdf5Source(Path(h5[0]), h5[1])
    path = Path(text)
    if not path.exists():
        return None
    if path.is_dir():
        from .dicom import find_dicom_files

        if any((path / m).exists() for m in ("zarr.json", ".zarray", ".zgroup")):
            return None
        files = find_dicom_files(path)
        if not files:
            return None
        from .dicom import DicomSeriesSource

        return DicomSeriesSource(files, str(path))
    from .ometiff import OME_SUFFIXES, open_ome_tiff

    if _has_suffix(path.name, OME_SUFFIXES):
        return open_ome_tiff(path)
    if _has_suffix(path.name, NIFTI_SUFFIXES):
        from .nifti import NiftiSource

        return NiftiSource(path)
    if _has_suffix(path.name, MRC_SUFFIXES):
        from .mrc import open_mrc

        return open_mrc(path)
    if path.suffix.lower() == ".dcm":
        from .dicom import DicomSeriesSource

        return DicomSeriesSource([path], str(path))
    return None
