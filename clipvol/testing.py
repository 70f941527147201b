"""``LoaderTests``: the conformance suite for loaders - bundled ones and yours.

Custom loaders are a product feature, so the contract in :mod:`clipvol.paging.loader` is checked by a
reusable pytest class (in the manner of zarr-python's ``zarr.testing.store.StoreTests``).
Subclass it in a test module and provide two fixtures::

    from clipvol.testing import LoaderTests

    class TestMyLoader(LoaderTests):
        @pytest.fixture(scope="class")
        @classmethod
        def loader(cls):
            return MyLoader(...)

        @pytest.fixture(scope="class")
        @classmethod
        def reference(cls):
            return the_full_level0_numpy_array   # or None for huge virtual volumes

Every test reads only a few bricks per level (corners, centre, edges), so the suite stays fast
on large virtual volumes. Each check compares against an independent numpy computation:
level 0 against ``reference``; coarse levels against :func:`clipvol.bricking.pyramid.downsample` of the
finer level assembled from its bricks; edge padding against :func:`numpy.pad` in ``edge`` mode.

Class attributes a subclass may override: ``check_filter = False`` when the stored coarse levels
come from another filter than ``pyramid.filter`` (e.g. an OME-Zarr written with a Gaussian);
``rtol`` / ``atol`` for float comparisons of coarse levels (exact for integers).
"""

from __future__ import annotations

import threading
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest

from .bricking.pyramid import Pyramid, downsample, level_shapes
from .paging.loader import HasBrickRanges, Loader, check_brick

__all__ = ["LoaderTests", "sample_bricks"]


def sample_bricks(pyramid: Pyramid, level: int, limit: int = 12) -> list[tuple[int, int, int]]:
    """A few bricks of ``level``: all if there are at most ``limit``, else the 8 grid corners,
    the centre and a couple of bricks beside the last one (edge bricks)."""
    g = pyramid.grid(level)
    if pyramid.num_bricks(level) <= limit:
        return [tuple(int(v) for v in i) for i in np.ndindex(*g)]
    out: list[tuple[int, int, int]] = []
    for c in np.ndindex(2, 2, 2):
        out.append(tuple((n - 1) * k for n, k in zip(g, c)))
    out.append(tuple(n // 2 for n in g))
    out.append(tuple(max(n - 2, 0) for n in g))
    out.append((g[0] - 1, g[1] // 2, max(g[2] - 2, 0)))
    return list(dict.fromkeys(out))[:limit]


def _valid(pyramid: Pyramid, level: int, index) -> tuple[slice, ...]:
    start, stop = pyramid.brick_voxel_box(level, index)
    return tuple(slice(0, b - a) for a, b in zip(start, stop))


class LoaderTests:
    """Conformance tests for a :class:`~clipvol.paging.loader.Loader` (see the module docstring)."""

    check_filter: bool = True
    rtol: float = 1e-5
    atol: float = 1e-6
    bricks_per_level: int = 12

    @pytest.fixture(scope="class")
    @classmethod
    def reference(cls):
        """The full level-0 array, or ``None`` (override in the subclass)."""
        return None

    # -- helpers ------------------------------------------------------------------------------
    def _assert_equal(self, got: np.ndarray, want: np.ndarray, what: str) -> None:
        if got.dtype.kind == "f":
            np.testing.assert_allclose(got, want, rtol=self.rtol, atol=self.atol, equal_nan=True, err_msg=what)
        else:
            np.testing.assert_array_equal(got, want, err_msg=what)

    # -- the tests ----------------------------------------------------------------------------
    def test_is_a_loader(self, loader) -> None:
        assert isinstance(loader, Loader)
        assert isinstance(loader.pyramid, Pyramid)

    def test_levels_halve(self, loader) -> None:
        pyr = loader.pyramid
        assert [lv.shape for lv in pyr.levels] == level_shapes(pyr.shape, pyr.brick_shape)
        for a, b in zip(pyr.levels, pyr.levels[1:]):
            np.testing.assert_allclose(b.scale, np.array(a.scale) * 2, rtol=1e-9)

    def test_value_range_holds_level0(self, loader, reference) -> None:
        lo, hi = loader.pyramid.value_range
        assert lo <= hi
        if reference is None:
            return
        r = np.asarray(reference)
        r = r[np.isfinite(r)] if r.dtype.kind == "f" else r
        if r.size:
            assert lo <= float(r.min()) and hi >= float(r.max())

    def test_brick_shape_and_dtype(self, loader) -> None:
        pyr = loader.pyramid
        for level in range(pyr.num_levels):
            for idx in sample_bricks(pyr, level, self.bricks_per_level):
                b = check_brick(loader, level, idx, loader.read_brick(level, idx))
                assert b.shape == pyr.brick_shape and b.dtype == pyr.dtype

    def test_edge_bricks_replicate(self, loader) -> None:
        pyr = loader.pyramid
        seen = 0
        for level in range(pyr.num_levels):
            for idx in sample_bricks(pyr, level, self.bricks_per_level):
                v = _valid(pyr, level, idx)
                if all(s.stop == b for s, b in zip(v, pyr.brick_shape)):
                    continue
                b = loader.read_brick(level, idx)
                want = np.pad(b[v], [(0, n - s.stop) for s, n in zip(v, pyr.brick_shape)], mode="edge")
                np.testing.assert_array_equal(b, want, err_msg=f"edge padding of level {level} brick {idx}")
                seen += 1
        if seen == 0 and any(s % b for s, b in zip(pyr.shape, pyr.brick_shape)):
            pytest.fail("no edge brick was checked although level 0 has partial bricks")

    def test_level0_equals_reference(self, loader, reference) -> None:
        if reference is None:
            pytest.skip("no reference array for this loader")
        pyr = loader.pyramid
        assert tuple(reference.shape) == pyr.shape
        for idx in sample_bricks(pyr, 0, max(self.bricks_per_level, 64)):
            start, stop = pyr.brick_voxel_box(0, idx)
            want = np.asarray(reference[tuple(slice(a, b) for a, b in zip(start, stop))])
            got = loader.read_brick(0, idx)[_valid(pyr, 0, idx)]
            np.testing.assert_array_equal(got, want.astype(pyr.dtype), err_msg=f"level 0 brick {idx}")

    def test_coarse_levels_are_downsampled(self, loader) -> None:
        pyr = loader.pyramid
        if not self.check_filter or pyr.num_levels < 2:
            pytest.skip("filter check disabled or single level")
        for level in range(1, pyr.num_levels):
            for idx in sample_bricks(pyr, level, 4):
                fine = level - 1
                B = pyr.brick_shape
                start = [2 * i * b for i, b in zip(idx, B)]
                stop = [min(s + 2 * b, n) for s, b, n in zip(start, B, pyr.levels[fine].shape)]
                region = np.empty([e - s for s, e in zip(start, stop)], dtype=pyr.dtype)
                for child in pyr.children(level, idx):
                    cs, ce = pyr.brick_voxel_box(fine, child)
                    region[tuple(slice(a - o, b - o) for a, b, o in zip(cs, ce, start))] = loader.read_brick(fine, child)[_valid(pyr, fine, child)]
                want = downsample(region, pyr.filter)
                got = loader.read_brick(level, idx)[_valid(pyr, level, idx)]
                self._assert_equal(got, want, f"level {level} brick {idx} vs {pyr.filter} of level {fine}")

    def test_concurrent_reads(self, loader) -> None:
        pyr = loader.pyramid
        keys = [(L, i) for L in range(pyr.num_levels) for i in sample_bricks(pyr, L, 4)][:24]
        serial = {k: np.array(loader.read_brick(*k)) for k in keys}
        barrier = threading.Barrier(4)

        def work(seed: int) -> dict:
            barrier.wait()
            order = np.random.default_rng(seed).permutation(len(keys))
            return {keys[j]: np.array(loader.read_brick(*keys[j])) for j in order}

        with ThreadPoolExecutor(4) as ex:
            results = list(ex.map(work, range(4)))
        for res in results:
            for k in keys:
                np.testing.assert_array_equal(res[k], serial[k], err_msg=f"concurrent read of {k}")

    def test_read_brick_into_equals_read_brick(self, loader) -> None:
        """The optional zero-copy ``read_brick_into`` writes exactly what ``read_brick`` returns."""
        into = getattr(loader, "read_brick_into", None)
        if into is None:
            pytest.skip("loader has no read_brick_into")
        pyr = loader.pyramid
        for L in range(pyr.num_levels):
            for idx in sample_bricks(pyr, L, self.bricks_per_level):
                slot = np.full(pyr.brick_shape, 7, dtype=pyr.dtype)  # a reused slot holds stale data
                into(L, idx, slot)
                np.testing.assert_array_equal(slot, loader.read_brick(L, idx), err_msg=f"read_brick_into level {L} {idx}")

    def test_bricks_are_not_shared(self, loader) -> None:
        """Writing into a returned brick must not change what the loader returns next."""
        pyr = loader.pyramid
        for level in (0, pyr.num_levels - 1):
            idx = (0, 0, 0)
            first = loader.read_brick(level, idx)
            keep = np.array(first)
            if first.flags.writeable:
                first[...] = 1 if first.dtype.kind != "f" else np.nan
            np.testing.assert_array_equal(loader.read_brick(level, idx), keep)

    def test_out_of_range_raises(self, loader) -> None:
        pyr = loader.pyramid
        g = pyr.grid(0)
        bad = [(0, g), (0, (g[0], 0, 0)), (0, (0, 0, g[2])), (0, (-1, 0, 0)), (pyr.num_levels, (0, 0, 0)), (-1, (0, 0, 0))]
        for level, idx in bad:
            with pytest.raises((ValueError, IndexError, KeyError)):
                loader.read_brick(level, idx)

    def test_brick_ranges_hold_values(self, loader) -> None:
        if not isinstance(loader, HasBrickRanges):
            pytest.skip("loader has no brick_ranges")
        pyr = loader.pyramid
        checked = 0
        for level in range(pyr.num_levels):
            keys = sample_bricks(pyr, level, self.bricks_per_level)
            ranges = loader.brick_ranges(level, np.array(keys, dtype=np.int64))
            if ranges is None:
                continue
            ranges = np.asarray(ranges, dtype=np.float64)
            assert ranges.shape == (len(keys), 2)
            for (lo, hi), idx in zip(ranges, keys):
                if np.isnan(lo) or np.isnan(hi):
                    continue  # [nan, nan] is "unknown" in the contract: nothing to check
                v = loader.read_brick(level, idx)[_valid(pyr, level, idx)].astype(np.float64)
                v = v[np.isfinite(v)]
                if v.size == 0:
                    continue
                tol = 1e-6 * max(1.0, abs(v).max())
                assert lo <= v.min() + tol and hi >= v.max() - tol, f"level {level} brick {idx}: range {lo, hi} misses {v.min(), v.max()}"
                checked += 1
        if checked == 0:
            pytest.skip("brick_ranges returned None for every level")
