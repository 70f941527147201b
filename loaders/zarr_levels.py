"""Coarse levels a plain OME-Zarr image does not store, computed from their children on demand.

Why: many OME-Zarr images stop their pyramid early, or store levels that are not the 2x (ceil)
down-sample the clip-texture needs (:mod:`clipvol.loaders.zarr_open` decides which levels
conform). From the first level that does not conform, each brick is made from its (up to 8)
children with the image's filter (:func:`clipvol.bricking.pyramid.downsample`) and kept in a
bounded least-recently-used cache, so panning over a coarse level does not re-read the fine one.
A clipvol store stores every level and never comes here.

A mixin of :class:`~clipvol.loaders.zarr_store.ZarrLoader`: it reads the children through the
loader's own ``read_brick`` (checked like any load) and shares its lock.
"""

from __future__ import annotations

import numpy as np

from clipvol.bricking.pyramid import Int3, downsample, pad_to_brick

__all__ = ["ComputedLevels", "DERIVED_CACHE_BYTES"]

#: bytes of derived (computed) bricks kept for plain OME-Zarr images missing coarse levels
DERIVED_CACHE_BYTES = 256 * 2**20


class ComputedLevels:
    """``read_brick`` of a level beyond the stored ones (:meth:`_derived_brick`)."""

    def _derived_brick(self, level: int, index: Int3) -> np.ndarray:
        """A brick of a level the OME-Zarr image does not store: the filter over its 8 children."""
        key = (level, index)
        with self._lock:
            hit = self._derived.get(key)
            if hit is not None:
                self._derived.move_to_end(key)
                return hit.copy()
        pyr = self._pyramid
        B = pyr.brick_shape
        fine = level - 1
        fshape = pyr.levels[fine].shape
        start = [2 * i * b for i, b in zip(index, B)]
        stop = [min(s + 2 * b, n) for s, b, n in zip(start, B, fshape)]
        region = np.empty(tuple(e - s for s, e in zip(start, stop)), dtype=pyr.dtype)
        for child in pyr.children(level, index):
            cs, ce = pyr.brick_voxel_box(fine, child)
            data = self.read_brick(fine, child)
            region[tuple(slice(a - o, b - o) for a, b, o in zip(cs, ce, start))] = data[tuple(slice(0, b - a) for a, b in zip(cs, ce))]
        out = pad_to_brick(downsample(region, pyr.filter), B)
        with self._lock:
            if key not in self._derived:
                self._derived[key] = out
                self._derived_bytes += out.nbytes
                while self._derived_bytes > DERIVED_CACHE_BYTES and len(self._derived) > 1:
                    _, old = self._derived.popitem(last=False)
                    self._derived_bytes -= old.nbytes
        return out.copy()
