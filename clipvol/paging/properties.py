"""What a loader knows about its data as a whole, for choices made once per data set.

The render actions compile shader variants per data property (see :mod:`clipvol.render.glsl`):
data that can hold no NaN or Inf gets a sampling path with no per-sample test at all. The answer
comes from the store's statistics where there are some (``nan_count``/``inf_count`` per brick,
written by ``clipvol brick``), from the dtype where it settles the question (integers hold no
NaN), and is "maybe" otherwise - the NaN-aware variant is always correct, only slower.
"""

from __future__ import annotations

import numpy as np

__all__ = ["may_hold_nonfinite"]


def may_hold_nonfinite(loader) -> bool:
    """False only when ``loader``'s data certainly holds no NaN or Inf at any level.

    Integer dtypes never do. For float data, a loader with ``brick_statistics(level)`` (the zarr
    store's per-brick ``nan_count``/``inf_count``) answers per level; without statistics the
    answer is True (unknown).
    """
    pyr = loader.pyramid
    if np.dtype(pyr.dtype).kind in "iub":
        return False
    stats_fn = getattr(loader, "brick_statistics", None)
    if stats_fn is None:
        declared = getattr(loader, "nonfinite", None)  # in-memory loaders may know exactly
        return True if declared is None else bool(declared)
    for level in range(pyr.num_levels):
        try:
            stats = stats_fn(level)
        except Exception:  # noqa: BLE001 - unreadable statistics mean "unknown", never a crash here
            return True
        if not stats or "nan_count" not in stats or "inf_count" not in stats:
            return True
        if "done" in stats and not bool(np.all(stats["done"])):
            return True
        if np.any(np.asarray(stats["nan_count"]) > 0) or np.any(np.asarray(stats["inf_count"]) > 0):
            return True
    return False
