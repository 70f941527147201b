"""Sharded zarr v3 arrays (``sharding_indexed``) on the loader's fast path: OME-Zarr images written by
zarr-python 3 with ``shards=`` read brick for brick what zarr-python reads, locally and from an HTTP
server on 127.0.0.1 whose own log shows neighbouring inner chunks fetched in one request; damaged
shards are refused naming the shard and the brick, never decoded into wrong voxels."""

from __future__ import annotations

import shutil

import numpy as np
import pytest
import zarr
from zarr.codecs import BloscCodec, BytesCodec, Crc32cCodec, ShardingCodec

from clipvol.errors import BrickIntegrityError
from clipvol.loaders.zarr_shard_index import ShardLayout, plan_runs
from clipvol.loaders.zarr_store import ZarrLoader
from clipvol.paging.cliptexture import ClipTexture
from clipvol.testing import LoaderTests

from optional import REMOTE_HTTP, REMOTE_S3
from remote_servers import moto_s3, serve_directory, upload_directory

SHAPE = (40, 50, 60)
B = 16  # inner chunk = brick
FILL = 7
#: runs of about three inner chunks (a shard's 8 decoded chunks are 64 kB): the index-then-ranges path
SMALL_RUN = 24_000


@pytest.fixture(scope="module")
def volume() -> np.ndarray:
    rng = np.random.default_rng(31)
    vol = (rng.random(SHAPE) * 4000).astype(np.uint16)
    vol[:16, :16] = FILL  # whole inner chunks of fill: zarr-python does not write them (absent in the index)
    return vol


def write_ome(path, vol: np.ndarray, *, index_location: str = "end", levels: int = 2) -> None:
    """An OME-Zarr 0.5 image written by zarr-python: sharded levels (2x2x2 inner chunks of B^3 per
    shard, blosc + crc32c inside), each level the 2x subsample of the one before."""
    g = zarr.open_group(str(path), mode="w", zarr_format=3)
    data = vol
    for L in range(levels):
        codec = ShardingCodec(chunk_shape=(B, B, B), codecs=[BytesCodec(), BloscCodec(), Crc32cCodec()],
                              index_location=index_location)
        a = g.create_array(str(L), shape=data.shape, dtype=data.dtype, chunks=(2 * B,) * 3, serializer=codec,
                           compressors=None, fill_value=FILL)
        a[...] = data
        data = data[::2, ::2, ::2]
    g.attrs["ome"] = {"version": "0.5", "multiscales": [{
        "axes": [{"name": n, "type": "space"} for n in "zyx"], "type": "subsample",
        "datasets": [{"path": str(L), "coordinateTransformations": [{"type": "scale", "scale": [2.0**L] * 3}]}
                     for L in range(levels)]}],
        "omero": {"channels": [{"window": {"min": float(vol.min()), "max": float(vol.max())}}]}}


@pytest.fixture(scope="module")
def site(tmp_path_factory, volume):
    root = tmp_path_factory.mktemp("shards")
    write_ome(root / "s.zarr", volume)
    return root


def index_of(shard_file, n: int) -> np.ndarray:
    """The (offset, nbytes) pairs of a shard with its index at the end, straight from its bytes."""
    raw = shard_file.read_bytes()
    return np.frombuffer(raw[len(raw) - 16 * n - 4: len(raw) - 4], dtype="<u8").reshape(n, 2)


def span(pairs: np.ndarray) -> int:
    """Bytes from the first to the end of the last of the present chunks among index ``pairs``."""
    p = pairs[pairs[:, 0] != 2**64 - 1].astype(np.int64)
    return int((p[:, 0] + p[:, 1]).max() - p[:, 0].min()) if len(p) else 0


def reference(store, level: int, pyr, idx) -> np.ndarray:
    start, stop = pyr.brick_voxel_box(level, idx)
    return np.asarray(zarr.open_array(str(store / str(level)), mode="r")[tuple(slice(a, b) for a, b in zip(start, stop))])


def valid(pyr, level, idx, brick) -> np.ndarray:
    start, stop = pyr.brick_voxel_box(level, idx)
    return brick[tuple(slice(0, b - a) for a, b in zip(start, stop))]


def assert_reads_like_zarr(loader, store) -> int:
    pyr = loader.pyramid
    n = 0
    for L in range(loader.stored_levels):
        for idx in np.ndindex(pyr.grid(L)):
            np.testing.assert_array_equal(valid(pyr, L, idx, loader.read_brick(L, idx)), reference(store, L, pyr, idx),
                                          err_msg=f"level {L} brick {idx}")
            out = np.empty(pyr.brick_shape, pyr.dtype)
            loader.read_brick_into(L, idx, out)
            np.testing.assert_array_equal(valid(pyr, L, idx, out), reference(store, L, pyr, idx))
            n += 1
    return n


@pytest.mark.parametrize("location", ["end", "start"])
def test_sharded_ome_zarr_reads_what_zarr_reads(tmp_path, volume, location):
    write_ome(tmp_path / "s.zarr", volume, index_location=location)
    loader = ZarrLoader(tmp_path / "s.zarr")
    assert loader.stored_levels == 2 and loader.pyramid.brick_shape == (B, B, B)
    assert all(am.shard is not None and am.fast for am in loader._arrays)  # the fast path, not zarr-python's
    assert assert_reads_like_zarr(loader, tmp_path / "s.zarr") > 0
    assert loader._zarr_arrays == {}  # no brick went through zarr-python


def test_absent_inner_chunks_are_the_fill_value(site, volume):
    shard = site / "s.zarr" / "0" / "c" / "0" / "0" / "0"
    ix = index_of(shard, 8)
    assert np.all(ix[0] == 2**64 - 1)  # inner chunk (0, 0, 0): not written by zarr-python (all fill)
    loader = ZarrLoader(site / "s.zarr")
    np.testing.assert_array_equal(loader.read_brick(0, (0, 0, 0)), np.full((B, B, B), FILL, np.uint16))
    np.testing.assert_array_equal(loader.read_brick(0, (1, 1, 1)), volume[16:32, 16:32, 16:32])


def test_neighbours_of_a_shard_are_read_once_and_each_brick_checked(site):
    """Reading the bricks of one shard reads its index and its chunks' bytes once (the file's own
    index says how many bytes that is): in one read of the whole shard where its decoded bricks fit
    in one run (the default), in fewer reads than chunks where runs are smaller than the shard, and
    one read per chunk with runs off."""
    shard = site / "s.zarr" / "0" / "c" / "0" / "1" / "1"
    ix = index_of(shard, 8)
    present = ix[:, 0] != 2**64 - 1
    want = int(ix[present, 1].sum()) + 16 * 8 + 4
    assert want == shard.stat().st_size  # zarr-python leaves no gaps: index + chunks = the file
    chunks = 1 + int(present.sum())
    for run_bytes, most in ((8 * 2**20, 1), (SMALL_RUN, chunks - 2), (0, chunks)):
        loader = ZarrLoader(site / "s.zarr", shard_run_bytes=run_bytes)
        for idx in np.ndindex(2, 2, 2):
            loader.read_brick(0, (idx[0], 2 + idx[1], 2 + idx[2]))
        assert loader.read_counter.bytes == want, run_bytes
        assert loader.read_counter.reads <= most and (run_bytes or loader.read_counter.reads == chunks), run_bytes


def test_plan_runs_covers_every_chunk_once_within_the_cap():
    rng = np.random.default_rng(3)
    sizes = rng.integers(1, 1000, 64)
    order = rng.permutation(64)
    offsets = np.zeros(64, np.int64)
    offsets[order] = np.concatenate([[0], np.cumsum(sizes[order])[:-1]])
    sizes[5] = -1
    offsets[5] = -1
    ix = plan_runs(offsets, sizes.astype(np.int64), cap=3000, max_gap=0)
    assert ix.run_of[5] == -1
    for r, (a, b) in enumerate(ix.runs):
        members = np.flatnonzero(ix.run_of == r)
        assert b - a <= 3000 and a == offsets[members].min() and b == (offsets[members] + sizes[members]).max()
        assert (sizes[members].sum()) == b - a  # contiguous: nothing read twice, nothing skipped
    assert sorted(np.flatnonzero(ix.run_of >= 0)) == [i for i in range(64) if i != 5]
    assert ShardLayout((32, 32, 32), (2, 2, 2)).locate((3, 1, 2)) == ((1, 0, 1), 0b110)  # C order of (1, 1, 0) in the shard


# -- faults: refused naming the shard and the brick, never wrong voxels -------------------------------
def damaged(site, tmp_path, how: str):
    """A copy of the store with shard 0/c/1/0/0 damaged ``how``; returns (store root, brick in it)."""
    root = tmp_path / "site"
    shutil.copytree(site, root)
    shard = root / "s.zarr" / "0" / "c" / "1" / "0" / "0"
    raw = bytearray(shard.read_bytes())
    ix = index_of(shard, 8)
    if how == "index":
        raw[-20] ^= 0x10  # a byte of the index's last entry
    elif how == "truncated":
        raw = raw[: len(raw) - 100]
    elif how == "chunk":
        off, nb = (int(v) for v in ix[0])  # inner chunk (0, 0, 0) of the shard = brick (2, 0, 0)
        raw[off + nb // 2] ^= 0x04
    shard.write_bytes(bytes(raw))
    return root, (2, 0, 0)


def check_fault(loader, brick, how: str, store) -> None:
    with pytest.raises(BrickIntegrityError) as e:
        loader.read_brick(0, brick)
    msg = str(e.value)
    assert "0/c/1/0/0 (shard)" in msg or "shard 0/c/1/0/0:" in msg, msg
    assert "brick (level 0, {}, {}, {})".format(*brick) in msg and "\n" not in msg, msg
    if how == "chunk":
        assert "crc32c" in msg
        # the other bricks of the run (fetched in the same read) still decode exactly
        pyr = loader.pyramid
        for idx in ((2, 0, 1), (2, 1, 0), (2, 1, 1)):
            np.testing.assert_array_equal(valid(pyr, 0, idx, loader.read_brick(0, idx)), reference(store, 0, pyr, idx))
    else:
        assert "index" in msg or "truncated" in msg


@pytest.mark.parametrize("run_bytes", [8 * 2**20, SMALL_RUN])
@pytest.mark.parametrize("how", ["index", "truncated", "chunk"])
def test_damaged_shard_is_refused_locally(site, tmp_path, how, run_bytes):
    root, brick = damaged(site, tmp_path, how)
    loader = ZarrLoader(root / "s.zarr", shard_run_bytes=run_bytes)
    check_fault(loader, brick, how, site / "s.zarr")
    with pytest.raises(BrickIntegrityError):
        out = np.empty((B, B, B), np.uint16)
        loader.read_brick_into(0, brick, out)


@REMOTE_HTTP
@pytest.mark.parametrize("run_bytes", [8 * 2**20, SMALL_RUN])
@pytest.mark.parametrize("how", ["index", "truncated", "chunk"])
def test_damaged_shard_is_refused_over_http(site, tmp_path, how, run_bytes):
    from clipvol.loaders.zarr_remote import RemoteZarrLoader

    root, brick = damaged(site, tmp_path, how)
    with serve_directory(root) as (url, _):
        loader = RemoteZarrLoader(f"{url}/s.zarr", shard_run_bytes=run_bytes)
        check_fault(loader, brick, how, site / "s.zarr")
        loader.close()


# -- over HTTP: fewer requests than inner chunks, bytes counted = bytes sent -------------------------
@REMOTE_HTTP
@pytest.mark.parametrize("run_bytes", [8 * 2**20, SMALL_RUN])
def test_view_over_http_coalesces_neighbours_and_counts_what_the_server_sent(site, run_bytes):
    """The server's own log: fewer requests than the inner chunks the view needed (whole shards by
    default; with small runs, index ranges and runs of neighbours), and exactly the bytes it sent
    counted by the loader and by its byte source."""
    from clipvol.loaders.zarr_remote import RemoteZarrLoader

    store = site / "s.zarr"
    with serve_directory(site, keep_alive=True) as (url, srv):
        loader = RemoteZarrLoader(f"{url}/s.zarr", max_in_flight=8, shard_run_bytes=run_bytes)
        start = len(srv.log)
        bytes0, fetched0 = loader.read_counter.bytes, loader.source.bytes_fetched
        with ClipTexture(loader, "64MB", threads=8) as ct:  # the whole image fits: every brick is a view's brick
            assert ct.wait_until_idle(timeout=60)
            resident = [(L, idx) for L, idx in ct.resident_bricks() if L < loader.stored_levels]
            pyr = loader.pyramid
            assert len(resident) == sum(pyr.num_bricks(L) for L in range(loader.stored_levels))
            for L, idx in resident:
                np.testing.assert_array_equal(valid(pyr, L, idx, ct.get_brick(L, idx)), reference(store, L, pyr, idx),
                                              err_msg=f"level {L} brick {idx}")
        log = [e for e in srv.log[start:] if e[0].startswith("/s.zarr/")]
        loader.close()
    # inner chunks the view needed, from the shards' own indices
    inner = 0
    for L in range(2):
        for f in (store / str(L) / "c").glob("*/*/*"):
            inner += int((index_of(f, 8)[:, 0] != 2**64 - 1).sum())
    assert log and all(e[2] in (200, 206) for e in log)
    ranged = [e for e in log if e[1] is not None]
    if run_bytes == SMALL_RUN:  # index suffixes, then runs of neighbours
        assert len(ranged) == len(log) and any(e[1].startswith("bytes=-") for e in log)
        runs = [e for e in log if not e[1].startswith("bytes=-")]
        assert len(runs) < inner / 2, (len(runs), inner)
    else:  # each shard whole, in one request
        whole = [e[0] for e in log if e[1] is None]
        files = {f"/s.zarr/{f.relative_to(store).as_posix()}" for L in range(2) for f in (store / str(L) / "c").glob("*/*/*")}
        assert sorted(whole) == sorted(files)  # every shard read whole, once
        # level 0's bricks are read once each: one request per shard; level 1's are read again for
        # the derived level 2 (a range each, their window spent), so the total varies a little
        assert len([e for e in log if e[0].startswith("/s.zarr/0/")]) == len(list((store / "0" / "c").glob("*/*/*")))
        assert len(log) < inner / 2, (len(log), inner)
    sent = sum(e[3] for e in log)
    assert loader.read_counter.bytes - bytes0 == sent == loader.source.bytes_fetched - fetched0


# -- the loader conformance suite over sharded images ------------------------------------------------
def _conformance_volume() -> np.ndarray:
    rng = np.random.default_rng(5)
    return (rng.random((36, 40, 44)) * 1000).astype(np.float32)


class TestShardedOmeZarr(LoaderTests):
    """The conformance suite over a sharded OME-Zarr image on disk."""

    @pytest.fixture(scope="class")
    @classmethod
    def reference(cls):
        return _conformance_volume()

    @pytest.fixture(scope="class")
    @classmethod
    def loader(cls, reference, tmp_path_factory):
        root = tmp_path_factory.mktemp("conf-shards")
        write_ome(root / "c.zarr", reference)
        return ZarrLoader(root / "c.zarr")


@REMOTE_HTTP
class TestShardedOmeZarrOverHttp(TestShardedOmeZarr):
    """The conformance suite over the same kind of image behind an HTTP server (ranged reads)."""

    @pytest.fixture(scope="class")
    @classmethod
    def loader(cls, reference, tmp_path_factory):
        from clipvol.loaders.zarr_remote import RemoteZarrLoader

        root = tmp_path_factory.mktemp("conf-shards-http")
        write_ome(root / "c.zarr", reference)
        with serve_directory(root) as (url, _):
            yield RemoteZarrLoader(f"{url}/c.zarr")


# -- the read plan: only the bricks about to be read are fetched together ----------------------------
def test_a_plan_limits_a_shard_read_to_the_planned_bricks(site):
    """With a plan of one z-layer of a shard's bricks, reading them fetches the index and exactly those
    inner chunks (the file's own index says their sizes), not the whole shard."""
    store = site / "s.zarr"
    shard = store / "0" / "c" / "0" / "1" / "1"
    ix = index_of(shard, 8)
    layer = [(0, 2, 2), (0, 2, 3), (0, 3, 2), (0, 3, 3)]  # inner z = 0: index positions 0-3 (C order)
    loader = ZarrLoader(store)
    loader.plan_reads(0, np.array(layer))
    pyr = loader.pyramid
    for idx in layer:
        np.testing.assert_array_equal(valid(pyr, 0, idx, loader.read_brick(0, idx)), reference(store, 0, pyr, idx))
    # zarr-python lays a shard's chunks out in Morton order, so the layer's chunks alternate with the
    # next layer's; gaps that small (< 64 KiB) are read through rather than paid with a request
    assert loader.read_counter.bytes == 16 * 8 + 4 + span(ix[:4]) < shard.stat().st_size
    assert loader.read_counter.reads == 2  # the index, then the layer in one range
    loader.plan_reads(0, None)  # no plan: the rest of the shard's run comes in one read
    reads = loader.read_counter.reads
    for idx in ((1, 2, 2), (1, 3, 3)):
        np.testing.assert_array_equal(valid(pyr, 0, idx, loader.read_brick(0, idx)), reference(store, 0, pyr, idx))
    assert loader.read_counter.reads == reads + 1


@REMOTE_HTTP
def test_a_clip_texture_region_reads_only_its_bricks_of_each_shard(site):
    """A clip-texture whose region is one layer of level-0 bricks tells the loader its plan: the server
    sends the layer's inner chunks (and the shards' indices), not the rest of each shard."""
    from clipvol.loaders.zarr_remote import RemoteZarrLoader
    from clipvol.paging.region import Region

    store = site / "s.zarr"
    with serve_directory(site) as (url, srv):
        loader = RemoteZarrLoader(f"{url}/s.zarr")
        pyr = loader.pyramid
        gz, gy, gx = pyr.grid(0)
        layer = np.array([(0, y, x) for y in range(gy) for x in range(gx)])  # inner z = 0 of shards z = 0
        lo, hi = pyr.volume_box()
        region = Region(tuple(((lo + hi) / 2).tolist()), (layer,) + (np.zeros((0, 3), np.int64),) * (pyr.num_levels - 1))
        start = len(srv.log)
        with ClipTexture(loader, "64MB", region=region) as ct:
            assert ct.wait_until_idle(timeout=60)
            got = {idx for L, idx in ct.resident_bricks() if L == 0}
            assert {tuple(b) for b in layer.tolist()} <= got
            for idx in layer.tolist():
                np.testing.assert_array_equal(valid(pyr, 0, idx, ct.get_brick(0, tuple(idx))), reference(store, 0, pyr, idx))
        log = [e for e in srv.log[start:] if e[0].startswith("/s.zarr/0/c/")]
        loader.close()
    want = 0
    for f in (store / "0" / "c" / "0").glob("*/*"):
        want += 16 * 8 + 4 + span(index_of(f, 8)[:4])  # the index, then the layer's chunks
    assert sum(e[3] for e in log) == want
    assert all(e[1] is not None for e in log)  # no shard read whole


# -- what stays with zarr-python, and metadata refused ------------------------------------------------
def test_shards_off_the_fast_path_are_read_by_zarr_python(tmp_path, volume):
    """Inner codecs the fast path does not decode (a transpose) or an index with other codecs: the
    level is read through zarr-python, with the same values."""
    from zarr.codecs import TransposeCodec

    for name, codec in (("transpose", ShardingCodec(chunk_shape=(B, B, B), codecs=[TransposeCodec(order=(2, 1, 0)), BytesCodec()])),
                        ("index", ShardingCodec(chunk_shape=(B, B, B), codecs=[BytesCodec()], index_codecs=[BytesCodec()]))):
        path = tmp_path / f"{name}.zarr"
        g = zarr.open_group(str(path), mode="w", zarr_format=3)
        a = g.create_array("0", shape=volume.shape, dtype=volume.dtype, chunks=(2 * B,) * 3, serializer=codec,
                           compressors=None, fill_value=FILL)
        a[...] = volume
        g.attrs["ome"] = {"version": "0.5", "multiscales": [{"axes": [{"name": n, "type": "space"} for n in "zyx"],
                                                             "datasets": [{"path": "0"}]}]}
        loader = ZarrLoader(path)
        am = loader._arrays[0]
        if name == "index":  # bytes without crc32c is an index the fast path reads
            assert am.shard is not None and not am.shard.index_crc
        else:
            assert am.shard is None and not am.fast
        pyr = loader.pyramid
        for idx in np.ndindex(pyr.grid(0)):
            start, stop = pyr.brick_voxel_box(0, idx)
            np.testing.assert_array_equal(valid(pyr, 0, idx, loader.read_brick(0, idx)),
                                          volume[tuple(slice(a, b) for a, b in zip(start, stop))])


@pytest.mark.parametrize("conf, what", [
    ({"chunk_shape": [5, 16, 16], "codecs": [{"name": "bytes"}]}, "does not divide"),
    ({"chunk_shape": [16, 16], "codecs": [{"name": "bytes"}]}, "inner chunk_shape"),
    ({"chunk_shape": [16, 16, 16], "codecs": [{"name": "bytes"}], "index_location": "middle"}, "index_location"),
])
def test_malformed_sharding_metadata_is_refused_naming_the_array(tmp_path, volume, conf, what):
    import json

    from clipvol.errors import InputFormatError
    from clipvol.loaders.zarr_meta import array_meta

    path = tmp_path / "s.zarr"
    write_ome(path, volume, levels=1)
    meta = json.loads((path / "0" / "zarr.json").read_text())
    meta["codecs"][0]["configuration"] = conf
    (path / "0" / "zarr.json").write_text(json.dumps(meta))
    with pytest.raises(InputFormatError, match=what) as e:
        array_meta(path / "0", "s.zarr level 0", path)
    assert "s.zarr level 0" in str(e.value) and "\n" not in str(e.value)


@REMOTE_HTTP
def test_byte_ranges_through_the_byte_source(tmp_path):
    """``FsspecByteSource.get_range`` against the file's own bytes: a range, a suffix, a range past
    the end (no bytes: the caller refuses a short read), an absent key; a server that ignores ranges
    is refused naming the URL."""
    from clipvol.errors import RemoteStoreError
    from clipvol.paging.bytesource import FsspecByteSource

    data = np.random.default_rng(0).bytes(5000)
    (tmp_path / "f").write_bytes(data)
    with serve_directory(tmp_path, answers={"/whole": (200, data)}) as (url, srv):
        src = FsspecByteSource(url, retries=0)
        assert src.get_range("f", 100, 300) == data[100:300]
        assert src.get_range("f", -132, None) == data[-132:]
        assert src.get_range("f", -9000, None) == data  # a suffix longer than the object: all of it
        assert src.get_range("f", 4900, 5100) == data[4900:]  # short: the caller compares lengths
        assert src.get_range("f", 6000, 6100) == b""  # HTTP 416
        assert src.get_range("absent", 0, 10) is None
        assert [e[2] for e in srv.log] == [206, 206, 206, 206, 416, 404]
        with pytest.raises(RemoteStoreError, match=r"whole: asked for 10 bytes .* ignores byte ranges"):
            src.get_range("whole", 0, 10)


@pytest.fixture(scope="module")
def s3_image(site):
    """The image uploaded to a moto S3 server (one per module); yields its URL."""
    with moto_s3() as endpoint:
        upload_directory(endpoint, site / "s.zarr", "shards", "img/s.zarr")
        yield "s3://shards/img/s.zarr"


@REMOTE_S3
@pytest.mark.parametrize("run_bytes", [pytest.param(8 * 2**20, marks=pytest.mark.slow), SMALL_RUN])
def test_sharded_image_on_s3_reads_what_zarr_reads(site, s3_image, run_bytes):
    """The same image in a moto S3 bucket: whole shards, or index suffixes and ranged runs, through s3fs."""
    from clipvol.paging.open import open_store

    loader = open_store(s3_image, shard_run_bytes=run_bytes)
    assert all(am.shard is not None for am in loader._arrays)
    assert assert_reads_like_zarr(loader, site / "s.zarr") > 0
    assert loader._zarr_arrays == {}
    loader.close()


@REMOTE_HTTP
def test_disk_cache_keeps_verified_inner_chunks_for_the_next_session(volume, tmp_path):
    """A second session over the same sharded image reads every brick from the on-disk cache: the
    server, refusing every shard, is asked for none; a cached inner chunk damaged on disk is dropped
    and read again from the server."""
    from clipvol.loaders.zarr_remote import RemoteZarrLoader

    cache = tmp_path / "cache"
    root = tmp_path / "site"
    full = volume.copy()
    full[:16, :16] += 1  # no inner chunk left absent (an absent one is never cached: the index is asked)
    write_ome(root / "s.zarr", full)
    store = root / "s.zarr"
    with serve_directory(root) as (url, srv):
        first = RemoteZarrLoader(f"{url}/s.zarr", cache=cache)
        assert_reads_like_zarr(first, store)
        first.close()
        srv.forbid = ("/s.zarr/0/c/", "/s.zarr/1/c/")
        start = len(srv.log)
        warm = RemoteZarrLoader(f"{url}/s.zarr", cache=cache)
        assert_reads_like_zarr(warm, store)
        assert not [e for e in srv.log[start:] if "/c/" in e[0]] and srv.counts and warm.source.cache.hits > 0
        warm.close()
        # damage one cached inner chunk: it fails its crc32c, is dropped and read from the server again
        cached = sorted((p for p in cache.rglob("*") if p.is_file() and p.name.count(".") == 1 and "c" in p.parts),
                        key=lambda p: p.stat().st_size)[-1]
        raw = bytearray(cached.read_bytes())
        raw[len(raw) // 2] ^= 1
        cached.write_bytes(bytes(raw))
        srv.forbid = ()
        start = len(srv.log)
        again = RemoteZarrLoader(f"{url}/s.zarr", cache=cache)
        assert_reads_like_zarr(again, store)
        again.close()
        shard = cached.relative_to(next(cache.iterdir()) / "data").as_posix().rsplit(".", 1)[0]
        assert [e[0] for e in srv.log[start:] if "/c/" in e[0]] == [f"/s.zarr/{shard}"]  # only the damaged one's shard
        assert cached.read_bytes() != bytes(raw)  # kept again, verified


# -- the caches: bounded, and one read per run however many threads ask -----------------------------
def test_shard_windows_read_a_run_once_for_many_threads_and_stay_bounded():
    import threading

    from clipvol.loaders.zarr_shard_cache import ShardWindows

    data = bytes(range(256)) * 40  # a run of 10 chunks of 1024 bytes at offset 5000
    calls = []
    gate = threading.Event()

    def fetch_run():
        calls.append(1)
        gate.wait(10)  # every thread asks while this read is in flight
        return 5000, data

    win = ShardWindows(max_bytes=3 * len(data))
    got = {}

    def ask(pos):
        got[pos] = bytes(win.chunk("run", pos, 5000 + 1024 * pos, 1024, lambda: set(range(10)), fetch_run,
                                   lambda: b"own read"))

    threads = [threading.Thread(target=ask, args=(p,)) for p in range(10)]
    for t in threads:
        t.start()
    gate.set()
    for t in threads:
        t.join(10)
    assert len(calls) == 1 and all(got[p] == data[1024 * p: 1024 * (p + 1)] for p in range(10))
    assert win.served == 9 and win._held == 0  # every chunk served once: the window is gone
    # a chunk served already is read again from storage, never from memory twice
    win.put("run2", 0, data, {0, 1})
    assert bytes(win.chunk("run2", 0, 0, 4, set, None, lambda: b"own")) == data[:4]
    assert win.chunk("run2", 0, 0, 4, set, None, lambda: b"own") == b"own"
    # bounded: the oldest windows go once more than max_bytes are held
    for k in range(5):
        win.put(("w", k), 0, data, {0})
    assert win._held <= 3 * len(data) and ("w", 4) in win._windows and ("w", 0) not in win._windows
