"""The frame loop every render action shares: select, plan uploads, upload, wait, converge.

A render action (volume, slice, splat) asks :meth:`FrameLoop.run` for a converged-enough
:class:`~clipvol.scene.selection.Selection` and then only draws it. The loop makes no GL call
itself: it talks to the clip-texture (main memory) and to the
:class:`~clipvol.render.gpu_cache.GpuBrickCache` (texture memory) through their methods, so the
whole data path - store, loader, clip-texture, selection, GPU cache - reads in one direction here.

One pass:

1. **Select** with the GPU cache as residency: a brick is drawable if it is on the GPU, or in the
   clip-texture's RAM and still inside this frame's ``texels_per_frame`` upload budget. When that
   budget binds, a dry run first chooses which uploads to allow (coarse levels first, then
   nearest), so a constrained frame still shows the whole view coarsely.
2. **Upload** what was reserved (:meth:`GpuBrickCache.commit`, the one place that writes textures).
3. With ``wait=True``: if some wanted brick (or a same-level neighbour its filtering reads) is not
   yet drawn, wait on the clip-texture for the ones that can still come and pass again - until the
   selection converges, nothing more can arrive, the texture budget cannot hold the view (a
   brick uploaded twice in one call), or ``timeout`` passes.

**Coherence.** A converged cut is kept with what it was made under (the parameters, the transfer
function's transparency test, the GPU cache's :attr:`~clipvol.render.gpu_cache.GpuBrickCache.generation`,
the clip-texture's ``residency_version`` and windows). The next frame draws it again - no
traversal, no reservations, no uploads - while all of those are unchanged and
:func:`~clipvol.scene.selection.coherence.cut_holds` says the new camera's traversal would make the
same cut (a camera-free policy: the fixed level; every culled box still out of view, every leaf in).
A brick that arrives or leaves, an upload, a new table or new parameters end the replay, and the
next frame selects from nothing. ``FramePlan.replayed`` says which frames were drawn again.

A projected-size cut changes with the camera, but only in a band of nodes near the level
boundaries and the frustum's sides: after a converged frame the loop keeps it as a
:class:`~clipvol.scene.selection.kept_cut.KeptCut` (under the same state key) and updates it for
the next camera, re-testing only that band, while every brick of the updated cut and every
neighbour its filtering reads is on the GPU already (else the frame selects and uploads from
nothing). The updated cut is the fresh selection's exactly, its items in depth-first order
(``Selection.ordered`` False, ``FramePlan.updated``): the render action orders the merged boxes
where a path needs an order; the single pass needs none. The GPU check follows the change too:
a cut with the same items as the last one checked needs none, and a changed one checks only the
bricks no earlier frame of the cut found on the GPU with all their neighbours
(:class:`CheckedBricks`), the whole cut only where one of those is missing.

**Cut first.** A frame drawn without waiting (``wait=False``, the viewer's) that is not converged
moves its cut's missing wanted bricks to the front of the clip-texture's load queue
(:meth:`~clipvol.paging.cliptexture.ClipTexture.prioritize`), so the next frames fill what they draw
before the rest of the windows, which the queue orders by distance from the centre of interest. On a
cold fill from slow storage the frame reaches the converged one sooner (docs/benchmarks.md,
"Ray-guided residency" and "Cut first in the frame loop"). The same missing set is asked for once
(until the queue is re-sorted), and a converged, replayed or kept frame asks nothing.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from .. import interrupts
from ..paging.cliptexture import BrickState, ClipTexture
from ..scene.params import RenderParams
from ..scene.selection import Selection, select
from ..scene.selection.coherence import cut_holds, replayable
from ..scene.selection.kept_cut import KeptCut
from ..scene.selection.policies import policy_for

__all__ = ["FrameLoop", "FramePlan"]


@dataclass
class FramePlan:
    """What :meth:`FrameLoop.run` settled on for one frame."""

    selection: Selection
    converged: bool
    passes: int
    bytes_uploaded: int
    bricks_uploaded: int
    times: dict = field(default_factory=dict)
    #: the last frame's cut drawn again (see the module docstring, "Coherence")
    replayed: bool = False
    #: the kept projected-size cut updated for this camera (module docstring): items in depth-first order
    updated: bool = False


class CheckedBricks:
    """The bricks of a kept cut found on the GPU with every neighbour, as a flag per brick of each
    level (pure numpy): while the GPU cache's slots and the clip-texture's residency stay as they
    were (the frame loop's state key), a brick found so stays so, and an updated cut checks only
    its bricks not found before - the few leaves the camera changed, not the whole cut (the 512^3
    head's 13 742 bricks and their neighbours: ~7 ms a frame)."""

    #: most bricks of a level held as flags (16 MB); a cut with a brick of a larger level is
    #: checked whole every frame
    MAX_CELLS = 1 << 24

    def __init__(self, pyramid) -> None:
        self.pyramid = pyramid
        self._flags: dict[int, np.ndarray | None] = {}

    def _flat(self, keys: np.ndarray, level: int) -> np.ndarray | None:
        if level not in self._flags:
            cells = int(np.prod(self.pyramid.grid(level), dtype=np.int64))
            self._flags[level] = np.zeros(cells, dtype=bool) if cells <= self.MAX_CELLS else None
        if self._flags[level] is None:
            return None
        g = self.pyramid.grid(level)
        return (keys[:, 1] * g[1] + keys[:, 2]) * g[2] + keys[:, 3]

    def unchecked(self, keys: np.ndarray) -> np.ndarray | None:
        """The rows of ``keys`` (``(n, 4)`` ``(level, z, y, x)``) not marked (None: a level too
        large to hold)."""
        out = []
        for L in np.unique(keys[:, 0]).tolist():
            k = keys[keys[:, 0] == L]
            flat = self._flat(k, L)
            if flat is None:
                return None
            out.append(k[~self._flags[L][flat]])
        return np.concatenate(out) if out else np.zeros((0, 4), dtype=np.int64)

    def mark(self, keys: np.ndarray) -> bool:
        """Mark ``keys`` checked; False where a level is too large to hold."""
        for L in np.unique(keys[:, 0]).tolist():
            k = keys[keys[:, 0] == L]
            flat = self._flat(k, L)
            if flat is None:
                return False
            self._flags[L][flat] = True
        return True


def on_gpu_with_neighbours(cache, keys: np.ndarray) -> bool:
    """Every brick of ``keys`` (``(n, 4)``) and each of its neighbours on the GPU (per level)."""
    return all(cache.on_gpu_with_neighbours(L, keys[keys[:, 0] == L, 1:]) for L in np.unique(keys[:, 0]).tolist())


class FrameLoop:
    """Selection and uploads of one render action over ``clip_texture`` into ``cache``."""

    def __init__(self, clip_texture: ClipTexture, cache, *, prioritize_missing: bool = True) -> None:
        self.clip_texture = clip_texture
        #: after a frame drawn without waiting that is not converged, move the cut's missing wanted
        #: bricks to the front of the clip-texture's load queue (module docstring, "Cut first");
        #: False leaves the queue's own order (distance from the centre of interest)
        self.prioritize_missing = bool(prioritize_missing)
        #: (clip-texture queue version, missing rows) of the last request: the same set is not asked again
        self._asked: tuple[int, np.ndarray] | None = None
        self.cache = cache
        self.pyramid = clip_texture.pyramid
        #: (state key, selection) of the last converged cut (module docstring, "Coherence")
        self._kept: tuple | None = None
        #: (state key, KeptCut) of the last converged projected-size cut (module docstring)
        self._cut: tuple | None = None
        self._verified: Selection | None = None  # the kept cut's last selection found all on the GPU
        #: the kept cut's bricks found on the GPU with their neighbours (None: not checked yet;
        #: False: not kept for this cut)
        self._checked: CheckedBricks | bool | None = None

    def _state(self, params: RenderParams, transparent, policy, version: int | None = None):
        """What a cut was made under, apart from the camera (None: nothing to replay against);
        ``version``: the clip-texture's residency version the selection saw (default: now)."""
        ct, cache = self.clip_texture, self.cache
        window = getattr(ct, "window", None)
        if policy is not None or window is None:
            return None
        version = ct.residency_version if version is None else version
        return (params, transparent, cache.generation, version, getattr(ct, "region", None),
                tuple(window(L) for L in range(self.pyramid.num_levels)), tuple(cache.windows))

    @staticmethod
    def _same(a, b) -> bool:
        """Two :meth:`_state` keys alike: the parameters and the transparency test by identity."""
        return a is not None and b is not None and a[0] is b[0] and a[1] is b[1] and a[4] is b[4] \
            and a[2:4] == b[2:4] and a[5:] == b[5:]

    def replay(self, camera, params: RenderParams, transparent=None, policy=None) -> Selection | None:
        """The last converged cut, if it is this frame's cut too (module docstring, "Coherence")."""
        kept = self._kept
        if kept is None or not self._same(kept[0], self._state(params, transparent, policy)):
            return None
        return kept[1] if cut_holds(kept[1], camera) else None

    def update(self, camera, params: RenderParams, transparent=None, policy=None) -> Selection | None:
        """The kept projected-size cut updated for ``camera``, if everything it draws (and every
        neighbour its filtering reads) is on the GPU already (module docstring); else None."""
        kept = self._cut
        if kept is None or not self._same(kept[0], self._state(params, transparent, policy)):
            return None
        sel = kept[1].update(camera, ordered=False)
        if sel is None:
            return None
        if self._verified is not None and sel.items is self._verified.items:
            return sel  # the same leaves passed the checks below, and the GPU holds what it did then
        keys = sel.item_keys()
        checked = self._checked
        if checked:  # only the bricks no earlier frame of this cut found on the GPU with their neighbours
            fresh = checked.unchecked(keys)
            if fresh is not None and on_gpu_with_neighbours(self.cache, fresh):
                checked.mark(fresh)
                self._verified = sel
                return sel
        cache = self.cache.begin_frame(self.clip_texture, 0)  # reserves the slots, uploads nothing
        for L in np.unique(keys[:, 0]).tolist():
            if not cache.reserve_on_gpu(L, keys[keys[:, 0] == L, 1:]):  # (resident_mask's answer here)
                return None
        cache.reserve_neighbours(sel)
        if cache.pending_keys() or cache.missing_neighbours(sel):
            return None
        self._verified = sel
        if checked is None:  # the first check of this cut: from now on only its new bricks, where the
            # whole cut's neighbours are on the GPU (else the whole check's finer answers - a failed
            # brick, a slot another brick of this cut holds - decide every frame)
            self._checked = CheckedBricks(self.pyramid) if on_gpu_with_neighbours(self.cache, keys) else False
            if self._checked and not self._checked.mark(keys):
                self._checked = False
        return sel
    def _upload_budget(self, params: RenderParams) -> int | None:
        """``texels_per_frame``, never less than one brick (a frame always makes progress)."""
        if params.texels_per_frame is None:
            return None
        return max(params.texels_per_frame, self.cache.brick_texels)

    def select(self, camera, params: RenderParams, transparent=None, policy=None, ordered: bool = True) -> Selection:
        """One selection against the GPU cache, reserving the uploads it implies (``ordered``: as
        for :func:`~clipvol.scene.selection.select`)."""
        cache, budget = self.cache, self._upload_budget(params)
        allow = None
        if budget is not None:  # dry run to choose the uploads coarse-first
            residency = cache.begin_frame(self.clip_texture, None)
            dry = select(self.pyramid, camera, params, residency=residency, transparent=transparent, policy=policy,
                         ordered=ordered)
            cache.reserve_neighbours(dry)
            if len(cache.pending_keys()) * cache.brick_texels <= budget:
                return dry  # the budget does not bind (the steady state): the real run would be the same
            allow = cache.plan_uploads(budget, dry)
        residency = cache.begin_frame(self.clip_texture, budget, allow)
        sel = select(self.pyramid, camera, params, residency=residency, transparent=transparent, policy=policy,
                     ordered=ordered)
        cache.reserve_neighbours(sel)
        return sel

    def _stand_in(self, level: int, idx) -> tuple[int, tuple[int, int, int]] | None:
        """The nearest ancestor of a failed brick that has not failed too: it is drawn in its place."""
        b = np.asarray(idx, dtype=np.int64)
        for L in range(level + 1, self.pyramid.num_levels):
            b = b // 2
            key = (L, (int(b[0]), int(b[1]), int(b[2])))
            if self.clip_texture.state(*key) != BrickState.FAILED:
                return key
        return None

    def _waitable(self, sel: Selection, neighbours) -> list:
        """Wanted bricks and neighbours not drawn that the clip-texture may still deliver - and for a
        wanted brick that failed, the ancestor that stands in for it (else the frame would be drawn
        from whatever coarser level happened to be resident: a different picture on every run)."""
        missing = sel.missing_wanted()
        ct = self.clip_texture
        stand_ins = [self._stand_in(L, idx) for L, idx in missing if ct.state(L, idx) == BrickState.FAILED]
        seen = set(missing)
        missing += [k for k in stand_ins if k is not None and k not in seen]
        seen |= set(missing)
        missing += [k for k in neighbours if k not in seen]
        ct, cache = self.clip_texture, self.cache
        out = []
        for level, idx in missing:
            one = np.array([idx])
            if (cache.windows[level] is not None and not cache.on_gpu_mask(level, one)[0]
                    and bool(np.asarray(ct.in_window_mask(level, one))[0])
                    and not bool(np.asarray(ct.resident_mask(level, one))[0])):
                out.append((level, idx))
        return out

    def _ask_missing(self, sel: Selection) -> None:
        """Move ``sel``'s missing wanted bricks to the front of the load queue, unless this very set
        was asked for last and the queue has not been re-sorted since (a still camera while nothing
        arrives asks nothing; :meth:`ClipTexture.prioritize` pushes only bricks not already in front)."""
        ct = self.clip_texture
        prioritize = getattr(ct, "prioritize", None)
        if prioritize is None:  # a clip-texture without a load queue
            return
        rows = sel.missing_wanted_keys()
        version = getattr(ct, "queue_version", None)
        asked = self._asked
        if asked is not None and asked[0] == version and np.array_equal(asked[1], rows):
            return
        prioritize(rows)
        self._asked = (version, rows)

    def run(self, camera, params: RenderParams, *, transparent=None, policy=None, wait: bool = False,
            timeout: float | None = None, ordered: bool = True) -> FramePlan:
        """Select and upload (and with ``wait``, repeat) for one frame; see the module docstring.
        ``ordered=False``: the caller orders the items itself where it needs an order (a cut of
        whole nodes then comes in depth-first order, ``Selection.ordered`` False)."""
        interrupts.check()  # a Ctrl-C that C code swallowed in the previous frame stops this one
        times = dict(select=0.0, upload=0.0, wait=0.0)
        t0 = time.perf_counter()
        kept = self.replay(camera, params, transparent, policy)
        if kept is not None:
            times["select"] = time.perf_counter() - t0
            return FramePlan(kept, True, 1, 0, 0, times, replayed=True)
        last = self._cut[1].selection if self._cut is not None else None
        sel = None if ordered else self.update(camera, params, transparent, policy)
        if sel is not None:
            times["select"] = time.perf_counter() - t0
            return FramePlan(sel, True, 1, 0, 0, times, replayed=sel is last, updated=sel is not last)
        self._kept = self._cut = self._verified = self._checked = None
        deadline = None if timeout is None else time.perf_counter() + float(timeout)
        passes = up_bytes = up_bricks = 0
        uploaded_now: set = set()  # bricks uploaded by this call: a second upload means thrashing
        ct, cache = self.clip_texture, self.cache
        while True:
            interrupts.check()  # ... and a frame that waits for bricks
            t0 = time.perf_counter()
            version = ct.residency_version  # before selecting: any change after counts
            sel = self.select(camera, params, transparent, policy, ordered)
            t1 = time.perf_counter()
            pending = set(cache.pending_keys())
            thrashing = bool(pending & uploaded_now)
            uploaded_now |= pending
            up_bytes += cache.commit()
            up_bricks += cache.bricks_uploaded
            times["select"] += t1 - t0
            times["upload"] += time.perf_counter() - t1
            passes += 1
            neighbours = cache.missing_neighbours(sel)
            converged = sel.is_converged() and not neighbours
            if not wait or converged:
                break
            left = None if deadline is None else deadline - time.perf_counter()
            if (left is not None and left <= 0) or thrashing:
                break  # out of time, or the texture budget cannot hold this view at once
            if cache.bricks_uploaded:
                continue  # more passes: the upload budget of one pass was spent
            waitable = self._waitable(sel, neighbours)
            if not waitable:
                if ct.residency_version != version:
                    continue  # bricks arrived while selecting: select again
                break  # what is missing can never come (failed, outside the windows, slot conflicts)
            t3 = time.perf_counter()
            ct.wait_for(waitable, timeout=left)
            times["wait"] += time.perf_counter() - t3
            if ct.residency_version == version:
                break
        if not converged and not wait and self.prioritize_missing:
            self._ask_missing(sel)
        if converged and replayable(sel):  # kept with what it was made under, after its uploads
            # (the version before its last selection: a brick that arrived since ends the replay)
            self._kept = (self._state(params, transparent, policy, version), sel)
        elif converged and policy is None and not (sel.counts.get("fallback") or sel.counts.get("missing")
                                                   or sel.counts.get("outside_window")):
            cut = KeptCut(self.pyramid, params, policy_for(params), self.cache, transparent)
            if cut.supported:  # updated from the next frame on (module docstring)
                self._cut = (self._state(params, transparent, policy, version), cut)
        return FramePlan(sel, converged, passes, up_bytes, up_bricks, times)
