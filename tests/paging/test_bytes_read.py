"""Bytes read from storage, counted where they are read: checked against the sizes of the chunk
files on disk (``os.path.getsize`` of the files a read touched) and the bytes of the source array."""

from __future__ import annotations

import os

import numpy as np
import pytest

from clipvol.bricking.pipeline import brick_volume
from clipvol.loaders.numpy_array import NumpyLoader
from clipvol.loaders.zarr_store import ZarrLoader
from clipvol.paging.cliptexture import ClipTexture
from clipvol.paging.readcount import ReadCounter, bytes_read_of

SHAPE = (20, 36, 44)
BRICK = 8


@pytest.fixture(scope="module")
def store(tmp_path_factory):
    rng = np.random.default_rng(3)
    vol = (rng.random(SHAPE) * 3000).astype(np.uint16)
    vol[:, :, :8] = 0  # a column of empty bricks: chunks never written, nothing to read
    path = tmp_path_factory.mktemp("bytes") / "s.zarr"
    brick_volume(vol, path, brick=BRICK, progress=False, workers=1)
    return path


def _chunk_file(store, level, idx) -> str:
    """The zarr v3 default chunk key of brick ``idx`` (``c/`` prefix, ``/`` separator)."""
    return os.path.join(store, str(level), "c", *(str(i) for i in idx))


def _size_on_disk(store, keys) -> int:
    return sum(os.path.getsize(_chunk_file(store, L, i)) for L, i in keys if os.path.exists(_chunk_file(store, L, i)))


def test_zarr_loader_counts_the_chunk_files_it_reads(store):
    ld = ZarrLoader(store)
    pyr = ld.pyramid
    keys = [(0, (0, 0, 0)), (0, (1, 2, 3)), (0, (2, 4, 5)), (1, (0, 1, 1)), (2, (0, 0, 0))]
    absent = (0, (1, 1, 0))  # x < 8: all zero, never written
    assert not os.path.exists(_chunk_file(store, *absent))
    before = ld.read_counter.bytes
    for L, idx in keys + [absent]:
        ld.read_brick(L, idx)
    # the slot path (read_brick_into, decoding straight into a buffer) counts the same bytes
    out = np.empty(pyr.brick_shape, dtype=pyr.dtype)
    ld.read_brick_into(0, (1, 2, 3), out)
    want = _size_on_disk(store, keys) + os.path.getsize(_chunk_file(store, 0, (1, 2, 3)))
    assert want > 0
    assert ld.read_counter.bytes - before == want
    assert bytes_read_of(ld) == ld.read_counter.bytes


def test_clip_texture_reports_every_chunk_file_read_once(store):
    ld = ZarrLoader(store)
    pyr = ld.pyramid
    with ClipTexture(ld, "64MB", 2) as ct:  # the whole pyramid fits: every brick is read once
        assert ct.wait_until_idle(60)
        every = [(L, idx) for L in range(pyr.num_levels) for idx in np.ndindex(pyr.grid(L))]
        assert len(ct.resident_bricks()) == len(every)
        on_disk = sum(os.path.getsize(os.path.join(d, f)) for L in range(pyr.num_levels)
                      for d, _, fs in os.walk(os.path.join(store, str(L), "c")) for f in fs)
        assert ct.stats.bytes_read == on_disk == ct.bytes_read


def test_numpy_loader_counts_the_source_bytes_it_slices():
    vol = np.arange(30 * 40 * 50, dtype=np.float32).reshape(30, 40, 50)
    ld = NumpyLoader(vol, brick=16, cache_bytes=0)  # no cached coarse levels: every read slices the source
    ld.read_brick(0, (1, 2, 3))  # voxels z 16:30, y 32:40, x 48:50 (an edge brick)
    assert ld.read_counter.bytes == vol[16:30, 32:40, 48:50].nbytes
    ld.read_brick(1, (0, 0, 0))  # level 1 brick 0 comes from level-0 voxels 0:32 per axis (clipped)
    assert ld.read_counter.bytes == vol[16:30, 32:40, 48:50].nbytes + vol[:30, :32, :32].nbytes


def test_loader_without_a_counter_reports_none():
    class Plain:
        def __init__(self, base):
            self.pyramid = base.pyramid
            self.base = base

        def read_brick(self, level, index):
            return self.base.read_brick(level, index)

    ld = Plain(NumpyLoader(np.zeros((16, 16, 16), np.uint8), brick=8))
    assert bytes_read_of(ld) is None
    with ClipTexture(ld, "8MB", 1) as ct:
        ct.wait_until_idle(30)
        assert ct.stats.bytes_read is None


def test_counter_is_exact_under_threads():
    import threading

    c = ReadCounter()

    def work():
        for _ in range(5000):
            c.add(3)

    ts = [threading.Thread(target=work) for _ in range(4)]
    for t in ts:
        t.start()
    for t in ts:
        t.join()
    assert (c.bytes, c.reads) == (4 * 5000 * 3, 4 * 5000)


def test_remote_reads_count_the_chunk_files_served(store):
    pytest.importorskip("aiohttp")
    from clipvol.loaders.zarr_remote import RemoteZarrLoader

    from remote_servers import serve_directory

    keys = [(0, (0, 1, 2)), (0, (2, 3, 4)), (1, (1, 1, 2))]
    with serve_directory(store.parent) as (base, _srv):
        ld = RemoteZarrLoader(f"{base}/{store.name}")
        try:
            net0 = ld.source.bytes_fetched
            for L, idx in keys:
                ld.read_brick(L, idx)
            want = _size_on_disk(store, keys)
            assert ld.read_counter.bytes == want
            # the byte source counts the same responses where they arrive (plus any statistics fetched)
            assert ld.source.bytes_fetched - net0 >= want
        finally:
            ld.close()
