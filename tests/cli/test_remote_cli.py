"""The CLI over remote stores: ``clipvol render`` of a store in a (moto) S3 bucket and behind a
slow, flaky HTTP server draws the same PNG as from local disk; bad URLs exit 2 with one line."""

from __future__ import annotations

import numpy as np
import pytest
from PIL import Image

from clipvol.bricking.pipeline import brick_volume
from clipvol.bricking.generators import parse_procedural
from clipvol.tools.cli import main

from optional import REMOTE_HTTP, REMOTE_S3
from remote_servers import moto_s3, serve_directory, upload_directory

RENDER = ["--size", "96x80", "--view", "iso", "--tf", "viridis", "--memory-budget", "32MB"]


@pytest.fixture(scope="module")
def site(tmp_path_factory):
    root = tmp_path_factory.mktemp("clisite")
    vol = parse_procedural("procedural:fractal?size=48").region(0, (0, 0, 0), (48, 48, 48)).astype(np.float32)
    brick_volume(vol, root / "f.zarr", brick=16, progress=False, workers=1)
    return root


def _render(source, out, *extra) -> np.ndarray:
    assert main(["render", str(source), "--out", str(out), *RENDER, *extra]) == 0
    return np.asarray(Image.open(out))


@pytest.mark.slow
@REMOTE_S3
@pytest.mark.gl
def test_render_from_s3_equals_local(site, tmp_path):
    local = _render(site / "f.zarr", tmp_path / "local.png")
    assert (local[..., 3] > 0).sum() > 500  # something was drawn
    with moto_s3() as endpoint:
        upload_directory(endpoint, site / "f.zarr", "bucket", "f.zarr")
        s3 = _render("s3://bucket/f.zarr", tmp_path / "s3.png")
    np.testing.assert_array_equal(s3, local)


@REMOTE_HTTP
@pytest.mark.gl
def test_render_from_slow_flaky_http_with_cache_equals_local(site, tmp_path):
    local = _render(site / "f.zarr", tmp_path / "local.png")
    with serve_directory(site, latency=0.005, fail_first=1) as (url, srv):
        http = _render(f"{url}/f.zarr", tmp_path / "http.png", "--cache", str(tmp_path / "cache"), "--in-flight", "6")
        assert srv.failures > 0
    np.testing.assert_array_equal(http, local)
    assert any((tmp_path / "cache").rglob("c/*"))


@REMOTE_HTTP
def test_bad_remote_sources_exit_2_with_one_line(site, tmp_path, capsys):
    out = str(tmp_path / "x.png")
    with serve_directory(site, forbid=("/f.zarr",)) as (url, srv):
        cases = [(f"{url}/f.zarr", "permission denied (HTTP 403)"), (f"{url}/nothing.zarr", "not a zarr store")]
        for source, what in cases:
            assert main(["render", source, "--out", out]) == 2
            err = capsys.readouterr().err
            assert err.count("\n") == 1 and source in err and what in err and "Traceback" not in err, err
    assert main(["render", f"{url}/f.zarr", "--out", out]) == 2  # the server is gone: unreachable
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"{url}/f.zarr" in err and "cannot connect" in err, err
    # remote options on a local source are refused, naming the option
    assert main(["render", str(site / "f.zarr"), "--out", out, "--cache", str(tmp_path)]) == 2
    assert "--cache" in capsys.readouterr().err


@REMOTE_S3
@pytest.mark.slow
def test_info_and_check_over_s3_and_http(site, capsys):
    with moto_s3() as endpoint:
        upload_directory(endpoint, site / "f.zarr", "bucket", "f.zarr")
        assert main(["info", "s3://bucket/f.zarr"]) == 0
        out = capsys.readouterr().out
        assert "store      s3://bucket/f.zarr" in out and "complete   yes" in out
        # level 0's row: the chunk objects S3 lists are the chunk files on local disk
        files = [p for p in (site / "f.zarr/0/c").rglob("*") if p.is_file()]
        row = next(line for line in out.splitlines() if line.split()[:1] == ["0"])
        assert row.split()[4] == str(len(files)), row
        assert main(["check", "s3://bucket/f.zarr", "--samples", "3"]) == 0
        assert "ok (" in capsys.readouterr().out
    with serve_directory(site) as (url, srv):
        assert main(["info", f"{url}/f.zarr"]) == 0
        out = capsys.readouterr().out
        assert "complete   yes" in out and "bytes stored unknown" in out  # HTTP cannot list: no made-up zero
        assert main(["check", f"{url}/f.zarr", "--samples", "2"]) == 0
        assert "ok (" in capsys.readouterr().out
