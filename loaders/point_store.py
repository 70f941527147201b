"""``PointStoreLoader``: a point store seen by the clip-texture as a sparse brick pyramid.

The octree of a point store is a pyramid whose depth-``d`` nodes are the bricks of level
``depth - d`` (grid ``2**d`` per axis, level 0 the deepest): the same octree the volume bricks
form. A node's payload is one fixed-size "brick" of shape ``(1, max_points, 4 + k)`` float32, one
row per point ``(x, y, z, 1, values...)`` (position minus the store's origin) and zero rows after
the node's points (the fourth column tells them apart). Nodes that do not exist are empty bricks:
:meth:`brick_ranges` reports them as ``[0, 0]``, so the clip-texture fills them without a read.
Hence node payloads go through the unchanged :class:`~clipvol.paging.cliptexture.ClipTexture`:
its distance-sorted queue, loader threads, memory budget, retries and failure reporting.

World frames: the clip-texture places bricks in the pyramid's frame (level-0 "voxel" centres at
``i * spacing``); :meth:`to_paging` maps a store-world point there. The node table (about 30 bytes
per node) is held in memory; points are read from the zarr arrays through a small cache of decoded
chunks shared by the loader threads (nodes of one subtree are stored next to each other).
"""

from __future__ import annotations

import threading
from collections import OrderedDict

import numpy as np

from clipvol.bricking.point_store import POINT_CHUNK, PointStoreMeta, open_point_store, read_node_table
from clipvol.bricking.points import NodeTable, morton_decode, morton_encode
from clipvol.bricking.pyramid import LevelInfo, Pyramid
from clipvol.errors import BrickLoadError

__all__ = ["PointStoreLoader"]

#: decoded point chunks kept (each POINT_CHUNK rows)
CHUNK_CACHE = 256


class PointStoreLoader:
    """Read a point store's node payloads as bricks (see the module docstring).

    Parameters
    ----------
    path : str or Path
        A store written by ``clipvol brick-points``.
    """

    def __init__(self, path) -> None:
        self.path = str(path)
        meta, g = open_point_store(path)
        self.meta: PointStoreMeta = meta
        self._xyz = g["points/xyz"]
        self._vals = g["points/values"]
        self.nodes = NodeTable(read_node_table(g), meta.origin, meta.edge)
        self.k = len(meta.value_names)
        self.max_points = meta.max_points
        D = self.nodes.max_depth
        self.depth = D
        brick = (1, meta.max_points, 4 + self.k)
        # level-0 "voxel" so that a brick (node) of level L spans edge / 2**(D - L) on every axis
        s0 = tuple(meta.edge / 2.0**D / b for b in brick)
        levels = []
        for L in range(D + 1):
            g_ = 2 ** (D - L)
            levels.append(LevelInfo((g_ * brick[0], g_ * brick[1], g_ * brick[2]), tuple(2.0**L * s for s in s0), (0.0, 0.0, 0.0)))
        lo, hi = meta.value_ranges[0]
        self._pyramid = Pyramid(tuple(levels), brick, "float32", (lo, hi), 0.0, "subsample")
        self._half = 0.5 * np.array(s0[::-1])  # (x, y, z)
        self._cache: OrderedDict[int, tuple[np.ndarray, np.ndarray]] = OrderedDict()
        self._lock = threading.Lock()

    # -- the loader contract ----------------------------------------------------------------
    @property
    def pyramid(self) -> Pyramid:
        return self._pyramid

    def node_of_brick(self, level: int, index) -> int:
        """Node id of brick ``(level, (bz, by, bx))`` or ``-1`` if there is no such node."""
        d = self.depth - int(level)
        bz, by, bx = (int(i) for i in index)
        code = int(morton_encode(np.array([bx]), np.array([by]), np.array([bz]))[0])
        return int(self.nodes.lookup(d, np.array([code]))[0])

    def brick_of_nodes(self, ids) -> tuple[np.ndarray, np.ndarray]:
        """``(levels, indices (n, 3) (bz, by, bx))`` of node ids."""
        ids = np.asarray(ids, np.int64)
        ixyz = morton_decode(self.nodes.code[ids])
        return self.depth - self.nodes.depth[ids], ixyz[:, ::-1].copy()

    def read_brick(self, level: int, index) -> np.ndarray:
        index = self._pyramid.check_key(level, index)  # names the level and brick if outside
        out = np.zeros(self._pyramid.brick_shape, np.float32)
        nid = self.node_of_brick(level, index)
        if nid >= 0:
            self._fill(nid, out[0])
        return out

    def brick_ranges(self, level: int, indices: np.ndarray) -> np.ndarray:
        """``[0, 0]`` (empty: never read) for bricks that are no node, unbounded for nodes."""
        idx = np.asarray(indices, np.int64).reshape(-1, 3)
        d = self.depth - int(level)
        codes = morton_encode(idx[:, 2], idx[:, 1], idx[:, 0])
        present = self.nodes.lookup(d, codes) >= 0
        out = np.zeros((len(idx), 2))
        out[present] = (-np.inf, np.inf)
        return out

    # -- points -----------------------------------------------------------------------------
    def node_points(self, nid: int) -> tuple[np.ndarray, np.ndarray]:
        """``(xyz float64 (n, 3) world, values float32 (n, k))`` of node ``nid``, read from the store."""
        rows = np.zeros((self.max_points, 4 + self.k), np.float32)
        self._fill(nid, rows)
        n = int(self.nodes.count[nid])
        return rows[:n, :3].astype(np.float64) + self.meta.origin, rows[:n, 4:]

    def leaf_points(self, max_points: int | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Every input point, read from the leaves: ``(xyz float64 (n, 3) world, values (n, k), h (n,))``.

        ``h`` is each point's leaf splat size (leaf edge / cbrt(points in the leaf)): what drawing
        every point at full detail uses (the reference of ``clipvol report`` and ``bench_splat``).
        Reads the whole store; ``max_points`` (a cap) raises a ParameterError naming it when exceeded.
        """
        from clipvol.errors import ParameterError

        n = self.nodes
        leaf = np.flatnonzero(n.child_mask == 0)
        total = int(n.count[leaf].sum())
        if max_points is not None and total > max_points:
            raise ParameterError(f"{self.path}: drawing every point needs all {total:,} points in memory, "
                                 f"more than the cap of {max_points:,}; raise the cap")
        order = np.argsort(n.offset[leaf], kind="stable")
        leaf = leaf[order]
        rows = np.concatenate([np.arange(o, o + c) for o, c in zip(n.offset[leaf], n.count[leaf])]) if len(leaf) else np.zeros(0, np.int64)
        xyz = np.asarray(self._xyz.get_orthogonal_selection((rows, slice(None))), np.float64) + np.asarray(self.meta.origin)
        vals = np.asarray(self._vals.get_orthogonal_selection((rows, slice(None))), np.float32)
        h = np.repeat(n.edges(leaf) / np.cbrt(np.maximum(n.count[leaf], 1)), n.count[leaf])
        return xyz, vals, h

    def _fill(self, nid: int, rows: np.ndarray) -> None:
        a = int(self.nodes.offset[nid])
        n = int(self.nodes.count[nid])
        i = 0
        while i < n:
            c, r = divmod(a + i, POINT_CHUNK)
            xyz, vals = self._chunk(c)
            m = min(n - i, len(xyz) - r)
            if m <= 0:
                raise BrickLoadError(f"{self.path}: node {nid} reads rows {a}..{a + n} past points/xyz ({c * POINT_CHUNK + len(xyz)} rows)")
            rows[i:i + m, :3] = xyz[r:r + m]
            rows[i:i + m, 3] = 1.0
            rows[i:i + m, 4:] = vals[r:r + m]
            i += m

    def _chunk(self, c: int) -> tuple[np.ndarray, np.ndarray]:
        with self._lock:
            hit = self._cache.get(c)
            if hit is not None:
                self._cache.move_to_end(c)
                return hit
        a, b = c * POINT_CHUNK, (c + 1) * POINT_CHUNK
        data = (np.asarray(self._xyz[a:b]), np.asarray(self._vals[a:b]))
        with self._lock:
            self._cache[c] = data
            while len(self._cache) > CHUNK_CACHE:
                self._cache.popitem(last=False)
        return data

    # -- frames -----------------------------------------------------------------------------
    def to_paging(self, xyz) -> np.ndarray:
        """A store-world point ``(x, y, z)`` in the clip-texture's frame (for ``set_center``)."""
        return np.asarray(xyz, np.float64) - self.meta.origin - self._half

    def world_box(self) -> tuple[np.ndarray, np.ndarray]:
        """The root cube ``(lo, hi)`` in world units."""
        o = np.asarray(self.meta.origin)
        return o, o + self.meta.edge

    def __repr__(self) -> str:
        return f"PointStoreLoader({self.path!r}, {len(self.nodes)} nodes, depth {self.depth})"
