"""Point-store nodes through the clip-texture: budget while roaming, payloads equal to the store."""

from __future__ import annotations

import numpy as np
import pytest
import zarr

from clipvol.bricking.point_sources import ClusteredPointSource
from clipvol.bricking.point_store import build_point_store
from clipvol.loaders.point_store import PointStoreLoader
from clipvol.paging.cliptexture import BrickState, ClipTexture
from clipvol.testing import LoaderTests


def test_budget_holds_while_roaming_and_resident_nodes_hold_the_store_points(tmp_path, rng):
    build_point_store(ClusteredPointSource(40_000, seed=3), tmp_path / "p", max_points=16, progress=False)
    loader = PointStoreLoader(tmp_path / "p")
    g = zarr.open_group(str(tmp_path / "p"), mode="r")  # the reference: zarr's own reads of the arrays
    xyz = np.asarray(g["points/xyz"][:])
    vals = np.asarray(g["points/values"][:])
    nodes = loader.nodes
    budget = 2_000_000
    lo, hi = loader.world_box()
    with ClipTexture(loader, budget, threads=2, center=loader.to_paging((lo + hi) / 2)) as ct:
        assert ct.window_size < 2 ** loader.depth  # the finest levels are windowed: roaming matters
        for step in range(12):
            c = lo + rng.random(3) * (hi - lo)
            ct.set_center(loader.to_paging(c))
            ct.wait_until_idle(timeout=30)
            st = ct.stats
            assert st.resident_bytes <= budget and st.pool_bytes <= budget
            assert st.failures == 0
            resident = ct.resident_bricks()
            assert resident
            for L, idx in resident[:: max(1, len(resident) // 40)]:
                b = ct.get_brick(L, idx)
                nid = loader.node_of_brick(L, idx)
                if nid < 0:  # a brick that is no node holds only zeros
                    assert not b.any()
                    continue
                a, n = int(nodes.offset[nid]), int(nodes.count[nid])
                np.testing.assert_array_equal(b[0, :n, :3], xyz[a:a + n])
                np.testing.assert_array_equal(b[0, :n, 4:], vals[a:a + n])
                assert (b[0, :n, 3] == 1).all() and not b[0, n:].any()
            # the bulk copy the splat action uses gives the same bricks as get_brick, one by one
            L0 = resident[-1][0]
            idx = np.array([i for L, i in resident if L == L0], np.int64)
            ok, data = ct.get_bricks(L0, idx)
            assert ok.all() and len(data) == len(idx)
            for i, b in zip(idx, data):
                np.testing.assert_array_equal(b, ct.get_brick(L0, tuple(i)))
        # the node under the last centre, at the finest depth, is resident
        d = loader.depth
        q = ((c - lo) / (hi - lo) * 2**d).astype(int).clip(0, 2**d - 1)
        L, idx = 0, (int(q[2]), int(q[1]), int(q[0]))
        assert ct.state(L, idx) == BrickState.RESIDENT


class TestPointStoreLoader(LoaderTests):
    """The loader contract (shapes, dtype, concurrency, ranges, bounds) for the point-node pyramid.

    ``check_filter`` is off: a node's brick holds its points, not a down-sampled finer level.
    """

    check_filter = False

    @pytest.fixture(scope="class")
    @classmethod
    def loader(cls, tmp_path_factory):
        p = tmp_path_factory.mktemp("conf") / "p"
        build_point_store(ClusteredPointSource(20_000, seed=9), p, max_points=8, progress=False)
        return PointStoreLoader(p)
