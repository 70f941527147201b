"""Building a point store: the out-of-core octree build (``clipvol brick-points``) and its resume.

Build (after Meredith & Ma 2001, section 3.1, made out of core): pass 1 streams the input for its
bounds, value ranges and count; the root is the cube around the bounds. Then, recursively, a node
whose points do not fit ``memory_points`` is *partitioned*: a histogram of its points over the
cells ``KB`` levels down decides the top of its subtree (split where more than ``max_points``),
the points are streamed into temporary files, one per group of consecutive frontier nodes (Morton
order), and each group is built in memory (sorted keys, vectorised splitting and representative
selection, :mod:`clipvol.bricking.points`). A frontier node that alone exceeds ``memory_points``
recurses. Nodes and points are appended to the store as groups finish, so memory is bounded by
``memory_points`` and the top of the tree, not by the input. ``complete`` is set by the very
last write.

Resume: the root's partition is checkpointed in ``_build_tmp/``: its plan (``plan.json``, written
once the temporary files are complete), then after every group the group's stored sets
(``stored<g>.npz``) and, atomically, the writer's state (``state.npz``: groups done, the lengths of
the arrays - whole chunks only until the build closes - and the partial tail still buffered). Run
again on the same input with the same parameters (``attrs["clipvol"]["job"]``), an interrupted
build truncates the arrays to the state and carries on with the next group, writing what the
uninterrupted build would have written, byte for byte. An interruption before the plan, a build
that fits in memory, or a changed input or parameter starts again from the beginning.
"""

from __future__ import annotations

import json
import os
import shutil
import sys
from pathlib import Path
from typing import Callable, Iterator

import numpy as np

from ..errors import InputFormatError, ParameterError
from .point_sources import PointSource
from .point_store_open import NODE_ARRAYS, POINT_FORMAT_VERSION, PointStoreMeta, _meta, is_point_store
from .point_store_write import _atomic_json, _atomic_npz, _Writer
from .points import (
    DEPTH, DUP_BITS, GEO_BITS, REPRESENTATIVES, build_subtrees, cell_means, choose_representatives, morton_encode,
    point_keys, quantise, rep_depth_step,
)

__all__ = ["build_point_store"]

#: levels of the histogram a partition step looks down (8**KB cells)
KB = 3


class _Build:
    """State of one build: the cube, the writer, the limits and the temporary folder."""

    def __init__(self, origin, edge, writer: _Writer, max_points: int, memory_points: int, tmp: Path, k: int, bar,
                 representative: str = "nearest") -> None:
        self.mean = representative == "mean"
        self.origin = np.asarray(origin, np.float64)
        self.edge = float(edge)
        self.w = writer
        self.N = max_points
        self.kstep = rep_depth_step(max_points)
        self.mem = max(int(memory_points), max_points + 1)
        self.tmp = tmp
        self.k = k
        self.rec = np.dtype([("xyz", "<f8", (3,)), ("v", "<f4", (k,))])
        self.bar = bar
        self._files = 0
        self.checkpoints = True  # checkpoint the root's partition (see "Resume" in the module docstring)

    # -- in memory --------------------------------------------------------------------------
    def in_memory(self, xyz: np.ndarray, vals: np.ndarray, roots_depth, roots_code):
        """Build the subtrees of ``roots`` from their points; write them; return each root's stored set."""
        keys, order = point_keys(xyz, self.origin, self.edge)
        xyz, vals = xyz[order], vals[order]
        rd = np.asarray(roots_depth, np.int64)
        rc = np.asarray(roots_code, np.int64)
        start = np.zeros(len(rd), np.int64)
        end = np.zeros(len(rd), np.int64)
        for i, (d, c) in enumerate(zip(rd.tolist(), rc.tolist())):  # Python ints: no overflow at the last cell
            sh = 3 * (DEPTH - d)
            start[i] = np.searchsorted(keys, c << sh)
            end[i] = len(keys) if (c + 1) << sh >= 1 << 63 else np.searchsorted(keys, (c + 1) << sh)
        b = build_subtrees(keys, rd, start, end, self.N)
        st_node, st_pt, st_val = [], [], []
        prev_node = np.zeros(0, np.int64)
        prev_pt = np.zeros(0, np.int64)
        prev_val = np.zeros((0, self.k), np.float32)
        for d in range(int(b.depth.max()), int(b.depth.min()) - 1, -1):
            at = np.flatnonzero(b.depth == d)
            lv = at[b.leaf[at]]
            cnt = b.end[lv] - b.start[lv]
            l_node = np.repeat(lv, cnt)
            l_pt = np.repeat(b.start[lv] - np.cumsum(cnt) + cnt, cnt) + np.arange(int(cnt.sum()))
            i_node = np.zeros(0, np.int64)
            i_pt = np.zeros(0, np.int64)
            i_val = np.zeros((0, self.k), np.float32)
            if len(prev_pt):
                o = np.argsort(prev_pt, kind="stable")  # key order (points are key-sorted)
                cand_pt = prev_pt[o]
                cand_parent = b.parent[prev_node[o]]
                sel = choose_representatives(d, self.kstep, keys[cand_pt], xyz[cand_pt], self.origin, self.edge)
                i_node, i_pt = cand_parent[sel], cand_pt[sel]
                i_val = cell_means(d, self.kstep, keys[cand_pt], prev_val[o]) if self.mean else prev_val[o][sel]
            cur_node = np.concatenate([l_node, i_node])
            cur_pt = np.concatenate([l_pt, i_pt])
            cur_val = np.concatenate([vals[l_pt], i_val])
            st_node.append(cur_node)
            st_pt.append(cur_pt)
            st_val.append(cur_val)
            keep = b.parent[cur_node] >= 0  # roots feed nothing in this build
            prev_node, prev_pt, prev_val = cur_node[keep], cur_pt[keep], cur_val[keep]
        node = np.concatenate(st_node)
        pt = np.concatenate(st_pt)
        val = np.concatenate(st_val)
        o = np.lexsort((pt, node))
        node, pt, val = node[o], pt[o], val[o]
        counts = np.bincount(node, minlength=len(b.depth))
        self.w.add(b.depth, b.code, b.end - b.start, b.child_mask, counts,
                   (xyz[pt] - self.origin).astype(np.float32), val)
        # stored sets of the roots, in the order given: copies, never views - a root's stored set lives
        # until its parent is built (for the root's partition, until every group is done), and a view
        # would keep this group's whole ``val`` alive with it (about 5 bytes per input point, for the
        # whole build: the memory that grew with N)
        out = []
        root_ids = np.flatnonzero(b.parent < 0)
        by_code = {(int(b.depth[i]), int(b.code[i])): i for i in root_ids}
        bounds = np.r_[0, np.cumsum(counts)]
        for d, c in zip(rd.tolist(), rc.tolist()):
            i = by_code[(d, c)]
            p = pt[bounds[i]:bounds[i + 1]]
            out.append((keys[p], xyz[p], val[bounds[i]:bounds[i + 1]].copy(), int(b.end[i] - b.start[i])))
        return out

    # -- out of core ------------------------------------------------------------------------
    def node(self, reader: Callable[[], Iterator], n: int, d0: int, code0: int):
        """Build the subtree of node ``(d0, code0)`` holding ``n`` points read by ``reader()``."""
        if n <= self.mem or d0 >= GEO_BITS:
            xyz, vals = _concat(reader(), self.k)
            res = self.in_memory(xyz, vals, [d0], [code0])[0]
            self.bar.update(n)
            return res
        top = d0 == 0 and self.checkpoints  # the root's partition: checkpointed, so a build resumes
        plan = self._load_plan() if top else None
        if plan is None:
            front, inner, groups = self._plan(reader, d0, code0)
        else:
            front, inner, groups = plan["front"], plan["inner"], plan["groups"]
        paths = [self.tmp / f"part{self._files + g}.bin" for g in range(len(groups))]
        self._files += len(groups)
        if plan is None:
            self._partition(reader, d0, code0, front, groups, paths)
            if top:
                _atomic_json(self.tmp / "plan.json", {"front": front, "inner": inner, "groups": groups})
        stored: dict[tuple[int, int], tuple] = {}
        done = self._load_state(stored) if top else 0
        for g, members in enumerate(groups):
            path = paths[g]
            if g < done:  # built before the interruption: its stored sets came back from the checkpoint
                self.bar.update(sum(front[i][2] for i in members))
                continue
            if len(members) == 1 and front[members[0]][2] > self.mem:
                d, c, cn = front[members[0]]
                res = [self.node(lambda p=path: self._read_file(p), cn, d0 + d, (code0 << 3 * d) | c)]
            else:
                xyz, vals = _concat(self._read_file(path), self.k)
                ds = [d0 + front[i][0] for i in members]
                cs = [(code0 << 3 * front[i][0]) | front[i][1] for i in members]
                res = self.in_memory(xyz, vals, ds, cs)
                self.bar.update(len(xyz))
            for i, r in zip(members, res):
                d, c, _ = front[i]
                stored[(d0 + d, (code0 << 3 * d) | c)] = r
            if top:
                self._save_state(g, [(d0 + front[i][0], (code0 << 3 * front[i][0]) | front[i][1]) for i in members], res)
            path.unlink()
        # inner nodes of the top, deepest first: representatives from their children's stored sets
        inner.sort(key=lambda t: -t[0])
        for j, c, cn, m in inner:
            d, code = d0 + j, (code0 << 3 * j) | c
            kids = [stored.pop((d + 1, code * 8 + o)) for o in range(8) if m >> o & 1]
            ck = np.concatenate([s[0] for s in kids])
            cx = np.concatenate([s[1] for s in kids])
            cv = np.concatenate([s[2] for s in kids])
            sel = choose_representatives(d, self.kstep, ck, cx, self.origin, self.edge)
            rv = cell_means(d, self.kstep, ck, cv) if self.mean else cv[sel]
            self.w.add(np.array([d]), np.array([code]), np.array([cn]), np.array([m]), np.array([len(sel)]),
                       (cx[sel] - self.origin).astype(np.float32), rv)
            stored[(d, code)] = (ck[sel], cx[sel], rv, cn)
        return stored[(d0, code0)]

    def _plan(self, reader, d0: int, code0: int):
        """The top of node ``(d0, code0)``'s subtree from a histogram ``KB`` levels down: frontier nodes
        ``(rel depth, rel code, count)`` in Morton order, inner nodes ``(rel depth, rel code, count,
        child mask)``, and groups of consecutive frontier nodes of at most ``mem`` points (a bigger node alone)."""
        hd = min(d0 + KB, GEO_BITS)
        rel = hd - d0
        hist = np.zeros(8 ** rel, np.int64)
        for xyz, _ in reader():
            hist += np.bincount(self._rel_code(xyz, hd, code0, rel), minlength=len(hist))
        # the top of the subtree: counts per depth from the histogram (children are 8 consecutive cells)
        cnt = [hist.reshape(8 ** j, -1).sum(axis=1) for j in range(rel + 1)]
        front = []  # (rel depth, rel code, count)
        inner = []  # (rel depth, rel code, count, child mask)
        open_ = np.array([0], np.int64)
        for j in range(rel):
            ch = (open_[:, None] * 8 + np.arange(8)).reshape(-1)
            c = cnt[j + 1][ch]
            present = (c > 0).reshape(-1, 8)
            masks = (present * (1 << np.arange(8))).sum(axis=1)
            inner += [(j, int(o), int(cnt[j][o]), int(m)) for o, m in zip(open_, masks)]
            ch, c = ch[c > 0], c[c > 0]
            last = j + 1 == rel
            f = (c <= self.N) | last
            front += [(j + 1, int(a), int(b)) for a, b in zip(ch[f], c[f])]
            open_ = ch[~f]
        front.sort(key=lambda t: (t[1] << 3 * (rel - t[0]), t[0]))
        groups, acc = [], self.mem + 1
        for i, (_, _, c) in enumerate(front):
            if acc + c > self.mem or c > self.mem:
                groups.append([])
                acc = 0
            groups[-1].append(i)
            acc += c
        return front, inner, groups

    def _partition(self, reader, d0: int, code0: int, front, groups, paths) -> None:
        """Stream the node's points into one temporary file per group."""
        rel = max(d for d, _, _ in front)
        hd = d0 + rel
        fstart = np.array([c << 3 * (rel - d) for d, c, _ in front], np.int64)
        gid = np.empty(len(front), np.int64)
        for g, members in enumerate(groups):
            gid[members] = g
        files = [open(p, "wb") for p in paths]
        try:
            for xyz, vals in reader():
                g = gid[np.searchsorted(fstart, self._rel_code(xyz, hd, code0, rel), side="right") - 1]
                o = np.argsort(g, kind="stable")
                rec = np.empty(len(xyz), self.rec)
                rec["xyz"], rec["v"] = xyz[o], vals[o]
                gs = g[o]
                cuts = np.flatnonzero(np.r_[True, gs[1:] != gs[:-1], True])
                for a, b in zip(cuts[:-1], cuts[1:]):
                    rec[a:b].tofile(files[gs[a]])
        finally:
            for f in files:
                f.close()

    # -- checkpoints (the root's partition only) -----------------------------------------------
    def _load_plan(self):
        p = self.tmp / "plan.json"
        if not p.is_file():
            return None
        plan = json.loads(p.read_text())
        return {"front": [tuple(t) for t in plan["front"]], "inner": [tuple(t) for t in plan["inner"]],
                "groups": plan["groups"]}

    def _save_state(self, g: int, roots, res) -> None:
        """After group ``g``: its roots' stored sets, then (atomically) the writer's state and ``g + 1`` done.

        The store's arrays hold whole chunks only until the build closes; the writer's partial tail
        is saved here, so a resumed build truncates the arrays to the state and carries on
        byte for byte as the uninterrupted build would."""
        arrays = {"roots": np.array(roots, np.int64).reshape(-1, 2), "lens": np.array([len(r[0]) for r in res], np.int64),
                  "count": np.array([r[3] for r in res], np.int64)}
        for j, name in enumerate(("keys", "xyz", "vals")):
            arrays[name] = np.concatenate([r[j] for r in res])
        _atomic_npz(self.tmp / f"stored{g}.npz", arrays)
        w = self.w
        state = {"done": np.array(g + 1), "nlen": np.array(w._nlen), "plen": np.array(w._plen),
                 "num_nodes": np.array(w.num_nodes), "num_points": np.array(w.num_points), "max_depth": np.array(w.max_depth),
                 "files": np.array(self._files)}
        for name in NODE_ARRAYS:
            state["n_" + name] = np.concatenate(w._nbuf[name]) if w._nbuf[name] else np.zeros(0, NODE_ARRAYS[name])
        state["p_xyz"] = np.concatenate([a for a, _ in w._pbuf]) if w._pbuf else np.zeros((0, 3), np.float32)
        state["p_vals"] = np.concatenate([b for _, b in w._pbuf]) if w._pbuf else np.zeros((0, self.k), np.float32)
        _atomic_npz(self.tmp / "state.npz", state)

    def _load_state(self, stored: dict) -> int:
        """Groups done before an interruption (0 if none); restores the writer and their stored sets."""
        p = self.tmp / "state.npz"
        if not p.is_file():
            return 0
        st = np.load(p)
        done = int(st["done"])
        self.w.restore(st)
        for g in range(done):
            z = np.load(self.tmp / f"stored{g}.npz")
            bounds = np.r_[0, np.cumsum(z["lens"])]
            for i, (d, c) in enumerate(z["roots"].tolist()):
                a, b = bounds[i], bounds[i + 1]
                stored[(d, c)] = (z["keys"][a:b], z["xyz"][a:b], z["vals"][a:b], int(z["count"][i]))
        return done

    def _rel_code(self, xyz, hd: int, code0: int, rel: int) -> np.ndarray:
        q = quantise(xyz, self.origin, self.edge) >> (GEO_BITS - hd)
        return morton_encode(q[:, 0], q[:, 1], q[:, 2]) - (code0 << 3 * rel)

    def _read_file(self, path: Path, rows: int = 1 << 20) -> Iterator:
        with open(path, "rb") as f:
            while True:
                rec = np.fromfile(f, self.rec, count=rows)
                if not len(rec):
                    return
                yield np.ascontiguousarray(rec["xyz"]), np.ascontiguousarray(rec["v"]).reshape(len(rec), self.k)


def _concat(chunks, k: int) -> tuple[np.ndarray, np.ndarray]:
    xs, vs = [], []
    for x, v in chunks:
        xs.append(x)
        vs.append(v)
    if not xs:
        return np.zeros((0, 3)), np.zeros((0, k), np.float32)
    return np.concatenate(xs), np.concatenate(vs)


def _scan(source: PointSource, bar):
    lo = np.full(3, np.inf)
    hi = np.full(3, -np.inf)
    k = len(source.value_names)
    vlo = np.full(k, np.inf)
    vhi = np.full(k, -np.inf)
    n = 0
    for xyz, vals in source.chunks():
        lo = np.minimum(lo, xyz.min(axis=0))
        hi = np.maximum(hi, xyz.max(axis=0))
        with np.errstate(invalid="ignore"):
            fin = np.where(np.isfinite(vals), vals, np.nan)
            if np.isfinite(fin).any():
                vlo = np.fmin(vlo, np.nanmin(fin, axis=0))
                vhi = np.fmax(vhi, np.nanmax(fin, axis=0))
        n += len(xyz)
        bar.update(len(xyz))
    if n == 0:
        raise InputFormatError(f"{source.name}: expected at least one point, got an empty input")
    vlo = np.where(np.isfinite(vlo), vlo, 0.0)
    vhi = np.where(np.isfinite(vhi), vhi, vlo)
    return lo, hi, vlo, vhi, n


def build_point_store(source: PointSource, output, *, max_points: int = 64, overwrite: bool = False,
                      progress: bool = True, memory_points: int = 1 << 21, unit: str = "",
                      box=None, representative: str = "nearest") -> PointStoreMeta:
    """Build the point octree of ``source`` into a new zarr store at ``output``.

    Parameters
    ----------
    source : PointSource
        The points (:func:`clipvol.bricking.point_sources.open_point_source`).
    output : path
        The store directory; an existing complete store needs ``overwrite``.
    max_points : int
        ``N``: at most this many points in any node (>= 8; Meredith & Ma's choice is 8).
    memory_points : int
        Most points held in memory at once by the build (the partition threshold).
    representative : {"nearest", "mean"}
        Values of an inner node's points: the nearest point's own (Meredith & Ma's choice) or the mean
        of the cell's candidates (the children's points in that cell).
    box : ((x0, y0, z0), (x1, y1, z1)), optional
        The domain (a simulation box): the root cube is the cube around it (and around every
        point, should one lie outside). Default: the points' bounds. A box aligned with the data's
        own structure (a lattice, a grid of cells) aligns the octree's cells with it too.
    """
    import zarr
    from tqdm import tqdm

    mp = int(max_points)
    if mp < 8 or mp > 1 << 16:
        raise ParameterError(f"--max-points: expected 8..65536, got {max_points}")
    rep_depth_step(mp)
    if representative not in REPRESENTATIVES:
        raise ParameterError(f"--representative: expected one of {', '.join(REPRESENTATIVES)}, got {representative!r}")
    out = Path(output)
    job = _job(source, mp, memory_points, representative, unit, box)
    resume = None
    from .output_guard import check_not_input, check_overwrite, exists_error, remove_output

    inputs = [p for p in (getattr(source, "path", None),) if p is not None]
    check_not_input(out, inputs)
    if out.exists() or out.is_symlink():
        cv = _clipvol_attrs(out) if is_point_store(out) else None
        if not overwrite and (cv is None or cv.get("complete")):
            raise exists_error(out, "store")
        if not overwrite and cv.get("job") == job and (out / "_build_tmp" / "plan.json").is_file():
            resume = cv  # an interrupted build of the same job: carried on from its last checkpoint
        else:  # overwrite, or an interrupted build of other input or parameters: rebuilt from the start
            check_overwrite(out, inputs)
            remove_output(out)
    k = len(source.value_names)
    with tqdm(total=2 * source.count, unit="pt", unit_scale=True, desc="points", file=sys.stderr,
              disable=not progress, dynamic_ncols=True) as bar:
        if resume is not None:  # the first pass's results are in the attributes
            attrs = resume
            origin, edge, n = np.asarray(attrs["origin"], np.float64), float(attrs["edge"]), int(attrs["num_points"])
            bar.update(n)
            group = zarr.open_group(str(out), mode="r+")
            writer = _Writer(group, k, reopen=True)
        else:
            attrs, origin, edge, n = _first_pass(source, bar, box, mp, representative, unit, job)
            group = zarr.open_group(str(out), mode="w", attributes={"clipvol": attrs})
            writer = _Writer(group, k)
        tmp = out / "_build_tmp"
        tmp.mkdir(exist_ok=True)
        build = _Build(origin, edge, writer, mp, memory_points, tmp, k, bar, representative)
        build.node(lambda: source.chunks(), n, 0, 0)
        writer.close()
        shutil.rmtree(tmp)
    attrs.update(depth=writer.max_depth, num_nodes=writer.num_nodes, num_stored=writer.num_points, complete=True)
    group.attrs["clipvol"] = attrs  # the very last write
    return _meta({"clipvol": attrs}, str(out))


def _clipvol_attrs(out: Path) -> dict:
    return json.loads((out / "zarr.json").read_text())["attributes"]["clipvol"]


def _job(source: PointSource, max_points: int, memory_points: int, representative: str, unit: str, box) -> dict:
    """What must match for an interrupted build to be resumed: the input's identity (name, count,
    value names, a hash of its first chunk, a file's size and modification time) and the parameters."""
    import hashlib
    import os

    ident = {"source": str(source.name), "count": int(source.count), "values": list(source.value_names)}
    try:
        st = os.stat(str(source.name))
        ident.update(size=int(st.st_size), mtime_ns=int(st.st_mtime_ns))
    except (OSError, ValueError):
        pass
    h = hashlib.sha1()
    for xyz, vals in source.chunks():
        h.update(np.ascontiguousarray(xyz).tobytes())
        h.update(np.ascontiguousarray(vals).tobytes())
        break
    ident["first_chunk_sha1"] = h.hexdigest()
    return {"identity": ident, "max_points": int(max_points), "memory_points": int(memory_points),
            "representative": representative, "unit": unit,
            "box": None if box is None else np.asarray(box, np.float64).reshape(2, 3).tolist()}


def _first_pass(source: PointSource, bar, box, mp: int, representative: str, unit: str, job: dict):
    """Bounds, value ranges and count of the input; the root cube; the store's attributes."""
    lo, hi, vlo, vhi, n = _scan(source, bar)
    if box is not None:
        try:
            blo, bhi = (np.asarray(b, np.float64).reshape(3) for b in box)
        except (TypeError, ValueError):
            raise ParameterError(f"box: expected ((x0, y0, z0), (x1, y1, z1)), got {box!r}") from None
        if not (np.all(np.isfinite(blo)) and np.all(np.isfinite(bhi)) and np.all(bhi > blo)):
            raise ParameterError(f"box: expected finite corners with x1 > x0, y1 > y0, z1 > z0, got {box!r}")
        lo, hi = np.minimum(lo, blo), np.maximum(hi, bhi)
    ext = float((hi - lo).max())
    edge = ext * (1.0 + 2.0**-20) if ext > 0 else max(1.0, float(np.abs(lo).max()) * 1e-6)
    origin = (lo + hi) / 2.0 - edge / 2.0
    volume = float(np.prod(np.maximum(hi - lo, ext * 1e-3 if ext > 0 else edge)))
    spacing = (volume / n) ** (1.0 / 3.0)
    attrs = {
        "kind": "points", "format_version": POINT_FORMAT_VERSION, "max_points": mp,
        "origin": [float(v) for v in origin], "edge": edge, "bounds": [lo.tolist(), hi.tolist()],
        "value_names": list(source.value_names), "value_ranges": [[float(a), float(b)] for a, b in zip(vlo, vhi)],
        "num_points": n, "point_spacing": spacing, "geo_bits": GEO_BITS, "dup_bits": DUP_BITS,
        "representative": representative, "unit": unit, "source": source.name, "complete": False, "job": job,
    }
    return attrs, origin, edge, n
