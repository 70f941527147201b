"""Sort-last rendering: groups of bricks drawn apart and composited with (1, 1 - alpha) in
visibility order give the single-process frame within 1 LSB per channel (MIP: the maximum)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from clipvol.app.sortlast import DistributedRenderer
from clipvol.bricking.generators import parse_procedural
from clipvol.bricking.pipeline import brick_volume
from clipvol.paging.cliptexture import ClipTexture
from clipvol.paging.open import open_store
from clipvol.render.action import ClipRenderAction
from clipvol.scene.params import RenderParams
from clipvol.scene.transfer import TransferFunction
from clipvol.scene.views import view_camera

from optional import DASK

pytestmark = pytest.mark.gl

SIZE = (96, 80)


@pytest.fixture(scope="module")
def store(tmp_path_factory):
    path = tmp_path_factory.mktemp("sl") / "f.zarr"
    vol = parse_procedural("procedural:fractal?size=48").region(0, (0, 0, 0), (48, 48, 48)).astype(np.float32)
    brick_volume(vol, path, brick=16, progress=False, workers=1)
    return str(path)


def _single(ctx, store, params, cam, tf):
    loader = open_store(store)
    with ClipTexture(loader, "64MB") as clip, ClipRenderAction(ctx, clip, params) as act:
        img = act.render(cam, tf, wait=True)
        assert act.last_frame_stats.converged
        return img


def _close(a, b):
    d = np.abs(a.astype(int) - b.astype(int))
    return int(d.max())


def test_inline_groups_composite_to_the_single_frame(gl, store):
    tf = TransferFunction.preset("viridis")
    pyr = open_store(store).pyramid
    with DistributedRenderer(store, 3, scheduler="inline", memory_budget="64MB") as dr:
        for mode, view, bg in (("composite", "iso", (0, 0, 0, 0)), ("composite", "side", (0.2, 0.3, 0.4, 1.0)),
                               ("mip", "front", (0, 0, 0, 0))):
            params = RenderParams(mode=mode, background=bg)
            dr.set_params(params)
            cam = view_camera(pyr, view, SIZE)
            ref = _single(gl, store, params, cam, tf)
            got = dr.render(cam, tf)
            assert (ref[..., 3] > 0).sum() > 1000
            assert _close(got, ref) <= 1, (mode, view)
            assert sorted(dr.last_stats.order) == [0, 1, 2] and dr.last_stats.converged
        # a wrong order is visibly wrong: the check above can fail
        dr.set_params(RenderParams())
        cam = view_camera(pyr, "iso", SIZE)
        good = dr.render(cam, tf)
        import clipvol.app.sortlast as sl

        real = sl.back_to_front
        try:
            sl.back_to_front = lambda tree, camera: real(tree, camera)[::-1]
            wrong = dr.render(cam, tf)
        finally:
            sl.back_to_front = real
        assert _close(wrong, good) > 8


@pytest.mark.slow
def test_two_dask_worker_processes_give_the_single_frame(gl, store):
    tf = TransferFunction.preset("magma")
    pyr = open_store(store).pyramid
    params = RenderParams(lod_threshold=2.0)
    with DistributedRenderer(store, 2, params, scheduler="processes", memory_budget="64MB") as dr:
        for view in ("iso", "top"):
            cam = view_camera(pyr, view, SIZE)
            assert _close(dr.render(cam, tf), _single(gl, store, params, cam, tf)) <= 1
        dr.set_params(replace(params, mode="mip"))
        cam = view_camera(pyr, "iso", SIZE)
        assert _close(dr.render(cam, tf), _single(gl, store, replace(params, mode="mip"), cam, tf)) <= 1
        assert len(dr.last_stats.group_seconds) == 2


def test_render_cli_refuses_bad_worker_options(tmp_path, store, capsys):
    from clipvol.tools.cli import main

    out = str(tmp_path / "x.png")
    assert main(["render", store, "--out", out, "--workers", "0"]) == 2
    assert "--workers" in capsys.readouterr().err


@DASK
def test_render_cli_refuses_a_scheduler_beside_workers(tmp_path, store, capsys):
    from clipvol.tools.cli import main

    out = str(tmp_path / "x.png")
    assert main(["render", store, "--out", out, "--workers", "2", "--scheduler", "threads"]) == 2
    assert "--scheduler" in capsys.readouterr().err


@pytest.mark.slow
def test_render_cli_with_two_workers_equals_one(tmp_path, store):
    from PIL import Image

    from clipvol.tools.cli import main

    common = ["--size", "80x64", "--view", "side", "--tf", "grey"]
    assert main(["render", store, "--out", str(tmp_path / "one.png"), *common]) == 0
    assert main(["render", store, "--out", str(tmp_path / "two.png"), "--workers", "2", *common]) == 0
    one, two = (np.asarray(Image.open(tmp_path / n)) for n in ("one.png", "two.png"))
    assert _close(one, two) <= 1 and (one[..., 3] > 0).sum() > 500


def test_offscreen_flythrough_sort_last_frames_equal_single_renders(gl, store, tmp_path, capsys):
    """``clipvol view --offscreen --workers 2`` (inline scheduler: the groups drawn in this process;
    the view's flythrough samples with jitter, so the single-process reference does too)."""
    from PIL import Image

    from clipvol.scene.paths import make_path
    from clipvol.tools.cli import main

    out = tmp_path / "frames"
    assert main(["view", store, "--offscreen", "--workers", "2", "--scheduler", "inline", "--frames", "3",
                 "--size", "64x64", "--out", str(out), "--tf", "viridis"]) == 0
    assert "wrote 3 frames" in capsys.readouterr().out
    rows = (out / "frames.csv").read_text().splitlines()
    assert len(rows) == 4 and rows[0].startswith("frame,frame_s,composite_s,converged,order,group0_s,group1_s")
    assert all(r.split(",")[3] == "True" for r in rows[1:])
    pyr = open_store(store).pyramid
    tf = TransferFunction.preset("viridis")
    for k, (cam, _coi) in enumerate(make_path("orbit", pyr, 3, size=(64, 64))):
        got = np.asarray(Image.open(out / f"frame_{k:04d}.png"))
        assert _close(got, _single(gl, store, RenderParams(jitter=True), cam, tf)) <= 1, k


def test_view_workers_needs_offscreen(store, capsys):
    from clipvol.tools.cli import main

    assert main(["view", store, "--workers", "2"]) == 2
    assert "--offscreen" in capsys.readouterr().err
