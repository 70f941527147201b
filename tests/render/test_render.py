"""The GL clip render action against an independent numpy ray caster (``reference_raycast.py``).

One standalone EGL context for the module (Mesa llvmpipe is enough); every test checks
``ctx.error`` afterwards. Images are small (<= 128 x 128) so the module runs in seconds.
"""

from __future__ import annotations

import numpy as np
import pytest
import reference_raycast as ref
from render_helpers import every_draw_path
from clipvol.loaders.numpy_array import NumpyLoader

from clipvol.bricking.pyramid import downsample
from clipvol.errors import ParameterError
from clipvol.paging.cliptexture import ClipTexture
from clipvol.scene.camera import Camera
from clipvol.scene.selection import DrawItem
from clipvol.scene.transfer import TransferFunction

pytestmark = pytest.mark.gl



@pytest.fixture(autouse=True)
def _gl_clean(ctx):
    assert ctx.error == "GL_NO_ERROR"
    yield
    assert ctx.error == "GL_NO_ERROR"


def smooth_volume(shape=(48, 40, 32), dtype=np.float32) -> np.ndarray:
    z, y, x = np.mgrid[0 : shape[0], 0 : shape[1], 0 : shape[2]].astype(np.float64)
    v = (np.sin(x / 3.0) + np.cos(y / 4.0) + np.sin(z / 2.5) + 3.0) / 6.0
    if np.dtype(dtype).kind in "iu":
        info = np.iinfo(dtype)
        lo, hi = max(info.min, -1000), min(info.max, 1000)
        return np.rint(lo + v * (hi - lo)).astype(dtype)
    return v.astype(dtype)


TF = TransferFunction.from_points([(0.0, (0, 0, 1, 0.0)), (0.5, (0, 1, 0, 0.05)), (1.0, (1, 0, 0, 0.3))])


class Scene:
    """A loader + clip-texture + action over an array, closed at the end of the test."""

    def __init__(self, ctx, vol, brick, **kwargs):
        self.vol = vol
        self.loader = NumpyLoader(vol, brick=brick)
        self.pyramid = self.loader.pyramid
        self.clip = ClipTexture(self.loader, "64MB", threads=2)
        self.action = None
        from clipvol.render.action import ClipRenderAction

        self.action = ClipRenderAction(ctx, self.clip, **kwargs)

    def render(self, cam, tf=TF, **kw):
        kw.setdefault("wait", True)
        kw.setdefault("timeout", 20)
        return self.action.render(cam, tf, **kw)

    def reference(self, cam, tf=TF, step=0.5, mode="composite"):
        fc = cam.fit_depth(*self.pyramid.volume_box())
        prem = ref.raycast(self.vol, self.pyramid.spacing, fc, tf.table, tf.window(self.pyramid.value_range), step, mode)
        return ref.to_uint8(prem)

    def close(self):
        self.action.close()
        self.clip.close()


@pytest.fixture
def scenes(ctx):
    made = []

    def make(vol, brick, **kwargs):
        s = Scene(ctx, vol, brick, **kwargs)
        made.append(s)
        return s

    yield make
    for s in made:
        s.close()


def centre_of(shape):
    return tuple((n - 1) / 2.0 for n in shape[::-1])


CAMERAS = {
    "perspective": lambda c: Camera.perspective((60.0, 50.0, -40.0), c, size=(96, 80), fov_y=40),
    "orthographic": lambda c: Camera.orthographic(c, (0.3, 0.2, 1.0), (0, -1, 0), 60, 50, size=(96, 80)),
    "inside_volume_and_brick": lambda c: Camera.perspective((10.0, 12.0, 14.0), (20.0, 25.0, 30.0), size=(64, 64), fov_y=70),
}


def diff(a, b) -> np.ndarray:
    return np.abs(a.astype(np.int64) - b.astype(np.int64))


def visible(img) -> float:
    return float((img[..., 3] > 0).mean())


# ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize("view", sorted(CAMERAS))
def test_composite_matches_reference_and_has_no_seams(scenes, view, draw_path):
    vol = smooth_volume()
    cam = CAMERAS[view](centre_of(vol.shape))
    small = scenes(vol, 16, policy="fixed", level=0, path=draw_path)
    big = scenes(vol, 128, policy="fixed", level=0, path=draw_path)
    a, b = small.render(cam), big.render(cam)
    assert small.action.last_frame_stats.converged and big.action.last_frame_stats.converged
    assert sum(small.action.last_frame_stats.bricks_drawn.values()) > 8  # really many bricks
    assert big.action.last_frame_stats.bricks_drawn == {0: 1}
    r = small.reference(cam)
    assert visible(r) > 0.3
    assert diff(a, b).max() <= 2, "seams between bricks"
    assert diff(a, r).max() <= 2
    assert diff(b, r).max() <= 2
    assert small.action.path_drawn == draw_path


@pytest.mark.parametrize("brick", [16, 64])
def test_axis_aligned_orthographic_mip_is_numpy_max_projection(scenes, brick):
    vol = smooth_volume((40, 36, 28))
    vol[5, 7, 9] = 1.5  # a single bright voxel must survive
    nz, ny, nx = vol.shape
    cam = Camera.orthographic(centre_of(vol.shape), (0, 0, 1), (0, -1, 0), nx, ny, size=(nx, ny))
    s = scenes(vol, brick, policy="fixed", level=0, mode="mip")
    img = s.render(cam, TransferFunction.preset("viridis"))
    lo, hi = float(vol.min()), float(vol.max())
    expect = ref.tf_lookup(TransferFunction.preset("viridis").table, (vol.max(axis=0) - lo) / (hi - lo))
    expect8 = ref.to_uint8(np.concatenate([expect[..., :3] * expect[..., 3:], expect[..., 3:]], axis=-1))
    assert diff(img, expect8).max() <= 1


@pytest.mark.parametrize("dtype", ["uint8", "int16", "uint16", "int64", "float64"])
def test_integer_and_wide_dtypes_match_reference(scenes, dtype):
    vol = smooth_volume((32, 32, 32), dtype)
    cam = CAMERAS["perspective"](centre_of(vol.shape))
    s = scenes(vol, 16, policy="fixed", level=0)
    img = s.render(cam)
    r = s.reference(cam)
    assert visible(r) > 0.3
    assert diff(img, r).max() <= 2


def _octree_items(pyr, eye, level, idx, refine):
    """Back-to-front items of the cut ``refine`` (nodes refined), computed here independently."""
    lo, hi = pyr.node_box(level, idx)
    if (level, idx) not in refine:
        return [DrawItem(level, idx, tuple(lo), tuple(hi))]
    split = pyr.node_box(level - 1, tuple(2 * i for i in idx))[1]
    kids = list(pyr.children(level, idx))

    def near_axes(c):
        clo = pyr.node_box(level - 1, c)[0]
        return sum((clo[a] >= split[a]) == (eye[a] >= split[a]) for a in range(3))

    out = []
    for c in sorted(kids, key=near_axes):  # fewest axes on the eye's side first = farthest first
        out += _octree_items(pyr, eye, level - 1, c, refine)
    return out


def test_mixed_level_cut_where_centre_sorting_fails(scenes):
    n = 128
    x = np.broadcast_to(np.arange(n, dtype=np.float32) / (n - 1), (n, n, n))
    vol = np.ascontiguousarray(x)
    tf = TransferFunction.from_points([(0, (0, 0, 1, 0.3)), (0.46, (0, 0, 1, 0.3)), (0.54, (1, 1, 0, 0.3)), (1, (1, 1, 0, 0.3))])
    s = scenes(vol, 16, path="bricks")  # render_items draws in the given order: the brick path
    pyr = s.pyramid
    s.clip.wait_until_idle(20)
    # the level-2 brick (0,0,0) (a 64^3 box) next to level-0 bricks (16^3)
    refine = {(3, (0, 0, 0))} | {(2, c) for c in pyr.children(3, (0, 0, 0)) if c != (0, 0, 0)}
    refine |= {(1, g) for (L, c) in list(refine) if L == 2 for g in pyr.children(2, c)}
    eye = np.array([50.0, -60.0, 32.0])
    cam = Camera.perspective(tuple(eye), (70.0, 63.5, 32.0), size=(64, 64), fov_y=60)
    items = _octree_items(pyr, eye, 3, (0, 0, 0), refine)
    assert {it.level for it in items} == {0, 2}
    levels, a = [], vol
    for L in range(pyr.num_levels):
        lv = pyr.levels[L]
        levels.append((a, np.array(lv.scale[::-1]), np.array(lv.translation[::-1])))
        a = downsample(a, "mean")
    fc = cam.fit_depth(*pyr.volume_box())
    expect = ref.to_uint8(ref.raycast_levels(levels, [(it.level, it.lo, it.hi) for it in items], fc, tf.table,
                                             pyr.value_range, 0.5, "composite", 1.0))
    good = s.action.render_items(cam, tf, items)
    centre_sorted = sorted(items, key=lambda it: -np.linalg.norm((np.add(it.lo, it.hi)) / 2 - eye))
    bad = s.action.render_items(cam, tf, centre_sorted)
    assert diff(bad, expect).max() > 40, "the scene must be one where centre sorting is wrong"
    assert diff(good, expect).max() <= 2
    # and the selection's own order for a similar multiresolution view agrees with the reference
    for path in every_draw_path():  # every path, each against the reference of its own cut
        s2 = scenes(vol, 16, lod_threshold=4.0, path=path)
        img = s2.render(cam, tf)
        sel = s2.action.last_selection
        assert len({it.level for it in sel.items}) >= 2 and s2.action.path_drawn == path
        expect2 = ref.to_uint8(ref.raycast_levels(levels, [(it.level, it.lo, it.hi) for it in sel.items], fc,
                                                  tf.table, pyr.value_range, 0.5, "composite", 1.0))
        d = diff(img, expect2)
        assert np.percentile(d, 99) <= 2 and d.mean() < 0.2  # faces next to bricks not on the GPU clamp


def test_error_falls_as_lod_threshold_falls(scenes):
    vol = smooth_volume((64, 64, 64))
    cam = Camera.perspective((-20.0, -10.0, -30.0), (31.5, 31.5, 31.5), size=(96, 96), fov_y=50)
    fine = scenes(vol, 8, policy="fixed", level=0).render(cam)
    errs, texels = [], []
    for thr in (8.0, 4.0, 2.0, 1.0):
        s = scenes(vol, 8, lod_threshold=thr)
        img = s.render(cam)
        errs.append(diff(img, fine).mean())
        texels.append(s.action.last_frame_stats.texels_drawn)
    assert all(b <= a + 1e-9 for a, b in zip(errs, errs[1:])), errs
    assert errs[-1] < errs[0]
    assert texels[0] < texels[-1]


def test_texture_memory_stays_in_budget(scenes, ctx):
    vol = smooth_volume((64, 64, 64))
    brick_bytes = 16**3 * 4
    budget = 20 * brick_bytes  # far less than the 64 + 8 + 1 bricks of the pyramid
    s = scenes(vol, 16, texture_budget=budget)
    for eye in [(-20.0, -10.0, -30.0), (80.0, 70.0, 90.0), (31.0, 31.0, -50.0)]:
        s.render(Camera.perspective(eye, (31.5, 31.5, 31.5), size=(64, 64)))
        st = s.action.last_frame_stats
        assert st.texture_bytes <= budget and st.texture_budget == budget
        assert sum(t.width * t.height * t.depth * 4 for t in s.action.cache.textures if t is not None) <= budget
    from clipvol.render.action import ClipRenderAction

    with pytest.raises(ParameterError, match="texture_budget"):
        ClipRenderAction(ctx, s.clip, texture_budget=brick_bytes - 1)


def test_uploads_per_frame_respect_texels_per_frame(scenes):
    vol = smooth_volume((64, 64, 64))
    per_frame = 3 * 16**3
    s = scenes(vol, 16, policy="fixed", level=0, texels_per_frame=per_frame)
    s.clip.wait_until_idle(20)
    cam = Camera.perspective((-20.0, -10.0, -30.0), (31.5, 31.5, 31.5), size=(64, 64), fov_y=50)
    frames = 0
    while True:
        img = s.render(cam, wait=False)
        st = s.action.last_frame_stats
        assert st.bricks_uploaded * 16**3 <= per_frame
        assert st.bytes_uploaded <= per_frame * 4
        frames += 1
        if st.converged or frames > 60:
            break
    assert st.converged and frames > 64 // 3  # it took many frames
    assert diff(img, s.reference(cam)).max() <= 2
    # wait=True does the same in internal passes
    s2 = scenes(vol, 16, policy="fixed", level=0, texels_per_frame=per_frame)
    img2 = s2.render(cam, wait=True)
    assert s2.action.last_frame_stats.converged and s2.action.last_frame_stats.passes > 1
    assert diff(img2, img).max() == 0


def test_partially_uploaded_frame_draws_coarser_not_holes(scenes):
    vol = smooth_volume((64, 64, 64))
    s = scenes(vol, 16, policy="fixed", level=0, texels_per_frame=16**3)
    s.clip.wait_until_idle(20)
    cam = Camera.perspective((-20.0, -10.0, -30.0), (31.5, 31.5, 31.5), size=(64, 64), fov_y=50)
    s.render(cam, wait=False)
    img = s.render(cam, wait=False)
    full = s.reference(cam)
    st = s.action.last_frame_stats
    assert not st.converged and st.counts["missing"] == 0
    # coverage is complete: every pixel the volume covers is drawn (coarser where not uploaded)
    assert np.array_equal(img[..., 3] > 0, full[..., 3] > 0) or (
        np.mean((img[..., 3] > 0) != (full[..., 3] > 0)) < 0.01
    )


def test_nan_and_inf_are_transparent_and_do_not_poison(scenes):
    vol = smooth_volume((32, 32, 32))
    vol[10:14, 10:20, 5:9] = np.nan
    vol[20, 20, 20] = np.inf
    cam = CAMERAS["perspective"](centre_of(vol.shape))
    s = scenes(vol, 16, policy="fixed", level=0)
    img = s.render(cam)
    r = s.reference(cam)
    assert visible(img) > 0.3
    d = diff(img, r)
    assert np.mean(d > 2) < 0.01  # only rays grazing a NaN texel's filter footprint may differ


@pytest.mark.slow
def test_opacity_extremes_and_step_sizes_are_stable(scenes):
    vol = smooth_volume((32, 32, 32))
    cam = CAMERAS["orthographic"](centre_of(vol.shape))
    opaque = TransferFunction.from_points([(0, (1, 0, 0, 1.0)), (1, (0, 0, 1, 1.0))])
    faint = TransferFunction.from_points([(0, (1, 1, 1, 1e-6)), (1, (1, 1, 1, 1e-6))])
    for tf in (opaque, faint):
        for step in (0.05, 0.5, 7.0):
            s = scenes(vol, 16, policy="fixed", level=0, step=step)
            img = s.render(cam, tf)
            r = s.reference(cam, tf, step=step)
            assert diff(img, r).max() <= 2, (tf, step)


def test_thin_prime_and_anisotropic_volumes(scenes):
    for shape in [(1, 17, 23), (13, 7, 29)]:
        vol = smooth_volume(shape)
        cam = Camera.perspective((-15.0, -12.0, -20.0), centre_of(shape), size=(64, 48), fov_y=50)
        s = scenes(vol, 8, policy="fixed", level=0)
        img = s.render(cam)
        r = s.reference(cam)
        assert diff(img, r).max() <= 2, shape


def test_parameters_are_validated(scenes, ctx):
    vol = smooth_volume((16, 16, 16))
    s = scenes(vol, 8)
    from clipvol.render.action import ClipRenderAction

    for kw, name in [({"mode": "x"}, "mode"), ({"selection": "x"}, "policy"), ({"policy": "texel-budget"}, "max_texels_drawn"), ({"step": 0}, "step"),
                     ({"lod_threshold": -1}, "lod_threshold"), ({"selection": "fixed", "level": 99}, "level"), ({"colour": 1}, "colour"),
                     ({"background": (2, 0, 0, 0)}, "background")]:
        with pytest.raises(ParameterError, match=name):
            ClipRenderAction(ctx, s.clip, **kw)


def test_shape_box_and_planes_clip_the_rays(scenes):
    from clipvol.scene.geometry import Shape

    vol = smooth_volume((32, 32, 32))
    box = ((5.0, 3.0, 4.0), (27.0, 29.0, 20.0))
    planes = ((1.0, 1.0, 0.0, -30.0),)  # keep x + y >= 30
    shape = Shape(box=box, planes=planes)
    cam = CAMERAS["perspective"](centre_of(vol.shape))
    s = scenes(vol, 8, policy="fixed", level=0, shape=shape)
    img = s.render(cam)
    assert s.action.last_frame_stats.counts["culled_shape"] > 0
    fc = cam.fit_depth(*s.pyramid.volume_box())
    r = ref.to_uint8(ref.raycast(vol, (1, 1, 1), fc, TF.table, s.pyramid.value_range, 0.5, shape=(box[0], box[1], planes)))
    full = s.reference(cam)
    assert diff(r, full).max() > 50  # the clipping matters
    assert diff(img, r).max() <= 2


def test_huge_virtual_volume_keeps_precision_in_brick_local_space(scenes, ctx):
    """A 2**20-per-axis procedural volume, viewed near its far corner: float32 world coordinates
    would be off by ~0.06 voxels there; brick-local coordinates render it like the reference."""
    from clipvol.loaders.procedural import ProceduralLoader

    from clipvol.render.action import ClipRenderAction
    from clipvol.scene.geometry import Shape

    n = 1 << 20
    loader = ProceduralLoader(f"procedural:fractal?size={n}&seed=3", brick=16)
    pyr = loader.pyramid
    s0 = n - 48
    box = ((s0 + 4.0,) * 3, (s0 + 36.0,) * 3)
    clip = ClipTexture(loader, "64MB", threads=2, center=(s0 + 20.0,) * 3)
    action = ClipRenderAction(ctx, clip, policy="fixed", level=0, shape=Shape(box=box))
    try:
        cam = Camera.perspective((s0 + 20.3, s0 + 20.2, s0 - 30.0), (s0 + 20.0,) * 3, size=(64, 64), fov_y=50)
        tf = TransferFunction.from_points([(0.0, (0, 0, 1, 0.0)), (0.5, (0, 1, 0, 0.1)), (1.0, (1, 0, 0, 0.5))])
        img = action.render(cam, tf, wait=True, timeout=60)
        assert action.last_frame_stats.converged
        start = (s0 - 1,) * 3
        sub = loader.generator.region(0, start, (s0 + 41,) * 3)
        fc = cam.fit_depth(*pyr.volume_box())
        r = ref.to_uint8(ref.raycast(sub, (1, 1, 1), fc, tf.table, tf.window(pyr.value_range), 0.5,
                                     shape=(box[0], box[1], ()), origin=(s0 - 1.0,) * 3))
        assert visible(r) > 0.3
        assert diff(img, r).max() <= 2
    finally:
        action.close()
        clip.close()


def test_front_to_back_with_early_termination_equals_back_to_front_over(scenes):
    vol = smooth_volume((48, 48, 48))
    opaque = TransferFunction.from_points([(0.0, (0, 0, 1, 0.1)), (1.0, (1, 0.5, 0, 0.9))])
    cam = Camera.perspective((-30.0, -20.0, -40.0), centre_of(vol.shape), size=(64, 64), fov_y=40)
    bg = (0.2, 0.3, 0.4, 1.0)
    a = scenes(vol, 8, policy="fixed", level=0, background=bg, merge_boxes=False, path="bricks")
    b = scenes(vol, 8, policy="fixed", level=0, background=bg, early_termination=False, merge_boxes=False,
               path="bricks")
    c = scenes(vol, 8, policy="fixed", level=0, background=bg, path="bricks")  # merged boxes, front to back
    d = scenes(vol, 8, policy="fixed", level=0, background=bg, path="single-pass")  # merged blocks in the table
    e = scenes(vol, 8, policy="fixed", level=0, background=bg, merge_boxes=False, path="single-pass")
    ia, ib, ic, id_ = a.render(cam, opaque), b.render(cam, opaque), c.render(cam, opaque), d.render(cam, opaque)
    ie = e.render(cam, opaque)
    assert a.action.occlusion_passes > 0 and b.action.occlusion_passes == 0
    assert a.action.boxes_drawn == 216 and c.action.boxes_drawn < 216
    assert d.action.path_drawn == "single-pass" and d.action.boxes_drawn == 1
    assert e.action.page_table_nodes == 216 and d.action.page_table_nodes == c.action.boxes_drawn
    assert diff(ia, ib).max() <= 1 and diff(ia, ic).max() <= 1 and diff(ia, id_).max() <= 1 and diff(ia, ie).max() <= 1
    # and both equal the reference composited over the background
    r = ref.raycast(vol, (1, 1, 1), cam.fit_depth(*a.pyramid.volume_box()), opaque.table, a.pyramid.value_range, 0.5)
    bgp = np.array([bg[0] * bg[3], bg[1] * bg[3], bg[2] * bg[3], bg[3]])
    assert diff(ib, ref.to_uint8(r + (1 - r[..., 3:4]) * bgp)).max() <= 2


def _black_wall_before_white():
    """A black front half whose opacity grows along x before an opaque white back half: the light
    that reaches the eye through the wall sweeps from visible to nothing across the image, so some
    pixels hold the last few 8-bit levels of white that a ray stopping early leaves out."""
    vol = np.ones((40, 24, 48), dtype=np.float32)  # z (towards the back), y, x
    vol[:20] = np.linspace(0.2, 0.6, 48, dtype=np.float32)[None, None, :]
    tf = TransferFunction.from_points([(0.0, (0, 0, 0, 0.0)), (0.6, (0, 0, 0, 0.35)), (0.61, (1, 1, 1, 1.0)),
                                       (1.0, (1, 1, 1, 1.0))], value_range=(0.0, 1.0))
    cam = Camera.perspective((23.5, 11.5, -90.0), (23.5, 11.5, 20.0), size=(96, 48), fov_y=20)
    return vol, tf, cam


def test_early_termination_changes_no_pixel_by_more_than_one_level(scenes, monkeypatch, draw_path):
    """A ray stops at OPAQUE = 1 - 0.5/255: what it leaves out is under half an 8-bit step, so the
    image is within 1 of the reference integrated to the end of every ray (no termination)."""
    import clipvol.render.paths.setup as setup_mod

    vol, tf, cam = _black_wall_before_white()
    s = scenes(vol, 16, policy="fixed", level=0, path=draw_path, merge_boxes=False)
    r = s.reference(cam, tf)
    assert visible(r) > 0.5
    assert diff(s.render(cam, tf), r).max() <= 1
    # the scene tells thresholds apart: a ray stopping at 0.99 leaves out up to 2.5 levels of the white
    monkeypatch.setattr(setup_mod, "OPAQUE", 0.99)
    loose = scenes(vol, 16, policy="fixed", level=0, path=draw_path, merge_boxes=False).render(cam, tf)
    assert diff(loose, r).max() >= 2


def test_auto_path_draws_many_boxes_in_one_pass_and_few_per_brick(scenes):
    """path="auto" (the default): a cut of at least AUTO_SINGLE_PASS_BOXES merged boxes is drawn by
    the single pass, a smaller one per brick; either way the image is the numpy reference's."""
    from clipvol.render.paths import AUTO_SINGLE_PASS_BOXES

    vol = smooth_volume((48, 48, 48))
    cam = Camera.perspective((-30.0, -20.0, -40.0), centre_of(vol.shape), size=(48, 48), fov_y=40)
    many = scenes(vol, 8, policy="fixed", level=0, merge_boxes=False)  # 216 boxes
    few = scenes(vol, 8, policy="fixed", level=0)  # merged into a handful
    a, b = many.render(cam), few.render(cam)
    assert many.action.params.path == few.action.params.path == "auto"
    assert many.action.page_table_nodes >= AUTO_SINGLE_PASS_BOXES and many.action.path_drawn == "single-pass"
    assert few.action.boxes_drawn < AUTO_SINGLE_PASS_BOXES and few.action.path_drawn == "bricks"
    r = many.reference(cam)
    assert visible(r) > 0.3
    assert diff(a, r).max() <= 2 and diff(b, r).max() <= 2


def test_merge_covers_bricks_beside_the_view_that_were_never_loaded(scenes):
    """A narrow view of a 48^3 volume loads only the bricks its rays reach (and their neighbours):
    the rest were never loaded. Where such bricks lie wholly beside the view, the merge still draws
    the volume as one box (no ray samples their slots), and the image is the unmerged frame's and
    the numpy reference's."""
    import itertools

    vol = smooth_volume((48, 48, 48))
    cam = Camera.perspective((-30.0, -20.0, -40.0), centre_of(vol.shape), size=(64, 64), fov_y=10)
    merged = scenes(vol, 8, policy="fixed", level=0, path="bricks")
    pieces = scenes(vol, 8, policy="fixed", level=0, path="bricks", merge_boxes=False)
    a, b = merged.render(cam), pieces.render(cam)
    grid = merged.pyramid.grid(0)
    every = np.array(list(itertools.product(*(range(k) for k in grid))))
    never_loaded = ~merged.action.cache.on_gpu_mask(0, every)
    assert never_loaded.sum() >= 10  # bricks the merged box covers without their data
    assert merged.action.boxes_drawn == 1 and pieces.action.boxes_drawn > 50
    r = merged.reference(cam)
    assert visible(r) > 0.9
    assert diff(a, b).max() <= 1 and diff(a, r).max() <= 2


def test_merged_boxes_never_cut_rays_short(scenes):
    """A merge whose box would need more samples per ray than the shader takes is not made."""
    vol = (np.random.default_rng(0).random((64, 64, 64)) * 0.2).astype(np.float32)
    tf = TransferFunction.from_points([(0.0, (1, 1, 1, 0.0)), (1.0, (1, 1, 1, 0.02))], value_range=(0, 1))
    cam = Camera.perspective((150.0, 130.0, 170.0), (32.0, 32.0, 32.0), fov_y=30, size=(12, 12))
    merged = scenes(vol, 8, policy="fixed", level=0, step=0.001, path="bricks")
    single = scenes(vol, 8, policy="fixed", level=0, step=0.001, merge_boxes=False, path="bricks")
    a, b = merged.render(cam, tf), single.render(cam, tf)
    assert merged.action.boxes_drawn == single.action.boxes_drawn == len(single.action.last_selection.items)
    np.testing.assert_array_equal(a, b)
    # the single pass takes no ray of more samples than llvmpipe's loop cap: drawn per brick instead
    sp = scenes(vol, 8, policy="fixed", level=0, step=0.001, path="single-pass")
    c = sp.render(cam, tf)
    assert sp.action.path_drawn == "bricks"
    np.testing.assert_array_equal(a, c)


def _pixel_rays_meet(cam, lo, hi) -> bool:
    """Does any pixel's ray (``cam.rays()``, in front of the eye) pass through box ``[lo, hi]``? (slab test)"""
    o, d = (v.reshape(-1, 3) for v in cam.rays())
    inv = 1.0 / np.where(np.abs(d) < 1e-300, 1e-300, d)
    t0, t1 = (np.asarray(lo) - o) * inv, (np.asarray(hi) - o) * inv
    near, far = np.minimum(t0, t1).max(axis=1), np.maximum(t0, t1).min(axis=1)
    return bool(np.any((near <= far) & (far >= 0)))


def test_may_cover_answers_whether_the_node_is_in_texture_memory_or_beside_the_view(scenes):
    """``merge_items``' ``may_cover`` (one-brick fast path and multi-brick nodes) against the bricks
    the frame actually put on the GPU and, for the others, against the pixels' rays: a node none of
    whose bricks' data a ray could read (its box grown by one voxel meets no ray) may be covered."""
    vol = smooth_volume((48, 40, 32))
    s = scenes(vol, 8, policy="fixed", level=0, path="bricks")
    # a narrow view: only some level-0 bricks are drawn (and uploaded)
    cam = Camera.perspective((15.0, 20.0, -6.0), (15.0, 20.0, 10.0), size=(32, 32), fov_y=20)
    s.render(cam)
    drawn = {tuple(int(v) for v in it.index) for it in s.action.last_selection.items if it.level == 0 and it.span == 1}
    may_cover = s.action._may_cover(cam)
    grid = s.pyramid.grid(0)
    every = np.array(list(np.ndindex(*grid)))
    on_gpu = s.action.cache.on_gpu_mask(0, every)  # the cache's own vectorised slot check
    uploaded = {tuple(int(v) for v in k) for k in every[on_gpu]}
    assert drawn and drawn <= uploaded and len(uploaded) < len(every)  # some bricks were never uploaded

    def unseen(level, node):
        lo, hi = s.pyramid.node_box(level, node)
        return not _pixel_rays_meet(cam, lo - 1.0, hi + 1.0)

    answers = []
    for idx in every:
        key = tuple(int(v) for v in idx)
        answers.append((key in uploaded, unseen(0, key)))
        assert may_cover(0, 0, [key]).tolist() == [key in uploaded or answers[-1][1]], idx
    assert any(not up and un for up, un in answers)  # never-loaded bricks beside the view: the new answer
    # a level-1 node: all eight of its level-0 bricks on the GPU, or the node beside the view
    for node in np.ndindex(*s.pyramid.grid(1)):
        kids = {tuple(2 * n + d for n, d in zip(node, o)) for o in np.ndindex(2, 2, 2)}
        kids = {k for k in kids if all(i < g for i, g in zip(k, grid))}
        assert may_cover(0, 1, [node]).tolist() == [kids <= uploaded or unseen(1, node)], node
