"""A frame names its failed bricks: which wanted brick failed, why, and which ancestor stands in
(None: a hole); ``hatch_failed`` marks exactly the hole's footprint.

References: the octree arithmetic written out here (an ancestor of ``(0, b)`` is ``(L, b >> L)``),
the chunk files damaged on disk, and the pixel rectangle of a brick under an orthographic
axis-aligned camera computed from its voxel box by hand (pixel ``i`` has its centre at
``i + 0.5 - 0.5`` world units: 1 world unit per pixel, the volume's box ``[-0.5, 31.5]``).
"""

from __future__ import annotations

import numpy as np
import pytest

from clipvol.bricking.pipeline import brick_volume
from clipvol.loaders.zarr_store import ZarrLoader
from clipvol.paging.cliptexture import ClipTexture
from clipvol.render.failures import FailedBrick, describe_failed, footprint_mask, hatch_failed
from clipvol.scene.camera import Camera
from clipvol.scene.transfer import TransferFunction

B = 8
TF = TransferFunction.from_points([(0.0, (1, 1, 1, 0.2)), (1.0, (1, 1, 1, 0.2))])
#: 32 x 32 pixels, one world unit each, looking down +z at the whole 32^3 volume
CAM = Camera.orthographic((15.5, 15.5, 15.5), (0, 0, 1), (0, -1, 0), 32, 32, size=(32, 32))


@pytest.fixture(scope="module")
def store(tmp_path_factory):
    out = tmp_path_factory.mktemp("failures") / "v.zarr"
    vol = np.random.default_rng(3).random((32, 32, 32)).astype(np.float32) + 0.1
    brick_volume(vol, out, brick=B, progress=False, workers=1, summary=False)
    return out


def _damage(root, level, index):
    z, y, x = index
    (root / str(level) / "c" / str(z) / str(y) / str(x)).write_bytes(b"not a chunk")


def _copy(store, tmp_path):
    import shutil

    dst = tmp_path / "copy.zarr"
    shutil.copytree(store, dst)
    return dst


def _render(ctx, root):
    from clipvol.render.action import ClipRenderAction

    with ClipTexture(ZarrLoader(root), "32MB", threads=2, retries=0) as clip, \
            ClipRenderAction(ctx, clip, policy="fixed", level=0) as action:
        img = action.render(CAM, TF, wait=True, timeout=30)
        return img, action.last_frame_stats


@pytest.mark.gl
def test_a_failed_brick_with_a_sound_parent_is_listed_as_replaced(ctx, store, tmp_path):
    root = _copy(store, tmp_path)
    _damage(root, 0, (1, 2, 3))
    img, st = _render(ctx, root)
    assert [(f.level, f.index) for f in st.failed_bricks] == [(0, (1, 2, 3))]
    f = st.failed_bricks[0]
    assert f.stand_in == (1, (0, 1, 1)) and f.replaced and st.unreplaced == ()
    assert "0/c/1/2/3" in f.cause


@pytest.mark.gl
def test_a_failed_brick_whose_ancestors_failed_is_a_hole_and_is_hatched_where_it_is(ctx, store, tmp_path):
    root = _copy(store, tmp_path)
    column = [(z, 2, 3) for z in range(4)]  # the whole column of bricks behind pixels y 16..23, x 24..31
    for b in column:
        for L in range(3):  # the brick and every ancestor: (1, (z >> 1, 1, 1)), (2, (0, 0, 0))
            _damage(root, L, tuple(v >> L for v in b))
    img, st = _render(ctx, root)
    holes = st.unreplaced
    assert sorted(f.index for f in holes) == column and all(f.level == 0 for f in holes)
    assert all(f.stand_in is None and "0/c/" in f.cause for f in holes)
    # the sound bricks that share the failed ancestors still draw themselves: only the column is empty
    # (x in [23.5, 31.5], y in [15.5, 23.5] world units; pixel centres at i)
    ys, xs = np.nonzero(img[..., 3] == 0)
    assert ys.size and ys.min() == 16 and ys.max() == 23 and xs.min() == 24 and xs.max() == 31
    assert (img[16:24, 24:32, 3] == 0).all()
    from clipvol.render.failures import HATCH_RGBA

    pyr = ZarrLoader(root).pyramid
    hatched = hatch_failed(img, CAM, pyr, st.failed_bricks)
    red = np.all(hatched == HATCH_RGBA, axis=-1) & ~np.all(img == HATCH_RGBA, axis=-1)
    rect = np.zeros(red.shape, bool)
    rect[16:24, 24:32] = True
    assert red.any() and not (red & ~rect).any()
    assert 0.3 < red[rect].mean() < 0.7  # stripes, not a fill: the image shows through
    assert np.array_equal(hatched[~red], img[~red])


def test_footprint_of_a_box_is_its_pixel_rectangle():
    # box x in [3.5, 9.5], y in [10.5, 12.5]: pixels 4..9 wide, rows 11..12 (centres at i)
    m = footprint_mask(CAM, [(3.5, 10.5, 0), (9.5, 10.5, 0), (3.5, 12.5, 0), (9.5, 12.5, 0),
                             (3.5, 10.5, 30), (9.5, 12.5, 30)], (32, 32))
    ref = np.zeros((32, 32), bool)
    ref[11:13, 4:10] = True
    assert np.array_equal(m, ref)


def test_describe_failed_names_a_few_then_counts():
    failed = [FailedBrick(0, (i, 0, 0), f"cause {i}") for i in range(5)]
    text = describe_failed(failed, 2)
    assert "brick (level 0, 0, 0, 0): cause 0" in text and "cause 1" in text and "cause 2" not in text
    assert text.endswith("and 3 more")
