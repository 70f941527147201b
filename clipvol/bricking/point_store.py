"""The point store: an out-of-core octree build (``clipvol brick-points``) into a zarr v3 group.

Layout (``docs/format.md``, section "Point stores")::

    points.zarr/
      zarr.json             attrs["clipvol"]: kind "points", format_version, max_points, origin,
                            edge, depth, value_names, value_ranges, num_points, num_nodes,
                            num_stored, point_spacing, representative, complete
      nodes/code            int64  Morton code of the node at its depth (key prefix)
      nodes/depth           uint8  0 = root
      nodes/offset          int64  first row of the node's points in points/*
      nodes/count           int32  points stored in the node (<= max_points)
      nodes/weight          int64  input points in the node's subtree
      nodes/child_mask      uint8  bit o set: child octant o (x | y << 1 | z << 2) exists
      points/xyz            float32 (M, 3) position minus ``origin`` (x, y, z)
      points/values         float32 (M, k) one column per value name

The store's code is split by job, one module each, and every public name stays importable from here:
:mod:`.point_store_open` (format constants, :class:`PointStoreMeta`, opening, the node table),
:mod:`.point_store_write` (chunked appends and checkpoints), :mod:`.point_store_build` (the
out-of-core build after Meredith & Ma, *Multiresolution view-dependent splat based volume rendering
of large irregular data*, 2001, and its resume) and :mod:`.point_store_check` (the invariants). The
octree arithmetic lives in :mod:`.points` and the readers of point files in :mod:`.point_sources`.
"""

from __future__ import annotations

from .point_store_build import KB, _Build, build_point_store  # noqa: F401  (_Build: tests patch its methods)
from .point_store_check import check_point_store
from .point_store_open import (NODE_ARRAYS, NODE_CHUNK, POINT_CHUNK, POINT_FORMAT_VERSION, PointStoreMeta,  # noqa: F401
                               is_point_store, open_point_store, read_node_table)
from .point_store_write import _Writer  # noqa: F401

__all__ = [
    "POINT_FORMAT_VERSION",
    "PointStoreMeta",
    "build_point_store",
    "is_point_store",
    "open_point_store",
    "read_node_table",
    "check_point_store",
]
