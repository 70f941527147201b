"""A 3-D dataset inside an HDF5 file (``data.h5:/entry/data``), read chunk-aligned with h5py.

h5py (Collette, *Python and HDF5*, 2013) reads any hyperslab of a dataset, decompressing only the
chunks it touches, so the bricker's z-slabs never load the whole dataset. HDF5 has no standard
for voxel geometry; two common conventions are honoured when present on the dataset:
``element_size_um`` (ilastik, ImageJ/Fiji: ``(z, y, x)`` in micrometres) and NeXus-style
``spacing`` with an optional ``units``. A user's ``--spacing`` overrides both.

``data.h5`` without a dataset path is accepted when the file holds exactly one 3-D dataset;
otherwise the error lists the datasets there are.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ...errors import InputFormatError, InputNotFoundError
from ..source_types import Source, _squeeze3
from . import require

__all__ = ["Hdf5Source", "list_datasets"]


def list_datasets(f) -> list[tuple[str, tuple[int, ...]]]:
    """``(path, shape)`` of every dataset in an open h5py file, in file order."""
    out: list[tuple[str, tuple[int, ...]]] = []

    def visit(name, obj):
        if hasattr(obj, "shape") and hasattr(obj, "dtype"):
            out.append(("/" + name, tuple(obj.shape)))

    f.visititems(visit)
    return out


class Hdf5Source(Source):
    """One dataset of an HDF5 file; the file stays open until :meth:`close`."""

    def __init__(self, path: Path, dataset: str | None) -> None:
        h5py = require("h5py", "hdf5")
        path = Path(path)
        if not path.exists():
            raise InputNotFoundError(f"{path}: no such file")
        try:
            self._file = h5py.File(path, "r")
        except OSError as e:
            raise InputFormatError(f"{path}: cannot read as HDF5 ({e})") from None
        try:
            listing = list_datasets(self._file)
            if dataset is None:
                three = [p for p, s in listing if len(s) >= 3 and sum(n > 1 for n in s) >= 2]
                if len(three) != 1:
                    have = ", ".join(f"{p} {s}" for p, s in listing) or "none"
                    raise InputFormatError(f"{path}: name the dataset as {path}:/path/to/dataset (datasets: {have})")
                dataset = three[0]
            node = self._file.get(dataset)
            if node is None or not isinstance(node, h5py.Dataset):
                have = ", ".join(p for p, _ in listing) or "none"
                what = "no dataset" if node is None else "a group, not a dataset,"
                raise InputFormatError(f"{path}: {what} at {dataset!r} (datasets: {have})")
            name = f"{path}:{dataset}"
            shape = _squeeze3(tuple(node.shape), name)
            self._lead = len(node.shape) - 3
            self._ds = node
            self._init(shape, node.dtype, name)
            self.spacing, self.unit = self._geometry(node, name)
        except Exception:
            self._file.close()
            raise

    @staticmethod
    def _geometry(node, name: str):
        for key, unit in (("element_size_um", "micrometer"), ("spacing", None)):
            if key in node.attrs:
                try:
                    sp = tuple(float(v) for v in np.ravel(node.attrs[key]))[-3:]
                except (TypeError, ValueError):
                    raise InputFormatError(f"{name}: attribute {key!r} is not three numbers: {node.attrs[key]!r}") from None
                if len(sp) != 3 or not all(np.isfinite(sp)) or min(sp) <= 0:
                    raise InputFormatError(f"{name}: attribute {key!r}: expected three numbers > 0 (z, y, x), got {sp}")
                if unit is None:
                    u = node.attrs.get("units", node.attrs.get("unit"))
                    unit = u.decode() if isinstance(u, bytes) else (str(u) if u is not None else None)
                return sp, unit
        return None, None

    def _read(self, start, stop):
        sl = tuple(slice(a, b) for a, b in zip(start, stop))
        try:
            if self._lead == -1:
                return np.asarray(self._ds[sl[1:]])[None]
            return np.asarray(self._ds[(0,) * self._lead + sl])
        except (OSError, ValueError) as e:
            raise InputFormatError(f"{self.name}: cannot read voxels {start}..{stop} ({e})") from None

    def close(self) -> None:
        f = getattr(self, "_file", None)
        if f is not None:
            f.close()
