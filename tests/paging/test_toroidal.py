"""Window math of the clip-texture, checked against brute-force numpy references."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from clipvol.errors import ParameterError
from clipvol.bricking.pyramid import Pyramid
from clipvol.paging.toroidal import (
    allocate,
    brick_costs,
    in_box,
    level_window,
    predicted_offset,
    slot_of,
    window_bricks,
    window_diff,
    window_shape,
)

axes3 = st.tuples(st.integers(1, 9), st.integers(1, 9), st.integers(1, 9))


@settings(max_examples=150, deadline=None)
@given(shape=axes3, origin=st.tuples(*[st.integers(-50, 50)] * 3))
def test_every_window_brick_maps_to_a_distinct_slot(shape, origin):
    start = tuple(o + 60 for o in origin)  # any position of the window, far from 0 too
    stop = tuple(a + w for a, w in zip(start, shape))
    bricks = window_bricks(start, stop)
    assert len(bricks) == math.prod(shape)
    slots = slot_of(bricks, shape)
    assert sorted(slots.tolist()) == list(range(math.prod(shape)))


@settings(max_examples=150, deadline=None)
@given(shape=axes3, a=st.tuples(*[st.integers(0, 12)] * 3), b=st.tuples(*[st.integers(0, 12)] * 3))
def test_moves_evict_exactly_the_bricks_that_left_and_reuse_their_slots(shape, a, b):
    old = (a, tuple(x + w for x, w in zip(a, shape)))
    new = (b, tuple(x + w for x, w in zip(b, shape)))
    entered, left = window_diff(old, new)
    old_set = {tuple(v) for v in window_bricks(*old).tolist()}
    new_set = {tuple(v) for v in window_bricks(*new).tolist()}
    assert {tuple(v) for v in left.tolist()} == old_set - new_set
    assert {tuple(v) for v in entered.tolist()} == new_set - old_set
    # the entering bricks take exactly the slots the leaving ones freed; the rest never move
    assert sorted(slot_of(entered, shape).tolist()) == sorted(slot_of(left, shape).tolist())


def test_in_box_matches_python():
    rng = np.random.default_rng(1)
    idx = rng.integers(-2, 10, size=(200, 3))
    start, stop = (1, 2, 0), (5, 4, 7)
    ref = [all(a <= i < b for i, a, b in zip(row, start, stop)) for row in idx.tolist()]
    assert in_box(idx, start, stop).tolist() == ref


@settings(max_examples=100, deadline=None)
@given(
    shape=axes3,
    brick=st.sampled_from([(4, 4, 4), (8, 4, 2), (3, 5, 7)]),
    w=st.integers(1, 6),
    frac=st.tuples(*[st.floats(-0.2, 1.2)] * 3),
)
def test_window_holds_the_centre_brick_and_stays_in_the_grid(shape, brick, w, frac):
    pyr = Pyramid.build(tuple(s * 5 for s in shape), brick, spacing=(1.0, 2.0, 0.5))
    lo, hi = pyr.volume_box()
    c = lo + np.array(frac) * (hi - lo)
    for L in range(pyr.num_levels):
        g = pyr.grid(L)
        ws = window_shape(g, w)
        start, stop = level_window(pyr, L, c, ws)
        assert tuple(b - a for a, b in zip(start, stop)) == ws
        assert all(0 <= a and b <= n for a, b, n in zip(start, stop, g))
        cb = pyr.world_to_brick(L, c)  # clamped brick holding the centre
        assert all(a <= i < b for i, a, b in zip(cb, start, stop))
        # odd windows away from the border are centred on that brick
        for i, a, ww, n in zip(cb, start, ws, g):
            if ww % 2 == 1 and (ww - 1) // 2 <= i < n - (ww - 1) // 2:
                assert a == i - (ww - 1) // 2


def _brute_allocate(pyr: Pyramid, budget: int):
    """Reference of the documented rule by exhaustive search."""
    slots = budget // pyr.brick_nbytes
    n = pyr.num_levels
    g = [pyr.grid(L) for L in range(n)]
    cnt = [math.prod(x) for x in g]
    need = lambda L, w: math.prod(min(w, v) for v in g[L])  # noqa: E731
    whole = []
    used = 0
    for L in reversed(range(n)):
        if used + cnt[L] + sum(need(l, 2) for l in range(L)) <= slots:
            whole.append(L)
            used += cnt[L]
        else:
            break
    windowed = [L for L in range(n) if L not in whole]
    best = None
    for w in range(2, max([max(g[0]), 2]) + 1):
        if used + sum(need(L, w) for L in windowed) <= slots:
            best = w
    return tuple(whole), best


@settings(max_examples=120, deadline=None)
@given(
    shape=st.tuples(st.integers(1, 700), st.integers(1, 700), st.integers(1, 700)),
    brick=st.sampled_from([(16, 16, 16), (32, 32, 32), (8, 16, 32)]),
    budget_bricks=st.integers(1, 3000),
)
def test_allocation_rule_matches_brute_force_and_fits_budget(shape, brick, budget_bricks):
    pyr = Pyramid.build(shape, brick, dtype="uint8")
    budget = budget_bricks * pyr.brick_nbytes + 7
    whole, w = _brute_allocate(pyr, budget)
    if w is None and len(whole) < pyr.num_levels:
        with pytest.raises(ParameterError, match="memory_budget"):
            allocate(pyr, budget)
        return
    a = allocate(pyr, budget)
    assert a.whole_levels == whole
    if len(whole) < pyr.num_levels:
        assert a.window == w
    assert a.nbytes <= budget
    for L in range(pyr.num_levels):
        expect = math.prod(pyr.grid(L)) if L in whole else math.prod(window_shape(pyr.grid(L), a.window))
        assert a.capacity[L] == expect


def test_too_small_budget_names_parameter_and_minimum():
    pyr = Pyramid.build((256, 256, 256), (32, 32, 32), dtype="float32")
    minimum = sum(math.prod(min(2, v) for v in pyr.grid(L)) for L in range(pyr.num_levels)) * pyr.brick_nbytes
    with pytest.raises(ParameterError, match=rf"memory_budget: expected at least {minimum} bytes"):
        allocate(pyr, minimum - 1)
    a = allocate(pyr, minimum)
    assert a.window == 2 and a.nbytes == minimum


def test_brick_costs_match_pointwise_distance():
    pyr = Pyramid.build((40, 50, 60), (8, 8, 8), spacing=(2.0, 1.0, 0.5))
    rng = np.random.default_rng(3)
    for L in range(pyr.num_levels):
        bricks = window_bricks((0, 0, 0), pyr.grid(L))
        p = rng.uniform(-10, 60, size=3)
        got = brick_costs(pyr, L, bricks, p)
        ext = np.array(pyr.brick_shape[::-1]) * 2.0**L * np.array(pyr.spacing[::-1])
        for b, c in zip(bricks, got):
            lo, hi = pyr.node_box(L, b)
            nearest = np.clip(p, lo, hi)
            assert c == pytest.approx(np.linalg.norm((p - nearest) / ext), abs=1e-12)
        # the brick holding a point inside the volume costs 0
        q = np.clip(p, *pyr.volume_box())
        hold = pyr.world_to_brick(L, q)
        assert brick_costs(pyr, L, np.array([hold]), q)[0] == 0.0


def test_predicted_offset_is_mean_move():
    h = [np.array([0.0, 0, 0]), np.array([1.0, 0, 0]), np.array([3.0, 1, 0])]
    assert np.allclose(predicted_offset(h, 2.0), [3.0, 1.0, 0.0])
    assert np.allclose(predicted_offset(h[:1]), 0.0)


def test_window_diff_of_identical_windows_is_empty():
    for start in itertools.product(range(2), repeat=3):
        stop = tuple(s + 3 for s in start)
        e, l = window_diff((start, stop), (start, stop))
        assert len(e) == 0 and len(l) == 0
