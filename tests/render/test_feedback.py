"""Ray feedback (``RenderParams.feedback``; clipvol.scene.feedback): the single pass reports the
page-table nodes its rays sampled, and the cut's missing bricks under them go to the front of the
clip-texture's load queue.

The reference is ray geometry in numpy from the volume's bytes: rays parallel to z enter each
brick column at the eye's side and stop in the first brick layer whose whole cross-section is
opaque (a slab), so the nodes sampled are the column's bricks up to and including that layer; a
column with a hole in the slab is sampled through to the back.
"""

from __future__ import annotations

import threading

import numpy as np
import pytest
from clipvol.loaders.numpy_array import NumpyLoader

from clipvol.paging.cliptexture import ClipTexture
from clipvol.scene.camera import Camera
from clipvol.scene.feedback import sampled_nodes, wanted_under
from clipvol.scene.page_table import PageTable, item_nodes
from clipvol.scene.transfer import TransferFunction

N, B = 64, 16
# faint below 0.7 (rays pass), opaque from 0.7 (a ray stops at its first sample there)
TF = TransferFunction.from_points([(0.0, (0, 0, 1, 0.0)), (0.6, (0, 1, 0, 0.004)), (0.7, (1, 1, 1, 1.0)),
                                   (1.0, (1, 0, 0, 1.0))])


def slab_volume(hole=(0, 0)):
    """0.5 everywhere; an opaque slab (1.0) filling brick layer bz = 2, but for the brick column ``hole``."""
    vol = np.full((N, N, N), 0.5, dtype=np.float32)
    vol[2 * B:3 * B] = 1.0
    hy, hx = hole
    vol[2 * B:3 * B, hy * B:(hy + 1) * B, hx * B:(hx + 1) * B] = 0.5
    return vol


def reference_nodes(vol, opaque=0.7):
    """Level-0 bricks ``(0, bz, by, bx)`` that rays along -z reach: per column, from the back of the
    volume (the eye's side, high z) down to the first layer whose cross-section is all opaque."""
    g = N // B
    out = []
    for by in range(g):
        for bx in range(g):
            for bz in range(g - 1, -1, -1):
                out.append((0, bz, by, bx))
                if (vol[bz * B:(bz + 1) * B, by * B:(by + 1) * B, bx * B:(bx + 1) * B] >= opaque).all(axis=(1, 2)).any():
                    break
    return np.array(sorted(out), dtype=np.int64)


class HeldLoader(NumpyLoader):
    """Reads every brick but those in ``held``, which wait until ``release`` is set (a cold fill)."""

    def __init__(self, vol, held) -> None:
        super().__init__(vol, brick=B)
        self.held = set(held)
        self.release = threading.Event()

    def read_brick(self, level, index):
        if (level, tuple(index)) in self.held:
            assert self.release.wait(30)
        return super().read_brick(level, index)


def camera(pyr):
    lo, hi = pyr.volume_box()
    c = (lo + hi) / 2
    # 48 pixels over 64 voxels: no pixel's ray runs along a brick face
    return Camera.orthographic((c[0], c[1], hi[2] + 50.0), (0, 0, -1), (0, 1, 0), width=float(hi[0] - lo[0]),
                               height=float(hi[1] - lo[1]), size=(48, 48))


@pytest.mark.gl
@pytest.mark.parametrize("held, asks", [((0, (0, 3, 3)), False), ((0, (0, 0, 0)), True)],
                         ids=["hidden-brick-missing", "seen-brick-missing"])
def test_a_frame_reports_the_nodes_its_rays_sample_and_asks_for_the_missing_bricks_under_them(ctx, held, asks):
    """One level-0 brick is missing, so the frame draws its node from the parent's data: behind the
    slab the node is neither reported nor its brick asked for; in the hole's column it is both."""
    from clipvol.render.action import ClipRenderAction

    vol = slab_volume()
    loader = HeldLoader(vol, [held])
    clip = ClipTexture(loader, "64MB", threads=2)
    kw = dict(policy="fixed", level=0, path="single-pass", merge_boxes=False)
    a = ClipRenderAction(ctx, clip, feedback=True, **kw)
    plain = ClipRenderAction(ctx, clip, **kw)
    try:
        g = N // B
        others = [(L, (z, y, x)) for L in range(clip.pyramid.num_levels) for z in range(g >> L)
                  for y in range(g >> L) for x in range(g >> L) if (L, (z, y, x)) != held]
        assert clip.wait_for(others, timeout=30)
        cam = camera(clip.pyramid)
        img = a.render(cam, TF)
        assert not a.last_frame_stats.converged and a.path_drawn == "single-pass"
        # the page table's nodes: each drawn item's box (a missing brick's node drawn from its parent)
        nodes = [[L, *idx] for L, idx in item_nodes(a.last_selection.items, clip.pyramid)]
        assert [0, *held[1]] in nodes and [0, *held[1]] not in a.last_selection.item_keys().tolist()
        reached = reference_nodes(vol)
        expected = [n for n in nodes
                    if any((np.array(r[1:]) >> n[0] == n[1:]).all() for r in reached.tolist())]
        got = sorted(map(tuple, a.sampled_nodes.tolist()))
        assert got == sorted(map(tuple, expected))
        assert a.feedback_asked == (1 if asks else 0)
        # the hook changes nothing drawn
        assert np.array_equal(img, plain.render(cam, TF))
        assert plain.sampled_nodes is None and plain.feedback_asked == 0
    finally:
        loader.release.set()
        a.close()
        plain.close()
        clip.close()
    assert ctx.error == "GL_NO_ERROR"


@pytest.mark.gl
def test_a_converged_frame_records_nothing(ctx):
    """Nothing is missing, so nothing is asked for: the frame is the plain variant, merged."""
    from clipvol.render.action import ClipRenderAction

    clip = ClipTexture(NumpyLoader(slab_volume(), brick=B), "64MB", threads=1)
    a = ClipRenderAction(ctx, clip, policy="fixed", level=0, path="single-pass", feedback=True)
    try:
        a.render(camera(clip.pyramid), TF, wait=True, timeout=30)
        assert a.last_frame_stats.converged
        assert a.sampled_nodes is None and a.feedback_asked == 0
    finally:
        a.close()
        clip.close()


def test_sampled_nodes_unravel_the_flag_of_each_level_box():
    # level 0: box of 2x3x4 cells at (1, 0, 2); level 1: box of 1x1x2 at (0, 0, 0)
    table = PageTable(entries=np.zeros(26, dtype=np.uint32), base=np.array([0, 24]),
                      c0=np.array([[1, 0, 2], [0, 0, 0]]), size=np.array([[2, 3, 4], [1, 1, 2]]))
    flags = np.zeros(30, dtype=np.uint32)
    flags[[0, 23, 25, 28]] = 1  # entries 0 and 23 of level 0, entry 1 of level 1, past the table
    got = sampled_nodes(table, flags)
    # entry 23 = (z 1, y 2, x 3) of the box: cell (2, 2, 5)
    assert got.tolist() == [[0, 1, 0, 2], [0, 2, 2, 5], [1, 0, 0, 1]]
    assert sampled_nodes(table, np.zeros(26)).shape == (0, 4)


def test_wanted_under_keeps_the_wanted_bricks_inside_sampled_node_boxes():
    nodes = np.array([[2, 0, 0, 1], [0, 5, 5, 5]])
    wanted = np.array([[0, 0, 0, 4], [0, 0, 0, 3], [1, 1, 1, 3], [1, 1, 1, 1], [0, 5, 5, 5], [0, 5, 5, 4],
                       [3, 0, 0, 0]])
    # level-2 node (0, 0, 1) covers level-0 x in [4, 8) and level-1 x in [2, 4); the coarser level-3 brick is not under it
    expected = [[0, 0, 0, 4], [1, 1, 1, 3], [0, 5, 5, 5]]
    assert wanted_under(nodes, wanted).tolist() == expected
    assert wanted_under(np.zeros((0, 4)), wanted).shape == (0, 4)
