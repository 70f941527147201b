"""The spread beside a clipvol store's coarse levels (:mod:`clipvol.bricking.spread`), read per brick.

``clipvol brick`` writes ``clipvol_spread/<L>`` (the standard deviation of the level-0 voxels
beneath each voxel of level ``L >= 1``) and describes it in ``attrs["clipvol"]["spread"]``. A store
without the block - an older clipvol store, a plain OME-Zarr image, a remote store - has no spread,
and the renderer classifies its coarse voxels by their mean, as it always did.

Read through zarr-python (one chunk per brick, its crc32c verified by zarr's codec): a spread brick
is read only for coarse levels, about 1/7 of the bricks, so the fast path of the levels is not
repeated here.
"""

from __future__ import annotations

import threading
from typing import Any

import numpy as np

from clipvol.bricking.pyramid import Int3, pad_to_brick
from clipvol.bricking.spread import SPREAD_GROUP, spread_dtype
from clipvol.errors import BrickIntegrityError

__all__ = ["SpreadReader"]


class SpreadReader:
    """Mixin of :class:`~clipvol.loaders.zarr_store.ZarrLoader`: :attr:`spread_levels` and
    :meth:`read_spread` (the optional ``HasSpread`` part of the loader contract)."""

    def _open_spread(self, attrs: dict) -> None:
        """Note the levels whose spread the store holds (none unless the block and its arrays are there)."""
        self._spread_arrays: dict[int, Any] = {}
        self._spread_lock = threading.Lock()
        info = attrs.get("clipvol", {}).get("spread") if isinstance(attrs.get("clipvol"), dict) else None
        levels: tuple[int, ...] = ()
        if isinstance(info, dict) and info.get("group") == SPREAD_GROUP and info.get("statistic") == "std" \
                and info.get("dtype") == spread_dtype(self._pyramid.dtype).name and not self._lead:
            want = info.get("levels")
            if isinstance(want, list) and all(isinstance(L, int) and 1 <= L < self._stored for L in want):
                levels = tuple(L for L in want if (self.path / SPREAD_GROUP / str(L) / "zarr.json").is_file())
        #: the levels whose voxels carry their spread (empty: the store has none)
        self.spread_levels: tuple[int, ...] = levels

    def read_spread(self, level: int, index: Int3) -> np.ndarray | None:
        """The spread of brick ``index`` of ``level`` (brick shape, :func:`spread_dtype`,
        edge-replicated like the brick), or None for a level without one."""
        if level not in self.spread_levels:
            return None
        import zarr

        index = self._pyramid.check_key(level, index)
        with self._spread_lock:
            arr = self._spread_arrays.get(level)
            if arr is None:
                arr = zarr.open_array(str(self.path / SPREAD_GROUP / str(level)), mode="r")
                self._spread_arrays[level] = arr
        start, stop = self._pyramid.brick_voxel_box(level, index)
        try:
            block = np.asarray(arr[tuple(slice(a, b) for a, b in zip(start, stop))])
        except Exception as e:  # a damaged chunk (crc32c) or file: never a wrong spread as if right
            raise BrickIntegrityError(f"{self._where}: {SPREAD_GROUP}/{level} brick {tuple(index)}: "
                                      f"unreadable ({type(e).__name__}: {e})") from e
        return pad_to_brick(block, self._pyramid.brick_shape)
