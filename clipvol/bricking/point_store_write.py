"""Writing a point store: nodes and points appended in whole chunks, and the build's atomic checkpoints.

The writing side of :mod:`clipvol.bricking.point_store` (the layout is described there). The
writer keeps whole chunks only until the build closes, so an interrupted build can be truncated back
to its last checkpoint (``state.npz``) and carried on byte for byte; the checkpoints are written
under a temporary name and renamed, so a crash leaves the previous one.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from .point_store_open import NODE_ARRAYS, NODE_CHUNK, POINT_CHUNK

__all__: list[str] = []

class _Writer:
    """Appends nodes and their points to the store in whole chunks (the last chunk at ``close``)."""

    def __init__(self, group, k: int, reopen: bool = False) -> None:
        self.k = k
        if reopen:  # a resumed build: the arrays exist (their lengths come from the checkpoint)
            self.nodes = {n: group[f"nodes/{n}"] for n in NODE_ARRAYS}
            self.xyz, self.vals = group["points/xyz"], group["points/values"]
        else:
            self.nodes = {n: group.create_array(f"nodes/{n}", shape=(0,), chunks=(NODE_CHUNK,), dtype=dt, fill_value=0)
                          for n, dt in NODE_ARRAYS.items()}
            self.xyz = group.create_array("points/xyz", shape=(0, 3), chunks=(POINT_CHUNK, 3), dtype="float32", fill_value=0)
            self.vals = group.create_array("points/values", shape=(0, k), chunks=(POINT_CHUNK, k), dtype="float32",
                                           fill_value=0)
        self._nbuf: dict[str, list] = {n: [] for n in NODE_ARRAYS}
        self._pbuf: list[tuple[np.ndarray, np.ndarray]] = []
        self._nlen = 0  # nodes written
        self._plen = 0  # points written
        self.num_nodes = 0
        self.num_points = 0  # stored (with representatives)
        self.max_depth = 0

    def add(self, depth, code, weight, child_mask, counts, xyz32, vals) -> None:
        counts = np.asarray(counts, np.int64)
        offset = self.num_points + np.cumsum(counts) - counts
        for n, v in (("code", code), ("depth", depth), ("offset", offset), ("count", counts), ("weight", weight),
                     ("child_mask", child_mask)):
            self._nbuf[n].append(np.asarray(v).astype(NODE_ARRAYS[n]))
        self._pbuf.append((np.asarray(xyz32, np.float32), np.asarray(vals, np.float32)))
        self.num_nodes += len(counts)
        self.num_points += int(counts.sum())
        if len(depth):
            self.max_depth = max(self.max_depth, int(np.max(depth)))
        self._flush(final=False)

    def _flush(self, final: bool) -> None:
        pending = self.num_points - self._plen
        n = pending if final else (pending // POINT_CHUNK) * POINT_CHUNK
        if n:
            xyz = np.concatenate([a for a, _ in self._pbuf])
            vals = np.concatenate([b for _, b in self._pbuf])
            self.xyz.resize((self._plen + n, 3))
            self.vals.resize((self._plen + n, self.k))
            self.xyz[self._plen:self._plen + n] = xyz[:n]
            self.vals[self._plen:self._plen + n] = vals[:n]
            self._plen += n
            self._pbuf = [(xyz[n:].copy(), vals[n:].copy())]  # copies: a view would keep the whole concatenation
        pending = self.num_nodes - self._nlen
        m = pending if final else (pending // NODE_CHUNK) * NODE_CHUNK
        if m:
            for name, arr in self.nodes.items():
                data = np.concatenate(self._nbuf[name])
                arr.resize((self._nlen + m,))
                arr[self._nlen:self._nlen + m] = data[:m]
                self._nbuf[name] = [data[m:].copy()]
            self._nlen += m

    def restore(self, st) -> None:
        """Back to a checkpoint (:meth:`_Build._save_state`): arrays truncated, the partial tail re-buffered."""
        self._nlen, self._plen = int(st["nlen"]), int(st["plen"])
        self.num_nodes, self.num_points, self.max_depth = int(st["num_nodes"]), int(st["num_points"]), int(st["max_depth"])
        for name, arr in self.nodes.items():
            arr.resize((self._nlen,))
            self._nbuf[name] = [np.asarray(st["n_" + name])]
        self.xyz.resize((self._plen, 3))
        self.vals.resize((self._plen, self.k))
        self._pbuf = [(np.asarray(st["p_xyz"]), np.asarray(st["p_vals"]))]

    def close(self) -> None:
        self._flush(final=True)


def _atomic_json(path: Path, obj) -> None:
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps(obj))
    os.replace(tmp, path)


def _atomic_npz(path: Path, arrays: dict) -> None:
    tmp = path.with_name(path.stem + ".tmp.npz")
    np.savez(tmp, **arrays)
    os.replace(tmp, path)
