"""Opening a point store: its format constants, validated attributes (:class:`PointStoreMeta`) and node table.

The reading side of :mod:`clipvol.bricking.point_store` (the layout is described there): the loader
(:mod:`clipvol.loaders.point_store`), the checker and a resumed build open a store through here.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import StoreFormatError, StoreIncompleteError

__all__ = ["POINT_FORMAT_VERSION", "NODE_CHUNK", "POINT_CHUNK", "NODE_ARRAYS", "PointStoreMeta", "is_point_store",
           "open_point_store", "read_node_table"]

POINT_FORMAT_VERSION = 1
NODE_CHUNK = 1 << 16
POINT_CHUNK = 1 << 12
NODE_ARRAYS = {"code": "int64", "depth": "uint8", "offset": "int64", "count": "int32", "weight": "int64", "child_mask": "uint8"}


@dataclass(frozen=True, slots=True)
class PointStoreMeta:
    """Validated attributes of a point store."""

    path: str
    max_points: int
    origin: tuple[float, float, float]
    edge: float
    depth: int
    value_names: tuple[str, ...]
    value_ranges: tuple[tuple[float, float], ...]
    num_points: int
    num_nodes: int
    num_stored: int
    point_spacing: float
    complete: bool

    def __post_init__(self) -> None:
        if self.max_points < 8 or not (self.edge > 0 and np.isfinite(self.edge)) or len(self.origin) != 3:
            raise StoreFormatError(f"{self.path}: point store attributes out of range (max_points {self.max_points}, edge {self.edge})")
        if not self.value_names or len(self.value_ranges) != len(self.value_names):
            raise StoreFormatError(f"{self.path}: expected one value range per value name, got {self.value_ranges} for {self.value_names}")


def is_point_store(path) -> bool:
    """True if ``path`` is a zarr group whose clipvol attributes say ``kind: points``."""
    from .store_kind import store_kind

    return store_kind(path) == "points"


def _meta(attrs: dict, where: str) -> PointStoreMeta:
    cv = attrs.get("clipvol")
    if not isinstance(cv, dict) or cv.get("kind") != "points":
        raise StoreFormatError(f"{where}: expected a clipvol point store (attrs clipvol.kind = 'points')")
    if cv.get("format_version") != POINT_FORMAT_VERSION:
        raise StoreFormatError(f"{where}: expected point format version {POINT_FORMAT_VERSION}, got {cv.get('format_version')!r}")
    try:
        return PointStoreMeta(
            where, int(cv["max_points"]), tuple(float(v) for v in cv["origin"]), float(cv["edge"]), int(cv.get("depth", 0)),
            tuple(str(v) for v in cv["value_names"]), tuple((float(a), float(b)) for a, b in cv["value_ranges"]),
            int(cv["num_points"]), int(cv.get("num_nodes", 0)), int(cv.get("num_stored", 0)),
            float(cv.get("point_spacing", 0.0)), bool(cv.get("complete", False)),
        )
    except (KeyError, TypeError, ValueError) as e:
        raise StoreFormatError(f"{where}: malformed point store attributes ({type(e).__name__}: {e})") from None


def open_point_store(path, *, require_complete: bool = True):
    """``(meta, group)`` of the point store at ``path``; refuses an interrupted build by default."""
    import zarr

    p = Path(path)
    if not (p / "zarr.json").is_file():
        raise StoreFormatError(f"{p}: expected a zarr group (zarr.json), found none")
    g = zarr.open_group(str(p), mode="r")
    meta = _meta(dict(g.attrs), str(p))
    if require_complete and not meta.complete:
        raise StoreIncompleteError(f"{p}: the point store build did not finish (complete is false); run brick-points again")
    return meta, g


def read_node_table(group) -> dict[str, np.ndarray]:
    """All node arrays, sorted by ``(depth, code)`` (so each depth is a sorted run of codes)."""
    t = {name: np.asarray(group[f"nodes/{name}"][:]) for name in NODE_ARRAYS}
    order = np.lexsort((t["code"], t["depth"]))
    return {k: v[order] for k, v in t.items()}
