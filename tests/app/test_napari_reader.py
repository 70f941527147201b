"""The napari reader's contract, without napari: lazy dask levels, OME scale, patient-frame affine.

References: zarr-python's read of the store, nibabel's data and affine of the source file, the npe2
manifest as YAML. napari itself is not installed in the test environment (too heavy for CI); the
layer data tuple is what napari's reader API consumes.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import zarr

da = pytest.importorskip("dask.array")
nib = pytest.importorskip("nibabel")


@pytest.fixture(scope="module")
def nifti_store(tmp_path_factory):
    from clipvol.bricking.pipeline import brick_volume

    d = tmp_path_factory.mktemp("napari")
    rng = np.random.default_rng(3)
    data = rng.integers(0, 3000, size=(40, 36, 20)).astype(np.uint16)  # (i, j, k)
    aff = np.array([[-1.2, 0, 0, 70.0], [0, 0.9, 0, -30.0], [0, 0, 2.0, -10.0], [0, 0, 0, 1]])
    src = d / "brain.nii.gz"
    nib.save(nib.Nifti1Image(data, aff), src)
    out = d / "brain.zarr"
    brick_volume(src, out, brick=8, progress=False)
    return out, data, aff


def test_reader_hook_accepts_only_clipvol_stores(nifti_store, tmp_path):
    from clipvol.napari_plugin import napari_get_reader, read_store

    store, _, _ = nifti_store
    assert napari_get_reader(str(store)) is read_store
    assert napari_get_reader([str(store)]) is read_store
    np.save(tmp_path / "a.npy", np.zeros((2, 2, 2)))
    assert napari_get_reader(str(tmp_path / "a.npy")) is None
    zarr.open_group(str(tmp_path / "plain.zarr"), mode="w")
    assert napari_get_reader(str(tmp_path / "plain.zarr")) is None


def test_layer_data_is_lazy_and_exact(nifti_store):
    from clipvol.napari_plugin import read_store

    store, data, _ = nifti_store
    [(levels, kw, kind)] = read_store(store)
    assert kind == "image" and kw["multiscale"] is True
    g = zarr.open_group(str(store), mode="r")
    assert len(levels) == len([k for k in g.array_keys() if k.isdigit()]) >= 3
    for L, lv in enumerate(levels):
        assert isinstance(lv, da.Array)  # nothing read yet
        assert lv.shape == g[str(L)].shape and lv.chunksize == tuple(min(8, s) for s in lv.shape)  # chunk = brick
        np.testing.assert_array_equal(np.asarray(lv[1:5, 2:7, 3:9]), g[str(L)][1:5, 2:7, 3:9])
    np.testing.assert_array_equal(levels[0].compute(), data.transpose(2, 1, 0))
    assert kw["contrast_limits"] == (float(data.min()), float(data.max()))


def test_layer_transform_maps_voxels_to_ras_like_nibabel(nifti_store):
    from clipvol.napari_plugin import read_store

    store, data, aff = nifti_store
    [(_, kw, _)] = read_store(store)
    # napari's chain for a layer: world = affine @ (scale * index + translate), axes (z, y, x)
    idx = np.array([[0, 0, 0], [3, 10, 25], [19, 35, 39]], dtype=float)  # (z, y, x)
    phys = idx * np.array(kw["scale"]) + np.array(kw["translate"])
    world = phys @ np.asarray(kw["affine"])[:3, :3].T + np.asarray(kw["affine"])[:3, 3]
    want = nib.affines.apply_affine(aff, idx[:, ::-1])[:, ::-1]  # nibabel: (i, j, k) -> RAS; reversed
    np.testing.assert_allclose(world, want, atol=1e-5)


def test_manifest_points_at_the_reader():
    import importlib
    import tomllib

    import yaml

    root = Path(__file__).resolve().parents[2]
    man = yaml.safe_load((root / "clipvol" / "napari.yaml").read_text())
    cmd = {c["id"]: c for c in man["contributions"]["commands"]}
    reader = man["contributions"]["readers"][0]
    mod, _, fn = cmd[reader["command"]]["python_name"].partition(":")
    assert getattr(importlib.import_module(mod), fn).__name__ == "napari_get_reader"
    assert reader["accepts_directories"] is True
    py = tomllib.loads((root / "pyproject.toml").read_text())
    assert py["project"]["entry-points"]["napari.manifest"]["clipvol"] == "clipvol:napari.yaml"
    assert "napari.yaml" in py["tool"]["setuptools"]["package-data"]["clipvol"]
