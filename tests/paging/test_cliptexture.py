"""The clip-texture under roaming, teleports, failing and hanging loaders, checked against numpy."""

from __future__ import annotations

import threading
import time
import warnings

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from clipvol.paging.cliptexture import BrickState, ClipTexture
from clipvol.errors import LoaderError, ParameterError
from clipvol.paging.loader import BrickKey
from clipvol.bricking.generators import parse_procedural
from clipvol.bricking.pyramid import Pyramid, downsample, pad_to_brick
from clipvol.paging.toroidal import window_bricks

# -- tiny in-test loaders ------------------------------------------------------------------------


class ArrayLoader:
    """A numpy volume as a loader; its levels are built with ``downsample`` here, in the test."""

    def __init__(self, vol: np.ndarray, brick=(8, 8, 8)):
        self.pyramid = Pyramid.build(vol.shape, brick, dtype=vol.dtype, value_range=(float(vol.min()), float(vol.max())))
        self.levels = [vol]
        while len(self.levels) < self.pyramid.num_levels:
            self.levels.append(downsample(self.levels[-1], "mean"))
        self.calls: list[tuple[int, tuple[int, int, int]]] = []
        self._lock = threading.Lock()

    def reference(self, level, index) -> np.ndarray:
        a, b = self.pyramid.brick_voxel_box(level, index)
        block = self.levels[level][a[0]:b[0], a[1]:b[1], a[2]:b[2]]
        return pad_to_brick(block, self.pyramid.brick_shape)

    def read_brick(self, level, index):
        with self._lock:
            self.calls.append((level, tuple(index)))
        return self.reference(level, index).copy()


class IntoLoader(ArrayLoader):
    """The same, also offering the optional zero-copy ``read_brick_into`` (the clip-texture uses it)."""

    def read_brick(self, level, index):  # pragma: no cover - must not be called
        raise AssertionError("read_brick_into should be used")

    def read_brick_into(self, level, index, out):
        with self._lock:
            self.calls.append((level, tuple(index)))
        out[...] = self.reference(level, index)


class ProceduralLoader:
    """A virtual volume: each brick evaluated by the procedural generator on demand."""

    def __init__(self, url: str, brick=(16, 16, 16)):
        self.gen = parse_procedural(url)
        self.pyramid = Pyramid.build(self.gen.shape, brick, value_range=(0.0, 1.0))

    def read_brick(self, level, index):
        a, b = self.pyramid.brick_voxel_box(level, index)
        return pad_to_brick(self.gen.region(level, a, b), self.pyramid.brick_shape)


def _vol(shape=(48, 40, 56), seed=0) -> np.ndarray:
    return np.random.default_rng(seed).random(shape, dtype=np.float32)


_VOL = _vol((40, 48, 56), seed=4)


def _brick_centre(pyr: Pyramid, level: int, index) -> np.ndarray:
    lo, hi = pyr.node_box(level, index)
    return (lo + hi) / 2


def _window_keys(ct: ClipTexture):
    for L in range(ct.pyramid.num_levels):
        for b in window_bricks(*ct.window(L)):
            yield L, tuple(int(v) for v in b)


def _reference_cost(pyr: Pyramid, level: int, index, point) -> float:
    """Distance from ``point`` to the brick's node box in units of the level's brick extent."""
    lo, hi = pyr.node_box(level, index)
    ext = np.array(pyr.brick_shape[::-1]) * 2.0**level * np.array(pyr.spacing[::-1])
    return float(np.linalg.norm((np.asarray(point) - np.clip(point, lo, hi)) / ext))


@pytest.fixture
def no_leaked_threads():
    before = set(threading.enumerate())
    yield
    deadline = time.monotonic() + 5
    while time.monotonic() < deadline:
        extra = [t for t in threading.enumerate() if t not in before and t.name.startswith("clipvol-loader")]
        if not extra:
            break
        time.sleep(0.01)
    assert not extra, f"loader threads outlived close(): {extra}"


# -- the tests -----------------------------------------------------------------------------------


@pytest.mark.parametrize("kind", [ArrayLoader, IntoLoader])
def test_budget_never_exceeded_and_data_exact_during_random_walk(kind, no_leaked_threads):
    loader = kind(_vol())
    pyr = loader.pyramid
    budget = 40 * pyr.brick_nbytes + 100
    rng = np.random.default_rng(42)
    lo, hi = pyr.volume_box()
    with ClipTexture(loader, budget, threads=2) as ct:
        assert ct.memory_budget == budget and ct.stats.pool_bytes <= budget
        versions = [ct.residency_version]
        for step in range(60):
            if rng.random() < 0.2:
                ct.set_center(rng.uniform(lo, hi))  # a jump
            else:
                ct.set_center(np.clip(ct.center + rng.normal(0, 6, 3), lo, hi))
            if step % 7 == 0:
                ct.set_roaming_window(int(rng.integers(2, 5)))
            st = ct.stats
            assert st.resident_bytes <= budget and st.pool_bytes <= budget
            for L in range(pyr.num_levels):
                assert st.resident_bricks[L] <= int(np.prod(ct.window_shape(L)))
            for L, idx in ct.resident_bricks()[:: max(1, len(ct.resident_bricks()) // 10)]:
                b = ct.get_brick(L, idx)  # resident until our own next move: never None
                assert b is not None and np.array_equal(b, loader.reference(L, idx)), (L, idx)
            versions.append(ct.residency_version)
            if step % 10 == 0:
                time.sleep(0.002)
        assert versions == sorted(versions)
        assert ct.wait_until_idle(20)
        # after idle every brick of every window is resident and holds exactly the loader's data
        n = 0
        for L, idx in _window_keys(ct):
            assert ct.state(L, idx) == BrickState.RESIDENT
            assert np.array_equal(ct.get_brick(L, idx), loader.reference(L, idx))
            n += 1
        assert n == sum(ct.stats.resident_bricks) == len(ct.resident_bricks())
        assert ct.stats.resident_bytes <= budget


def test_windows_whole_levels_and_masks():
    loader = ArrayLoader(_vol((64, 64, 64)))
    pyr = loader.pyramid  # grids 8, 4, 2, 1
    with ClipTexture(loader, (1 + 8 + 2 * 27) * pyr.brick_nbytes, threads=1, center=(20.0, 30.0, 40.0)) as ct:
        assert ct.whole_levels == (3, 2)
        assert ct.window_size == 3
        assert ct.window(3) == ((0, 0, 0), (1, 1, 1)) and ct.window_shape(2) == (2, 2, 2)
        start, stop = ct.window(0)
        assert ct.window_shape(0) == (3, 3, 3) == tuple(b - a for a, b in zip(start, stop))
        # the window of level 0 holds the brick containing the centre (x=20 -> bx 2, y 30 -> 3, z 40 -> 5)
        assert all(a <= i < b for i, a, b in zip((5, 3, 2), start, stop))
        allb = window_bricks((0, 0, 0), pyr.grid(0))
        ref = np.all((allb >= start) & (allb < stop), axis=1)
        assert np.array_equal(ct.in_window_mask(0, allb), ref)
        assert ct.wait_until_idle(10)
        assert np.array_equal(ct.resident_mask(0, allb), ref)
        assert ct.state(0, (0, 0, 0)) in (BrickState.ABSENT, BrickState.RESIDENT)
        b = ct.get_brick(0, tuple(start))
        with pytest.raises(ValueError):
            b[0, 0, 0] = 1  # read-only
        out = tuple(i for i, r in zip(allb.tolist(), ref) if not r)[0]
        assert ct.get_brick(0, out) is None and ct.state(0, out) == BrickState.ABSENT
        with pytest.raises(ParameterError, match="roaming window"):
            ct.set_roaming_window(1)
        ct.set_roaming_window(99)  # limited by the budget
        assert ct.window_size == 3
        with pytest.raises(ParameterError, match="center"):
            ct.set_center((np.nan, 0, 0))


def test_single_thread_serves_queue_in_priority_order(no_leaked_threads):
    loader = ArrayLoader(_vol((64, 64, 64)))
    pyr = loader.pyramid
    gate = threading.Event()
    first = threading.Event()
    read = loader.read_brick

    def gated(level, index):
        if not first.is_set():
            first.set()
            assert gate.wait(10)
        return read(level, index)

    loader.read_brick = gated
    c0 = np.array([10.0, 50.0, 23.0])
    with ClipTexture(loader, 400 * pyr.brick_nbytes, threads=1, center=c0, predictive=False) as ct:
        assert first.wait(10)
        c1 = np.array([45.0, 12.0, 33.0])
        ct.set_center(c1)
        gate.set()
        assert ct.wait_until_idle(10)
        calls = loader.calls[1:]
        assert len(calls) > 20
        keys = [(_reference_cost(pyr, L, idx, c1), -L) for L, idx in calls]
        for (c_a, l_a), (c_b, l_b) in zip(keys, keys[1:]):
            assert c_a <= c_b + 1e-9, (c_a, c_b)
            if abs(c_a - c_b) < 1e-9:
                assert l_a <= l_b  # coarse (higher level) before fine at equal distance
        # the first call (before the move) was the cheapest brick for c0: the coarsest level
        assert loader.calls[0][0] == pyr.num_levels - 1


@pytest.mark.parametrize("predictive", [True, False])
def test_predictive_loading_prefers_bricks_ahead(predictive, no_leaked_threads):
    loader = ArrayLoader(_vol((64, 64, 128)))
    pyr = loader.pyramid  # level 0 grid (8, 8, 16)
    gate = threading.Event()
    first = threading.Event()
    read = loader.read_brick

    def gated(level, index):
        if not first.is_set():
            first.set()
            assert gate.wait(10)
        return read(level, index)

    loader.read_brick = gated
    y = z = 27.5  # a brick centre (brick 3 of 8 voxels)
    start_x, end_x = 8 * 4 + 3.5, 8 * 8 + 3.5
    with ClipTexture(loader, 600 * pyr.brick_nbytes, threads=1, center=(start_x, y, z), predictive=predictive) as ct:
        ct.set_roaming_window(5)
        assert first.wait(10)
        for x in np.arange(start_x + 4, end_x + 1, 4.0):  # moving +x by half a brick per move
            ct.set_center((x, y, z))
        gate.set()
        assert ct.wait_until_idle(10)
        c = np.array([end_x, y, z])
        order = {k: i for i, k in enumerate(loader.calls[1:])}
        pairs = 0
        for L in range(pyr.num_levels - 1):
            keys = [k for k in order if k[0] == L]
            for ka in keys:
                lo_a, _ = pyr.node_box(L, ka[1])
                if lo_a[0] <= c[0]:
                    continue  # not wholly ahead
                da = _reference_cost(pyr, L, ka[1], c)
                for kb in keys:
                    _, hi_b = pyr.node_box(L, kb[1])
                    if hi_b[0] >= c[0] or abs(_reference_cost(pyr, L, kb[1], c) - da) > 1e-12:
                        continue  # not wholly behind at the same distance
                    pairs += 1
                    if predictive:
                        assert order[ka] < order[kb], (ka, kb)
                    elif ka[1][:2] == kb[1][:2]:
                        assert order[ka] > order[kb]  # no prediction: index order breaks the tie
        assert pairs > 10


def test_flaky_loader_with_teleports_under_stress(no_leaked_threads):
    base = ProceduralLoader("procedural:fractal?size=96&seed=3", brick=(16, 16, 16))
    rng = np.random.default_rng(7)
    lock = threading.Lock()
    errors: list[tuple[BrickKey, BaseException]] = []

    class Flaky:
        pyramid = base.pyramid

        def read_brick(self, level, index):
            with lock:
                fail = rng.random() < 0.3
            if fail:
                raise OSError(f"flaky read of {level} {index}")
            return base.read_brick(level, index)

    pyr = base.pyramid
    with ClipTexture(Flaky(), 30 * pyr.brick_nbytes, threads=3, retries=2, retry_backoff=0.001,
                     on_error=lambda k, e: errors.append((k, e))) as ct:
        walk = np.random.default_rng(11)
        lo, hi = pyr.volume_box()
        for _ in range(40):
            ct.set_center(walk.uniform(lo, hi))
            time.sleep(0.001)
            assert ct.stats.resident_bytes <= ct.memory_budget
        assert ct.wait_until_idle(30)
        st = ct.stats
        assert st.retries > 0
        failed = 0
        for L, idx in _window_keys(ct):
            s = ct.state(L, idx)
            assert s in (BrickState.RESIDENT, BrickState.FAILED)
            if s == BrickState.RESIDENT:
                assert np.array_equal(ct.get_brick(L, idx), base.read_brick(L, idx))
            else:
                failed += 1
                exc = ct.failures[BrickKey(L, idx)]
                assert isinstance(exc, OSError) and "flaky" in str(exc)
                assert ct.get_brick(L, idx) is None
        assert st.failures == len(ct.failures) >= failed
        assert {k for k, _ in errors} >= set(ct.failures)
        assert all(isinstance(e, OSError) for _, e in errors)


def test_retries_then_success_and_failure_after_retries(no_leaked_threads):
    base = ArrayLoader(_vol((32, 32, 32)))
    counts: dict = {}
    lock = threading.Lock()

    class FailTwice:
        pyramid = base.pyramid

        def read_brick(self, level, index):
            with lock:
                n = counts[(level, tuple(index))] = counts.get((level, tuple(index)), 0) + 1
            if n <= 2:
                raise TimeoutError("try again")
            return base.reference(level, index)

    with ClipTexture(FailTwice(), "1MB", threads=2, retries=2, retry_backoff=0.001) as ct:
        assert ct.wait_until_idle(10)
        keys = list(_window_keys(ct))
        assert all(ct.state(L, i) == BrickState.RESIDENT for L, i in keys)
        assert ct.stats.retries == 2 * len(keys) and not ct.failures
        assert all(counts[k] == 3 for k in keys)
    counts.clear()
    with ClipTexture(FailTwice(), "1MB", threads=2, retries=1, retry_backoff=0.001) as ct:
        assert ct.wait_until_idle(10)
        assert all(ct.state(L, i) == BrickState.FAILED for L, i in keys)
        assert set(ct.failures) == {BrickKey(L, i) for L, i in keys}
        assert all(counts[k] == 2 for k in keys)
        assert ct.stats.failures == len(keys)


def test_wrong_shape_is_a_loader_error_and_not_retried(no_leaked_threads):
    base = ArrayLoader(_vol((32, 32, 32)))
    bad = (1, (0, 1, 0))
    calls: list = []

    class Broken:
        pyramid = base.pyramid

        def read_brick(self, level, index):
            calls.append((level, tuple(index)))
            b = base.reference(level, index)
            return b[:-1] if (level, tuple(index)) == bad else b

    seen = []
    with ClipTexture(Broken(), "1MB", threads=2, retries=3, on_error=lambda k, e: seen.append((k, e))) as ct:
        assert ct.wait_until_idle(10)
        assert ct.state(*bad) == BrickState.FAILED
        exc = ct.failures[BrickKey(*bad)]
        assert isinstance(exc, LoaderError)
        msg = str(exc)
        assert "Broken" in msg and "level 1" in msg and "0, 1, 0" in msg and "expected shape (8, 8, 8)" in msg
        assert calls.count(bad) == 1
        assert [k for k, _ in seen] == [BrickKey(*bad)]
        others = [k for k in _window_keys(ct) if k != bad]
        assert all(ct.state(L, i) == BrickState.RESIDENT for L, i in others)


def test_late_result_for_evicted_brick_is_dropped(no_leaked_threads):
    loader = ArrayLoader(_vol((64, 64, 64), seed=5))
    pyr = loader.pyramid
    c0 = np.array([4.0, 4.0, 4.0])
    x_key = (0, pyr.world_to_brick(0, c0))  # brick (0, (0, 0, 0))
    entered = threading.Event()
    release = threading.Event()
    finished = threading.Event()
    read = loader.read_brick

    def slow(level, index):
        if (level, tuple(index)) == x_key:
            entered.set()
            release.wait(10)
            out = read(level, index)
            finished.set()
            return out
        return read(level, index)

    loader.read_brick = slow
    ct = ClipTexture(loader, (1 + 8 + 2 * 8) * pyr.brick_nbytes, threads=2, center=c0)
    try:
        assert ct.window_size == 2
        assert entered.wait(10)
        assert ct.state(*x_key) == BrickState.LOADING
        ct.set_center((58.0, 58.0, 58.0))  # teleport: x_key leaves; its slot goes to a brick of the new window
        assert ct.state(*x_key) == BrickState.ABSENT
        y_key = (0, (6, 6, 6))  # (6, 6, 6) mod 2 == (0, 0, 0): the same slot
        assert ct.in_window_mask(0, np.array([y_key[1]]))[0]
        assert ct.wait_until_idle(10)  # the stuck load no longer counts
        assert np.array_equal(ct.get_brick(*y_key), loader.reference(*y_key))
        d0 = ct.stats.dropped  # other loads in flight at the teleport may have been dropped already
        release.set()
        assert finished.wait(10)
        deadline = time.monotonic() + 5
        while ct.stats.dropped < d0 + 1 and time.monotonic() < deadline:
            time.sleep(0.005)
        assert ct.stats.dropped == d0 + 1
        assert ct.state(*x_key) == BrickState.ABSENT and ct.get_brick(*x_key) is None
        assert np.array_equal(ct.get_brick(*y_key), loader.reference(*y_key))
        assert (0, x_key[1]) not in ct.resident_bricks()
    finally:
        release.set()
        assert ct.close()


def test_close_with_hanging_loader_returns_false_and_threads_end(no_leaked_threads):
    loader = ArrayLoader(_vol((32, 32, 32)))
    hang = threading.Event()

    class Hanging:
        pyramid = loader.pyramid

        def read_brick(self, level, index):
            hang.wait(10)
            return loader.reference(level, index)

    before = set(threading.enumerate())
    ct = ClipTexture(Hanging(), "1MB", threads=2)
    assert len(set(threading.enumerate()) - before) == 2
    assert not ct.wait_until_idle(0.05)
    t0 = time.monotonic()
    with pytest.warns(RuntimeWarning, match="still inside read_brick"):
        assert ct.close(timeout=0.2) is False
    assert time.monotonic() - t0 < 2
    hang.set()  # the loader returns; the threads drop their results and end
    for t in set(threading.enumerate()) - before:
        t.join(5)
    assert not (set(threading.enumerate()) - before)
    with pytest.raises(ParameterError, match="closed"):
        ct.set_center((1, 1, 1))


def test_no_thread_outlives_close_and_wait_for():
    before = set(threading.enumerate())
    loader = ArrayLoader(_vol((32, 32, 32)))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with ClipTexture(loader, "1MB", threads=4) as ct:
            keys = [(0, (1, 1, 1)), BrickKey(2, (0, 0, 0))]
            assert ct.wait_for(keys, timeout=10)
            assert all(ct.state(k[0], k[1]) == BrickState.RESIDENT for k in keys[:1])
            assert ct.state(2, (0, 0, 0)) == BrickState.RESIDENT
        assert set(threading.enumerate()) == before


def test_parameters_are_validated():
    loader = ArrayLoader(_vol((32, 32, 32)))
    for kw, name in [({"threads": 0}, "threads"), ({"retries": -1}, "retries"), ({"retry_backoff": -1.0}, "retry_backoff"), ({"retry_backoff": "soon"}, "retry_backoff"), ({"threads": 1.5}, "threads"),
                     ({"on_error": 3}, "on_error"), ({"memory_budget": "lots"}, "memory_budget"),
                     ({"memory_budget": 100}, "memory_budget")]:
        with pytest.raises(ParameterError, match=name):
            ClipTexture(loader, **kw)
    assert not [t for t in threading.enumerate() if t.name.startswith("clipvol-loader")]


def test_late_writer_into_a_reused_slot_never_corrupts_it(no_leaked_threads):
    """``read_brick_into``: a stuck write for an evicted brick holds its slot; the slot's new brick
    waits for it, then loads, and ends up exact (the stale writer's garbage never shows)."""
    loader = IntoLoader(_vol((64, 64, 64), seed=9))
    pyr = loader.pyramid
    c0 = np.array([4.0, 4.0, 4.0])
    x_key = (0, (0, 0, 0))
    entered, release = threading.Event(), threading.Event()
    into = loader.read_brick_into

    def slow(level, index, out):
        if (level, tuple(index)) == x_key:
            out[...] = -1.0  # a partial, wrong write
            entered.set()
            release.wait(10)
            out[...] = -2.0
            return
        into(level, index, out)

    loader.read_brick_into = slow
    ct = ClipTexture(loader, (1 + 8 + 2 * 8) * pyr.brick_nbytes, threads=2, center=c0)
    try:
        assert entered.wait(10)
        ct.set_center((58.0, 58.0, 58.0))
        y_key = (0, (6, 6, 6))  # takes x_key's slot
        assert not ct.wait_until_idle(0.2)  # y waits for the stuck writer
        assert ct.state(*y_key) == BrickState.QUEUED and ct.get_brick(*y_key) is None
        others = [k for k in _window_keys(ct) if k != y_key]
        assert all(ct.state(L, i) == BrickState.RESIDENT for L, i in others)
        release.set()
        assert ct.wait_until_idle(10)
        assert np.array_equal(ct.get_brick(*y_key), loader.reference(*y_key))
        assert ct.stats.dropped >= 1 and ct.get_brick(*x_key) is None
        for L, i in _window_keys(ct):
            assert np.array_equal(ct.get_brick(L, i), loader.reference(L, i))
    finally:
        release.set()
        assert ct.close()


def test_wait_for_returns_when_its_bricks_settle_before_idle(no_leaked_threads):
    loader = ArrayLoader(_vol((64, 64, 64)))
    read = loader.read_brick
    hold = threading.Event()

    def slow_fine(level, index):
        if level == 0:
            hold.wait(10)  # level 0 stays loading until released
        return read(level, index)

    loader.read_brick = slow_fine
    with ClipTexture(loader, "4MB", threads=2) as ct:
        c = ct.center  # the bricks holding the centre cost 0: coarse ones are served before level 0
        coarse = [(L, ct.pyramid.world_to_brick(L, c)) for L in range(1, ct.pyramid.num_levels)]
        assert ct.wait_for(coarse, timeout=10)
        assert all(ct.state(L, i) == BrickState.RESIDENT for L, i in coarse)
        assert ct.stats.queued + ct.stats.loading > 0  # level 0 still pending: not idle
        assert not ct.wait_for([(0, (0, 0, 0))], timeout=0.05)
        hold.set()
        assert ct.wait_until_idle(10)


def test_threads_end_when_an_unclosed_clip_texture_is_dropped():
    import gc

    before = set(threading.enumerate())
    ct = ClipTexture(ArrayLoader(_vol((32, 32, 32))), "1MB", threads=2)
    assert ct.wait_until_idle(10)
    mine = set(threading.enumerate()) - before
    assert len(mine) == 2
    del ct
    gc.collect()
    for t in mine:
        t.join(5)  # idle threads notice within IDLE_POLL_S that their clip-texture is gone
    assert not any(t.is_alive() for t in mine)


@settings(max_examples=12, deadline=None)
@given(
    ops=st.lists(
        st.one_of(
            st.tuples(st.just("move"), st.tuples(*[st.floats(-10, 70)] * 3)),
            st.tuples(st.just("window"), st.integers(2, 5)),
            st.tuples(st.just("idle"), st.just(None)),
        ),
        min_size=1,
        max_size=12,
    ),
    into=st.booleans(),
)
def test_invariants_hold_for_any_sequence_of_moves(ops, into):
    loader = (IntoLoader if into else ArrayLoader)(_VOL)
    pyr = loader.pyramid
    budget = 30 * pyr.brick_nbytes
    with ClipTexture(loader, budget, threads=2) as ct:
        for op, arg in ops:
            if op == "move":
                ct.set_center(arg)
            elif op == "window":
                ct.set_roaming_window(arg)
            else:
                assert ct.wait_until_idle(10)
            assert ct.stats.resident_bytes <= budget and ct.stats.pool_bytes <= budget
            for L, idx in ct.resident_bricks():
                assert ct.in_window_mask(L, np.array([idx]))[0]
                assert np.array_equal(ct.get_brick(L, idx), loader.reference(L, idx))
            for L in range(pyr.num_levels):
                allb = window_bricks((0, 0, 0), pyr.grid(L))
                inside = ct.in_window_mask(L, allb)
                assert inside.sum() == np.prod(ct.window_shape(L))
                for b in allb[~inside][:5]:
                    assert ct.state(L, tuple(b)) == BrickState.ABSENT
        assert ct.wait_until_idle(10)
        assert all(ct.state(L, i) == BrickState.RESIDENT for L, i in _window_keys(ct))


class SparseIntoLoader(IntoLoader):
    """A volume that is zero (the fill value) outside a few blobs, with bounds per brick computed
    here from the numpy levels (the reference) - or a bounds call that always fails."""

    def __init__(self, vol: np.ndarray, brick=(8, 8, 8), failing_bounds: bool = False):
        super().__init__(vol, brick)
        self.failing_bounds = failing_bounds
        self.bounds_calls = 0

    def brick_ranges(self, level, indices):
        with self._lock:
            self.bounds_calls += 1
        if self.failing_bounds:
            raise OSError("bounds unavailable")
        out = []
        for idx in np.asarray(indices).reshape(-1, 3):
            b = self.reference(level, tuple(int(v) for v in idx))
            out.append((float(b.min()), float(b.max())))
        return np.array(out, dtype=np.float64).reshape(-1, 2)


def _sparse_vol() -> np.ndarray:
    vol = np.zeros((40, 48, 56), dtype=np.float32)
    vol[2:9, 30:44, 5:12] = _VOL[2:9, 30:44, 5:12] + 0.5
    vol[25:37, 3:10, 40:50] = 2.0
    return vol


@pytest.mark.parametrize("prefault", [True, False])
def test_empty_bricks_decided_once_per_window_entry_and_data_exact(prefault, no_leaked_threads):
    """Bricks whose bounds are [fill, fill] are filled without a read, the bounds are asked once
    per level and move (not once per load), and every brick equals the numpy reference - also
    after a window resize moves bricks (and their empty flag) to other slots."""
    loader = SparseIntoLoader(_sparse_vol())
    pyr = loader.pyramid
    rng = np.random.default_rng(7)
    lo, hi = pyr.volume_box()
    with ClipTexture(loader, 60 * pyr.brick_nbytes, threads=2, prefault=prefault) as ct:
        assert loader.bounds_calls <= pyr.num_levels  # one vectorised call per placed level
        moves = 0
        for step in range(12):
            ct.set_center(rng.uniform(lo, hi))
            moves += 1
            if step % 4 == 3:
                ct.set_roaming_window(int(rng.integers(2, 5)))
                moves += 1
            assert ct.wait_until_idle(20)
            for L, idx in _window_keys(ct):
                assert ct.state(L, idx) == BrickState.RESIDENT
                assert np.array_equal(ct.get_brick(L, idx), loader.reference(L, idx)), (L, idx)
        assert loader.bounds_calls <= pyr.num_levels * (moves + 1)
        read = set(loader.calls)
        empty_seen = [(L, idx) for L, idx in _window_keys(ct) if not loader.reference(L, idx).any()]
        assert empty_seen and not (set(empty_seen) & read)  # empty bricks were never read
        assert ct.stats.empty_skipped >= len(empty_seen)


def test_failing_bounds_only_mean_every_brick_is_read(no_leaked_threads):
    """Bounds are an optimisation: when the call fails, bricks are read (and right), none fails."""
    loader = SparseIntoLoader(_sparse_vol(), failing_bounds=True)
    with ClipTexture(loader, "8MB", threads=2) as ct:
        assert ct.wait_until_idle(20)
        ct.set_center(np.array(loader.pyramid.volume_box()[0]) + 1.0)
        assert ct.wait_until_idle(20)
        keys = list(_window_keys(ct))
        for L, idx in keys:
            assert np.array_equal(ct.get_brick(L, idx), loader.reference(L, idx))
        assert set(keys) <= set(loader.calls)
        assert ct.stats.failures == 0 and ct.stats.empty_skipped == 0
        # a failed bounds call is not repeated on every move (it runs under the lock)
        calls = loader.bounds_calls
        ct.set_center(np.array(loader.pyramid.volume_box()[1]) - 1.0)
        assert ct.wait_until_idle(20)
        assert loader.bounds_calls == calls


def test_bricks_waited_for_are_loaded_before_the_rest_of_the_window(no_leaked_threads):
    """``wait_for`` moves its bricks to the front of the queue: a far brick is read among the first,
    not after every nearer brick of the window (the queue alone orders by distance)."""
    loader = ArrayLoader(_vol((64, 64, 64)))
    pyr = loader.pyramid
    gate = threading.Event()
    read = loader.read_brick

    def gated(level, index):
        assert gate.wait(10)
        return read(level, index)

    loader.read_brick = gated
    c0 = np.array([4.0, 4.0, 4.0])
    with ClipTexture(loader, 600 * pyr.brick_nbytes, threads=1, center=c0, predictive=False) as ct:
        keys = list(_window_keys(ct))
        far = max((k for k in keys if k[0] == 0), key=lambda k: _reference_cost(pyr, k[0], k[1], c0))
        assert len(keys) > 100
        waiter = threading.Thread(target=lambda: ct.wait_for([far], timeout=20))
        waiter.start()
        time.sleep(0.05)  # the waiter has prioritised its brick while the thread is held at its first read
        gate.set()
        waiter.join(20)
        assert ct.state(*far) == BrickState.RESIDENT
        order = [k for k in loader.calls]
        assert order.index(far) <= 2, order.index(far)  # the held first read, then the far brick
        assert ct.wait_until_idle(10)
        assert len(set(loader.calls)) == len(loader.calls) == len(keys)  # each brick read once, none twice
        assert all(np.array_equal(ct.get_brick(L, i), loader.reference(L, i)) for L, i in keys)


def test_prioritised_brick_keeps_its_retry_back_off(no_leaked_threads):
    """A brick that fails after being prioritised waits out its back-off like any other retry."""
    base = ArrayLoader(_vol((32, 32, 32)))
    times: dict = {}
    lock = threading.Lock()
    gate = threading.Event()

    class FailOnce:
        pyramid = base.pyramid

        def read_brick(self, level, index):
            assert gate.wait(10)  # the first read holds the one thread until the bricks are prioritised
            with lock:
                times.setdefault((level, tuple(index)), []).append(time.monotonic())
                n = len(times[(level, tuple(index))])
            if n == 1 and level == 0:
                raise TimeoutError("try again")
            return base.reference(level, index)

    with ClipTexture(FailOnce(), "1MB", threads=1, retries=2, retry_backoff=0.3) as ct:
        keys = [k for k in _window_keys(ct) if k[0] == 0]
        assert ct.prioritize(keys) == len(keys)
        ct.prioritize(keys)  # twice: a stale duplicate must not bypass the back-off either
        gate.set()
        assert ct.wait_until_idle(20)
        for k in keys:
            t = times[k]
            assert len(t) == 2 and t[1] - t[0] >= 0.25, (k, t)
        assert ct.prioritize([(0, (99, 99, 99)), (7, (0, 0, 0))]) == 0  # outside the window / no such level


def test_prioritize_pushes_a_brick_once_and_takes_key_rows(no_leaked_threads):
    """Asking twice for the same bricks pushes nothing the second time (the queue does not grow per
    frame), and the ``(m, 4)`` array form moves the same bricks, in the same order, as the key form."""
    orders = []
    for form in ("keys", "rows"):
        loader = ArrayLoader(_VOL)
        started, gate = threading.Event(), threading.Event()
        read = loader.read_brick

        def held(level, index, read=read, started=started, gate=gate):
            started.set()
            assert gate.wait(10)  # the one thread holds its first brick: the rest waits in the queue
            return read(level, index)

        loader.read_brick = held
        with ClipTexture(loader, "4MB", threads=1) as ct:
            assert started.wait(10)
            # far from the centre of interest: the queue's own order reads them last
            keys = [k for k in _window_keys(ct) if k[0] == 0 and k[1][0] == 0 and k[1][1] == 0][:5]
            keys += [(0, (99, 99, 99)), (9, (0, 0, 0)), keys[0]]  # outside the window, no such level, a repeat
            asked = keys if form == "keys" else np.array([(L, *i) for L, i in keys], dtype=np.int64)
            n0 = len(ct._queue)
            assert ct.prioritize(asked) == 5
            n1 = len(ct._queue)
            assert n1 == n0 + 5
            assert ct.prioritize(asked) == 0 and len(ct._queue) == n1  # already in front: nothing pushed
            gate.set()
            assert ct.wait_until_idle(20)
            assert set(loader.calls[1:6]) == set(keys[:5])  # the five, before every other brick
            orders.append(loader.calls[1:6])
            # once read, a brick can be asked for again (the mark left with its entry)
            assert ct.prioritize(asked) == 0  # resident: nothing to move
    assert orders[0] == orders[1]
