"""The draw-mode registry (clipvol.render.modes): every registered mode, drawn by every registered
draw path, equals a numpy reference of that mode that shares nothing with the renderer; and a mode
registered here (one class, one register call) is accepted by RenderParams, draws through both
paths with its own GLSL, and is forgotten again when unregistered.

The scene is test_modes' (its volume, camera and colour mapping): an axis-aligned orthographic
camera whose pixel centres and samples (step 1) lie on voxel centres, so every ray's samples are
exactly one column ``vol[:, y, x]`` of the array. The references, per mode name:

* composite - :func:`reference_raycast.raycast`, the numpy emission-absorption ray caster;
* mip / minip / average - numpy ``max`` / ``min`` / ``mean`` of the column through the table;
* iso - the first column sample at or above the value, placed linearly between it and the sample
  before (the depth the target holds), opaque wherever a column reaches the value.

A newly registered mode without a reference here fails its test, naming what to add.
"""

from __future__ import annotations

import numpy as np
import pytest
import reference_raycast as ref
from test_modes import TF, columns_volume, diff, expected, render, z_camera

from clipvol.errors import ParameterError
from clipvol.render import modes, paths
from clipvol.render.modes import DRAW_MODES, DrawMode
from clipvol.scene.params import RenderParams

pytestmark = pytest.mark.gl

ISO = 0.75  # inside the columns' range: some rays reach it at once, some later, some never


@pytest.fixture(autouse=True)
def _gl_clean(ctx):
    assert ctx.error == "GL_NO_ERROR"
    yield
    assert ctx.error == "GL_NO_ERROR"


def _composite(vol, img, raw, action):
    fc = z_camera(vol.shape).fit_depth(*action.pyramid.volume_box())
    expect = ref.to_uint8(ref.raycast(vol, (1, 1, 1), fc, TF.table, TF.window(action.pyramid.value_range), 1.0))
    assert diff(img, expect).max() <= 2
    assert expect[..., 3].mean() > 0.3  # the reference is mostly visible


def _reduction(reduce):
    def check(vol, img, raw, action):
        lo, hi = action.pyramid.value_range
        expect = expected(reduce(vol.astype(np.float64), axis=0), lo, hi)
        assert diff(img, expect).max() <= 1
        assert expect[..., 3].mean() > 0.5

    return check


def _iso(vol, img, raw, action):
    v = vol.astype(np.float64)
    reached = v >= ISO
    hit = reached.any(axis=0)
    first = np.argmax(reached, axis=0)
    v1 = np.take_along_axis(v, first[None], 0)[0]
    v0 = np.take_along_axis(v, np.maximum(first - 1, 0)[None], 0)[0]
    z_ref = np.where(first > 0, first - (v1 - ISO) / np.where(first > 0, v1 - v0, 1.0), 0.0)
    assert 0.1 < hit.mean() < 0.9  # some columns reach the value, some do not
    got = raw[..., 3] > 0.5
    assert np.array_equal(got, hit)
    cz = vol.shape[0] // 2  # the camera's plane (t = 0) through the centre voxel (z_camera)
    assert np.abs(raw[..., 0][hit] + cz - z_ref[hit]).max() < 1e-3
    assert (img[..., 3][hit] == 255).all() and (img[..., 3][~hit] == 0).all()


#: mode name -> (extra RenderParams fields, check(vol, image, raw target, action))
REFERENCES = {
    "composite": ({}, _composite),
    "mip": ({}, _reduction(np.max)),
    "minip": ({}, _reduction(np.min)),
    "average": ({}, _reduction(np.mean)),
    "iso": ({"iso_value": ISO}, _iso),
}


@pytest.mark.parametrize("path", sorted(paths.DRAW_PATHS))
@pytest.mark.parametrize("mode", sorted(DRAW_MODES))
def test_every_registered_mode_matches_its_numpy_reference(ctx, mode, path):
    if mode not in REFERENCES:
        pytest.fail(f"mode {mode!r} is registered but has no numpy reference: add one to REFERENCES in {__file__}")
    kw, check = REFERENCES[mode]
    vol = columns_volume()
    img, raw, action = render(ctx, vol, z_camera(vol.shape), mode=mode, step=1.0, path=path, **kw)
    assert action.path_drawn == path
    if path == "bricks":
        assert sum(action.last_frame_stats.bricks_drawn.values()) > 1  # boxes blended with each other
    check(vol, img, raw, action)


def test_every_reference_names_a_registered_mode():
    """The references stay in step with the registry (a renamed mode is not silently untested)."""
    assert set(REFERENCES) <= set(DRAW_MODES)


# -- a mode registered by the test ---------------------------------------------------------------
class Spread(DrawMode):
    """Max minus min along the ray: the target holds ``(max, -min)`` (both blend with ``MAX``
    between boxes); the read-back shows the difference as grey over the table's window."""

    name = "test-spread"
    clear = (-3.0e38, -3.0e38, 0.0, 0.0)
    glsl = """
#define STATE inout vec2 mm, inout bool hit
#define STATE_ARGS mm, hit
#define STATE_INIT vec2 mm = vec2(-3.0e38); bool hit = false;
#define STATE_OUT { if (!hit) discard; f_color = vec4(mm, 0.0, 1.0); }
#define MODE_TAKE(texel) { float v_ = (texel); mm = max(mm, vec2(v_, -v_)); hit = true; }
"""

    def set_blend(self, ctx, mgl) -> bool:
        ctx.blend_equation = mgl.MAX
        return True

    def read_back(self, raw, params, tf, fmt, value_range, depth):
        r = raw.astype(np.float64)
        hit = r[..., 3] > 0.5
        lo, hi = tf.window(value_range)
        g = np.where(hit, np.clip(fmt.a * (r[..., 0] + r[..., 1]) / (hi - lo), 0.0, 1.0), 0.0)
        a = hit.astype(np.float64)
        return np.stack([g, g, g, a], axis=-1)


@pytest.fixture
def spread():
    with pytest.raises(ParameterError, match="test-spread"):
        RenderParams(mode="test-spread")  # not a mode before it is registered
    modes.register(Spread)
    yield Spread
    modes.unregister(Spread.name)
    with pytest.raises(ParameterError, match="mode: expected one of"):
        RenderParams(mode="test-spread")
    assert Spread.name not in DRAW_MODES


@pytest.mark.parametrize("nan", [False, True], ids=["finite", "nan"])
@pytest.mark.parametrize("path", ["bricks", "single-pass"])
def test_a_mode_registered_here_draws_through_both_paths(ctx, spread, path, nan):
    """Its own GLSL in the plain and in the NaN-aware march: the target holds numpy's max and min
    of each column (NaN skipped), the image their difference as grey."""
    vol = columns_volume()
    if nan:
        vol[2:5, 3:9, 4:11] = np.nan
    assert RenderParams(mode="test-spread").mode == "test-spread"
    img, raw, action = render(ctx, vol, z_camera(vol.shape), mode="test-spread", step=1.0, path=path)
    assert action.path_drawn == path
    assert action.defines()["MODE_GLSL"]
    if path == "bricks":
        assert sum(action.last_frame_stats.bricks_drawn.values()) > 1
    v = vol.astype(np.float64)
    vmax, vmin = np.nanmax(v, axis=0), np.nanmin(v, axis=0)
    assert np.abs(raw[..., 0] - vmax).max() < 1e-6
    assert np.abs(-raw[..., 1] - vmin).max() < 1e-6
    lo, hi = TF.window(action.pyramid.value_range)
    grey = np.rint(np.clip((vmax - vmin) / (hi - lo), 0.0, 1.0) * 255.0)
    assert np.abs(img[..., 0].astype(np.float64) - grey).max() <= 1
    assert (img[..., 3] == 255).all()
    assert np.ptp(grey) > 50  # the spread differs between columns


def test_a_mode_needs_its_ray_code_once():
    class Neither(DrawMode):
        name = "test-neither"

    class Both(DrawMode):
        name = "test-both"
        define = "MODE_MIP"
        glsl = "// nothing"

    for cls in (Neither, Both):
        with pytest.raises(ParameterError, match=cls.__name__):
            modes.register(cls)
        assert cls.name not in DRAW_MODES


def test_overlays_are_refused_by_modes_that_do_not_classify():
    """An overlay is composited over the primary's classified samples: a mode that does not
    classify (the projections, iso) refuses it, naming the overlay; composite takes it."""
    from clipvol.loaders.numpy_array import NumpyLoader
    from clipvol.scene.overlay import Overlay

    ov = Overlay(NumpyLoader(np.zeros((8, 8, 8), np.float32), brick=8), TF)
    for name, mode in DRAW_MODES.items():
        kw = REFERENCES.get(name, ({}, None))[0]
        if mode.classifies:
            assert RenderParams(mode=name, overlays=(ov,), **kw).overlays == (ov,)
        else:
            with pytest.raises(ParameterError, match=f"overlays: expected mode 'composite'.*{name}"):
                RenderParams(mode=name, overlays=(ov,), **kw)


def test_built_in_modes_are_checked_before_the_renderer_is_imported():
    """The scene stage states the built-in modes' needs itself (it imports no render module), so
    ``RenderParams(mode="iso")`` without a value is refused even where nothing has imported
    ``clipvol.render.modes``: a fresh interpreter shows it, and the statement agrees with the
    registered modes."""
    import subprocess
    import sys

    from clipvol.scene.params import BUILT_IN_MODE_NEEDS

    for name, (requires, classifies) in BUILT_IN_MODE_NEEDS.items():
        m = DRAW_MODES[name]
        assert (tuple(m.requires), bool(m.classifies)) == (requires, classifies), name
    code = ("import sys\nfrom clipvol.scene.params import RenderParams\nfrom clipvol.errors import ParameterError\n"
            "assert 'clipvol.render.modes' not in sys.modules\n"
            "try:\n    RenderParams(mode='iso')\nexcept ParameterError as e:\n    print('refused', e)\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert "refused iso_value" in out.stdout
