"""A remote read has a deadline for its whole answer, and a command's ``--timeout`` bounds it all.

A server that sends a chunk one byte a second never trips a per-read (socket) timeout; requests
queued behind such reads waited for a free slot without limit. With a ``deadline`` no request waits
for a slot, starts or goes on past it. The CLI: a render of a store whose chunks drip ends at its
``--timeout`` with one clean line and exit 3 (it once took 97 s, and 29 s with ``--timeout 20``
and a raw ``RuntimeWarning``). References: the server's own log of what it was asked, the clock
(bounds generous against the limits asked, tiny against the old behaviour's minutes).
"""

from __future__ import annotations

import time

import numpy as np
import pytest

from clipvol.bricking.pipeline import brick_volume
from clipvol.errors import RemoteStoreError
from clipvol.paging.bytesource import FsspecByteSource
from clipvol.tools.cli import main

from bounded_call import bounded
from optional import REMOTE_HTTP
from remote_servers import serve_directory

pytestmark = REMOTE_HTTP


@pytest.fixture(scope="module")
def site(tmp_path_factory):
    root = tmp_path_factory.mktemp("site")
    vol = (np.random.default_rng(2).random((32, 32, 32)) * 1000).astype(np.uint16)
    brick_volume(vol, root / "s.zarr", brick=16, progress=False, workers=1, summary=False)
    return root


def test_a_dripping_chunk_is_given_up_at_the_deadline_naming_it(site):
    with serve_directory(site, drip=("/s.zarr/0/c/",)) as (url, srv):
        src = FsspecByteSource(f"{url}/s.zarr", timeout=600, read_timeout=600, deadline=time.monotonic() + 1.5)
        t0 = time.monotonic()
        err, _ = bounded(lambda: src.get("0/c/0/0/0"), 30, "a dripping chunk held the read past its deadline")
        spent = time.monotonic() - t0
        assert isinstance(err, RemoteStoreError) and "time limit ran out" in str(err) and "0/c/0/0/0" in str(err)
        assert spent < 10  # the old read waited for the per-key budget (600 s here)
        # past the deadline nothing is asked of the server at all
        asked = sum(srv.counts.values())
        err, _ = bounded(lambda: src.get("zarr.json"), 10)
        assert isinstance(err, RemoteStoreError) and "time limit ran out" in str(err)
        assert sum(srv.counts.values()) == asked


def test_a_request_queued_behind_dripping_reads_does_not_wait_past_the_deadline(site):
    with serve_directory(site, drip=("/s.zarr/0/c/",)) as (url, srv):
        src = FsspecByteSource(f"{url}/s.zarr", max_in_flight=1, timeout=600, read_timeout=600,
                               deadline=time.monotonic() + 2.0)
        import threading

        threading.Thread(target=lambda: bounded(lambda: src.get("0/c/0/0/0"), 30), daemon=True).start()
        while not srv.counts:  # the dripping read holds the only slot
            time.sleep(0.01)
        t0 = time.monotonic()
        err, _ = bounded(lambda: src.get("zarr.json"), 30, "a queued request waited past the deadline")
        assert isinstance(err, RemoteStoreError) and "time limit ran out" in str(err)
        assert time.monotonic() - t0 < 10


def test_render_of_a_dripping_store_ends_at_its_timeout_with_one_clean_line(site, tmp_path, capsys):
    with serve_directory(site, drip=("/s.zarr/0/c/",)) as (url, srv):
        out = tmp_path / "d.png"
        t0 = time.monotonic()
        err, rc = bounded(lambda: main(["render", f"{url}/s.zarr", "--out", str(out), "--size", "24x24", "--level", "0",
                                        "--policy", "fixed", "--timeout", "2"]), 120, "the render did not end")
        spent = time.monotonic() - t0
    assert err is None and rc == 3
    cap = capsys.readouterr()
    assert "Traceback" not in cap.err and "RuntimeWarning" not in cap.err and "warnings.warn" not in cap.err
    assert "--timeout" in cap.err and not out.exists()
    assert spent < 20  # 2 s asked: the old command took 31 s per dripping read, several in a row
