"""Stability matrix, load: 10,000 random moves of the centre of interest, with teleports, against a
16 MB budget on a 64 MB (level 0) procedural volume.

Each move is ``ClipTexture.set_center`` (evictions, slot reuse, queue re-sort while two loader
threads keep loading) plus, on every ``SELECT_EVERY``-th move and after every teleport, a selection
against the clip-texture's residency (the render action's per-frame query). Asserted: the budget is
never exceeded (the slot pool is allocated once, and the resident bytes are sampled during the
run), the run ends in bounded time (a watchdog: a deadlock fails the test instead of hanging it),
every resident brick then holds exactly the loader's data, and the final converged render equals
a converged render of the same view from a fresh clip-texture.

``CLIPVOL_STABILITY_FULL=1`` selects on every move (about 10 ms each on this 2-core machine, so
~2 minutes; the default keeps the suite fast).
"""

from __future__ import annotations

import os
import threading
import time

import numpy as np
import pytest

from clipvol.scene.camera import Camera
from clipvol.paging.cliptexture import BrickState, ClipTexture
from clipvol.loaders.procedural import ProceduralLoader
from clipvol.scene.params import RenderParams
from clipvol.scene.selection import select
from clipvol.scene.transfer import TransferFunction
from render_helpers import render_converged

MOVES = 10_000
SELECT_EVERY = 1 if os.environ.get("CLIPVOL_STABILITY_FULL") else 20
BUDGET = 16 * 2**20
URL = "procedural:fractal?size=256&seed=5"
TF = TransferFunction.from_points([(0.0, (0, 0, 1, 0.0)), (0.5, (0, 1, 0, 0.04)), (1.0, (1, 0, 0, 0.3))])


def camera_for(center, size=(48, 48)) -> Camera:
    c = np.asarray(center, dtype=np.float64)
    return Camera.perspective(c - np.array([20.0, 30.0, 60.0]), c, up=(0, -1, 0), fov_y=50, size=size)


def _roam(clip: ClipTexture, pyr, rng, log: dict) -> None:
    lo, hi = pyr.volume_box()
    c = (lo + hi) / 2
    params = RenderParams(lod_threshold=4.0)
    for i in range(MOVES):
        teleport = rng.random() < 0.03
        if teleport:
            c = rng.uniform(lo, hi)
            log["teleports"] += 1
        else:
            c = np.clip(c + rng.normal(0.0, 3.0, 3), lo, hi)
        clip.set_center(c)
        if teleport or i % SELECT_EVERY == 0:
            sel = select(pyr, camera_for(c, (16, 16)), params, residency=clip)
            log["selections"] += 1
            log["items"] += len(sel.items)
        if i % 16 == 0:
            rb = clip.stats.resident_bytes
            log["max_resident"] = max(log["max_resident"], rb)
    log["final_center"] = c


@pytest.mark.slow  # a soak of random roaming (15 s on 2 cores); `pytest -m slow` runs it
def test_random_roaming_with_teleports(ctx):
    loader = ProceduralLoader(URL, brick=32)
    pyr = loader.pyramid
    level0 = int(np.prod(pyr.shape)) * pyr.dtype.itemsize
    assert level0 >= 4 * BUDGET  # the data does not fit: windows must move and evict
    rng = np.random.default_rng(2024)
    log = dict(teleports=0, selections=0, items=0, max_resident=0, error=None)
    clip = ClipTexture(loader, BUDGET, threads=2)
    try:
        st0 = clip.stats
        assert st0.pool_bytes <= BUDGET

        def body():
            try:
                _roam(clip, pyr, rng, log)
            except BaseException as e:  # reported below
                log["error"] = e

        worker = threading.Thread(target=body, name="stability-roam", daemon=True)
        t0 = time.monotonic()
        worker.start()
        worker.join(timeout=600)
        assert not worker.is_alive(), "roaming did not finish in 600 s: deadlock?"
        assert log["error"] is None, repr(log["error"])
        assert log["teleports"] > 100 and log["selections"] >= MOVES // SELECT_EVERY and log["items"] > 0
        assert 0 < log["max_resident"] <= BUDGET
        st = clip.stats
        assert st.pool_bytes == st0.pool_bytes <= BUDGET  # allocated once, never grown
        assert st.resident_bytes <= BUDGET and st.failures == 0
        assert st.loads_total > 0 and st.dropped >= 0
        assert clip.wait_until_idle(timeout=120), "the queue did not drain"
        # every resident brick holds exactly the loader's data (a sample of them)
        res = clip.resident_bricks()
        assert res
        pick = rng.choice(len(res), size=min(48, len(res)), replace=False)
        for k in pick:
            L, idx = res[k]
            np.testing.assert_array_equal(clip.get_brick(L, idx), loader.read_brick(L, idx))
            assert clip.state(L, idx) == BrickState.RESIDENT
        elapsed = time.monotonic() - t0
        assert elapsed < 600
        final_center = log["final_center"]
        _compare_final_render(ctx, clip, loader, final_center)
    finally:
        assert clip.close(timeout=10)
    assert not any(t.is_alive() for t in clip._threads)


def _compare_final_render(ctx, clip, loader, center) -> None:
    from clipvol.render.action import ClipRenderAction

    cam = camera_for(center)
    images = []
    for c in (clip, ClipTexture(loader, BUDGET, threads=2, center=center)):
        action = ClipRenderAction(ctx, c, texture_budget="64MB", lod_threshold=2.0)
        try:
            images.append(render_converged(action, cam, TF))
        finally:
            action.close()
            if c is not clip:
                c.close()
    assert images[0][..., 3].max() > 0
    d = np.abs(images[0].astype(int) - images[1].astype(int))
    assert d.max() <= 1, f"roamed vs fresh clip-texture: max diff {d.max()}"
    assert ctx.error == "GL_NO_ERROR"
