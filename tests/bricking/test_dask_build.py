"""Bricking on Dask: the store is byte-identical to the local threaded build (every chunk file,
every statistics chunk, the metadata), its levels are the reference filter's, workers read the
input themselves, and an interrupted build resumes."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import zarr

pytest.importorskip("distributed")

from clipvol.bricking.dask_build import brick_volume_dask  # noqa: E402
from clipvol.bricking.pipeline import brick_volume  # noqa: E402
from clipvol.bricking.source_types import ArraySource  # noqa: E402
from clipvol.errors import ParameterError  # noqa: E402
from clipvol.tools.cli import main  # noqa: E402

from test_pyramid import ref_downsample  # noqa: E402
from build_hooks import after_each_brick  # noqa: E402


def _tree(path: Path) -> dict[str, bytes]:
    return {p.relative_to(path).as_posix(): p.read_bytes() for p in sorted(path.rglob("*")) if p.is_file()}


def _volume(shape=(70, 45, 90), dtype=np.uint16, seed=1) -> np.ndarray:
    rng = np.random.default_rng(seed)
    vol = (rng.random(shape) * 60000).astype(dtype)
    vol[:20] = 0  # empty bricks: not written by either path
    return vol


@pytest.mark.parametrize("span", [pytest.param(s, marks=pytest.mark.slow) if s < 3 else s for s in (1, 2, 3)])
def test_threads_build_is_byte_identical_to_local(tmp_path, span):
    vol = _volume()
    np.save(tmp_path / "v.npy", vol)
    brick_volume(tmp_path / "v.npy", tmp_path / "local" / "s.zarr", brick=16, progress=False, workers=2)
    meta = brick_volume_dask(tmp_path / "v.npy", tmp_path / "dask" / "s.zarr", brick=16, progress=False,
                             workers=2, span=span, scheduler="threads")
    assert meta.complete and meta.pyramid.num_levels == 4
    local, dask = _tree(tmp_path / "local" / "s.zarr"), _tree(tmp_path / "dask" / "s.zarr")
    assert len(local) > 100 and sorted(local) == sorted(dask)
    assert [k for k in local if local[k] != dask[k]] == []
    # and independently of the local path: level L is the reference mean of level L-1 (zarr reads)
    ref = vol
    for L in range(meta.pyramid.num_levels):
        got = zarr.open_array(str(tmp_path / "dask" / "s.zarr" / str(L)), mode="r")[...]
        np.testing.assert_array_equal(got, ref)
        ref = ref_downsample(ref, "mean")


def test_float_max_filter_odd_shape(tmp_path):
    rng = np.random.default_rng(5)
    vol = rng.normal(size=(33, 17, 40)).astype(np.float32)
    vol[3, 4, 5] = np.nan
    np.save(tmp_path / "v.npy", vol)
    brick_volume(tmp_path / "v.npy", tmp_path / "a" / "s.zarr", brick=8, filter="max", progress=False, workers=1)
    brick_volume_dask(tmp_path / "v.npy", tmp_path / "b" / "s.zarr", brick=8, filter="max", progress=False,
                      workers=2, span=2)
    assert _tree(tmp_path / "a" / "s.zarr") == _tree(tmp_path / "b" / "s.zarr")


def test_one_options_value_builds_the_same_store_both_ways(tmp_path):
    """One frozen BuildOptions (with an origin) given to the local and the Dask build: the same bytes,
    and the OME translation is the origin given (read back from zarr.json, not through clipvol)."""
    from clipvol.bricking.build_options import BuildOptions

    vol = _volume((24, 20, 28), np.uint8, seed=3)
    opts = BuildOptions(brick=8, codec="zstd", spacing=(2.0, 1.0, 1.0), origin=(-4.0, 2.0, 3.0), workers=2,
                        progress=False)
    brick_volume(vol, tmp_path / "a" / "s.zarr", opts)
    brick_volume_dask(vol, tmp_path / "b" / "s.zarr", opts, span=2)
    a, b = _tree(tmp_path / "a" / "s.zarr"), _tree(tmp_path / "b" / "s.zarr")
    assert len(a) > 10 and a == b
    scales = json.loads(a["zarr.json"])["attributes"]["ome"]["multiscales"][0]["datasets"][0]["coordinateTransformations"]
    assert [t["translation"] for t in scales if t["type"] == "translation"] == [[-4.0, 2.0, 3.0]]


_READS_LEFT = [0]


class _Flaky(ArraySource):
    """An in-memory input whose reads fail once ``_READS_LEFT`` runs out (a worker losing its
    input). The counter is module state, shared by the copies Dask makes of the task arguments
    (the threads scheduler runs them in this process)."""

    def __init__(self, array) -> None:
        super().__init__(array, name="flaky")

    def _read(self, start, stop):
        _READS_LEFT[0] -= 1
        if _READS_LEFT[0] < 0:
            raise OSError("input went away")
        return super()._read(start, stop)


def test_interrupted_dask_build_resumes_to_the_same_store(tmp_path):
    vol = _volume((64, 32, 48), seed=3)
    brick_volume(ArraySource(vol, name="flaky"), tmp_path / "ref" / "s.zarr", brick=8, progress=False, workers=1)
    out = tmp_path / "run" / "s.zarr"
    # the job's source identity samples the input, the value-range scan reads 1 slab, then 9 of the
    # 24 tier-0 regions (6 per z-row) succeed
    from clipvol.bricking.sources import source_identity

    _READS_LEFT[0] = 10**6
    source_identity(_Flaky(vol))
    _READS_LEFT[0] = 10 + (10**6 - _READS_LEFT[0])
    with pytest.raises(OSError, match="input went away"):
        brick_volume_dask(_Flaky(vol), out, brick=8, progress=False, workers=1, span=2)
    attrs = json.loads((out / "zarr.json").read_text())["attributes"]
    assert attrs["clipvol"]["complete"] is False
    assert zarr.open_array(str(out / "clipvol_stats/0/done"), mode="r")[...].any()  # some rows were finished
    _READS_LEFT[0] = 10**6
    brick_volume_dask(_Flaky(vol), out, brick=8, progress=False, workers=1, span=2)
    assert _tree(out) == _tree(tmp_path / "ref" / "s.zarr")


def test_local_build_interrupted_resumes_on_dask(tmp_path, monkeypatch):
    vol = _volume((48, 24, 40), seed=4)
    np.save(tmp_path / "v.npy", vol)
    brick_volume(tmp_path / "v.npy", tmp_path / "ref" / "s.zarr", brick=8, progress=False, workers=1)
    out = tmp_path / "run" / "s.zarr"
    seen = []

    def crash(level, index):
        seen.append(level)
        if len(seen) >= 40:
            raise RuntimeError("simulated crash")

    after_each_brick(monkeypatch, crash)
    with pytest.raises(RuntimeError):
        brick_volume(tmp_path / "v.npy", out, brick=8, progress=False, workers=1)
    after_each_brick(monkeypatch, None)
    assert main(["brick", str(tmp_path / "v.npy"), str(out), "--brick", "8", "--scheduler", "threads", "--quiet"]) == 0
    assert _tree(out) == _tree(tmp_path / "ref" / "s.zarr")


def test_bad_scheduler_is_refused(tmp_path, capsys):
    np.save(tmp_path / "v.npy", _volume((16, 16, 16)))
    with pytest.raises(ParameterError, match="--scheduler"):
        brick_volume_dask(tmp_path / "v.npy", tmp_path / "s.zarr", brick=8, scheduler="gpu", progress=False)
    assert not (tmp_path / "s.zarr" / "zarr.json").exists() or not json.loads(
        (tmp_path / "s.zarr" / "zarr.json").read_text())["attributes"]["clipvol"]["complete"]
    assert main(["brick", str(tmp_path / "v.npy"), str(tmp_path / "t.zarr"), "--brick", "8", "--scheduler", "nope"]) == 2
    assert "--scheduler" in capsys.readouterr().err


@pytest.mark.slow
def test_local_cluster_over_tcp_reads_zarr_input_in_the_workers(tmp_path, capsys):
    """A dask.distributed LocalCluster of 2 worker processes, reached by its tcp:// address, bricks a
    zarr input that each worker opens itself; the store equals the local build's."""
    from distributed import LocalCluster

    vol = _volume((64, 40, 72), seed=2)
    src = zarr.open_array(str(tmp_path / "in.zarr"), mode="w", shape=vol.shape, chunks=(16, 40, 72), dtype=vol.dtype)
    src[...] = vol
    brick_volume(tmp_path / "in.zarr", tmp_path / "a" / "s.zarr", brick=16, progress=False, workers=2)
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1", dashboard_address="127.0.0.1:0",
                      worker_dashboard_address="127.0.0.1:0") as cluster:
        rc = main(["brick", str(tmp_path / "in.zarr"), str(tmp_path / "b" / "s.zarr"), "--brick", "16",
                   "--scheduler", cluster.scheduler_address])
    assert rc == 0
    assert "Dask dashboard" in capsys.readouterr().err
    assert _tree(tmp_path / "a" / "s.zarr") == _tree(tmp_path / "b" / "s.zarr")


@pytest.mark.slow
def test_a_worker_killed_mid_build_still_gives_the_same_store(tmp_path):
    """A worker process is killed while the build runs: Dask re-runs its tasks on the restarted
    worker (chunk writes are idempotent) and the store is still byte-identical."""
    import threading
    import time

    from distributed import Client, LocalCluster

    vol = _volume((64, 64, 64), seed=6)
    np.save(tmp_path / "v.npy", vol)
    brick_volume(tmp_path / "v.npy", tmp_path / "a" / "s.zarr", brick=8, progress=False, workers=2)
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1", dashboard_address="127.0.0.1:0",
                      worker_dashboard_address="127.0.0.1:0") as cluster, Client(cluster) as client:
        client.run(lambda: __import__("clipvol.bricking.dask_build"))
        killed = []

        def kill_one():
            import psutil

            rows = tmp_path / "b" / "s.zarr" / "0" / "c"
            for _ in range(400):  # until the first chunks appear, then kill a worker
                if rows.exists() and any(rows.iterdir()):
                    break
                threading.Event().wait(0.02)
            pid = next(iter(client.run(__import__("os").getpid).values()))
            psutil.Process(pid).kill()
            killed.append(time.monotonic())

        t = threading.Thread(target=kill_one)
        t.start()
        brick_volume_dask(tmp_path / "v.npy", tmp_path / "b" / "s.zarr", brick=8, span=1, progress=False, client=client)
        finished = time.monotonic()
        t.join()
    assert killed and killed[0] < finished  # the worker died while the build ran
    assert _tree(tmp_path / "a" / "s.zarr") == _tree(tmp_path / "b" / "s.zarr")


@pytest.mark.slow
def test_chunked_hdf5_and_nifti_inputs_give_the_local_store(tmp_path):
    """Inputs the workers open themselves by path: a chunked HDF5 dataset (h5py) and a NIfTI file
    with its own spacing and world frame (nibabel) - same store as the local build."""
    h5py = pytest.importorskip("h5py")
    nib = pytest.importorskip("nibabel")
    vol = _volume((40, 36, 44), seed=8)
    with h5py.File(tmp_path / "v.h5", "w") as f:
        f.create_dataset("scan", data=vol, chunks=(8, 36, 44))
    affine = np.diag([0.5, 0.75, 2.0, 1.0])
    affine[:3, 3] = (10.0, -4.0, 3.0)
    nib.save(nib.Nifti1Image(np.ascontiguousarray(vol.transpose(2, 1, 0)), affine), tmp_path / "v.nii.gz")
    for name in ("v.h5:/scan", "v.nii.gz"):
        src = f"{tmp_path}/{name}"
        brick_volume(src, tmp_path / "a" / name.split(".")[1][:3] / "s.zarr", brick=8, progress=False, workers=1)
        brick_volume_dask(src, tmp_path / "b" / name.split(".")[1][:3] / "s.zarr", brick=8, span=2, progress=False,
                          workers=2)
        a, b = (_tree(tmp_path / d / name.split(".")[1][:3] / "s.zarr") for d in ("a", "b"))
        assert len(a) > 50 and a == b, name
