"""SliceAction: slices read back against numpy's slices and scipy's resampling; no seams at level
changes; a moved point of interest uploads only the tiles that changed."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
from scipy.ndimage import map_coordinates

from clipvol.errors import ParameterError
from clipvol.loaders.numpy_array import NumpyLoader
from clipvol.paging.cliptexture import BrickState, ClipTexture
from clipvol.render.slice_action import SliceAction, window_level_grey
from clipvol.scene.plane import Plane

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from slice_reference import finest_in_reach  # noqa: E402


@pytest.fixture
def vol_u8(rng):
    return rng.integers(0, 256, size=(40, 70, 90), dtype=np.uint8)


def _render(gl, vol, plane, *, brick=16, size=None, px=None, **params):
    ld = NumpyLoader(vol, brick=brick)
    with ClipTexture(ld, "64MB", 2) as ct, SliceAction(gl, ct, **params) as sa:
        rgba, values = sa.render(plane, size, px, wait=True, timeout=60, return_values=True)
        return rgba, values, sa.last_stats, ld.pyramid


def test_axis_slices_at_level0_equal_numpy_exactly_for_integers(gl, vol_u8):
    ld = NumpyLoader(vol_u8, brick=16)
    pyr = ld.pyramid
    with ClipTexture(ld, "64MB", 2) as ct, SliceAction(gl, ct, level=0) as sa:
        for name, k, ref in [("axial", 17, vol_u8[17]), ("coronal", 33, vol_u8[:, 33, :][::-1]),
                             ("sagittal", 50, vol_u8[:, :, 50][::-1])]:
            _, v = sa.render(Plane.axis(pyr, name, k), wait=True, timeout=60, return_values=True)
            assert v.dtype == np.float32 and v.shape == ref.shape
            assert np.array_equal(v, ref.astype(np.float32)), name
            assert sa.last_stats.converged and set(sa.last_stats.tiles_per_level) == {0}


@pytest.mark.parametrize("dtype", ["int16", "uint16", "int8"])
def test_axial_slice_is_exact_for_other_integer_types(gl, rng, dtype):
    info = np.iinfo(dtype)
    vol = rng.integers(info.min, info.max, size=(20, 24, 28), endpoint=True).astype(dtype)
    pl = Plane.axis(NumpyLoader(vol, brick=8).pyramid, "axial", 7)
    _, v, st, _ = _render(gl, vol, pl, brick=8, level=0)
    np.testing.assert_array_equal(v, vol[7].astype(np.float32))


def test_axis_slice_of_float_data_within_1e6(gl, rng):
    vol = rng.normal(size=(24, 33, 41)).astype(np.float32) * 100
    pl = Plane.axis(NumpyLoader(vol, brick=8).pyramid, "axial", 11)
    _, v, st, _ = _render(gl, vol, pl, brick=8, level=0)
    assert np.max(np.abs(v - vol[11])) <= 1e-6 * np.ptp(vol)


def test_oblique_slice_equals_scipy_map_coordinates(gl, rng):
    vol = rng.random((40, 70, 90)).astype(np.float32)
    pl = Plane.through((45.3, 30.1, 20.2), (0.3, -0.5, 0.8), up=(0, 0, 1))
    _, v, st, _ = _render(gl, vol, pl, size=(96, 64), px=1.3, level=0)
    pts = pl.pixel_points((96, 64), 1.3)
    ref = map_coordinates(vol.astype(np.float64), pts[..., ::-1].transpose(2, 0, 1), order=1, mode="nearest")
    # signed distance outside the volume box; pixels within the rasteriser's sub-pixel precision
    # (1/256 pixel) of its faces may go either way
    out = np.maximum(np.maximum(-0.5 - pts, pts - np.array([89.5, 69.5, 39.5])), -np.inf).max(axis=-1)
    inside, outside = out < -0.01 * 1.3, out > 0.01 * 1.3
    assert inside.sum() > 1000 and outside.sum() > 100
    assert np.all(np.isfinite(v[inside])) and np.all(np.isnan(v[outside]))
    assert np.max(np.abs(v[inside] - ref[inside])) <= 1e-3 * np.ptp(vol)


def _smooth(shape):
    z, y, x = np.meshgrid(*(np.arange(n, dtype=np.float64) for n in shape), indexing="ij")
    return (np.sin(x / 5.0) * np.cos(y / 7.0) + 0.5 * np.sin((z + x) / 6.0)).astype(np.float32)


class _LevelsDisagree:
    """A loader whose level ``L`` is a gentle ramp plus ``L``: every level change is a jump of 1
    unless the renderer blends (the worst case of a pyramid whose levels disagree)."""

    def __init__(self, shape, brick):
        z, y, x = np.meshgrid(*(np.arange(n, dtype=np.float64) for n in shape), indexing="ij")
        self.base = NumpyLoader((0.002 * x + 0.001 * y + 0.001 * z).astype(np.float32), brick=brick)
        self.pyramid = self.base.pyramid

    def read_brick(self, level, index):
        return self.base.read_brick(level, index) + np.float32(level)


def _steps(v, levels):
    """``(across, inside)``: largest |step| between horizontally / vertically adjacent pixels whose
    tiles differ in level, and between pixels both in level-0 tiles."""
    across = inside = 0.0
    for a, b, la, lb in ((v[:, :-1], v[:, 1:], levels[:, :-1], levels[:, 1:]),
                         (v[:-1], v[1:], levels[:-1], levels[1:])):
        d = np.abs(a - b)
        ok = np.isfinite(d) & (la >= 0) & (lb >= 0)
        if (ok & (la != lb)).any():
            across = max(across, float(d[ok & (la != lb)].max()))
        if (ok & (la == 0) & (lb == 0)).any():
            inside = max(inside, float(d[ok & (la == 0) & (lb == 0)].max()))
    return across, inside


def _ramp(pts):
    """The base of :class:`_LevelsDisagree` at world points (linear: every level samples it exactly)."""
    return 0.002 * pts[..., 0] + 0.001 * pts[..., 1] + 0.001 * pts[..., 2]


@pytest.mark.parametrize("df", [1.0, 0.5])
def test_each_pixel_shows_the_finest_level_in_reach_and_blends_only_towards_its_parent(gl, df):
    """Against the rule stated point by point (tests/slice_reference.py): without blending every pixel
    shows exactly its finest level in reach (level ``L`` reads ``ramp + L``); with it, a pixel moves
    from its level towards the next coarser one and no further."""
    shape = (64, 96, 96)
    ld = _LevelsDisagree(shape, 8)
    pl = Plane.through((47.5, 47.5, 31.5), (0.2, 0.3, 0.93))
    pts = pl.pixel_points((96, 96), 1.0)
    flat = pts.reshape(-1, 3)
    want = finest_in_reach(flat, (20.0, 20.0, 31.5), df, shape, 8, ld.pyramid.num_levels).reshape(96, 96)
    # pixels inside the volume, at least one voxel of their level from every face of their level's bricks
    # and from the volume's faces (a tile clamps at a face whose neighbour is not paged, and every
    # level at the volume's faces: the ramp is then read up to half a voxel short)
    inside = np.all((pts > 0.5) & (pts < np.array(shape[::-1]) - 1.5), axis=-1)
    interior = inside.copy()
    for L in range(ld.pyramid.num_levels):
        t = (pts + 0.5) / (8 * 2.0**L)
        far = np.all(np.abs(t - np.rint(t)) * 8 > 1.0, axis=-1)
        far &= np.all((pts > 2.0**L - 0.5) & (pts < np.array(shape[::-1]) - 0.5 - 2.0**L), axis=-1)
        interior &= (want != L) | far
    with ClipTexture(ld, "64MB", 2) as ct, SliceAction(gl, ct, focus=(20.0, 20.0, 31.5), distance_factor=df) as sa:
        sa.blend = False
        _, v = sa.render(pl, (96, 96), 1.0, wait=True, timeout=60, return_values=True)
        assert sa.last_stats.converged and len(np.unique(want[inside])) >= 3
        assert interior.sum() > 2000
        np.testing.assert_allclose(v[interior], (_ramp(pts) + want)[interior], atol=1e-3)
        off = np.abs(v - _ramp(pts) - want)  # within a voxel of a face: clamped, never another level
        assert np.all(off[inside] < 0.05)
        sa.blend = True
        _, vb = sa.render(pl, (96, 96), 1.0, wait=True, timeout=60, return_values=True)
        assert sa.last_stats.converged and sa.last_stats.blended > 0
        shown = vb - _ramp(pts)
        assert np.all(shown[inside] > want[inside] - 0.05) and np.all(shown[inside] < want[inside] + 1.05)
        assert np.any(shown[inside] > want[inside] + 0.5)  # tiles do blend
        assert _steps(vb, want)[0] < _steps(v, want)[0] or _steps(vb, want)[0] <= 1.05


def test_level_changes_blend_and_a_jump_shows_the_levels_it_skips(gl):
    """A tile next to a coarser box blends towards its parent, so a change of one level shows no
    step larger than the blend leaves (one level where a box cannot blend), and a jump of ``k``
    levels an edge of at least ``k - 1`` levels' difference: the finer side reaches its parent's
    level, not the coarser side's (no balancing between neighbours)."""
    shape = (64, 96, 96)
    ld = _LevelsDisagree(shape, 8)
    pl = Plane.through((47.5, 47.5, 31.5), (0, 0, 1))
    pts = pl.pixel_points((96, 96), 1.0)
    focus, df = (20.0, 20.0, 31.5), 0.15
    want = finest_in_reach(pts.reshape(-1, 3), focus, df, shape, 8, ld.pyramid.num_levels).reshape(96, 96)
    with ClipTexture(ld, "64MB", 2) as ct, SliceAction(gl, ct, focus=focus, distance_factor=df) as sa:
        _, v = sa.render(pl, (96, 96), 1.0, wait=True, timeout=60, return_values=True)
        assert sa.last_stats.converged
        shown = v - _ramp(pts)
        jumps = 0
        for a, b, la, lb in ((shown[:, :-1], shown[:, 1:], want[:, :-1], want[:, 1:]),
                             (shown[:-1], shown[1:], want[:-1], want[1:])):
            k = np.abs(la - lb)
            ok = np.isfinite(a) & np.isfinite(b)
            jumps += int((ok & (k >= 2)).sum())
            step = np.abs(a - b)
            assert np.all(step[ok & (k >= 2)] >= k[ok & (k >= 2)] - 1 - 0.05)
            assert np.all(step[ok & (k <= 1)] <= 1.05)
        assert jumps > 0  # the point of interest's level-0 part meets level 2


def test_moving_the_point_of_interest_uploads_only_the_tiles_that_changed(gl):
    vol = _smooth((32, 128, 128))
    ld = NumpyLoader(vol, brick=8)
    pl = Plane.axis(ld.pyramid, "axial", 15)
    with ClipTexture(ld, "64MB", 2) as ct, SliceAction(gl, ct, focus=(10.0, 10.0, 15.0)) as sa:
        sa.render(pl, wait=True, timeout=60)
        cache = sa.cache
        uploads: list = []
        commit = cache.commit

        def spy():
            uploads.extend(cache.pending_keys())
            return commit()

        cache.commit = spy

        def on_gpu():
            out = set()
            for L, keys in enumerate(cache._slot_key):
                if keys is not None:
                    out |= {(L, tuple(int(i) for i in k)) for k in keys.reshape(-1, 3) if k[0] >= 0}
            return out

        def needed():
            sel = sa.last_selection
            return {(it.level, tuple(it.index)) for it in sel.items}

        before, need1 = on_gpu(), needed()
        sa.set_params(sa.params.__class__(**{**{f: getattr(sa.params, f) for f in sa.params.names()},
                                             "focus": (110.0, 100.0, 15.0)}))
        sa.render(pl, wait=True, timeout=60)
        need2 = needed()
        assert need1 & need2 and need2 - need1  # some tiles stay, some change
        up = set(uploads)
        assert not (up & before), "a brick already on the GPU was uploaded again"
        assert need2 - before <= up  # every new tile came in this frame
        # nothing else came: only new tiles, their low tiles and their same-level filtering neighbours
        allowed = set()
        for L, b in need2 | {(L + 1, tuple(i // 2 for i in b)) for L, b in need2}:
            for d in np.ndindex(3, 3, 3):
                allowed.add((L, tuple(int(i) + int(o) - 1 for i, o in zip(b, d))))
        assert up <= allowed
        uploads.clear()
        sa.render(pl, wait=True, timeout=60)
        assert uploads == [] and sa.last_stats.bytes_uploaded == 0


def test_window_level_and_bad_input(gl, vol_u8):
    rgba, v, st, pyr = _render(gl, vol_u8, Plane.axis(NumpyLoader(vol_u8, brick=16).pyramid, "axial", 3), level=0)
    assert rgba.shape == (70, 90, 4) and np.all(rgba[..., 3] == 255)
    g = window_level_grey(v, 100.0, 50.0)
    assert np.all(g[v <= 75, 0] == 0) and np.all(g[v >= 125, 0] == 255)
    with pytest.raises(ParameterError, match="window"):
        window_level_grey(v, 100.0, 0.0)
    ld = NumpyLoader(vol_u8, brick=16)
    with ClipTexture(ld, "64MB", 2) as ct, SliceAction(gl, ct) as sa:
        with pytest.raises(ParameterError, match="plane"):
            sa.render(Plane.through((0, 0, 500.0), (0, 0, 1)))
        with pytest.raises(ParameterError, match="pixel_size"):
            sa.render(Plane.axis(ld.pyramid, "axial", 3), pixel_size=0.0)


def test_slice_in_the_3d_view_is_the_plane_seen_by_the_camera(gl, rng):
    """Perspective view of an oblique plane: the pixels it covers are the rays that meet the plane
    inside the volume (numpy), coloured by the transfer function of scipy's resampling there."""
    from clipvol.render.action import ClipRenderAction
    from clipvol.scene.camera import Camera
    from clipvol.scene.transfer import TransferFunction

    vol = rng.random((24, 40, 48)).astype(np.float32)
    ld = NumpyLoader(vol, brick=8)
    tf = TransferFunction.preset("viridis")
    pl = Plane.through((24.0, 20.0, 12.0), (0.2, 0.4, 0.9))
    cam = Camera.perspective((90.0, -50.0, -70.0), (23.5, 19.5, 11.5), up=(0, -1, 0), fov_y=40, size=(96, 80))
    with ClipTexture(ld, "64MB", 2) as ct, ClipRenderAction(gl, ct) as va, SliceAction(gl, ct, level=0) as sa:
        img = sa.render_in_view(va, cam, tf, pl, wait=True, timeout=60)
        vol_only = va.render(cam, tf, wait=True, timeout=60)
    o, d = cam.rays()
    n = np.asarray(pl.normal)
    t = ((np.asarray(pl.origin) - o) @ n) / (d @ n)
    hit = o + t[..., None] * d
    out = np.maximum(np.maximum(-0.5 - hit, hit - np.array([47.5, 39.5, 23.5])), -np.inf).max(axis=-1)
    inside, outside = (out < -0.05) & (t > 0), (out > 0.05) | (t <= 0)
    ref = map_coordinates(vol.astype(np.float64), hit[..., ::-1].transpose(2, 0, 1), order=1, mode="nearest")
    want = np.rint(tf.lookup(ref, ld.pyramid.value_range)[..., :3] * 255)
    assert inside.sum() > 1000
    assert np.all(img[inside, 3] == 255)
    assert np.max(np.abs(img[inside, :3].astype(int) - want[inside])) <= 2
    # rays that miss the volume box show the (transparent) background; the rest of the volume
    # still shows where the plane is not; the plane covers what the uncut volume showed
    lo_b, hi_b = np.array([-0.5] * 3), np.array([47.5, 39.5, 23.5])
    with np.errstate(divide="ignore", invalid="ignore"):
        ta, tb = (lo_b - o) / d, (hi_b - o) / d
    t0, t1 = np.minimum(ta, tb).max(axis=-1), np.maximum(ta, tb).min(axis=-1)
    miss = ~(t1 > np.maximum(t0, 0))
    assert miss.sum() > 100 and np.all(img[miss, 3] == 0)
    assert np.any(img[outside & ~miss, 3] > 0)
    assert np.mean(np.abs(img[inside, :3].astype(int) - vol_only[inside, :3].astype(int))) > 5


def _chunk_bytes_on_disk(store, keys) -> int:
    import os

    total = 0
    for L, idx in keys:
        f = os.path.join(store, str(L), "c", *(str(int(i)) for i in idx))
        total += os.path.getsize(f) if os.path.exists(f) else 0
    return total


@pytest.fixture(scope="module")
def wave_store(tmp_path_factory):
    from clipvol.bricking.pipeline import brick_volume

    shape = (48, 96, 96)
    z, y, x = np.meshgrid(*(np.arange(n, dtype=np.float64) for n in shape), indexing="ij")
    vol = ((np.sin(x / 9) * np.cos(y / 7) + 0.5 * np.sin((z + x) / 6)) * 1000 + 2000).astype(np.uint16)
    path = tmp_path_factory.mktemp("slab") / "s.zarr"
    brick_volume(vol, path, brick=8, progress=False, workers=1)
    return vol, path


def test_slab_windows_read_only_the_slab_and_draw_the_same_levels(gl, wave_store):
    from clipvol.loaders.zarr_store import ZarrLoader
    from clipvol.paging.region import Region

    vol, path = wave_store
    out = {}
    for follow in (True, False):
        ld = ZarrLoader(path)
        pyr = ld.pyramid
        kw = dict(region=Region.empty(pyr.num_levels)) if follow else {}
        with ClipTexture(ld, "64MB", 2, **kw) as ct, SliceAction(gl, ct, focus=(30.0, 40.0, 21.0)) as sa:
            sa.follow_plane, sa.blend = follow, False
            _, v = sa.render(Plane.axis(pyr, "axial", 21), wait=True, timeout=60, return_values=True)
            st = sa.last_stats
            assert st.converged and st.bytes_read is not None and st.bytes_read > 0
            assert ct.wait_until_idle(60)
            # every brick read is resident (the whole pyramid fits): the bytes read are their chunk files
            assert ld.read_counter.bytes == _chunk_bytes_on_disk(path, ct.resident_bricks())
            out[follow] = (v, sa.last_levels.copy(), ld.read_counter.bytes, len(ct.resident_bricks()))
    (v1, l1, b1, n1), (v0, l0, b0, n0) = out[True], out[False]
    np.testing.assert_array_equal(l1, l0)  # the same cut, level for level
    level0 = l1 == 0
    assert level0.sum() > 100
    # pixel centres on voxel centres of integer data: level-0 tiles are exact
    np.testing.assert_array_equal(v1[level0], vol[21][level0].astype(np.float32))
    assert np.all(np.isfinite(v1))
    assert b1 * 4 < b0 and n1 * 4 < n0  # cube windows read the whole pyramid here


def test_scrolling_prefetches_the_next_slab(gl, wave_store):
    from clipvol.loaders.zarr_store import ZarrLoader
    from clipvol.paging.region import Region

    vol, path = wave_store
    ld = ZarrLoader(path)
    pyr = ld.pyramid
    nxt = (0, (2, 5, 5))  # level 0, the layer of voxels 16..23 under the focus
    with ClipTexture(ld, "64MB", 2, region=Region.empty(pyr.num_levels)) as ct, \
            SliceAction(gl, ct, level=0) as sa:
        sa.render(Plane.axis(pyr, "axial", 14), wait=True, timeout=60)
        assert ct.wait_until_idle(60)
        assert ct.state(*nxt) != BrickState.RESIDENT  # one slice reads its own layer only
        sa.render(Plane.axis(pyr, "axial", 15), wait=True, timeout=60)  # scrolling up by one voxel
        assert ct.wait_until_idle(60)
        assert ct.state(*nxt) == BrickState.RESIDENT  # the next slice's layer was read ahead
        before = ld.read_counter.bytes
        sa.render(Plane.axis(pyr, "axial", 16), wait=True, timeout=60)
        assert sa.last_stats.converged and sa.last_stats.bytes_read == ld.read_counter.bytes - before


def test_a_viewer_that_never_waits_converges_on_bricks_beyond_the_region(gl):
    # y = 64 with the point of interest there: balancing wants a few coarse bricks the region rule
    # leaves out (tests/scene/test_slice_region.py); the slice asks for them itself
    from clipvol.paging.region import Region

    vol = _smooth((96, 128, 160))
    ld = NumpyLoader(vol, brick=8)
    pl = Plane.through((30.0, 64.0, 20.0), (0, 1, 0))
    with ClipTexture(ld, "64MB", 2, region=Region.empty(ld.pyramid.num_levels)) as ct, \
            SliceAction(gl, ct, focus=(30.0, 64.0, 20.0), distance_factor=0.5) as sa:
        done = []
        for _ in range(4):
            sa.render(pl, (128, 96), 1.0, wait=False)
            done.append(sa.last_stats.converged)
            assert ct.wait_until_idle(30)
        assert not done[0] and done[-1]
