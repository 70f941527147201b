"""``clipvol.open``: the voxels of every level equal the source array (level 0) and a numpy 2x2x2 mean
written here (coarser levels, docs/format.md), world <-> voxel maps agree with nibabel's
``apply_affine`` on the NIfTI's own affine, channel sets / time series open from their root, and a
corrupt chunk is refused (the reads go through the verified loader, not zarr)."""

from __future__ import annotations

import sys

import nibabel as nib
import numpy as np
import pytest
import zarr
from nibabel.affines import apply_affine
from optional import needs

import clipvol
from clipvol.bricking.pipeline import brick_volume
from clipvol.errors import BrickIntegrityError, MissingExtraError, ParameterError
from clipvol.tools.cli import main

SHAPE = (21, 18, 27)  # odd sizes: the coarse levels' edge blocks are partial


def mean2(a: np.ndarray) -> np.ndarray:
    """2x2x2 mean with edge replication on odd axes (the mean of the voxels that exist), float64."""
    out = a.astype(np.float64)
    for axis in range(3):
        n = out.shape[axis]
        if n % 2:
            last = np.take(out, [n - 1], axis=axis)
            out = np.concatenate([out, last], axis=axis)
        sl0 = [slice(None)] * 3
        sl1 = [slice(None)] * 3
        sl0[axis], sl1[axis] = slice(0, None, 2), slice(1, None, 2)
        out = (out[tuple(sl0)] + out[tuple(sl1)]) / 2
    return out


@pytest.fixture(scope="module")
def store(tmp_path_factory):
    d = tmp_path_factory.mktemp("access")
    rng = np.random.default_rng(5)
    data = rng.normal(50.0, 10.0, SHAPE).astype(np.float32)
    brick_volume(data, d / "v.zarr", brick=8, progress=False, summary=False)
    return d / "v.zarr", data


def test_metadata_and_level0_slices_equal_the_source(store):
    path, data = store
    vol = clipvol.open(path)
    assert vol.shape == SHAPE and vol.dtype == data.dtype and vol.axes == ("z", "y", "x")
    assert vol.spacing == (1.0, 1.0, 1.0) and len(vol.levels) == 3 and vol.levels[0].shape == SHAPE
    lv = vol.level(0)
    for key in [np.s_[3:17, 5:12, 1:26], np.s_[...], np.s_[4, :, 9], np.s_[-3:, ::3, 2:20:5], np.s_[7],
                np.s_[:, -1, -1], np.s_[20:, 17:, 26:], np.s_[5:5, :, :]]:
        got = lv[key]
        assert got.shape == data[key].shape, key
        np.testing.assert_array_equal(got, data[key], err_msg=str(key))
    np.testing.assert_array_equal(np.asarray(lv), data)


def test_integer_indices_give_a_scalar_as_numpy_does(store):
    path, data = store
    lv = clipvol.open(path).level(0)
    for key in [(3, 4, 5), (-1, -1, -1), (np.int64(20), 0, 26)]:
        got = lv[key]
        assert np.ndim(got) == 0 and np.ndim(data[key]) == 0, key  # before: a 1-element array
        assert got == data[key] and type(got) is type(data[key]), key


def test_coarse_levels_equal_a_numpy_mean(store):
    path, data = store
    vol = clipvol.open(path)
    ref1 = mean2(data)
    ref2 = mean2(ref1.astype(np.float32))
    assert vol.level(1).shape == ref1.shape and vol.level(2).shape == ref2.shape
    np.testing.assert_allclose(vol.level(1)[...], ref1, rtol=1e-6)
    np.testing.assert_allclose(vol.level(2)[1:4, :, 2:], ref2[1:4, :, 2:], rtol=1e-6)


def test_bad_indices_and_levels_are_refused(store):
    path, _ = store
    vol = clipvol.open(path)
    with pytest.raises(ParameterError, match="level"):
        vol.level(3)
    with pytest.raises(ParameterError, match="step"):
        vol.level(0)[::-1]
    with pytest.raises(ParameterError, match="integer or a slice"):
        vol.level(0)[[1, 2]]
    with pytest.raises(IndexError):
        vol.level(0)[21]
    with pytest.raises(ParameterError, match="at most 3"):
        vol.level(0)[1, 2, 3, 4]


def test_a_corrupt_chunk_is_refused_not_returned(store, tmp_path):
    import shutil

    path, _ = store
    copy = tmp_path / "v.zarr"
    shutil.copytree(path, copy)
    chunk = copy / "0" / "c" / "1" / "1" / "1"
    raw = bytearray(chunk.read_bytes())
    raw[len(raw) // 2] ^= 0xFF
    chunk.write_bytes(bytes(raw))
    vol = clipvol.open(copy)
    np.testing.assert_array_equal(vol.level(0)[0:8, 0:8, 0:8], store[1][0:8, 0:8, 0:8])  # other bricks read
    with pytest.raises(BrickIntegrityError):
        vol.level(0)[8:16, 8:16, 8:16]


@needs("dask")
def test_to_dask_equals_the_source(store):
    path, data = store
    d = clipvol.open(path).to_dask(0)
    assert d.chunksize == (8, 8, 8)
    np.testing.assert_array_equal(d[2:19, :, 3:].compute(), data[2:19, :, 3:])
    np.testing.assert_allclose(float(d.mean().compute()), float(data.astype(np.float64).mean()), rtol=1e-6)


def test_to_dask_without_dask_names_the_extra(store, monkeypatch):
    monkeypatch.setitem(sys.modules, "dask", None)
    monkeypatch.setitem(sys.modules, "dask.array", None)
    with pytest.raises(MissingExtraError, match=r"clipvol\[dask\]"):
        clipvol.open(store[0]).to_dask(0)


@pytest.fixture(scope="module")
def nifti(tmp_path_factory):
    """An oblique, anisotropic NIfTI and the store ``clipvol.open`` bricks it into."""
    d = tmp_path_factory.mktemp("nifti")
    rng = np.random.default_rng(9)
    data = rng.integers(0, 1000, SHAPE).astype(np.int16)  # (z, y, x)
    c, s = np.cos(0.3), np.sin(0.3)
    aff = np.array([[0.9 * c, -1.1 * s, 0.0, -40.0], [0.9 * s, 1.1 * c, 0.0, 12.5], [0.0, 0.0, 2.5, 30.0], [0, 0, 0, 1]])
    nib.save(nib.Nifti1Image(data.T.copy(), aff), d / "scan.nii.gz")
    brick_volume(str(d / "scan.nii.gz"), d / "scan.zarr", brick=8, progress=False, summary=False)
    vol = clipvol.open(d / "scan.nii.gz", store=d / "scan.zarr")  # the brick-once cache: reused, not rebuilt
    return vol, data, nib.load(d / "scan.nii.gz").affine


def test_a_nifti_is_bricked_once_and_read_back(nifti):
    vol, data, _ = nifti
    assert vol.source.endswith("scan.zarr") and vol.unit == "millimeter"
    assert vol.brick_shape == (8, 8, 8) and len(vol.levels) == 3  # the store built beforehand, not a new one
    np.testing.assert_array_equal(vol.level(0)[...], data)


def test_a_nifti_without_a_store_is_bricked_beside_the_working_directory(tmp_path, monkeypatch, capsys):
    data = np.arange(6 * 5 * 4, dtype=np.float32).reshape(6, 5, 4)
    nib.save(nib.Nifti1Image(data.T.copy(), np.diag([2.0, 3.0, 4.0, 1.0])), tmp_path / "small.nii")
    monkeypatch.chdir(tmp_path)
    vol = clipvol.open(tmp_path / "small.nii")
    assert vol.source == str(tmp_path / "small.zarr") and (tmp_path / "small.zarr" / "zarr.json").is_file()
    assert str(tmp_path / "small.zarr") in capsys.readouterr().err  # it says where it put the store
    clipvol.open(tmp_path / "small.nii")
    assert f"using {tmp_path / 'small.zarr'}" in capsys.readouterr().err  # and which one it reuses
    np.testing.assert_array_equal(vol.level(0)[...], data)
    assert vol.spacing == (4.0, 3.0, 2.0)


def test_world_to_voxel_agrees_with_nibabel(nifti):
    vol, _, aff = nifti
    rng = np.random.default_rng(2)
    world = apply_affine(aff, rng.uniform(-2, 25, (50, 3)))
    ijk = apply_affine(np.linalg.inv(aff), world)  # nibabel: (i, j, k) = (x, y, z) voxel order
    np.testing.assert_allclose(vol.world_to_voxel(world), ijk[:, ::-1], atol=1e-4)
    np.testing.assert_allclose(vol.voxel_to_world(ijk[:, ::-1]), world, atol=1e-4)
    np.testing.assert_allclose(vol.voxel_to_world(), aff, atol=1e-5)
    # a coarse voxel's centre is the mean of the 2x2x2 level-0 centres it covers (mean filter)
    corner = apply_affine(aff, [[2 * 3 + 0.5, 2 * 4 + 0.5, 2 * 5 + 0.5]])
    np.testing.assert_allclose(vol.voxel_to_world([5, 4, 3], level=1), corner[0], atol=1e-4)
    np.testing.assert_allclose(vol.world_to_voxel(corner, level=1), [[5, 4, 3]], atol=1e-4)


@pytest.mark.parametrize("axes", ["czyx", "tzyx"])
def test_a_4d_brick_root_opens_as_one_volume(tmp_path, axes):
    rng = np.random.default_rng(4)
    data = rng.integers(0, 255, (3, 12, 10, 14)).astype(np.uint8)
    np.save(tmp_path / "stack.npy", data)
    root = tmp_path / "stack.zarr"
    assert main(["brick", str(tmp_path / "stack.npy"), str(root), "--brick", "8", "--axes", axes, "--quiet"]) == 0
    vol = clipvol.open(root)
    assert vol.axes == (axes[0], "z", "y", "x") and vol.shape == data.shape
    np.testing.assert_array_equal(vol.level(0)[...], data)
    np.testing.assert_array_equal(vol.level(0)[2, 3:9, :, 5], data[2, 3:9, :, 5])
    np.testing.assert_array_equal(vol.level(0)[1:, 4], data[1:, 4])
    blocks = data[1].astype(np.int64).reshape(6, 2, 5, 2, 7, 2).sum(axis=(1, 3, 5))
    np.testing.assert_array_equal(vol.level(1)[1], (blocks + 4) // 8)  # integers: floor((sum + 4) / 8)
    # the root is one OME-Zarr 0.5 image with a leading c or t axis that zarr-python reads whole
    g = zarr.open_group(str(root), mode="r")
    ms = g.attrs["ome"]["multiscales"][0]
    assert [a["name"] for a in ms["axes"]] == [axes[0], "z", "y", "x"]
    lv0 = g[ms["datasets"][0]["path"]]
    assert lv0.chunks == (1, 8, 8, 8)
    np.testing.assert_array_equal(lv0[...], data)
    np.testing.assert_array_equal(g[ms["datasets"][1]["path"]][1], (blocks + 4) // 8)


def test_an_ome_zarr_image_with_t_and_c_axes_opens_whole(tmp_path):
    """An OME-Zarr image written here with zarr-python (not by clipvol): axes t, c, z, y, x."""
    data = np.random.default_rng(6).random((2, 3, 9, 10, 11)).astype(np.float32)
    g = zarr.open_group(str(tmp_path / "img.zarr"), mode="w", zarr_format=3)
    g.create_array("0", shape=data.shape, chunks=(1, 1, 8, 8, 8), dtype="float32")[...] = data
    axes = [{"name": "t", "type": "time"}, {"name": "c", "type": "channel"}] + \
        [{"name": a, "type": "space", "unit": "micrometer"} for a in "zyx"]
    g.attrs.update({"ome": {"version": "0.5", "multiscales": [{"axes": axes, "datasets": [
        {"path": "0", "coordinateTransformations": [{"type": "scale", "scale": [1, 1, 2.0, 0.5, 0.5]}]}]}]}})
    vol = clipvol.open(tmp_path / "img.zarr")
    assert vol.axes == ("t", "c", "z", "y", "x") and vol.shape == data.shape and vol.spacing == (2.0, 0.5, 0.5)
    np.testing.assert_array_equal(vol.level(0)[...], data)
    np.testing.assert_array_equal(vol.level(0)[1, 2, 3:7, ::2, -1], data[1, 2, 3:7, ::2, -1])
    np.testing.assert_allclose(vol.world_to_voxel([[1.0, 2.0, 4.0]]), [[2.0, 4.0, 2.0]])
