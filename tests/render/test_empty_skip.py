"""Empty-space skipping below the brick (RenderParams.skip_empty, clipvol.scene.occupancy) draws
the image the numpy reference caster draws, in both draw paths, and follows the transfer function.

The volume is mostly air with a thin shell and a small blob inside: most cells of the bricks that
hold the shell are empty, so the rays really leap (checked on the occupancy the frame used)."""

from __future__ import annotations

import numpy as np
import pytest
import reference_raycast as ref
from render_helpers import every_draw_path
from clipvol.loaders.numpy_array import NumpyLoader

from clipvol.paging.cliptexture import ClipTexture
from clipvol.scene.camera import Camera
from clipvol.scene.transfer import TransferFunction

pytestmark = pytest.mark.gl

SHELL = TransferFunction.from_points([(0.0, (0, 0, 0, 0)), (0.6, (0, 0, 0, 0)), (0.75, (1.0, 0.8, 0.5, 0.35)),
                                      (1.0, (1.0, 1.0, 1.0, 0.6))], value_range=(0.0, 1.0))
# the blob (value 0.4) becomes visible as well
SHELL_AND_BLOB = TransferFunction.from_points([(0.0, (0, 0, 0, 0)), (0.3, (0, 0, 0, 0)), (0.4, (0.2, 0.4, 1.0, 0.5)),
                                               (0.5, (0, 0, 0, 0)), (0.6, (0, 0, 0, 0)), (0.75, (1.0, 0.8, 0.5, 0.35)),
                                               (1.0, (1.0, 1.0, 1.0, 0.6))], value_range=(0.0, 1.0))


def shell_volume(n: int = 64) -> np.ndarray:
    """Air (0), a spherical shell about two voxels thick (0.8 .. 1.0), and a blob (0.4) off centre."""
    z, y, x = np.mgrid[0:n, 0:n, 0:n].astype(np.float64)
    c = (n - 1) / 2.0
    r = np.sqrt((x - c) ** 2 + (y - c) ** 2 + (z - c) ** 2)
    vol = np.clip(1.0 - np.abs(r - 0.4 * n) / 2.0, 0.0, 1.0) * 0.2 + 0.8 * (np.abs(r - 0.4 * n) < 1.5)
    blob = np.sqrt((x - c - 5) ** 2 + (y - c + 4) ** 2 + (z - c) ** 2) < 4.0
    vol[blob] = 0.4
    return vol.astype(np.float32)


@pytest.fixture
def scene(ctx):
    vol = shell_volume()
    loader = NumpyLoader(vol, brick=16, value_range=(0.0, 1.0))
    clip = ClipTexture(loader, "64MB", threads=2)
    actions = []

    def action(**kw):
        from clipvol.render.action import ClipRenderAction

        a = ClipRenderAction(ctx, clip, policy="fixed", level=0, **kw)
        actions.append(a)
        return a

    yield vol, loader.pyramid, action
    for a in actions:
        a.close()
    clip.close()
    assert ctx.error == "GL_NO_ERROR"


def diff(a, b) -> int:
    return int(np.abs(a.astype(np.int64) - b.astype(np.int64)).max())


def camera():
    c = (31.5, 31.5, 31.5)
    return Camera.perspective((95.0, 75.0, -40.0), c, size=(96, 80), fov_y=40)


def reference(vol, pyr, cam, tf):
    fc = cam.fit_depth(*pyr.volume_box())
    return ref.to_uint8(ref.raycast(vol, pyr.spacing, fc, tf.table, tf.window(pyr.value_range), 0.5))


def leapt_cells(action) -> float:
    """Fraction of level 0's cells the last frame's occupancy marked empty."""
    cache = action.cache
    (cx, cy, cz), z0 = cache.occupancy_levels[0]
    tex = cache._occ_tex
    flags = np.frombuffer(tex.read(), dtype=np.uint8).reshape(tex.size[2], tex.size[1], tex.size[0])
    return float((flags[z0:z0 + cz, :cy, :cx] == 0).mean())


def test_skipping_draws_the_reference_image_with_air_and_a_thin_shell(scene, draw_path):
    vol, pyr, action = scene
    cam = camera()
    skip = action(path=draw_path)
    plain = action(path=draw_path, skip_empty=False)
    img = skip.render(cam, SHELL, wait=True, timeout=30)
    assert skip.path_drawn == draw_path and skip.skipped_empty
    assert leapt_cells(skip) > 0.2  # the rays do leap
    full = plain.render(cam, SHELL, wait=True, timeout=30)
    assert not plain.skipped_empty
    r = reference(vol, pyr, cam, SHELL)
    assert (r[..., 3] > 0).mean() > 0.3
    assert diff(img, full) <= 1  # the same image as without skipping
    assert diff(img, r) <= 2  # and the independent caster's


def test_a_transfer_function_change_rederives_occupancy(scene, draw_path):
    """The blob's cells are empty under SHELL; under SHELL_AND_BLOB they must be drawn."""
    vol, pyr, action = scene
    cam = camera()
    a = action(path=draw_path)
    first = a.render(cam, SHELL, wait=True, timeout=30)
    assert diff(first, reference(vol, pyr, cam, SHELL)) <= 2
    img = a.render(cam, SHELL_AND_BLOB, wait=True, timeout=30)
    r = reference(vol, pyr, cam, SHELL_AND_BLOB)
    assert diff(img, r) <= 2
    changed = np.abs(r.astype(np.int64) - first.astype(np.int64)).max(axis=-1) > 8  # where the blob shows
    assert changed.mean() > 0.01
    assert diff(img[changed], first[changed]) > 8  # drawn now, not leapt with the old flags


def test_a_table_visible_everywhere_draws_without_lookups(scene):
    """Under a table with no transparent value no cell is empty: the frame is drawn without the
    EMPTY_SKIP variant (MIN_EMPTY_FRACTION), and MIP never leaps."""
    vol, pyr, action = scene
    everywhere = TransferFunction.from_points([(0.0, (1, 1, 1, 0.01)), (1.0, (1, 0, 0, 0.3))], value_range=(0.0, 1.0))
    a = action(path="bricks")
    img = a.render(camera(), everywhere, wait=True, timeout=30)
    assert a.cache.empty_fraction() == 0.0 and not a.skipped_empty and not a.defines()["EMPTY_SKIP"]
    assert diff(img, reference(vol, pyr, camera(), everywhere)) <= 2
    m = action(path="bricks", mode="mip")
    m.render(camera(), SHELL, wait=True, timeout=30)
    assert not m.skipped_empty


def test_no_cells_with_an_odd_brick(ctx):
    from clipvol.render.action import ClipRenderAction

    vol = shell_volume(30)
    loader = NumpyLoader(vol, brick=15, value_range=(0.0, 1.0))  # 15 = 3 x 5: no cells of >= 2 voxels
    clip = ClipTexture(loader, "64MB", threads=2)
    try:
        with ClipRenderAction(ctx, clip, policy="fixed", level=0) as a:
            a.render(Camera.perspective((50.0, 40.0, -20.0), (14.5,) * 3, size=(32, 32)), SHELL, wait=True, timeout=30)
            assert a.cache.cell_edges is None and not a.skipped_empty
    finally:
        clip.close()


@pytest.mark.parametrize("variant", ["shading", "nan"])
def test_skipping_in_the_lit_and_nan_aware_variants_changes_no_pixel(ctx, variant):
    """The general march (HAS_NAN, SHADING) leaps like the fast one: same image as without skipping."""
    from clipvol.render.action import ClipRenderAction

    vol = shell_volume()
    if variant == "nan":
        vol[:6] = np.nan  # a slab of NaN in the air, and some next to the shell
        vol[30:34, 2:12, 28:36] = np.nan
    loader = NumpyLoader(vol, brick=16, value_range=(0.0, 1.0))
    clip = ClipTexture(loader, "64MB", threads=2)
    try:
        for path in every_draw_path():
            kw = dict(policy="fixed", level=0, path=path, shading=variant == "shading")
            with ClipRenderAction(ctx, clip, **kw) as a, ClipRenderAction(ctx, clip, skip_empty=False, **kw) as b:
                img = a.render(camera(), SHELL, wait=True, timeout=30)
                assert a.skipped_empty and a.defines()["HAS_NAN" if variant == "nan" else "SHADING"]
                full = b.render(camera(), SHELL, wait=True, timeout=30)
                assert (full[..., 3] > 0).mean() > 0.3
                assert diff(img, full) <= 1
    finally:
        clip.close()
    assert ctx.error == "GL_NO_ERROR"


def test_cells_derived_brick_by_brick_equal_the_whole_level(scene):
    """A few bricks per frame: each frame updates only the cells next to the new bricks; the flags
    (and the texture the shader reads) must equal the level derived whole from the cells' ranges."""
    from clipvol.scene.occupancy import occupancy, widen

    vol, pyr, action = scene
    a = action(path="bricks", texels_per_frame=3 * 16 ** 3)
    cache = a.cache
    assert a.clip_texture.wait_until_idle(30)  # in RAM: the upload budget alone paces the frames
    arrived = []
    for _ in range(8):
        a.render(camera(), SHELL)
        for L in range(pyr.num_levels):
            lo, hi = cache._cell_lo[L], cache._cell_hi[L]
            assert np.array_equal(cache._occ_flags[L], occupancy(*widen(lo, hi), SHELL, pyr.value_range))
        arrived.append(int(np.isfinite(cache._cell_lo[0]).sum()))
    assert arrived[-1] > arrived[-3] > 0  # level-0 bricks did arrive over several frames
    (cx, cy, cz), z0 = cache.occupancy_levels[0]
    tex = cache._occ_tex
    shown = np.frombuffer(tex.read(), dtype=np.uint8).reshape(tex.size[2], tex.size[1], tex.size[0])
    assert np.array_equal(shown[z0:z0 + cz, :cy, :cx], cache._occ_flags[0] * 255)


def test_cells_computed_at_upload_when_the_clip_texture_takes_none(ctx):
    """ClipTexture(cells_on_load=False): the GPU cache computes the cells itself; same flags, same image."""
    from clipvol.render.action import ClipRenderAction

    vol = shell_volume()
    imgs, flags = [], []
    for on_load in (True, False):
        clip = ClipTexture(NumpyLoader(vol, brick=16, value_range=(0.0, 1.0)), "64MB", threads=2, cells_on_load=on_load)
        try:
            assert (clip.cell_edges is not None) == on_load
            with ClipRenderAction(ctx, clip, policy="fixed", level=0, path="bricks") as a:
                imgs.append(a.render(camera(), SHELL, wait=True, timeout=30))
                assert a.skipped_empty
                flags.append(a.cache._occ_flags[0].copy())
        finally:
            clip.close()
    assert np.array_equal(flags[0], flags[1]) and diff(imgs[0], imgs[1]) == 0
