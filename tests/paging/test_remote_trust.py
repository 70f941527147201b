"""A remote store is trusted no more than a local one, and a remote failure is never kept or
reported as corruption: a 404 or an HTML error page is never cached, a 404 on the manifest makes
the store unverified and a 404 on the statistics never makes bricks look empty, a stalled server
is given up on within its time budget, and 401/403 say "permission denied".

Servers are real sockets on 127.0.0.1 (``tests/remote_servers.py``); the references are the
source array (numpy) and the chunk files on disk.
"""

from __future__ import annotations


import numpy as np
import pytest

from clipvol.bricking.pipeline import brick_volume
from clipvol.errors import BrickIntegrityError, ParameterError, RemoteStoreError, StoreFormatError
from clipvol.loaders.zarr_store import UnverifiedStoreWarning
from clipvol.paging.bytesource import FsspecByteSource
from clipvol.paging.open import open_store
from clipvol.tools.cli import main

from bounded_call import bounded
from optional import REMOTE_HTTP
from remote_servers import serve_directory

pytestmark = REMOTE_HTTP

B = 16


@pytest.fixture(scope="module")
def vol():
    rng = np.random.default_rng(3)
    v = (rng.random((32, 48, 32)) * 4000 + 1).astype(np.uint16)
    v[:16, :16] = 0  # empty bricks: no chunks
    return v


@pytest.fixture(scope="module")
def site(tmp_path_factory, vol):
    root = tmp_path_factory.mktemp("trustsite")
    brick_volume(vol, root / "s.zarr", brick=B, progress=False, workers=1)
    return root


def _ref(vol, idx):
    return vol[idx[0] * B:(idx[0] + 1) * B, idx[1] * B:(idx[1] + 1) * B, idx[2] * B:(idx[2] + 1) * B]


def _bounded(fn, seconds=90):
    return bounded(fn, seconds)


def test_the_cache_never_keeps_a_404_or_an_html_page(site, vol, tmp_path):
    cache = tmp_path / "cache"
    bad = {"/s.zarr/0/c/1/1/1": (404, b""), "/s.zarr/0/c/1/2/0": (200, b"<html><body>Service moved</body></html>")}
    with serve_directory(site, answers=bad) as (url, srv):
        first = open_store(f"{url}/s.zarr", cache=cache)
        with pytest.raises(BrickIntegrityError, match=r"0/c/1/1/1 is missing"):
            first.read_brick(0, (1, 1, 1))
        with pytest.raises(BrickIntegrityError, match=r"0/c/1/2/0"):
            first.read_brick(0, (1, 2, 0))
        np.testing.assert_array_equal(first.read_brick(0, (1, 0, 0)), _ref(vol, (1, 0, 0)))
        cached = sorted(p.relative_to(cache).as_posix().split("/", 1)[1] for p in cache.rglob("*") if p.is_file())
        assert cached == ["data/0/c/1/0/0"]  # only the verified chunk; no 404 marker, no HTML, no metadata
        srv.answers.clear()  # the server recovers: the next session reads the truth, not the cache's failures
        second = open_store(f"{url}/s.zarr", cache=cache)
        for idx in ((1, 1, 1), (1, 2, 0), (1, 0, 0)):
            np.testing.assert_array_equal(second.read_brick(0, idx), _ref(vol, idx))
        assert srv.counts["/s.zarr/0/c/1/0/0"] == 1  # that one came from the cache


def test_cached_bytes_that_fail_are_dropped_and_fetched_again(site, vol, tmp_path):
    cache = tmp_path / "cache"
    with serve_directory(site) as (url, srv):
        open_store(f"{url}/s.zarr", cache=cache).read_brick(0, (1, 1, 1))
        (kept,) = [p for p in cache.rglob("1/1/1") if p.is_file()]
        kept.write_bytes((site / "s.zarr" / "0" / "c" / "1" / "0" / "0").read_bytes())  # another brick's chunk
        np.testing.assert_array_equal(open_store(f"{url}/s.zarr", cache=cache).read_brick(0, (1, 1, 1)), _ref(vol, (1, 1, 1)))
        assert srv.counts["/s.zarr/0/c/1/1/1"] == 2
        assert kept.read_bytes() == (site / "s.zarr" / "0" / "c" / "1" / "1" / "1").read_bytes()


def test_a_404_on_the_manifest_makes_the_store_unverified(site, tmp_path):
    with serve_directory(site, answers={"/s.zarr/clipvol_manifest/manifest.json": (404, b"")}) as (url, srv):
        with pytest.warns(UnverifiedStoreWarning, match="manifest.json is missing"):
            loader = open_store(f"{url}/s.zarr")
        assert not loader.verified
        assert main(["check", f"{url}/s.zarr", "--samples", "2"]) == 1


def test_a_404_on_the_statistics_never_makes_bricks_empty(site, vol, tmp_path):
    gone = {f"/s.zarr/clipvol_stats/0/{name}/c/1/0/0": (404, b"") for name in ("min", "max")}
    with serve_directory(site, answers=gone) as (url, srv):
        loader = open_store(f"{url}/s.zarr")
        assert loader.verified
        idx = np.array([[1, 0, 0], [1, 2, 1], [0, 0, 0]])
        ref = [[_ref(vol, tuple(i)).min(), _ref(vol, tuple(i)).max()] for i in idx]
        np.testing.assert_array_equal(loader.brick_ranges(0, idx), ref)
        with pytest.raises(StoreFormatError, match=r"clipvol_stats/0/(max|min) differs from the manifest"):
            loader.brick_statistics(0)
        np.testing.assert_array_equal(loader.read_brick(0, (1, 2, 1)), _ref(vol, (1, 2, 1)))


def test_a_stalled_server_is_given_up_on_within_the_budget(site):
    with serve_directory(site, stall=("/s.zarr/",)) as (url, srv):
        e, _ = _bounded(lambda: open_store(f"{url}/s.zarr", connect_timeout=1, read_timeout=0.5, timeout=2, retries=5))
        assert isinstance(e, RemoteStoreError) and "cannot read zarr.json: timed out" in str(e), e
        assert srv.counts["/s.zarr/zarr.json"] <= 3  # no six full waits: retries stop at the budget


def test_a_stalled_info_exits_2_with_one_line(site, capsys):
    with serve_directory(site, stall=("/s.zarr/",)) as (url, srv):
        e, rc = _bounded(lambda: main(["info", f"{url}/s.zarr", "--read-timeout", "0.5", "--connect-timeout", "1"]))
    assert e is None and rc == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "timed out" in err, err


def test_forbidden_chunks_are_permission_denied_not_corruption(site, capsys):
    with serve_directory(site, forbid=("/s.zarr/0/c/",)) as (url, srv):
        with pytest.raises(RemoteStoreError, match=r"0/c/1/1/1: permission denied \(HTTP 403\)"):
            open_store(f"{url}/s.zarr").read_brick(0, (1, 1, 1))
        capsys.readouterr()
        assert main(["check", f"{url}/s.zarr", "--all", "--quiet"]) == 2
        err = capsys.readouterr().err
        assert "permission denied (HTTP 403)" in err and "repair" not in err and "bad" not in err, err


@pytest.mark.parametrize("kw", [{"timeout": -1}, {"connect_timeout": 0}, {"read_timeout": float("nan")},
                                {"read_timeout": 1e9}])
def test_absurd_time_outs_are_refused_naming_them(kw):
    name = next(iter(kw))
    with pytest.raises(ParameterError, match=name):
        FsspecByteSource("http://127.0.0.1:9/s.zarr", **kw)


def test_absurd_time_outs_on_the_command_line_exit_2(site, tmp_path, capsys):
    out = str(tmp_path / "x.png")
    for argv, what in ((["render", str(site / "s.zarr"), "--out", out, "--timeout", "-1"], "--timeout"),
                       (["render", "http://127.0.0.1:9/s.zarr", "--out", out, "--read-timeout", "0"], "--read-timeout"),
                       (["info", "http://127.0.0.1:9/s.zarr", "--connect-timeout", "inf"], "--connect-timeout"),
                       (["info", str(site / "s.zarr"), "--read-timeout", "5"], "--read-timeout")):
        assert main(argv) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and what in err, err
