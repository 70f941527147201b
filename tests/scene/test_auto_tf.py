"""The automatic transfer function on three differently distributed volumes.

References are independent of the code under test: numpy percentiles of the volume's own voxels
(which voxels are background is known by construction), and the voxel values themselves.
"""

from __future__ import annotations

import numpy as np
import pytest

from clipvol.bricking.pipeline import brick_volume
from clipvol.loaders.numpy_array import NumpyLoader
from clipvol.loaders.zarr_store import ZarrLoader
from clipvol.scene.auto_tf import auto_transfer_function, auto_window, value_histogram
from sample_volumes import VOLUMES



@pytest.fixture(scope="module")
def stores(tmp_path_factory):
    rng = np.random.default_rng(7)
    out = {}
    for name, make in VOLUMES.items():
        vol, fg, bg = make(rng)
        path = tmp_path_factory.mktemp(name) / "v.zarr"
        brick_volume(vol, path, brick=16, progress=False, workers=1)
        out[name] = (vol, fg, bg, path)
    return out


def test_stored_histogram_is_numpys_histogram_of_the_voxels(stores):
    vol, _, _, path = stores["ct"]
    h = value_histogram(ZarrLoader(path))
    assert h.stored and h.level == 0
    v = vol.astype(np.float64)
    ref = np.histogram(v, bins=64, range=(v.min(), v.max()))[0]
    np.testing.assert_array_equal(h.counts, ref)
    # a loader without statistics reads bricks of a coarse level; at level 0 it is the same histogram
    h2 = value_histogram(NumpyLoader(vol, brick=16))
    assert not h2.stored
    if h2.level == 0:
        np.testing.assert_array_equal(h2.counts, ref)
    assert h2.counts.sum() == int(np.prod(NumpyLoader(vol, brick=16).pyramid.levels[h2.level].shape))


@pytest.mark.parametrize("name", ["ct", "fluorescence"])
def test_window_sits_on_the_foreground_of_unsigned_data(stores, name):
    vol, fg, bgmask, path = stores[name]
    loader = ZarrLoader(path)
    aw = auto_window(value_histogram(loader), float_data=False)
    assert not aw.signed
    v = vol.astype(np.float64)
    bg = v[bgmask]
    width = (v.max() - v.min()) / 64
    # the window starts above (nearly) all the background and below the bulk of the structure
    assert aw.window[0] >= np.percentile(bg, 99.9) - width
    assert aw.window[0] <= np.percentile(v[fg], 50)
    assert aw.window[1] <= v.max() + 1e-9 and aw.window[1] > aw.window[0]
    tf = auto_transfer_function(loader)
    assert tf.name.startswith("auto: viridis")
    # background voxels are transparent; the brightest structure is visible
    alpha_bg = tf.lookup(bg)[:, 3]
    assert np.mean(alpha_bg == 0) > 0.999
    assert tf.lookup([np.percentile(v[fg], 99)])[0, 3] > 0.1


def test_signed_float_data_get_a_diverging_map_transparent_around_zero(stores):
    vol, _, _, path = stores["signed"]
    loader = ZarrLoader(path)
    tf = auto_transfer_function(loader)
    assert tf.name.startswith("auto: diverging")
    lo, hi = tf.value_range
    assert lo == -hi and hi > 0
    v = vol[np.isfinite(vol)].astype(np.float64)
    assert hi <= np.abs(v).max() + 1e-6
    # the zero background (noise +- 0.05) is transparent, both blobs' cores are visible
    np.testing.assert_array_equal(tf.lookup(v[np.abs(v) < 0.2])[:, 3], 0.0)
    assert tf.lookup([np.nanmax(vol)])[0, 3] > 0.3 and tf.lookup([np.nanmin(vol)])[0, 3] > 0.3
    # (NaN voxels are skipped by the ray caster; tests/render/test_auto_tf_render.py renders them)


def test_explicit_preset_and_opacity_keep_the_automatic_window(stores):
    _, _, _, path = stores["fluorescence"]
    loader = ZarrLoader(path)
    a = auto_transfer_function(loader)
    b = auto_transfer_function(loader, preset="magma", opacity="flat")
    assert a.value_range == b.value_range and b.name.startswith("auto: magma (flat)")
