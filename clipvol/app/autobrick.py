"""One command from a scan to a picture: the store a NIfTI / DICOM / HDF5 / MRC input is bricked into.

``clipvol view``, ``clipvol render`` and ``clipvol.show()`` take what a user has — a ``.nii.gz``,
a DICOM folder, ``FILE.h5:/dataset``, an MRC map — as well as a store. Such an input is bricked
once into ``NAME.zarr`` (in the working folder, or a ``store`` the caller names) and that store is
reused while it is complete and records the same source file; stores, ``.npy`` files,
``procedural:`` volumes and URLs pass through unchanged.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Callable

__all__ = ["store_name", "bricked_source"]

#: suffixes stripped from an input's name to name its store
_SUFFIXES = (".nii.gz", ".nii", ".hdr", ".img", ".mrc", ".map", ".mrcs", ".rec", ".st", ".h5", ".hdf5", ".hdf", ".nxs", ".dcm")


def store_name(text: str) -> str:
    """``scan.nii.gz`` -> ``scan``; ``data.h5:/raw`` -> ``data``; ``ct_folder/`` -> ``ct_folder``."""
    base = text.split(".h5:")[0].split(".hdf5:")[0].rstrip("/\\")
    name = Path(base).name
    for suf in _SUFFIXES:
        if name.lower().endswith(suf):
            return name[: -len(suf)] or "volume"
    return name or "volume"


def bricked_source(text: str, store: str | os.PathLike | None = None, *, log: Callable[[str], None] = print) -> str:
    """``text`` itself, or for a NIfTI / DICOM / HDF5 / MRC input the store it is (or is now) bricked into.

    ``store`` defaults to ``./NAME.zarr`` (:func:`store_name`); a complete store bricked from the
    same file is reused. ``log`` gets one line saying which store is used or built.
    """
    from ..paging.bytesource import is_remote_url

    p = Path(text)
    if is_remote_url(text):  # a store behind a URL is opened as it is
        return text
    if text.startswith("procedural:") or p.suffix.lower() == ".npy" or (p.is_dir() and any((p / m).exists() for m in ("zarr.json", ".zgroup"))):
        return text
    from ..bricking.formats import open_format

    src = open_format(text)
    if src is None:
        return text
    src.close()
    out = Path(store) if store else Path.cwd() / f"{store_name(text)}.zarr"
    try:
        cv = json.loads((out / "zarr.json").read_text())["attributes"]["clipvol"]
        if cv.get("complete") and str(cv.get("source", "")).startswith(os.path.abspath(text) + " ("):
            log(f"using {out} (bricked from {text})")
            return str(out)
    except (OSError, ValueError, KeyError, TypeError):
        pass
    from ..bricking.pipeline import brick_volume

    log(f"bricking {text} into {out}")
    brick_volume(text, out, progress=True)
    return str(out)
