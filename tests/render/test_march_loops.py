"""The march loops and the page table's addressing draw the numpy reference caster's image.

The loops of ``volume_common.glsl``'s fast march test their end after their samples (a do-while
behind a test of the count, so that llvmpipe does not run a masked body once more per node a ray
crosses; the single pass leaps empty cells in blocks of 2 samples, the per-brick path in blocks
of 8), and ``raymarch.frag.glsl`` finds an entry's row and column of the page-table texture by a
shift and a mask (``PT_WIDTH_LOG2``). What could go wrong: a segment of no sample taking one (the
test of the count), a run's last sample taken twice or not at all, an entry beyond the texture's
first row read from the wrong place. So: bricks drawn unmerged (one node per brick, so rays cross
many nodes), a step of several voxels (segments of zero, one, a few samples) and one below a
voxel, with and without empty-space skipping, each draw path; and a cut of small bricks whose
table fills more than one row.
"""

from __future__ import annotations

import numpy as np
import pytest
import reference_raycast as ref

from clipvol.loaders.numpy_array import NumpyLoader
from clipvol.paging.cliptexture import ClipTexture
from clipvol.scene.camera import Camera
from clipvol.scene.transfer import TransferFunction

pytestmark = pytest.mark.gl

#: air transparent (so that skipping leaps), the blobs' values visible
TF = TransferFunction.from_points([(0.0, (0, 0, 0, 0)), (0.25, (0, 0, 0, 0)), (0.45, (0.9, 0.5, 0.2, 0.25)),
                                   (1.0, (1.0, 1.0, 0.9, 0.55))], value_range=(0.0, 1.0))


def blobs(shape, seed: int = 0) -> np.ndarray:
    """Smooth blobs in air (0) filling about a third of ``shape`` (z, y, x): every node a ray
    crosses holds a different length of visible data."""
    rng = np.random.default_rng(seed)
    z, y, x = np.mgrid[0:shape[0], 0:shape[1], 0:shape[2]].astype(np.float64)
    vol = np.zeros(shape)
    for _ in range(12):
        c = rng.uniform(0, 1, 3) * np.array(shape)
        r = rng.uniform(0.12, 0.22) * min(shape)
        vol = np.maximum(vol, np.clip(1.0 - np.sqrt((z - c[0]) ** 2 + (y - c[1]) ** 2 + (x - c[2]) ** 2) / r, 0, 1))
    return vol.astype(np.float32)


@pytest.fixture
def scene(ctx):
    made = []

    def make(vol, brick: int, **kw):
        from clipvol.render.action import ClipRenderAction

        loader = NumpyLoader(vol, brick=brick, value_range=(0.0, 1.0))
        clip = ClipTexture(loader, "64MB", threads=2)
        a = ClipRenderAction(ctx, clip, policy="fixed", level=0, merge_boxes=False, **kw)
        made.append((a, clip))
        return a, loader.pyramid

    yield make
    for a, clip in made:
        a.close()
        clip.close()
    assert ctx.error == "GL_NO_ERROR"


def camera(vol, size=(64, 48)):
    n = np.array(vol.shape[::-1], dtype=np.float64)
    c = (n - 1) / 2.0
    return Camera.perspective(tuple(c + np.array([0.8, 0.55, -1.0]) * n.max()), tuple(c), size=size, fov_y=35)


def reference(vol, pyr, cam, step: float) -> np.ndarray:
    fc = cam.fit_depth(*pyr.volume_box())
    return ref.to_uint8(ref.raycast(vol, pyr.spacing, fc, TF.table, TF.window(pyr.value_range), step))


def diff(a, b) -> int:
    return int(np.abs(a.astype(np.int64) - b.astype(np.int64)).max())


@pytest.mark.parametrize("skip", [True, False])
@pytest.mark.parametrize("step", [5.0, 0.75])
def test_segments_of_no_one_or_a_few_samples_draw_the_reference_image(scene, draw_path, skip, step):
    vol = blobs((64, 64, 64))
    action, pyr = scene(vol, 16, path=draw_path, skip_empty=skip, step=step)
    cam = camera(vol)
    img = action.render(cam, TF, wait=True, timeout=60)
    assert action.path_drawn == draw_path and action.skipped_empty == skip
    r = reference(vol, pyr, cam, step)
    assert (r[..., 3] > 0).mean() > 0.3  # the blobs fill the image
    assert diff(img, r) <= 2


def test_a_page_table_longer_than_one_row_draws_the_reference_image(scene):
    from clipvol.render.paths.single_pass import PAGE_TABLE_WIDTH

    vol = blobs((64, 96, 96), seed=1)  # 8 x 12 x 12 = 1 152 bricks of 8^3, one table entry each
    action, pyr = scene(vol, 8, path="single-pass", step=1.0)
    cam = camera(vol, size=(64, 64))
    img = action.render(cam, TF, wait=True, timeout=120)
    assert action.path_drawn == "single-pass"
    assert action.last_frame_stats.page_table_nodes > PAGE_TABLE_WIDTH  # entries past the first row are read
    r = reference(vol, pyr, cam, 1.0)
    assert (r[..., 3] > 0).mean() > 0.2
    assert diff(img, r) <= 2
