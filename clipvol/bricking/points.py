"""The point octree: Morton keys, node splitting and representative points (pure numpy, no I/O).

After Meredith & Ma (2001), section 2.2 and 3.1: a cube around the points is the root; a node
holding more than ``N`` points is split into its eight octants; every node stores at most ``N``
points - a leaf its own points, an inner node *representatives* of its subtree, so that any cut
through the tree is a complete, coarser or finer, point cloud of the data. A node's splats are
its projected size over the cube root of its point count.

Keys. A point's position is quantised to ``GEO_BITS`` bits per axis inside the root cube; its
key interleaves the bits (Morton order, octant digit ``x | y << 1 | z << 2`` per level), so a node
at depth ``d`` is a key prefix (``key >> 3 * (DEPTH - d)``, its *code*) and the points of any
node are one contiguous run of the sorted keys. Points that quantise to one cell (duplicates,
coincident points) get ``DUP_BITS`` more levels of "virtual" digits from their rank in that cell,
so up to ``8 ** DUP_BITS * N`` coincident points still split into leaves of at most ``N``: a
virtual node's box is an octant of the quantum cell, an error below ``2 ** -GEO_BITS`` of the
root's edge.

Representatives. An inner node at depth ``d`` keeps, for every non-empty cell of depth
``d + k`` below it (``8 ** k <= N``), the candidate nearest that cell's centre, the candidates
being its children's stored points - Meredith & Ma's "point closest to the centre", applied to a grid
of ``8 ** k`` cells rather than one point per leaf, so an inner node is as full as a leaf.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import InputFormatError, ParameterError

__all__ = [
    "GEO_BITS",
    "DUP_BITS",
    "DEPTH",
    "morton_encode",
    "morton_decode",
    "quantise",
    "point_keys",
    "rep_depth_step",
    "SubtreeBuild",
    "build_subtrees",
    "choose_representatives",
    "cell_means",
    "REPRESENTATIVES",
    "NodeTable",
]

#: how an inner node's point for a cell gets its values: the nearest point's own (Meredith & Ma's
#: choice), or the mean over the cell's candidates (smoother, no longer an input value)
REPRESENTATIVES = ("nearest", "mean")
GEO_BITS = 17
DUP_BITS = 4
DEPTH = GEO_BITS + DUP_BITS  # 21 levels below the root: 63-bit keys
_U = np.uint64


def _spread(v: np.ndarray) -> np.ndarray:
    v = np.asarray(v, dtype=np.uint64) & _U(0x1FFFFF)
    v = (v | (v << _U(32))) & _U(0x1F00000000FFFF)
    v = (v | (v << _U(16))) & _U(0x1F0000FF0000FF)
    v = (v | (v << _U(8))) & _U(0x100F00F00F00F00F)
    v = (v | (v << _U(4))) & _U(0x10C30C30C30C30C3)
    v = (v | (v << _U(2))) & _U(0x1249249249249249)
    return v


def _compact(v: np.ndarray) -> np.ndarray:
    v = np.asarray(v, dtype=np.uint64) & _U(0x1249249249249249)
    v = (v ^ (v >> _U(2))) & _U(0x10C30C30C30C30C3)
    v = (v ^ (v >> _U(4))) & _U(0x100F00F00F00F00F)
    v = (v ^ (v >> _U(8))) & _U(0x1F0000FF0000FF)
    v = (v ^ (v >> _U(16))) & _U(0x1F00000000FFFF)
    v = (v ^ (v >> _U(32))) & _U(0x1FFFFF)
    return v


def morton_encode(ix, iy, iz) -> np.ndarray:
    """Interleave up to 21-bit integer coordinates into int64 codes (octant ``x | y << 1 | z << 2``)."""
    return (_spread(ix) | (_spread(iy) << _U(1)) | (_spread(iz) << _U(2))).astype(np.int64)


def morton_decode(code) -> np.ndarray:
    """``(n, 3)`` int64 ``(ix, iy, iz)`` of node codes (the inverse of :func:`morton_encode`)."""
    c = np.asarray(code, dtype=np.int64).astype(np.uint64)
    return np.stack([_compact(c), _compact(c >> _U(1)), _compact(c >> _U(2))], axis=-1).astype(np.int64)


def quantise(xyz: np.ndarray, origin, edge: float) -> np.ndarray:
    """``(n, 3)`` int64 cell of each point on the ``2 ** GEO_BITS`` grid of the root cube."""
    n = 1 << GEO_BITS
    q = np.floor((np.asarray(xyz, dtype=np.float64) - np.asarray(origin, dtype=np.float64)) * (n / edge))
    return np.clip(q, 0, n - 1).astype(np.int64)


def point_keys(xyz: np.ndarray, origin, edge: float) -> tuple[np.ndarray, np.ndarray]:
    """Full keys of points (duplicate ranks included) and the order that sorts them.

    Returns ``(keys_sorted, order)``: ``xyz[order]`` has keys ``keys_sorted``. The points of one
    quantum cell must all be in ``xyz`` (the build partitions by cells, so they are).
    """
    q = quantise(xyz, origin, edge)
    geo = morton_encode(q[:, 0], q[:, 1], q[:, 2])
    order = np.argsort(geo, kind="stable")
    g = geo[order]
    start = np.r_[True, g[1:] != g[:-1]] if len(g) else np.zeros(0, bool)
    run0 = np.maximum.accumulate(np.where(start, np.arange(len(g)), 0))
    rank = (np.arange(len(g)) - run0) & ((1 << (3 * DUP_BITS)) - 1)
    qs = q[order]
    vx = np.zeros(len(g), np.int64)
    vy = np.zeros(len(g), np.int64)
    vz = np.zeros(len(g), np.int64)
    for j in range(DUP_BITS):  # virtual level j + 1 takes digit j of the rank: round robin first
        digit = (rank >> (3 * j)) & 7
        bit = DUP_BITS - 1 - j
        vx |= (digit & 1) << bit
        vy |= ((digit >> 1) & 1) << bit
        vz |= ((digit >> 2) & 1) << bit
    keys = morton_encode((qs[:, 0] << DUP_BITS) | vx, (qs[:, 1] << DUP_BITS) | vy, (qs[:, 2] << DUP_BITS) | vz)
    o2 = np.argsort(keys, kind="stable")
    return keys[o2], order[o2]


def rep_depth_step(max_points: int) -> int:
    """``k`` with ``8 ** k <= max_points``: an inner node keeps one point per cell ``k`` levels down."""
    if max_points < 8:
        raise ParameterError(f"max_points: expected >= 8 (an inner node needs one point per octant), got {max_points}")
    k = 1
    while 8 ** (k + 1) <= max_points:
        k += 1
    return k


def node_box(depth, code, origin, edge: float) -> tuple[np.ndarray, np.ndarray]:
    """World ``(lo, hi)`` ``(n, 3)`` of nodes ``(depth, code)``."""
    d = np.asarray(depth, dtype=np.int64)
    idx = morton_decode(code).astype(np.float64)
    size = (edge / 2.0 ** d)[..., None]
    lo = np.asarray(origin, dtype=np.float64) + idx * size
    return lo, lo + size


@dataclass
class SubtreeBuild:
    """Nodes of subtrees built in memory, in pre-order (a node before its children, octant order).

    ``start``/``end`` index the sorted points for leaves; ``parent`` is -1 for a subtree root.
    """

    depth: np.ndarray
    code: np.ndarray
    start: np.ndarray
    end: np.ndarray
    parent: np.ndarray
    leaf: np.ndarray
    child_mask: np.ndarray


def build_subtrees(keys: np.ndarray, roots_depth, roots_start, roots_end, max_points: int) -> SubtreeBuild:
    """Split each root segment ``[start, end)`` of the sorted ``keys`` until nodes hold ``<= max_points``.

    Level by level and vectorised over all open nodes: a node's children are the runs of equal key
    prefix one level down inside its segment.
    """
    keys = np.asarray(keys, dtype=np.int64)
    depth_l = [np.asarray(roots_depth, np.int64)]
    start_l = [np.asarray(roots_start, np.int64)]
    end_l = [np.asarray(roots_end, np.int64)]
    parent_l = [np.full(len(start_l[0]), -1, np.int64)]
    cur = np.arange(len(start_l[0]))
    cur_depth, cur_start, cur_end = depth_l[0], start_l[0], end_l[0]
    masks: dict[int, int] = {}
    leaf_parts = []
    while len(cur):
        n = cur_end - cur_start
        split = n > max_points
        stuck = split & (cur_depth >= DEPTH)
        if stuck.any():
            i = int(np.argmax(stuck))
            raise InputFormatError(
                f"more than {max_points * 8 ** DUP_BITS} coincident points (key {int(keys[cur_start[i]])}); "
                f"raise --max-points"
            )
        leaf_parts.append((cur, ~split))
        s_ids = cur[split]
        if not len(s_ids):
            break
        s0, s1, sd = cur_start[split], cur_end[split], cur_depth[split]
        cnt = s1 - s0
        seg = np.repeat(np.arange(len(s0)), cnt)
        idx = np.repeat(s0 - np.cumsum(cnt) + cnt, cnt) + np.arange(int(cnt.sum()))
        cd = sd[seg] + 1
        ccode = keys[idx] >> (3 * (DEPTH - cd))
        new = np.r_[True, (ccode[1:] != ccode[:-1]) | (seg[1:] != seg[:-1])]
        first = np.flatnonzero(new)
        c_start = idx[first]
        c_seg = seg[first]
        c_end = np.r_[idx[first[1:] - 1] + 1, idx[-1] + 1]
        octant = (ccode[first] & 7).astype(np.int64)
        mask = np.zeros(len(s0), np.int64)
        np.bitwise_or.at(mask, c_seg, 1 << octant)
        for i, m in zip(s_ids.tolist(), mask.tolist()):
            masks[i] = m
        base_new = sum(len(a) for a in start_l)
        depth_l.append(sd[c_seg] + 1)
        start_l.append(c_start)
        end_l.append(c_end)
        parent_l.append(s_ids[c_seg])
        cur = base_new + np.arange(len(c_start))
        cur_depth, cur_start, cur_end = depth_l[-1], c_start, c_end
    depth = np.concatenate(depth_l)
    start = np.concatenate(start_l)
    end = np.concatenate(end_l)
    parent = np.concatenate(parent_l)
    leaf = np.zeros(len(depth), bool)
    for ids, is_leaf in leaf_parts:
        leaf[ids[is_leaf]] = True
    child_mask = np.zeros(len(depth), np.uint8)
    if masks:
        k = np.fromiter(masks.keys(), np.int64, len(masks))
        child_mask[k] = np.fromiter(masks.values(), np.int64, len(masks))
    code = keys[start] >> (3 * (DEPTH - depth))
    # pre-order: by the node's first key cell, parents (smaller depth) first
    order = np.lexsort((depth, code << (3 * (DEPTH - depth))))
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    par = parent[order]
    par = np.where(par >= 0, rank[np.maximum(par, 0)], -1)
    return SubtreeBuild(depth[order], code[order], start[order], end[order], par, leaf[order], child_mask[order])


def choose_representatives(depth: int, k: int, cand_keys: np.ndarray, cand_xyz: np.ndarray, origin, edge: float) -> np.ndarray:
    """Indices of the candidates an inner node at ``depth`` keeps: per cell of depth ``depth + k``
    (capped at :data:`DEPTH`), the candidate nearest the cell's centre; sorted by key.

    Candidates of several nodes of the same depth may be passed at once (cells never straddle nodes).
    """
    sd = min(depth + k, DEPTH)
    sub = np.asarray(cand_keys, np.int64) >> (3 * (DEPTH - sd))
    lo, hi = node_box(np.full(len(sub), sd), sub, origin, edge)
    dist = ((np.asarray(cand_xyz, np.float64) - (lo + hi) * 0.5) ** 2).sum(axis=1)
    order = np.lexsort((dist, sub))
    s = sub[order]
    first = np.r_[True, s[1:] != s[:-1]] if len(s) else np.zeros(0, bool)
    return np.sort(order[first])


def cell_means(depth: int, k: int, cand_keys: np.ndarray, cand_vals: np.ndarray) -> np.ndarray:
    """Mean values of the candidates of each cell of depth ``depth + k`` (the cells
    :func:`choose_representatives` picks one point for, in the same order)."""
    sd = min(depth + k, DEPTH)
    sub = np.asarray(cand_keys, np.int64) >> (3 * (DEPTH - sd))
    _, inv, cnt = np.unique(sub, return_inverse=True, return_counts=True)
    v = np.asarray(cand_vals, np.float64).reshape(len(sub), -1)
    out = np.zeros((len(cnt), v.shape[1]))
    np.add.at(out, inv, np.nan_to_num(v, nan=0.0))
    fin = np.zeros((len(cnt), v.shape[1]))
    np.add.at(fin, inv, np.isfinite(v))
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(fin > 0, out / np.maximum(fin, 1), np.nan).astype(np.float32)


class NodeTable:
    """The octree's nodes sorted by ``(depth, code)``, with per-depth runs for lookups.

    Attributes are numpy arrays of one entry per node: ``depth``, ``code``, ``offset``, ``count``,
    ``weight``, ``child_mask``; ``origin`` and ``edge`` give node boxes.
    """

    def __init__(self, t: dict[str, np.ndarray], origin, edge: float) -> None:
        self.depth = t["depth"].astype(np.int64)
        self.code = t["code"].astype(np.int64)
        self.offset = t["offset"].astype(np.int64)
        self.count = t["count"].astype(np.int64)
        self.weight = t["weight"].astype(np.int64)
        self.child_mask = t["child_mask"].astype(np.int64)
        self.origin = np.asarray(origin, np.float64)
        self.edge = float(edge)
        self.max_depth = int(self.depth.max()) if len(self.depth) else 0
        b = np.searchsorted(self.depth, np.arange(self.max_depth + 2))
        self._runs = [(int(b[d]), int(b[d + 1])) for d in range(self.max_depth + 1)]

    def __len__(self) -> int:
        return len(self.depth)

    def lookup(self, depth: int, codes) -> np.ndarray:
        """Node ids of ``codes`` at ``depth`` (``-1`` where no such node)."""
        codes = np.asarray(codes, np.int64)
        if depth > self.max_depth or depth < 0:
            return np.full(codes.shape, -1, np.int64)
        a, b = self._runs[depth]
        run = self.code[a:b]
        pos = np.searchsorted(run, codes)
        ok = pos < len(run)
        ok[ok] = run[pos[ok]] == codes[ok]
        return np.where(ok, a + pos, -1)

    def children(self, ids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(parent_index, child_id)`` of every existing child of nodes ``ids`` (octant order)."""
        ids = np.asarray(ids, np.int64)
        bits = (self.child_mask[ids][:, None] >> np.arange(8)) & 1
        par, octant = np.nonzero(bits)
        if not len(par):
            return par, par
        d = self.depth[ids][par]
        codes = self.code[ids][par] * 8 + octant
        out = np.empty(len(par), np.int64)
        for dd in np.unique(d):
            m = d == dd
            out[m] = self.lookup(int(dd) + 1, codes[m])
        return par, out

    def boxes(self, ids) -> tuple[np.ndarray, np.ndarray]:
        """World ``(lo, hi)`` of nodes ``ids``."""
        ids = np.asarray(ids, np.int64)
        return node_box(self.depth[ids], self.code[ids], self.origin, self.edge)

    def edges(self, ids) -> np.ndarray:
        """Edge length of nodes ``ids`` (world units)."""
        return self.edge / 2.0 ** self.depth[np.asarray(ids, np.int64)]
