"""The GPU cache's per-frame bookkeeping against plain-Python statements of the same rules.

``resident_mask`` reserves texture slots in call order (a slot holds one brick a frame; a brick
not on the GPU takes a slot only if it is allowed and the upload budget lasts); ``_neighbours`` is
every brick within one step (26-neighbourhood) of a drawn one, inside the grid. The cache answers
both from arrays; the references here loop over bricks with dicts and sets, as the cache once did.
"""

from __future__ import annotations

import numpy as np
import pytest

from clipvol.loaders.numpy_array import NumpyLoader
from clipvol.render.gpu_cache import GpuBrickCache
from clipvol.scene.selection import DrawItem

pytestmark = pytest.mark.gl


class FakeClip:
    """A clip-texture stand-in: a fixed random set of bricks in RAM, some of whose reads fail."""

    def __init__(self, rng, grid_by_level):
        self.ram = {L: rng.random(g) < 0.5 for L, g in grid_by_level.items()}
        self.fails = {L: rng.random(g) < 0.2 for L, g in grid_by_level.items()}

    def resident_mask(self, level, idx):
        idx = np.asarray(idx)
        return self.ram[level][idx[:, 0], idx[:, 1], idx[:, 2]]

    def get_brick(self, level, key):
        return None if self.fails[level][key] else np.zeros(1)


def reference_resident(cache, state, level, idx, on_gpu, clip):
    """The rule, brick by brick in order (``state``: slot -> brick, pending, budget left)."""
    out = np.zeros(len(idx), dtype=bool)
    w = cache.windows[level]
    for i, k in enumerate(map(tuple, idx.tolist())):
        if not (on_gpu[i] or clip.ram[level][k]):
            continue
        slot = (level,) + tuple(v % s for v, s in zip(k, w))
        if slot in state["held"]:
            out[i] = state["held"][slot] == k
            continue
        if not on_gpu[i]:
            if state["left"] < cache.brick_texels or clip.get_brick(level, k) is None:
                continue
            state["pending"].add((level, k))
            state["left"] -= cache.brick_texels
        state["held"][slot] = k
        out[i] = True
    return out


@pytest.mark.parametrize("seed", range(4))
def test_resident_mask_reserves_slots_in_call_order(ctx, seed):
    rng = np.random.default_rng(seed)
    pyr = NumpyLoader(np.zeros((96, 80, 64), np.float32), brick=8).pyramid  # grid 12 x 10 x 8 at level 0
    cache = GpuBrickCache(ctx, pyr, 40 * pyr.brick_nbytes)  # windows smaller than the grid: slots alias
    try:
        levels = [L for L, w in enumerate(cache.windows) if w is not None]
        assert any(np.any(np.asarray(pyr.grid(L)) > np.asarray(cache.windows[L])) for L in levels)
        clip = FakeClip(rng, {L: tuple(pyr.grid(L)) for L in levels})
        for L in levels:  # some bricks already on the GPU (the cache's slot keys)
            g = np.asarray(pyr.grid(L))
            for k in rng.integers(0, g, size=(int(g.prod()) // 3, 3)):
                cache._slot_key[L][tuple(k % np.asarray(cache.windows[L]))] = k
        budget = 20 * cache.brick_texels
        cache.begin_frame(clip, budget)
        state = {"held": {}, "pending": set(), "left": budget}
        for _ in range(40):  # several calls a frame, with repeats and aliasing slots
            L = int(rng.choice(levels))
            g = np.asarray(pyr.grid(L))
            idx = rng.integers(0, g, size=(int(rng.integers(1, 40)), 3))
            on_gpu = cache.on_gpu_mask(L, idx)
            want = reference_resident(cache, state, L, idx, on_gpu, clip)
            np.testing.assert_array_equal(cache.resident_mask(L, idx), want)
        assert set(cache.pending_keys()) == state["pending"]
        assert any(state["held"].values()) and state["pending"]
    finally:
        cache.release()


@pytest.mark.parametrize("seed", range(3))
def test_reserve_on_gpu_is_resident_mask_of_a_cut_all_on_the_gpu(ctx, seed):
    """``reserve_on_gpu`` (a kept cut's check, no uploads) answers the plain rule's "every brick
    drawable with no upload budget" and reserves the slots the rule would; a set that fails
    reserves nothing. Checked by the slots later calls of the rule find held."""
    import copy

    rng = np.random.default_rng(seed)
    pyr = NumpyLoader(np.zeros((96, 80, 64), np.float32), brick=8).pyramid
    cache = GpuBrickCache(ctx, pyr, 40 * pyr.brick_nbytes)  # windows smaller than the grid: slots alias
    try:
        levels = [L for L, w in enumerate(cache.windows) if w is not None]
        clip = FakeClip(rng, {L: tuple(pyr.grid(L)) for L in levels})
        on = {}
        for L in levels:
            g = np.asarray(pyr.grid(L))
            for k in rng.integers(0, g, size=(int(g.prod()) // 3, 3)):
                cache._slot_key[L][tuple(k % np.asarray(cache.windows[L]))] = k
            on[L] = np.argwhere(np.ones(tuple(g), bool))
            on[L] = on[L][cache.on_gpu_mask(L, on[L])]
        cache.begin_frame(clip, 0)
        state = {"held": {}, "pending": set(), "left": 0}
        answers = []
        held = [L for L in levels if len(on[L])]
        for _ in range(30):
            L = int(rng.choice(held))
            g = np.asarray(pyr.grid(L))
            n = int(rng.integers(1, 12))
            idx = on[L][rng.integers(0, len(on[L]), size=n)]  # on the GPU ...
            if rng.random() < 0.4:  # ... or with a brick that may not be
                idx[rng.integers(0, n)] = rng.integers(0, g)
            trial = copy.deepcopy(state)
            want = bool(reference_resident(cache, trial, L, idx, cache.on_gpu_mask(L, idx), clip).all())
            if want:
                state = trial
            got = cache.reserve_on_gpu(L, idx)
            assert got == want
            answers.append(got)
        assert any(answers) and not all(answers)
        held = {}  # the slots the cache holds this frame: as the rule's reservations
        for L in levels:
            r = cache._reserved[L]
            for slot in np.argwhere(r[..., 0] >= 0):
                held[(L, *map(int, slot))] = tuple(int(v) for v in r[tuple(slot)])
        assert held == state["held"] and held
        assert not cache.pending_keys()
    finally:
        cache.release()


@pytest.mark.parametrize("dilate", [True, False])  # the occupancy dilation, and the row-by-row fallback
def test_neighbours_are_the_26_neighbourhood_inside_the_grid(ctx, rng, monkeypatch, dilate):
    import clipvol.render.gpu_cache as gc_module

    if not dilate:
        monkeypatch.setattr(gc_module, "DILATE_MAX_CELLS", 0)
    pyr = NumpyLoader(np.zeros((96, 80, 64), np.float32), brick=8).pyramid
    cache = GpuBrickCache(ctx, pyr, 10_000 * pyr.brick_nbytes)
    try:
        items = []
        for L in (0, 1, 2):
            g = np.asarray(pyr.grid(L))
            for k in rng.integers(0, g, size=(15, 3)).tolist() + [[0, 0, 0], (g - 1).tolist()]:
                items.append(DrawItem(L, tuple(k), (0.0, 0.0, 0.0), (1.0, 1.0, 1.0)))
        cache.begin_frame(None, None)
        got = cache._neighbours(items)
        for L in (0, 1, 2):
            g = pyr.grid(L)
            want = set()
            for it in items:
                if it.level != L:
                    continue
                for dz in (-1, 0, 1):
                    for dy in (-1, 0, 1):
                        for dx in (-1, 0, 1):
                            n = (it.index[0] + dz, it.index[1] + dy, it.index[2] + dx)
                            if all(0 <= v < s for v, s in zip(n, g)):
                                want.add(n)
            assert sorted(want) == [tuple(r) for r in got[L].tolist()]  # the set, in lexicographic order
    finally:
        cache.release()


class ReachClip:
    """A clip-texture stand-in whose region leaves a random fifth of the bricks out of reach."""

    def __init__(self, rng, grid_by_level):
        self.away = {L: rng.random(g) < 0.2 for L, g in grid_by_level.items()}

    def out_of_reach_mask(self, level, idx):
        idx = np.asarray(idx)
        return self.away[level][idx[:, 0], idx[:, 1], idx[:, 2]]


def reference_open_faces(cache, clip, level, idx):
    """The rule brick by brick: the face neighbour exists, and every existing brick of the 3x3 slab
    behind the face is in its slot on the GPU or out of the region's reach (and the window is at
    least two bricks wide on that axis)."""
    grid, w = cache.pyramid.grid(level), cache.windows[level]

    def good(k):
        if not all(0 <= v < g for v, g in zip(k, grid)):
            return True
        slot = tuple(v % s for v, s in zip(k, w))
        return cache._slot_key[level][slot].tolist() == list(k) or bool(clip.away[level][k])

    out = np.zeros((len(idx), 3, 2), dtype=bool)
    for i, b in enumerate(map(tuple, idx.tolist())):
        for a in range(3):
            for side, d in ((0, -1), (1, 1)):
                f = list(b)
                f[a] += d
                if not 0 <= f[a] < grid[a] or w[a] < 2:
                    continue
                others = [o for o in range(3) if o != a]
                slab = []
                for u in (-1, 0, 1):
                    for v in (-1, 0, 1):
                        k = list(f)
                        k[others[0]] += u
                        k[others[1]] += v
                        slab.append(good(tuple(k)))
                out[i, a, side] = all(slab)
    return out


@pytest.mark.parametrize("seed", range(3))
@pytest.mark.parametrize("dense", [True, False])  # the grid with its erosion, and brick by brick
def test_open_faces_follow_the_slab_behind_each_face(ctx, seed, dense):
    rng = np.random.default_rng(seed)
    pyr = NumpyLoader(np.zeros((96, 80, 64), np.float32), brick=8).pyramid  # grid 12 x 10 x 8 at level 0
    cache = GpuBrickCache(ctx, pyr, 3000 * pyr.brick_nbytes)
    try:
        levels = [L for L, w in enumerate(cache.windows) if w is not None]
        clip = ReachClip(rng, {L: tuple(pyr.grid(L)) for L in levels})
        cache.begin_frame(clip, None)
        answers = []
        for L in levels:
            g = np.asarray(pyr.grid(L))
            every = np.argwhere(np.ones(tuple(g), dtype=bool))
            for k in every[rng.random(len(every)) < 0.93]:  # most bricks in their slots
                cache._slot_key[L][tuple(k % np.asarray(cache.windows[L]))] = k
            idx = rng.integers(0, g, size=(30, 3))
            idx = np.concatenate([idx, [[0, 0, 0], g - 1]])
            got = cache.open_faces(L, idx, dense=dense)
            want = reference_open_faces(cache, clip, L, idx)
            np.testing.assert_array_equal(got, want)
            answers.append(want)
        both = np.concatenate(answers)
        assert both.any() and not both.all()
    finally:
        cache.release()


@pytest.mark.parametrize("seed", range(3))
def test_on_gpu_with_neighbours_is_every_brick_and_neighbour_in_its_slot(ctx, seed):
    """A kept cut's check of its new bricks against the rule brick by brick: the brick and each
    brick within one step of it (inside the grid) holds its own slot; and CheckedBricks hands back
    exactly the keys not marked before (a Python set as the reference)."""
    from clipvol.render.frame_loop import CheckedBricks

    rng = np.random.default_rng(seed)
    pyr = NumpyLoader(np.zeros((96, 80, 64), np.float32), brick=8).pyramid
    cache = GpuBrickCache(ctx, pyr, 400 * pyr.brick_nbytes)
    try:
        levels = [L for L, w in enumerate(cache.windows) if w is not None]
        for L in levels:
            g = np.asarray(pyr.grid(L))
            for k in np.argwhere(rng.random(tuple(g)) < 0.9):  # most bricks on the GPU
                cache._slot_key[L][tuple(k % np.asarray(cache.windows[L]))] = k
        answers = []
        checked, marked = CheckedBricks(pyr), set()
        for _ in range(30):
            L = int(rng.choice(levels))
            g = np.asarray(pyr.grid(L))
            idx = rng.integers(0, g, size=(int(rng.integers(1, 4)), 3))
            want = all(tuple(cache._slot_key[L][tuple(n % np.asarray(cache.windows[L]))]) == tuple(n)
                       for b in idx.tolist() for n in (np.array(b) + np.array([dz, dy, dx])
                                                       for dz in (-1, 0, 1) for dy in (-1, 0, 1) for dx in (-1, 0, 1))
                       if np.all((n >= 0) & (n < g)))
            got = cache.on_gpu_with_neighbours(L, idx)
            assert got == want
            answers.append(got)
            keys = np.concatenate([np.full((len(idx), 1), L), idx], axis=1)
            new = checked.unchecked(keys)
            assert sorted(map(tuple, new.tolist())) == sorted(k for k in map(tuple, keys.tolist()) if k not in marked)
            checked.mark(keys)
            marked |= set(map(tuple, keys.tolist()))
        assert any(answers) and not all(answers)
    finally:
        cache.release()
