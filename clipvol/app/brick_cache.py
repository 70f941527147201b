"""One step from a scan to a store: a NIfTI / DICOM / HDF5 / MRC input is bricked once and reused.

``clipvol view ct_folder/`` and ``clipvol.open("scan.nii.gz")`` brick a file format into
``./<name>.zarr`` (or a store the caller names) the first time and open that store afterwards, as
long as the store is complete and records the same input (its ``source`` attribute starts with the
input's absolute path). Stores, ``.npy`` files (memory-mapped as they are), procedural volumes and
URLs are returned unchanged: they need no bricking to be paged.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Callable

__all__ = ["store_name", "bricked_source"]

_SUFFIXES = (".nii.gz", ".nii", ".hdr", ".img", ".mrc", ".map", ".mrcs", ".rec", ".st", ".h5", ".hdf5", ".hdf",
             ".nxs", ".dcm")


def store_name(text: str) -> str:
    """The stem a bricked store of ``text`` is named after (``scan.nii.gz`` -> ``scan``)."""
    base = text.split(".h5:")[0].split(".hdf5:")[0].rstrip("/\\")
    name = Path(base).name
    for suf in _SUFFIXES:
        if name.lower().endswith(suf):
            return name[: -len(suf)] or "volume"
    return name or "volume"


def bricked_source(text: str, store: str | Path | None = None, *, progress: bool = True,
                   log: Callable[[str], None] | None = print) -> str:
    """``text`` itself, or for a file format that must be bricked first the store it is bricked into.

    Parameters
    ----------
    text : str
        A path or URL as a user writes it.
    store : str or Path, optional
        Where to brick it (default ``./<name>.zarr`` in the working directory).
    progress : bool
        Show the bricking progress bar.
    log : callable or None
        Receives one line saying which store is used or built (None: silent).
    """
    from ..paging.bytesource import is_remote_url

    text = str(text)
    p = Path(text)
    if is_remote_url(text):  # a store behind a URL is opened as it is
        return text
    if text.startswith("procedural:") or p.suffix.lower() == ".npy" or (
            p.is_dir() and any((p / m).exists() for m in ("zarr.json", ".zgroup"))):
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
            if log:
                log(f"using {out} (bricked from {text})")
            return str(out)
    except (OSError, ValueError, KeyError, TypeError):
        pass
    from ..bricking.pipeline import brick_volume

    if log:
        log(f"bricking {text} into {out}")
    brick_volume(text, out, progress=progress)
    return str(out)
