"""Time series: step t renders exactly as a store holding only step t, the prefetched next step
and the current one stay within one memory budget, and mismatched steps are refused."""

from __future__ import annotations

import numpy as np
import pytest
import zarr

from clipvol.errors import ParameterError

pytestmark = pytest.mark.gl


@pytest.fixture(scope="module")
def series(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("ts")
    n, T = 32, 3
    z, y, x = np.mgrid[:n, :n, :n].astype(np.float32)
    data = np.stack([np.exp(-((x - 8 - 7 * t) ** 2 + (y - 16) ** 2 + (z - 16) ** 2) / 40.0) for t in range(T)])
    data = data.astype(np.float32)
    root = tmp / "ts.zarr"
    g = zarr.open_group(str(root), mode="w")
    g.create_array("0", shape=data.shape, chunks=(1, 16, 16, 16), dtype="float32")[...] = data
    axes = [{"name": "t", "type": "time"}] + [{"name": a, "type": "space"} for a in "zyx"]
    g.attrs.update({"ome": {"version": "0.5", "multiscales": [{"axes": axes, "datasets": [
        {"path": "0", "coordinateTransformations": [{"type": "scale", "scale": [1, 1, 1, 1]}]}]}],
        "omero": {"channels": [{"window": {"min": 0.0, "max": 1.0}}]}}})
    return tmp, root, data


def _camera():
    from clipvol.scene.camera import Camera

    return Camera.perspective((15.5, 10.0, -45.0), (15.5, 15.5, 15.5), up=(0, 1, 0), fov_y=40.0, size=(64, 64))


def test_each_step_renders_as_a_store_of_that_step_alone(series, ctx):
    from clipvol.app.timeseries import TimeSeriesPlayer
    from clipvol.loaders.zarr_store import ZarrLoader
    from clipvol.loaders.numpy_array import NumpyLoader
    from clipvol.paging.cliptexture import ClipTexture
    from clipvol.render.action import ClipRenderAction
    from clipvol.scene.transfer import TransferFunction

    tmp, root, data = series
    tf = TransferFunction.preset("bone")
    cam = _camera()
    loaders = [ZarrLoader(root, t=k) for k in range(len(data))]
    with TimeSeriesPlayer(loaders, ctx, memory_budget="16MB", params=None) as player:
        player.set_center(cam.target)
        frames = []
        for k in range(len(data)):
            if k:
                player.advance()
            assert player.step == k
            frames.append(player.render(cam, tf, wait=True))
    for k, frame in enumerate(frames):
        alone = NumpyLoader(np.ascontiguousarray(data[k]), brick=16, value_range=(0.0, 1.0))
        with ClipTexture(alone, "16MB") as ct, ClipRenderAction(ctx, ct) as act:
            ref = act.render(cam, tf, wait=True)
        assert np.abs(frame.astype(int) - ref).max() <= 1, k
    assert np.abs(frames[0].astype(int) - frames[2]).max() > 20  # the steps really differ


def test_the_budget_holds_while_playing_and_the_next_step_is_prefetched(series, ctx):
    from clipvol.app.timeseries import TimeSeriesPlayer
    from clipvol.loaders.zarr_store import ZarrLoader
    from clipvol.scene.transfer import TransferFunction

    tmp, root, data = series
    budget = 4 << 20
    loaders = [ZarrLoader(root, t=k) for k in range(len(data))]
    cam = _camera()
    with TimeSeriesPlayer(loaders, ctx, memory_budget=budget) as player:
        player.set_center(cam.target)
        assert player.next is not None and player.next.wait_until_idle(timeout=30)
        assert player.prefetch_state == "ready"
        for _ in range(7):  # wraps around the series
            player.render(_camera(), TransferFunction.preset("bone"))
            assert player.resident_bytes <= budget
            player.advance()
            assert player.resident_bytes <= budget
    with TimeSeriesPlayer(loaders, ctx, memory_budget=budget, prefetch=False) as player:
        assert player.prefetch_state == "off" and player.next is None


def test_steps_of_another_geometry_are_refused(series, ctx, tmp_path):
    from clipvol.app.timeseries import TimeSeriesPlayer
    from clipvol.loaders.numpy_array import NumpyLoader
    from clipvol.loaders.zarr_store import ZarrLoader

    tmp, root, data = series
    other = NumpyLoader(np.zeros((16, 32, 32), np.float32), brick=16)
    with pytest.raises(ParameterError, match=r"loaders\[1\]"):
        TimeSeriesPlayer([ZarrLoader(root, t=0), other], ctx)
    with pytest.raises(ParameterError, match="loaders"):
        TimeSeriesPlayer([], ctx)
