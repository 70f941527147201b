"""Hiding labels: the tagged loader's bricks equal the image with hidden voxels removed (numpy), it
passes the loader conformance suite, and a MIP with label k hidden equals numpy's masked max."""

from __future__ import annotations

import numpy as np
import pytest

from clipvol.errors import ParameterError
from clipvol.paging.tagging import TaggedLoader
from clipvol.testing import LoaderTests


@pytest.fixture(scope="module")
def stores(tmp_path_factory):
    from clipvol.bricking.labels import brick_labels
    from clipvol.bricking.pipeline import brick_volume

    tmp = tmp_path_factory.mktemp("tag")
    rng = np.random.default_rng(2)
    img = (rng.random((24, 24, 24)) * 100).astype(np.float32)
    lab = np.zeros(img.shape, np.uint8)
    lab[4:20, 4:20, 4:12] = 1
    lab[6:18, 6:18, 14:22] = 2
    img[lab == 2] += 500.0  # the brightest structure: hiding it must change the MIP
    np.save(tmp / "img.npy", img)
    np.save(tmp / "lab.npy", lab)
    brick_volume(tmp / "img.npy", tmp / "img.zarr", brick=8, progress=False)
    brick_labels(tmp / "img.zarr", tmp / "lab.npy", "lab", progress=False)
    return tmp, img, lab


def _loaders(tmp, hidden):
    from clipvol.paging.open import open_store

    return TaggedLoader(open_store(tmp / "img.zarr"), open_store(tmp / "img.zarr" / "labels" / "lab"), hidden)


def test_level_zero_bricks_are_the_image_with_hidden_voxels_removed(stores):
    tmp, img, lab = stores
    loader = _loaders(tmp, {2})
    want = np.where(lab == 2, np.nan, img).astype(np.float32)
    for idx in [(0, 0, 0), (1, 1, 2), (2, 2, 2)]:
        sl = tuple(slice(8 * i, 8 * i + 8) for i in idx)
        np.testing.assert_array_equal(loader.read_brick(0, idx), want[sl])
    ranges = loader.brick_ranges(0, np.array([[0, 0, 0], [1, 1, 2]]))
    assert np.isfinite(ranges[0]).all()  # brick (0,0,0) holds labels 0 and 1 only
    assert np.isnan(ranges[1]).all()  # brick (1,1,2) may hold label 2: bounds unknown


class TestTaggedLoaderConformance(LoaderTests):
    @pytest.fixture
    def loader(self, stores):
        return _loaders(stores[0], {1})


def test_mismatched_label_pyramid_is_refused(stores, tmp_path):
    from clipvol.paging.open import open_store

    tmp, img, lab = stores
    np.save(tmp_path / "other.npy", img[:16])
    from clipvol.bricking.pipeline import brick_volume

    brick_volume(tmp_path / "other.npy", tmp_path / "other.zarr", brick=8, progress=False)
    with pytest.raises(ParameterError, match="labels"):
        TaggedLoader(open_store(tmp / "img.zarr"), open_store(tmp_path / "other.zarr"), {1})
    with pytest.raises(ParameterError, match="integer"):
        TaggedLoader(open_store(tmp / "img.zarr"), open_store(tmp / "img.zarr"), {1})


@pytest.mark.gl
def test_mip_with_a_label_hidden_equals_numpys_masked_max(stores, ctx):
    """Orthographic MIP along z at level 0, rays through voxel centres: hiding label 2 gives
    numpy's max over the voxels whose label is not 2 (the bright structure disappears)."""
    from clipvol.paging.cliptexture import ClipTexture
    from clipvol.render.action import ClipRenderAction
    from clipvol.scene.camera import Camera
    from clipvol.scene.transfer import TransferFunction

    tmp, img, lab = stores
    loader = _loaders(tmp, {2})
    nz, ny, nx = img.shape
    centre = ((nx - 1) / 2, (ny - 1) / 2, (nz - 1) / 2)
    cam = Camera.orthographic(centre, (0, 0, 1), (0, -1, 0), nx, ny, size=(nx, ny))  # row i is y = i
    tf = TransferFunction.preset("grey")
    with ClipTexture(loader, "64MB") as clip, ClipRenderAction(ctx, clip, mode="mip", policy="fixed", level=0) as act:
        rgba = act.render(cam, tf, wait=True)
    masked = np.where(lab == 2, -np.inf, img).max(axis=0)  # (y, x)
    lo, hi = loader.pyramid.value_range
    want = tf.lookup(masked, (lo, hi))[..., 0]
    got = rgba[..., 0].astype(np.float64) / 255.0
    assert np.abs(got - want).max() <= 1.5 / 255
    unmasked = tf.lookup(img.max(axis=0), (lo, hi))[..., 0]
    assert np.abs(unmasked - want).max() > 0.3  # hiding label 2 really changed the picture
