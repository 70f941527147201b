"""The render modes beside composite: minimum intensity projection, the average along the ray and the
iso-surface, in both draw paths, against references that share nothing with the renderer.

* minIP / average: numpy ``min`` / ``mean`` of the array along z, seen by an axis-aligned
  orthographic camera whose pixel centres and samples lie on voxel centres (step 1), so every ray's
  samples are exactly the voxels of one column; at a coarse level, against a 2x2x2 block mean of
  the array computed here.
* iso: the hit distance along each ray against the analytic sphere the volume samples (a distance
  field, so its iso-surface is the sphere itself), within half a voxel, and against an independent
  numpy ray march of the array (scipy's ``map_coordinates``, first sample at or above the value,
  linear between it and the sample before).
"""

from __future__ import annotations

import numpy as np
import pytest
import reference_raycast as ref
from scipy.ndimage import map_coordinates

from clipvol.errors import ParameterError
from clipvol.loaders.numpy_array import NumpyLoader
from clipvol.paging.cliptexture import ClipTexture
from clipvol.render.action import ClipRenderAction
from clipvol.scene.camera import Camera
from clipvol.scene.params import RenderParams
from clipvol.scene.transfer import TransferFunction

pytestmark = pytest.mark.gl

TF = TransferFunction.preset("viridis")


@pytest.fixture(autouse=True)
def _gl_clean(ctx):
    assert ctx.error == "GL_NO_ERROR"
    yield
    assert ctx.error == "GL_NO_ERROR"


def render(ctx, vol, cam, brick=8, tf=TF, **kw):
    """(image, raw float target, the action's defines) of one converged frame."""
    clip = ClipTexture(NumpyLoader(vol, brick=brick), "64MB", threads=2)
    kw.setdefault("policy", "fixed")
    kw.setdefault("level", 0)
    action = ClipRenderAction(ctx, clip, **kw)
    try:
        img = action.render(cam, tf, wait=True, timeout=20)
        assert action.last_frame_stats.converged
        raw = action.last_raw
        return img, None if raw is None else raw.copy(), action
    finally:
        action.close()
        clip.close()


def columns_volume(shape=(20, 24, 28)) -> np.ndarray:
    rng = np.random.default_rng(7)
    z, y, x = np.mgrid[0:shape[0], 0:shape[1], 0:shape[2]].astype(np.float64)
    v = 0.5 + 0.3 * np.sin(x / 3.0 + z / 4.0) * np.cos(y / 5.0) + 0.1 * rng.random(shape)
    v[3, 5, 7] = -0.2  # a single dark voxel must survive minIP
    return v.astype(np.float32)


def z_camera(shape, scale=1.0):
    """Orthographic along +z, one pixel per voxel of a level of voxel size ``scale``; the lattice
    plane (t = 0) through a voxel centre of that level, so step 1 samples exactly the centres."""
    nz, ny, nx = shape
    cz = scale * (nz // scale // 2) + 0.5 * (scale - 1.0)  # a centre of the level's voxels along z
    centre = ((nx - 1) / 2, (ny - 1) / 2, cz)
    return Camera.orthographic(centre, (0, 0, 1), (0, -1, 0), nx, ny, size=(int(nx / scale), int(ny / scale)))


def expected(values, lo, hi) -> np.ndarray:
    rgba = ref.tf_lookup(TF.table, (values - lo) / (hi - lo))
    return ref.to_uint8(np.concatenate([rgba[..., :3] * rgba[..., 3:], rgba[..., 3:]], axis=-1))


def diff(a, b) -> np.ndarray:
    return np.abs(a.astype(np.int64) - b.astype(np.int64))


@pytest.mark.parametrize("dtype", ["float32", "uint8", "uint16", "int16"])
@pytest.mark.parametrize("mode,reduce", [("minip", np.min), ("average", np.mean)])
def test_axis_aligned_projection_is_numpy_min_or_mean(ctx, draw_path, mode, reduce, dtype):
    """Every texture format: normalised r8 / r16 (signed shifted) and raw r32f."""
    vol = columns_volume()
    if dtype != "float32":  # whole numbers over a few dozen values: a mean between them must not round
        vol = (np.rint((vol + 0.2) * 40.0) - (10 if dtype == "int16" else 0)).astype(dtype)
    img, _, action = render(ctx, vol, z_camera(vol.shape), mode=mode, step=1.0, path=draw_path)
    assert action.path_drawn == draw_path
    assert sum(action.last_frame_stats.bricks_drawn.values()) > 1
    lo, hi = float(vol.min()), float(vol.max())
    expect = expected(reduce(vol.astype(np.float64), axis=0), lo, hi)
    assert diff(img, expect).max() <= 1
    assert expect[..., 3].mean() > 0.5  # the reference is mostly visible


def test_minip_and_mip_differ_where_a_dark_voxel_is(ctx, draw_path):
    """The dark voxel shows in minIP and not in MIP (the modes really differ)."""
    vol = columns_volume()
    a, _, _ = render(ctx, vol, z_camera(vol.shape), mode="minip", step=1.0, path=draw_path)
    b, _, _ = render(ctx, vol, z_camera(vol.shape), mode="mip", step=1.0, path=draw_path)
    lo, hi = float(vol.min()), float(vol.max())
    dark = expected(np.array([[-0.2]]), lo, hi)[0, 0]
    assert diff(a[5, 7], dark).max() <= 1
    assert diff(b[5, 7], dark).max() > 20


@pytest.mark.parametrize("mode,reduce", [("minip", np.min), ("average", np.mean)])
def test_coarse_level_frame_is_the_reduction_of_the_block_means(ctx, draw_path, mode, reduce):
    """A frame drawn from level 1 equals numpy's reduction of the 2x2x2 block means (the pyramid's
    mean filter, computed here) along z."""
    vol = columns_volume((24, 24, 28))
    img, _, action = render(ctx, vol, z_camera(vol.shape, 2.0), mode=mode, step=1.0, path=draw_path, level=1)
    assert set(action.last_frame_stats.bricks_drawn) == {1}
    v = vol.astype(np.float64)
    coarse = v.reshape(12, 2, 12, 2, 14, 2).mean(axis=(1, 3, 5))
    lo, hi = action.pyramid.value_range
    expect = expected(reduce(coarse, axis=0), lo, hi)
    assert diff(img, expect).max() <= 1


def test_iso_surface_of_a_sphere_is_the_sphere(ctx, draw_path):
    """A distance field's iso-surface at radius R is the sphere of radius R: the first-hit distance
    of every pixel whose ray meets it is the analytic ray-sphere distance within half a voxel, and
    equals a numpy ray march of the same array; rays that miss the sphere draw nothing."""
    n, R = 40, 12.0
    z, y, x = np.mgrid[0:n, 0:n, 0:n].astype(np.float64)
    c = (n - 1) / 2.0
    dist = np.sqrt((x - c) ** 2 + (y - c) ** 2 + (z - c) ** 2)
    vol = (30.0 - dist).astype(np.float32)  # >= 30 - R inside the sphere
    iso = 30.0 - R
    eye = np.array([c + 20.0, c - 25.0, c - 60.0])
    cam = Camera.perspective(tuple(eye), (c, c, c), size=(48, 40), fov_y=35)
    img, raw, action = render(ctx, vol, cam, brick=16, mode="iso", iso_value=iso, path=draw_path)
    assert action.path_drawn == draw_path
    o, d = cam.rays()
    o, d = o.reshape(-1, 3), d.reshape(-1, 3)
    # analytic: |o + t d - centre| = R
    oc = o - c
    b = (oc * d).sum(1)
    disc = b * b - ((oc * oc).sum(1) - R * R)
    hit = disc > 0
    t_exact = -b - np.sqrt(np.where(hit, disc, 0.0))
    got_hit = raw[..., 3].reshape(-1) > 0.5
    t_gl = raw[..., 0].reshape(-1)
    assert hit.sum() > 200
    # pixels whose ray grazes the sphere (within a voxel) may go either way
    margin = np.abs(np.sqrt(np.maximum((oc * oc).sum(1) - b * b, 0.0)) - R) < 1.0
    assert np.array_equal(got_hit[~margin], hit[~margin])
    both = hit & got_hit & ~margin
    assert np.abs(t_gl[both] - t_exact[both]).max() < 0.5
    # an independent numpy march of the array: samples t = k * delta, first >= iso, linear refinement
    delta = 0.5
    ks = np.arange(int(30 / delta), int(110 / delta))
    p = o[both, None, :] + (ks * delta)[None, :, None] * d[both, None, :]
    vals = map_coordinates(vol.astype(np.float64), p[..., ::-1].reshape(-1, 3).T, order=1, mode="nearest").reshape(p.shape[:2])
    first = np.argmax(vals >= iso, axis=1)
    assert (first > 0).all()
    rows = np.arange(len(first))
    v1, v0 = vals[rows, first], vals[rows, first - 1]
    t_ref = (ks[first] - (v1 - iso) / (v1 - v0)) * delta
    assert np.abs(t_gl[both] - t_ref).max() < 0.05
    # the image: opaque where the surface is, lit (brighter facing the eye), nothing elsewhere
    alpha = img[..., 3].reshape(-1)
    assert (alpha[both] == 255).all() and (alpha[~hit & ~margin] == 0).all()


def test_iso_paths_agree_and_depth_colouring_follows_distance(ctx):
    n, R = 32, 10.0
    z, y, x = np.mgrid[0:n, 0:n, 0:n].astype(np.float64)
    c = (n - 1) / 2.0
    vol = (20.0 - np.sqrt((x - c) ** 2 + (y - c) ** 2 + (z - c) ** 2)).astype(np.float32)
    cam = Camera.perspective((c + 10, c - 15, c - 50), (c, c, c), size=(40, 40), fov_y=35)
    grey = TransferFunction.preset("grey")
    a, ra, _ = render(ctx, vol, cam, brick=8, tf=grey, mode="iso", iso_value=10.0, path="bricks")
    b, rb, _ = render(ctx, vol, cam, brick=8, tf=grey, mode="iso", iso_value=10.0, path="single-pass")
    assert diff(a, b).max() <= 1
    dimg, draw, _ = render(ctx, vol, cam, brick=8, tf=grey, mode="iso", iso_value=10.0, iso_color="depth",
                           path="bricks", ambient=1.0, diffuse=0.0, specular=0.0)
    hit = draw[..., 3] > 0.5
    t = draw[..., 0][hit]
    g = dimg[..., 0][hit].astype(float)
    # unlit depth colouring through the grey table: nearer is darker, monotonic in distance
    assert np.corrcoef(t, g)[0, 1] > 0.99


def test_iso_needs_a_finite_value_and_modes_are_checked():
    with pytest.raises(ParameterError, match="iso_value"):
        RenderParams(mode="iso")
    with pytest.raises(ParameterError, match="iso_value"):
        RenderParams(mode="iso", iso_value=float("nan"))
    with pytest.raises(ParameterError, match="iso_color"):
        RenderParams(mode="iso", iso_value=1.0, iso_color="rainbow")
    with pytest.raises(ParameterError, match="mode"):
        RenderParams(mode="median")
    assert RenderParams(mode="iso", iso_value="2.5").iso_value == 2.5


@pytest.mark.slow_paths("bricks")
def test_iso_skips_what_lies_below_its_value_and_draws_the_same(ctx, tmp_path, draw_path):
    """Bricks (from a store's per-brick value ranges) and cells whose values all lie below the
    iso-value are culled / leapt - none of their samples can be a hit: the hit distances and the
    lighting equal those of a frame over an in-memory array that culls nothing and samples everything."""
    from clipvol.bricking.pipeline import brick_volume
    from clipvol.loaders.zarr_store import ZarrLoader

    n = 64
    z, y, x = np.mgrid[0:n, 0:n, 0:n].astype(np.float64)
    c = (n - 1) / 2.0
    vol = (30.0 - np.sqrt((x - c) ** 2 + (y - c) ** 2 + (z - c) ** 2)).astype(np.float32)
    brick_volume(vol, tmp_path / "s.zarr", brick=8, progress=False, workers=1)
    cam = Camera.perspective((c + 15, c - 20, c - 70), (c, c, c), size=(48, 48), fov_y=35)
    clip = ClipTexture(ZarrLoader(tmp_path / "s.zarr"), "64MB", threads=2)
    a = ClipRenderAction(ctx, clip, policy="fixed", level=0, mode="iso", iso_value=20.0, path=draw_path)
    try:
        a.render(cam, TF, wait=True, timeout=20)
        fast = a.last_raw.copy()
        assert a.skipped_empty and a.last_frame_stats.counts["culled_transparent"] > 0
        # and a composite frame under a table visible everywhere culls nothing: the culling is the iso-value's
        a.set_params(RenderParams(policy="fixed", level=0, path=draw_path))
        a.render(cam, TransferFunction.from_points([(0, (1, 1, 1, 0.1)), (1, (1, 1, 1, 0.1))]), wait=True, timeout=20)
        assert a.last_frame_stats.counts["culled_transparent"] == 0
    finally:
        a.close()
        clip.close()
    _, slow, b = render(ctx, vol, cam, brick=8, mode="iso", iso_value=20.0, path=draw_path, skip_empty=False)
    assert not b.skipped_empty
    hit = slow[..., 3] > 0.5
    assert hit.sum() > 100 and np.array_equal(hit, fast[..., 3] > 0.5)
    assert np.abs(fast[..., 0][hit] - slow[..., 0][hit]).max() < 1e-3
    assert np.abs(fast[..., 1][hit] - slow[..., 1][hit]).max() < 1e-3


def test_iso_surface_drawn_from_a_coarse_level_is_that_level_s_surface(ctx, draw_path):
    """From level 1 (2x2x2 block means, computed here) the hits equal a numpy march of the coarse
    array on level 1's lattice (step 0.5 of its voxel) and lie within half a coarse voxel of the
    analytic sphere."""
    n, R = 40, 10.0
    z, y, x = np.mgrid[0:n, 0:n, 0:n].astype(np.float64)
    c = (n - 1) / 2.0
    vol = (30.0 - np.sqrt((x - c) ** 2 + (y - c) ** 2 + (z - c) ** 2)).astype(np.float32)
    coarse = vol.astype(np.float64).reshape(20, 2, 20, 2, 20, 2).mean(axis=(1, 3, 5))
    cam = Camera.perspective((c + 20.0, c - 25.0, c - 60.0), (c, c, c), size=(40, 40), fov_y=30)
    _, raw, action = render(ctx, vol, cam, brick=8, mode="iso", iso_value=30.0 - R, path=draw_path, level=1)
    assert set(action.last_frame_stats.bricks_drawn) == {1}
    o, d = (a.reshape(-1, 3) for a in cam.rays())
    oc = o - c
    b = (oc * d).sum(1)
    disc = b * b - ((oc * oc).sum(1) - R * R)
    inner = disc > 4.0 * R  # away from the silhouette (where a coarse surface may differ in extent)
    got = raw[..., 3].reshape(-1) > 0.5
    t_gl = raw[..., 0].reshape(-1)
    assert inner.sum() > 100 and got[inner].all()
    t_exact = -b[inner] - np.sqrt(disc[inner])
    assert np.abs(t_gl[inner] - t_exact).max() < 1.0  # half a level-1 voxel
    delta = 1.0  # step 0.5 of level 1's voxel (2 world units)
    ks = np.arange(20, 110)
    p = o[inner, None, :] + (ks * delta)[None, :, None] * d[inner, None, :]
    u = (p - 0.5) / 2.0  # level-1 voxel coordinates: centre of coarse voxel i at 2 i + 0.5
    vals = map_coordinates(coarse, u[..., ::-1].reshape(-1, 3).T, order=1, mode="nearest").reshape(p.shape[:2])
    first = np.argmax(vals >= 30.0 - R, axis=1)
    rows = np.arange(len(first))
    v1, v0 = vals[rows, first], vals[rows, first - 1]
    t_ref = (ks[first] - (v1 - (30.0 - R)) / (v1 - v0)) * delta
    assert np.abs(t_gl[inner] - t_ref).max() < 0.05


def test_average_over_a_cut_of_two_levels_weights_samples_by_their_length(ctx):
    """Half of each ray through level 0, half through level 1 (samples twice as far apart): the
    average is the length-weighted mean of the two halves' samples, computed here with scipy's
    ``map_coordinates`` on the array and on its 2x2x2 block means - not the plain mean of the
    samples, which would count the coarse half half as much."""
    from clipvol.scene.selection import DrawItem

    z, y, x = np.mgrid[0:32, 0:16, 0:16].astype(np.float64)
    vol = (z / 31.0 + 0.1 * np.sin(x / 2.0) * np.cos(y / 3.0)).astype(np.float32)
    coarse = vol.astype(np.float64).reshape(16, 2, 8, 2, 8, 2).mean(axis=(1, 3, 5))
    loader = NumpyLoader(vol, brick=16)
    pyr = loader.pyramid
    clip = ClipTexture(loader, "64MB", threads=2)
    action = ClipRenderAction(ctx, clip, mode="average", step=1.0, path="bricks", merge_boxes=False)
    try:
        clip.wait_until_idle(20)
        lo0, hi0 = pyr.node_box(0, (0, 0, 0))  # level 0: z in [-0.5, 15.5)
        lo1, hi1 = pyr.node_box(1, (0, 0, 0))  # level 1 drawn over z in [15.5, 31.5)
        items = [DrawItem(1, (0, 0, 0), (lo1[0], lo1[1], hi0[2]), tuple(hi1)), DrawItem(0, (0, 0, 0), tuple(lo0), tuple(hi0))]
        # pixels on voxel centres in x, y; the lattice plane at z = 16: level-0 samples at z = 0..15,
        # level-1 samples (delta 2) at z = 16, 18, ..., 30
        cam = Camera.orthographic((7.5, 7.5, 16.0), (0, 0, 1), (0, -1, 0), 16, 16, size=(16, 16))
        img = action.render_items(cam, TF, items)
        value_range = pyr.value_range
    finally:
        action.close()
        clip.close()
    yy, xx = np.mgrid[0:16, 0:16].astype(np.float64)
    s0 = sum(vol.astype(np.float64)[k] for k in range(16))  # level 0: voxel centres, weight 1 each
    zs = np.arange(16, 31, 2, dtype=np.float64)
    pts = np.stack(np.broadcast_arrays((zs[:, None, None] - 0.5) / 2, (yy - 0.5) / 2, (xx - 0.5) / 2))
    v1 = map_coordinates(coarse, pts.reshape(3, -1), order=1, mode="nearest").reshape(8, 16, 16)
    weighted = (s0 * 1.0 + v1.sum(0) * 2.0) / (16 * 1.0 + 8 * 2.0)
    plain = (s0 + v1.sum(0)) / 24.0
    lo, hi = value_range
    assert diff(img, expected(weighted, lo, hi)).max() <= 1
    assert diff(img, expected(plain, lo, hi)).max() > 10


def test_iso_surface_cut_by_a_clip_plane_shows_the_cut_face(ctx, draw_path):
    """A solid ball cut by the plane z = c + 3 (the near part removed): rays that meet the plane
    inside the ball start inside the surface and hit at the plane itself (the cut face is drawn,
    flat), the others hit the sphere beyond it - both against the analytic geometry."""
    from clipvol.scene.geometry import Shape

    n, R = 40, 12.0
    z, y, x = np.mgrid[0:n, 0:n, 0:n].astype(np.float64)
    c = (n - 1) / 2.0
    vol = (30.0 - np.sqrt((x - c) ** 2 + (y - c) ** 2 + (z - c) ** 2)).astype(np.float32)
    zc = c + 3.0
    cam = Camera.perspective((c + 6.0, c - 4.0, c - 60.0), (c, c, c), size=(40, 40), fov_y=30)
    shape = Shape(planes=((0.0, 0.0, 1.0, -zc),))  # keep z >= zc
    _, raw, _ = render(ctx, vol, cam, brick=16, mode="iso", iso_value=30.0 - R, path=draw_path, shape=shape)
    o, d = (a.reshape(-1, 3) for a in cam.rays())
    t_plane = (zc - o[:, 2]) / d[:, 2]
    p = o + t_plane[:, None] * d
    r_at_plane = np.sqrt(((p - c) ** 2).sum(1))
    oc = o - c
    b = (oc * d).sum(1)
    disc = b * b - ((oc * oc).sum(1) - R * R)
    t_far = -b + np.sqrt(np.maximum(disc, 0.0))
    got = raw[..., 3].reshape(-1) > 0.5
    t_gl = raw[..., 0].reshape(-1)
    cap = r_at_plane < R - 1.0  # the plane cuts the ball here: the hit is on the plane
    assert cap.sum() > 100 and got[cap].all()
    assert np.abs(t_gl[cap] - t_plane[cap]).max() < 0.5
    ring = (r_at_plane > R + 1.0) & (disc > 4.0 * R) & (t_far > t_plane + 1.0)  # the sphere beyond the plane
    if ring.any():
        assert got[ring].all()
        t_near = -b - np.sqrt(np.maximum(disc, 0.0))
        assert np.abs(t_gl[ring] - np.maximum(t_near[ring], t_plane[ring])).max() < 0.5
    miss = disc < -4.0 * R
    assert miss.sum() > 20 and not got[miss].any()
