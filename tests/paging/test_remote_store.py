"""Remote stores: a clipvol store and an OME-Zarr image behind real servers on 127.0.0.1 (a static
HTTP server, optionally slow and failing with 503; a moto S3 server) read exactly what zarr-python
reads from the same store on local disk."""

from __future__ import annotations

import shutil

import numpy as np
import pytest
import zarr

from clipvol.bricking.pipeline import brick_volume
from clipvol.errors import ClipvolError, InputFormatError, RemoteStoreError
from clipvol.loaders.zarr_remote import RemoteZarrLoader
from clipvol.paging.bytesource import FsspecByteSource, is_remote_url, redact_url
from clipvol.paging.cliptexture import ClipTexture
from clipvol.paging.open import open_store
from clipvol.testing import LoaderTests

from optional import REMOTE_HTTP, REMOTE_S3
from remote_servers import moto_s3, serve_directory, upload_directory

SHAPE = (40, 50, 60)
BRICK = 16


@pytest.fixture(scope="module")
def volume() -> np.ndarray:
    rng = np.random.default_rng(7)
    vol = (rng.random(SHAPE) * 4000).astype(np.uint16)
    vol[:18] = 0  # empty bricks: absent chunks
    return vol


@pytest.fixture(scope="module")
def site(tmp_path_factory, volume):
    """A directory holding ``s.zarr`` (clipvol store of ``volume``)."""
    root = tmp_path_factory.mktemp("site")
    brick_volume(volume, root / "s.zarr", brick=BRICK, progress=False, workers=1)
    return root


def zarr_reference(path, level: int, pyr, idx) -> np.ndarray:
    """The valid (unpadded) part of brick ``idx`` as zarr-python reads it from the local store."""
    start, stop = pyr.brick_voxel_box(level, idx)
    return np.asarray(zarr.open_array(str(path / str(level)), mode="r")[tuple(slice(a, b) for a, b in zip(start, stop))])


def assert_same_bricks(loader, path) -> None:
    pyr = loader.pyramid
    for L in range(pyr.num_levels):
        for idx in np.ndindex(pyr.grid(L)):
            start, stop = pyr.brick_voxel_box(L, idx)
            got = loader.read_brick(L, idx)[tuple(slice(0, b - a) for a, b in zip(start, stop))]
            np.testing.assert_array_equal(got, zarr_reference(path, L, pyr, idx), err_msg=f"level {L} brick {idx}")


def test_url_detection_and_redaction():
    assert is_remote_url("s3://b/x.zarr") and is_remote_url("https://h/x.zarr") and is_remote_url("gs://b/x")
    assert not is_remote_url("procedural:fractal?size=8") and not is_remote_url("/data/x.zarr")
    assert not is_remote_url("file:///data/x.zarr")
    assert redact_url("https://alice:secret@host:8080/x.zarr") == "https://***@host:8080/x.zarr"
    assert redact_url("s3://bucket/x.zarr") == "s3://bucket/x.zarr"


@REMOTE_HTTP
def test_http_store_reads_what_zarr_reads_locally(site):
    with serve_directory(site) as (url, srv):
        loader = open_store(f"{url}/s.zarr")
        assert isinstance(loader, RemoteZarrLoader) and loader.is_clipvol_store
        assert loader.pyramid.shape == SHAPE
        assert_same_bricks(loader, site / "s.zarr")
        # statistics: the arrays zarr-python reads from the local store
        for L in range(loader.pyramid.num_levels):
            st = loader.brick_statistics(L)
            for name in ("min", "max", "histogram"):
                ref = zarr.open_array(str(site / "s.zarr" / "clipvol_stats" / str(L) / name), mode="r")[...]
                np.testing.assert_array_equal(st[name], ref)
        # nothing was written next to the store by reading it
        assert not any(p.name.startswith(".") for p in (site / "s.zarr").iterdir())
        loader.close()


@REMOTE_HTTP
def test_slow_server_failing_every_first_request_still_reads_everything(site):
    """20 ms per answer and HTTP 503 for the first request of every path: retries with backoff
    recover every chunk, and the clip-texture's many threads fill the window."""
    with serve_directory(site, latency=0.02, fail_first=1) as (url, srv):
        loader = open_store(f"{url}/s.zarr", max_in_flight=8)
        assert loader.preferred_threads == 8
        with ClipTexture(loader, "64MB") as ct:  # the whole volume fits: every brick is loaded
            assert "threads=8" in repr(ct)  # threads default to the loader's requests in flight
            assert ct.wait_until_idle(timeout=60)
            resident = ct.resident_bricks()
            pyr = loader.pyramid
            assert len(resident) == sum(pyr.num_bricks(L) for L in range(pyr.num_levels))
            for L, idx in resident:
                start, stop = pyr.brick_voxel_box(L, idx)
                got = ct.get_brick(L, idx)[tuple(slice(0, b - a) for a, b in zip(start, stop))]
                np.testing.assert_array_equal(got, zarr_reference(site / "s.zarr", L, pyr, idx))
        assert srv.failures > 0 and loader.source.retried >= srv.failures


@REMOTE_HTTP
def test_disk_cache_serves_a_second_session_without_the_server(site, tmp_path):
    cache = tmp_path / "cache"
    with serve_directory(site) as (url, srv):
        first = open_store(f"{url}/s.zarr", cache=cache)
        assert_same_bricks(first, site / "s.zarr")
        # now the server refuses every chunk of every level: only the cache can answer (metadata is
        # never cached: it comes from the server each session)
        srv.forbid = tuple(f"/s.zarr/{L}/c/" for L in range(first.pyramid.num_levels))
        srv.counts.clear()
        warm = open_store(f"{url}/s.zarr", cache=cache)
        assert_same_bricks(warm, site / "s.zarr")
        assert [p for p in srv.counts if "/c/" in p] == []  # no chunk was asked of the server
        assert warm.source.cache.hits > 0
        # a changed store (other root metadata) gets a fresh namespace: never stale chunks
        assert len(list(cache.iterdir())) == 1


@REMOTE_HTTP
def test_ome_zarr_v2_image_over_http(tmp_path, volume):
    """A plain OME-Zarr 0.4 image written by zarr-python (v2 format, two levels)."""
    import numcodecs

    root = tmp_path / "ome.zarr"
    g = zarr.open_group(str(root), mode="w", zarr_format=2)
    lv0 = volume[:32, :32, :32]
    lv1 = lv0.reshape(16, 2, 16, 2, 16, 2).mean(axis=(1, 3, 5)).astype(np.uint16)
    for name, data in (("0", lv0), ("1", lv1)):
        a = g.create_array(name, shape=data.shape, chunks=(16, 16, 16), dtype=data.dtype,
                           compressors=numcodecs.Blosc(cname="lz4", shuffle=1))
        a[...] = data
    g.attrs["multiscales"] = [{"version": "0.4", "axes": [{"name": n, "type": "space"} for n in "zyx"],
                               "datasets": [{"path": "0", "coordinateTransformations": [{"type": "scale", "scale": [1, 1, 1]}]},
                                            {"path": "1", "coordinateTransformations": [{"type": "scale", "scale": [2, 2, 2]}]}]}]
    with serve_directory(tmp_path) as (url, srv):
        loader = open_store(f"{url}/ome.zarr")
        assert not loader.is_clipvol_store and loader.stored_levels == 2
        np.testing.assert_array_equal(loader.read_brick(0, (1, 0, 1)), lv0[16:32, 0:16, 16:32])
        np.testing.assert_array_equal(loader.read_brick(1, (0, 0, 0)), lv1)


@pytest.fixture(scope="module")
def s3(site):
    with moto_s3() as endpoint:
        upload_directory(endpoint, site / "s.zarr", "scans", "cohort/s.zarr")
        yield endpoint


@REMOTE_S3
def test_s3_store_reads_what_zarr_reads_locally(site, s3):
    loader = open_store("s3://scans/cohort/s.zarr")
    assert loader.url == "s3://scans/cohort/s.zarr"
    assert_same_bricks(loader, site / "s.zarr")
    st = loader.brick_statistics(0)
    np.testing.assert_array_equal(st["max"], zarr.open_array(str(site / "s.zarr/clipvol_stats/0/max"), mode="r")[...])


@REMOTE_S3
def test_s3_errors_name_the_url(s3, monkeypatch, tmp_path):
    with pytest.raises(InputFormatError, match=r"^s3://scans/nothing\.zarr: not a zarr store"):
        open_store("s3://scans/nothing.zarr")
    for k in ("AWS_ACCESS_KEY_ID", "AWS_SECRET_ACCESS_KEY", "AWS_PROFILE", "AWS_SESSION_TOKEN"):
        monkeypatch.delenv(k, raising=False)
    monkeypatch.setenv("AWS_SHARED_CREDENTIALS_FILE", str(tmp_path / "none"))
    monkeypatch.setenv("AWS_CONFIG_FILE", str(tmp_path / "none"))
    with pytest.raises(RemoteStoreError, match=r"^s3://scans/cohort/s\.zarr: cannot read zarr\.json: no credentials"):
        open_store("s3://scans/cohort/s.zarr", retries=0)


@REMOTE_HTTP
def test_http_errors_are_one_line_naming_the_url(site):
    with serve_directory(site, forbid=("/s.zarr",)) as (url, srv):
        with pytest.raises(RemoteStoreError, match=r"s\.zarr: cannot read zarr\.json: permission denied \(HTTP 403\)") as ei:
            open_store(f"{url}/s.zarr")
        assert str(ei.value).startswith(url) and "\n" not in str(ei.value)
        assert srv.counts["/s.zarr/zarr.json"] == 1  # a 403 is not retried
    with serve_directory(site) as (url, srv):
        with pytest.raises(InputFormatError, match="not a zarr store"):
            open_store(f"{url}/")  # the directory above the store
    with serve_directory(site, fail_first=100) as (url, srv):  # a server that never recovers
        with pytest.raises(RemoteStoreError, match=r"HTTP 503 after 3 attempts"):
            open_store(f"{url}/s.zarr", retries=2)
        assert srv.counts["/s.zarr/zarr.json"] == 3
    # a closed port: nothing listens (the server above has shut down)
    with pytest.raises(RemoteStoreError, match=r"cannot read zarr\.json: cannot connect"):
        FsspecByteSource(f"{url}/s.zarr", retries=1, backoff=0.01).get("zarr.json")
    assert issubclass(RemoteStoreError, ClipvolError) and issubclass(RemoteStoreError, OSError)


@REMOTE_HTTP
def test_incomplete_remote_store_names_the_url(site, tmp_path):
    import json

    bad = tmp_path / "b"
    shutil.copytree(site / "s.zarr", bad / "s.zarr")
    meta = json.loads((bad / "s.zarr/zarr.json").read_text())
    meta["attributes"]["clipvol"]["complete"] = False
    (bad / "s.zarr/zarr.json").write_text(json.dumps(meta))
    with serve_directory(bad) as (url, srv):
        with pytest.raises(ClipvolError, match=rf"^{url}/s\.zarr: the store is incomplete") as ei:
            open_store(f"{url}/s.zarr")
        assert "clipvol-remote-meta" not in str(ei.value)


@REMOTE_HTTP
class TestRemoteZarrOverHttp(LoaderTests):
    """The loader conformance suite over HTTP (the server lives as long as the class)."""

    @pytest.fixture(scope="class")
    @classmethod
    def reference(cls):
        rng = np.random.default_rng(3)
        return (rng.random((36, 40, 44)) * 1000).astype(np.float32)

    @pytest.fixture(scope="class")
    @classmethod
    def loader(cls, reference, tmp_path_factory):
        root = tmp_path_factory.mktemp("conf")
        brick_volume(reference, root / "c.zarr", brick=16, progress=False, workers=1)
        with serve_directory(root) as (url, srv):
            yield open_store(f"{url}/c.zarr")


@REMOTE_HTTP
def test_credentials_in_a_url_never_reach_a_message(site):
    with serve_directory(site) as (url, srv):
        port = url.rsplit(":", 1)[1]
    with pytest.raises(RemoteStoreError) as ei:  # nothing listens there any more
        open_store(f"http://alice:s3cret@127.0.0.1:{port}/s.zarr", retries=0)
    assert "s3cret" not in str(ei.value) and f"http://***@127.0.0.1:{port}/s.zarr" in str(ei.value)
