"""HDF5 datasets and MRC maps: bytes and geometry end to end, from files written by h5py / mrcfile.

References: h5py's and mrcfile's own reads of the same files, and the voxel size / origin written
into them.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
import zarr

from clipvol.bricking.pipeline import brick_volume
from clipvol.bricking.sources import open_source
from clipvol.errors import InputFormatError, InputNotFoundError
from clipvol.tools.cli import main

h5py = pytest.importorskip("h5py")
mrcfile = pytest.importorskip("mrcfile")


def _attrs(store):
    return json.loads((store / "zarr.json").read_text())["attributes"]


def _ome0(store):
    ds = _attrs(store)["ome"]["multiscales"][0]["datasets"][0]
    tr = {t["type"]: t[t["type"]] for t in ds["coordinateTransformations"]}
    return tr["scale"], tr["translation"]


@pytest.fixture
def h5file(tmp_path, rng):
    p = tmp_path / "scan.h5"
    vol = rng.random((19, 23, 17)).astype(np.float32)
    with h5py.File(p, "w") as f:
        d = f.create_dataset("entry/data", data=vol, chunks=(4, 8, 8), compression="gzip")
        d.attrs["element_size_um"] = [2.0, 0.5, 0.25]
        f.create_dataset("entry/dark", data=np.zeros((4, 4)))
    return p, vol


def test_hdf5_dataset_path_bytes_and_spacing(h5file, tmp_path, capsys):
    p, _ = h5file
    out = tmp_path / "scan.zarr"
    assert main(["brick", f"{p}:/entry/data", str(out), "--brick", "8", "--quiet"]) == 0
    with h5py.File(p, "r") as f:
        ref = f["entry/data"][()]
    np.testing.assert_array_equal(zarr.open_group(str(out), mode="r")["0"][:], ref)
    scale, trans = _ome0(out)
    assert scale == [2.0, 0.5, 0.25] and trans == [0.0, 0.0, 0.0]
    assert _attrs(out)["clipvol"]["unit"] == "micrometer"


def test_hdf5_region_reads_match_h5py(h5file):
    p, vol = h5file
    with open_source(f"{p}:/entry/data") as src:
        np.testing.assert_array_equal(src.read((3, 5, 7), (11, 20, 16)), vol[3:11, 5:20, 7:16])


def test_hdf5_missing_dataset_names_file_and_lists_datasets(h5file, tmp_path, capsys):
    p, _ = h5file
    assert main(["brick", f"{p}:/entry/dta", str(tmp_path / "o.zarr"), "--quiet"]) == 2
    err = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
    assert len(err) == 1 and "scan.h5" in err[0] and "/entry/dta" in err[0] and "/entry/data" in err[0]
    assert not (tmp_path / "o.zarr").exists()


def test_hdf5_without_path_needs_one_volume(h5file, tmp_path):
    p, vol = h5file
    src = open_source(p)  # one 3-D dataset: taken
    assert src.shape == vol.shape
    src.close()
    with h5py.File(p, "a") as f:
        f.create_dataset("other", data=np.zeros((3, 3, 3)))
    with pytest.raises(InputFormatError, match="name the dataset"):
        open_source(p)
    with pytest.raises(InputNotFoundError, match="nope.h5"):
        open_source(tmp_path / "nope.h5:/x")


def test_mrc_bytes_voxel_size_and_origin(tmp_path, rng):
    p = tmp_path / "map.mrc"
    vol = rng.normal(size=(12, 15, 18)).astype(np.float32)
    with mrcfile.new(p) as m:
        m.set_data(vol)
        m.voxel_size = (1.25, 1.5, 2.0)  # x, y, z in angstrom
        m.header.origin = (10.0, 20.0, 30.0)
    out = tmp_path / "map.zarr"
    brick_volume(p, out, brick=8, progress=False)
    with mrcfile.open(p) as m:
        np.testing.assert_array_equal(zarr.open_group(str(out), mode="r")["0"][:], m.data)
    scale, trans = _ome0(out)
    np.testing.assert_allclose(scale, [2.0, 1.5, 1.25])
    np.testing.assert_allclose(trans, [30.0, 20.0, 10.0])
    assert _attrs(out)["clipvol"]["unit"] == "angstrom"


def test_mrc_big_endian_and_truncated(tmp_path, rng):
    vol = rng.integers(-300, 300, size=(4, 5, 6)).astype(np.int16)
    p = tmp_path / "be.mrc"
    with mrcfile.new(p) as m:
        m.set_data(vol.astype(">i2"))
    src = open_source(p)
    np.testing.assert_array_equal(src.read((0, 0, 0), src.shape), vol)
    p.write_bytes(p.read_bytes()[:-10])
    with pytest.raises(InputFormatError, match=r"be\.mrc: truncated MRC"):
        open_source(p)


def test_ome_tiff_voxel_size_from_its_xml(tmp_path, rng):
    tifffile = pytest.importorskip("tifffile")
    vol = rng.integers(0, 60000, size=(6, 20, 24)).astype(np.uint16)
    p = tmp_path / "stack.ome.tif"
    tifffile.imwrite(p, vol, ome=True, metadata={"axes": "ZYX", "PhysicalSizeX": 0.325, "PhysicalSizeY": 0.325,
                                                "PhysicalSizeZ": 2.0, "PhysicalSizeXUnit": "µm"})
    out = tmp_path / "stack.zarr"
    brick_volume(p, out, brick=8, progress=False)
    np.testing.assert_array_equal(zarr.open_group(str(out), mode="r")["0"][:], tifffile.imread(p))
    scale, _ = _ome0(out)
    np.testing.assert_allclose(scale, [2.0, 0.325, 0.325])
    assert _attrs(out)["clipvol"]["unit"] == "micrometer"
