"""The draw-path registry (clipvol.render.paths): a path registered there is the one
``RenderParams.path`` selects - the registry is the only place a new path is named - and a path
that declines a cut hands it to the per-brick path.

The test paths draw through the shared set-up (target, read-back); their images are checked
against values computed here (8-bit rounding of a constant colour) and against the per-brick
path's own image of the same cut.
"""

from __future__ import annotations

import numpy as np
import pytest
from clipvol.loaders.numpy_array import NumpyLoader

from clipvol.errors import ParameterError
from clipvol.paging.cliptexture import ClipTexture
from clipvol.render import paths
from clipvol.render.paths import DrawPath
from clipvol.scene.camera import Camera
from clipvol.scene.params import RenderParams
from clipvol.scene.transfer import TransferFunction

pytestmark = pytest.mark.gl

COLOUR = (0.2, 0.4, 0.6, 1.0)  # premultiplied, opaque
TF = TransferFunction.from_points([(0.0, (0, 0, 1, 0.0)), (1.0, (1, 0, 0, 0.4))])


class FlatPath(DrawPath):
    """Fills the image with one opaque colour; records the cut it was handed."""

    name = "test-flat"

    def __init__(self, action) -> None:
        super().__init__(action)
        self.cuts: list[int] = []

    def draw(self, cam, tf, items):
        self.cuts.append(len(items))
        _fbo, previous, t0 = self.setup.begin(cam, COLOUR)
        return self.setup.read_back(previous, tf, True, t0)


class DecliningPath(DrawPath):
    """Declines every cut (as the single pass does for a cut its page table cannot hold)."""

    name = "test-declines"

    def draw(self, cam, tf, items):
        return None


@pytest.fixture
def registered():
    added = []

    def register(cls):
        paths.register(cls)
        added.append(cls.name)

    yield register
    for name in added:
        paths.unregister(name)


@pytest.fixture
def action(ctx):
    z, y, x = np.mgrid[0:16, 0:16, 0:16].astype(np.float32)
    clip = ClipTexture(NumpyLoader((x + y + z) / 45.0, brick=8), "16MB", threads=1)
    made = []

    def make(**kw):
        from clipvol.render.action import ClipRenderAction

        a = ClipRenderAction(ctx, clip, policy="fixed", level=0, **kw)
        made.append(a)
        return a

    yield make
    for a in made:
        a.close()
    clip.close()
    assert ctx.error == "GL_NO_ERROR"


def camera():
    return Camera.perspective((30.0, 25.0, -30.0), (7.5, 7.5, 7.5), size=(32, 24), fov_y=40)


def test_a_registered_path_is_the_one_render_params_path_selects(registered, action):
    with pytest.raises(ParameterError, match="test-flat"):
        RenderParams(path="test-flat")  # not a path before it is registered
    registered(FlatPath)
    a = action(path="test-flat")
    img = a.render(camera(), TF, wait=True, timeout=20)
    assert a.path_drawn == "test-flat"
    flat = a._paths["test-flat"]
    assert flat.cuts and flat.cuts[-1] >= 1  # it was handed the frame's cut
    expected = np.rint(np.array(COLOUR) * 255.0).astype(np.uint8)
    assert img.shape == (24, 32, 4)
    assert (img == expected).all()
    assert a.last_frame_stats.bricks_distinct == 8  # the frame's bookkeeping is the action's, not the path's


def test_a_declined_cut_is_drawn_by_the_per_brick_path(registered, action):
    registered(DecliningPath)
    declines = action(path="test-declines")
    bricks = action(path="bricks")
    img = declines.render(camera(), TF, wait=True, timeout=20)
    assert declines.path_drawn == "bricks"
    ref = bricks.render(camera(), TF, wait=True, timeout=20)
    assert (img[..., 3] > 0).mean() > 0.2  # the volume is on the image
    assert np.array_equal(img, ref)


def test_unregistered_and_reserved_names_are_refused(registered):
    registered(FlatPath)
    assert RenderParams(path="test-flat").path == "test-flat"
    paths.unregister("test-flat")
    with pytest.raises(ParameterError, match="path: expected one of"):
        RenderParams(path="test-flat")

    class Auto(DrawPath):
        name = "auto"

    with pytest.raises(ParameterError, match="Auto"):
        paths.register(Auto)
    assert paths.DRAW_PATHS["bricks"] is paths.bricks.BricksPath  # the built-ins stay
    assert RenderParams(path="bricks").path == "bricks"


@pytest.mark.parametrize("kw", [dict(path="bricks"), dict(path="single-pass"), dict(path="bricks", merge_boxes=False),
                                dict(path="bricks", refine_tolerance=0.1), dict(path="test-flat")])
def test_a_step_whose_rays_would_be_cut_short_is_refused_for_every_path(registered, action, kw):
    """The volume is 16 voxels a side (spacing 1): a ray's path through any box is at least a
    little and at most 16 * sqrt(3) voxels, so at step 1e-4 some ray needs far more than the
    loop's 65 536 samples in one box and at step 1e-3 none needs more than about 28 000. The
    action refuses the first, naming ``step``, whichever path draws (a registered one too) and
    however the frame is drawn; the second draws."""
    registered(FlatPath)
    assert 16 / 1e-4 > 65536 and 16 * np.sqrt(3) / 1e-3 * 1.1 < 65536
    with pytest.raises(ParameterError, match="step"):
        action(step=1e-4, **kw).render(camera(), TF, wait=True, timeout=20)
    img = action(step=1e-3, **kw).render(camera(), TF, wait=True, timeout=20)
    assert img.shape == (24, 32, 4)
