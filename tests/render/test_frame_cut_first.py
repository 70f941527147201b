"""A frame drawn without waiting asks for its cut's missing bricks first (clipvol.render.frame_loop,
"Cut first"): on a cold clip-texture whose one loader thread is held, the bricks read after one
non-waiting frame are the bricks the converged cut of that camera wants, before the rest of the
window that the queue would read nearest the centre first."""

from __future__ import annotations

import threading

import numpy as np
import pytest

from clipvol.loaders.numpy_array import NumpyLoader
from clipvol.paging.cliptexture import ClipTexture
from clipvol.render.action import ClipRenderAction
from clipvol.scene.camera import Camera
from clipvol.scene.transfer import TransferFunction

from counting_loader import ReadThrough

pytestmark = pytest.mark.gl


class OrderLoader(ReadThrough):
    """A loader that records the order of its reads and holds the first one until ``gate`` is set."""

    def __init__(self, inner) -> None:
        super().__init__(inner)
        self.reads: list[tuple[int, tuple[int, int, int]]] = []
        self.started, self.gate = threading.Event(), threading.Event()
        self._lock = threading.Lock()

    def read_brick(self, level, index):
        with self._lock:
            self.reads.append((int(level), tuple(int(v) for v in index)))
        self.started.set()
        assert self.gate.wait(30)
        return self._inner.read_brick(level, index)


def volume(n: int = 48) -> np.ndarray:
    """Texture everywhere above zero: no brick is transparent, the frustum alone makes the cut."""
    z, y, x = np.mgrid[0:n, 0:n, 0:n].astype(np.float32)
    return (0.6 + 0.3 * np.sin(x / 3.0) * np.cos(y / 4.0) + 0.1 * z / n).astype(np.float32)


def corner_camera(pyr, size: int = 32) -> Camera:
    """A narrow view down z through a column of bricks at the low x, y corner: far from the centre of
    interest (the volume's centre), where the queue's distance order reads last."""
    lo, hi = pyr.volume_box()
    ext = hi - lo
    target = np.array([lo[0] + 0.12 * ext[0], lo[1] + 0.12 * ext[1], (lo[2] + hi[2]) / 2])
    eye = target - np.array([0.0, 0.0, 2.0 * ext[2]])
    return Camera.perspective(tuple(eye), tuple(target), up=(0, -1, 0), fov_y=4, size=(size, size))


@pytest.mark.parametrize("cut_first", [True, False])
def test_non_waiting_frame_reads_its_cut_first(ctx, cut_first):
    vol = volume()
    tf = TransferFunction.from_points([(0.0, (0.2, 0.2, 0.2, 0.2)), (1.0, (1, 1, 1, 0.6))])
    params = dict(policy="fixed", level=0)
    # the reference: the cut a converged frame of this camera wants, from a warm clip-texture of its own
    warm = ClipTexture(NumpyLoader(vol, brick=8), "64MB", threads=1)
    ref_action = ClipRenderAction(ctx, warm, **params)
    try:
        cam = corner_camera(ref_action.pyramid)
        ref_action.render(cam, tf, wait=True, timeout=60)
        assert ref_action.last_frame_stats.converged
        wanted = {(int(r[0]), tuple(int(v) for v in r[1:])) for r in ref_action.last_selection.wanted_keys()}
    finally:
        ref_action.close()
        warm.close()
    pyr = ref_action.pyramid
    window = sum(int(np.prod(pyr.grid(L))) for L in range(pyr.num_levels))
    assert 0 < len(wanted) < window // 4  # a thin column of the volume's bricks

    loader = OrderLoader(NumpyLoader(vol, brick=8))
    clip = ClipTexture(loader, "64MB", threads=1)
    a = ClipRenderAction(ctx, clip, **params)
    a.frame_loop.prioritize_missing = cut_first
    try:
        assert loader.started.wait(30)  # the one thread holds its first brick: the rest waits in the queue
        a.render(cam, tf)  # without waiting: nothing drawn yet at level 0
        assert not a.last_frame_stats.converged
        a.render(cam, tf)  # the same missing set again: asked for once
        loader.gate.set()
        assert clip.wait_until_idle(60)
        first = loader.reads[0]
        rest = loader.reads[1:]
        todo = wanted - {first}
        head = set(rest[:len(todo)])
        if cut_first:
            assert head == todo, f"{len(head - todo)} bricks outside the cut read before it"
        else:  # the queue's own order (nearest the centre first) reads other bricks before the cut
            assert head != todo
        assert len(set(loader.reads)) == len(loader.reads)  # each brick read once
    finally:
        loader.gate.set()
        a.close()
        clip.close()
