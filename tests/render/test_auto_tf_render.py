"""The automatic transfer function, rendered: the empty corner is transparent, the structure shows.

The reference is the volume itself: the corner rays of an axis-aligned orthographic view cross
only background voxels (checked on the array), the centre rays cross the structure.
"""

from __future__ import annotations

import numpy as np
import pytest

from clipvol.bricking.pipeline import brick_volume
from clipvol.loaders.zarr_store import ZarrLoader
from clipvol.paging.cliptexture import ClipTexture
from clipvol.scene.auto_tf import auto_transfer_function
from clipvol.scene.camera import Camera
from render_helpers import render_converged
from sample_volumes import VOLUMES

pytestmark = pytest.mark.gl


@pytest.mark.parametrize("name", sorted(VOLUMES))
def test_auto_tf_leaves_the_empty_corner_transparent_and_shows_the_structure(gl, tmp_path, name):
    from clipvol.render.action import ClipRenderAction

    vol, fg, bg = VOLUMES[name](np.random.default_rng(3))
    path = tmp_path / "v.zarr"
    brick_volume(vol, path, brick=16, progress=False, workers=1)
    loader = ZarrLoader(path)
    tf = auto_transfer_function(loader)
    n = vol.shape[0]
    c = (n - 1) / 2.0
    cam = Camera.orthographic((c, c, c), (0, 0, 1), (0, -1, 0), n, n, size=(n, n))
    with ClipTexture(loader, "32MB", threads=2) as clip, ClipRenderAction(gl, clip, policy="fixed", level=0) as action:
        img = render_converged(action, cam, tf)
    alpha = img[..., 3].astype(int)
    # pixel (row i, column j) sees voxel column (y = i, x = j) along z; a corner block of 6x6
    # columns holds background only (or NaN), as the array says
    k = 6
    for rows, cols in ((slice(0, k), slice(0, k)), (slice(-k, None), slice(-k, None))):
        col = vol[:, rows, cols]
        assert bg[:, rows, cols].all() or np.isnan(col).all(), "the test volume's corner must be background"
        assert alpha[rows, cols].max() == 0, f"{name}: the empty corner is not transparent ({tf.name})"
    # structure: the pixels whose columns cross the foreground are visible
    seen = fg.any(axis=0)
    assert seen.sum() > 20
    assert np.mean(alpha[seen] > 20) > 0.5, f"{name}: the structure does not show ({tf.name})"


def test_session_resolves_auto_to_the_automatic_transfer_function(gl, tmp_path):
    from clipvol.app.session import RenderSession

    vol, _, _ = VOLUMES["signed"](np.random.default_rng(4))
    path = tmp_path / "s.zarr"
    brick_volume(vol, path, brick=16, progress=False, workers=1)
    with RenderSession(ZarrLoader(path), gl, tf="auto") as s:
        tf = s.transfer_function
    ref = auto_transfer_function(ZarrLoader(path))
    assert tf.name == ref.name and tf.name.startswith("auto: diverging")
    np.testing.assert_array_equal(tf.table, ref.table)
