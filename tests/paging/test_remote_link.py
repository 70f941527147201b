"""A remote store read with its requests in flight sized from the measured link: behind a server
on 127.0.0.1 with injected latency, a bandwidth cap and kept-alive connections, every brick equals
the volume it was bricked from, connections are reused, and the size stays within its bounds."""

from __future__ import annotations

import numpy as np

from clipvol.bricking.pipeline import brick_volume
from clipvol.loaders.zarr_remote import RemoteZarrLoader
from clipvol.paging.bytesource import DEFAULT_IN_FLIGHT, MAX_IN_FLIGHT
from clipvol.paging.cliptexture import ClipTexture

from optional import REMOTE_HTTP
from remote_servers import serve_directory


@REMOTE_HTTP
def test_reads_under_latency_and_a_bandwidth_cap_are_exact(tmp_path):
    rng = np.random.default_rng(3)
    vol = (rng.random((40, 48, 56)) * 4000).astype(np.uint16)
    brick_volume(vol, tmp_path / "s.zarr", brick=8, progress=False, workers=1)
    with serve_directory(tmp_path, latency=0.02, bandwidth=20e6, keep_alive=True) as (url, srv):
        loader = RemoteZarrLoader(f"{url}/s.zarr")  # max_in_flight=None: sized from the link
        src = loader.source
        assert src.adaptive and loader.preferred_threads == MAX_IN_FLIGHT
        with ClipTexture(loader, "64MB") as ct:  # the whole pyramid fits: every brick is read
            assert ct.wait_until_idle(timeout=120)
            pyr = loader.pyramid
            for L, idx in ct.resident_bricks():
                if L:
                    continue
                start, stop = pyr.brick_voxel_box(0, idx)
                got = ct.get_brick(0, idx)[tuple(slice(0, b - a) for a, b in zip(start, stop))]
                np.testing.assert_array_equal(got, vol[tuple(slice(a, b) for a, b in zip(start, stop))])
            assert sum(1 for L, _ in ct.resident_bricks() if L == 0) == pyr.num_bricks(0)
        # every answer waited the injected 20 ms: the latency learnt is at least that
        lat, _ = src.link.estimate()
        assert lat >= 0.02
        assert DEFAULT_IN_FLIGHT <= src.max_in_flight <= MAX_IN_FLIGHT
        # connections were kept alive and reused (HTTP/1.0 would open one per request; an error
        # answer - the metadata probes' 404s - closes its connection)
        assert src.requests > 200 and 2 * srv.connections < src.requests
        loader.close()


@REMOTE_HTTP
def test_a_fixed_in_flight_is_kept(tmp_path):
    vol = np.arange(16 * 16 * 16, dtype=np.uint16).reshape(16, 16, 16)
    brick_volume(vol, tmp_path / "s.zarr", brick=8, progress=False, workers=1)
    with serve_directory(tmp_path, latency=0.005, keep_alive=True) as (url, _):
        loader = RemoteZarrLoader(f"{url}/s.zarr", max_in_flight=4)
        assert not loader.source.adaptive and loader.preferred_threads == 4
        np.testing.assert_array_equal(loader.read_brick(0, (1, 0, 1)), vol[8:16, 0:8, 8:16])
        assert loader.source.max_in_flight == 4
        loader.close()
