"""An interrupted ``brick-points`` build resumes and ends with the store a clean build writes.

The reference is a clean, uninterrupted build of the same input in another folder, compared
array by array through zarr's own reader: node table, positions and values, point for point.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
import zarr

from clipvol.bricking import point_store
from clipvol.bricking.point_sources import ClusteredPointSource
from clipvol.bricking.point_store import NODE_ARRAYS, build_point_store, open_point_store
from clipvol.errors import StoreIncompleteError

KW = dict(max_points=16, memory_points=3000, progress=False)


def _arrays(path):
    g = zarr.open_group(str(path), mode="r")
    out = {f"nodes/{n}": np.asarray(g[f"nodes/{n}"][:]) for n in NODE_ARRAYS}
    out["points/xyz"] = np.asarray(g["points/xyz"][:])
    out["points/values"] = np.asarray(g["points/values"][:])
    return out, dict(g.attrs)["clipvol"]


def _assert_same_store(a, b):
    arrs_a, attrs_a = _arrays(a)
    arrs_b, attrs_b = _arrays(b)
    for name in arrs_a:
        np.testing.assert_array_equal(arrs_a[name], arrs_b[name], err_msg=name)
    attrs_a.pop("job"), attrs_b.pop("job")
    assert attrs_a == attrs_b


@pytest.fixture(scope="module")
def clean(tmp_path_factory):
    path = tmp_path_factory.mktemp("clean") / "p.zarr"
    build_point_store(ClusteredPointSource(40_000, seed=5), path, **KW)
    return path


def test_interrupted_build_resumes_to_the_clean_store(tmp_path, monkeypatch, clean):
    calls = []
    original = point_store._Build.in_memory

    def flaky(self, *a, **k):
        calls.append(1)
        if len(calls) == 9:
            raise KeyboardInterrupt  # Ctrl+C in the middle of the build
        return original(self, *a, **k)

    monkeypatch.setattr(point_store._Build, "in_memory", flaky)
    out = tmp_path / "p.zarr"
    with pytest.raises(KeyboardInterrupt):
        build_point_store(ClusteredPointSource(40_000, seed=5), out, **KW)
    assert (out / "_build_tmp" / "state.npz").is_file()
    with pytest.raises(StoreIncompleteError, match="did not finish"):
        open_point_store(out)
    done = int(np.load(out / "_build_tmp" / "state.npz")["done"])
    assert done >= 1
    calls.clear()
    monkeypatch.setattr(point_store._Build, "in_memory", lambda self, *a, **k: (calls.append(1), original(self, *a, **k))[1])
    meta = build_point_store(ClusteredPointSource(40_000, seed=5), out, **KW)  # no --overwrite: resumes
    resumed_calls = len(calls)
    calls.clear()
    build_point_store(ClusteredPointSource(40_000, seed=5), tmp_path / "again.zarr", **KW)
    assert resumed_calls < len(calls)  # the groups done before the interruption were not built again
    assert meta.complete and not (out / "_build_tmp").exists()
    _assert_same_store(out, clean)


def test_changed_input_or_parameters_start_again(tmp_path, monkeypatch):
    original = point_store._Build.in_memory
    n = []

    def flaky(self, *a, **k):
        n.append(1)
        if len(n) == 6:
            raise KeyboardInterrupt
        return original(self, *a, **k)

    out = tmp_path / "p.zarr"
    monkeypatch.setattr(point_store._Build, "in_memory", flaky)
    with pytest.raises(KeyboardInterrupt):
        build_point_store(ClusteredPointSource(20_000, seed=1), out, **KW)
    monkeypatch.setattr(point_store._Build, "in_memory", original)
    # other points, same count and name: the first chunk's hash differs, so nothing is reused
    build_point_store(ClusteredPointSource(20_000, seed=2), out, **KW)
    build_point_store(ClusteredPointSource(20_000, seed=2), tmp_path / "ref.zarr", **KW)
    _assert_same_store(out, tmp_path / "ref.zarr")


_CHILD = r"""
import sys
from clipvol.bricking.point_sources import ClusteredPointSource
from clipvol.bricking.point_store import build_point_store
build_point_store(ClusteredPointSource(40_000, seed=5), sys.argv[1], max_points=16, memory_points=3000, progress=False)
"""


def test_killed_build_resumes_to_the_clean_store(tmp_path, clean):
    """SIGKILL (no clean-up at all) once a checkpoint exists; the next run resumes."""
    out = tmp_path / "p.zarr"
    state = out / "_build_tmp" / "state.npz"
    proc = subprocess.Popen([sys.executable, "-c", _CHILD, str(out)], env={**os.environ, "PYTHONHASHSEED": "0"})
    try:
        for _ in range(600):  # at most 60 s
            if state.is_file() or proc.poll() is not None:
                break
            time.sleep(0.1)
        if proc.poll() is not None:
            pytest.skip("the build finished before it could be killed")
        os.kill(proc.pid, signal.SIGKILL)
    finally:
        proc.wait(timeout=30)
    assert not open_point_store(out, require_complete=False)[0].complete
    build_point_store(ClusteredPointSource(40_000, seed=5), out, **KW)
    _assert_same_store(out, clean)
