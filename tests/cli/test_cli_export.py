"""``clipvol export``: every format holds the source's voxels (level 0: the array itself; level 1: a
numpy 2x2x2 mean written here), the NIfTI's affine puts voxel (0, 0, 0) where nibabel's affine of
the source puts the box's corner, a world box selects the voxels whose centres nibabel places
inside it, bad input exits 2 naming the parameter, and an interrupted export leaves nothing behind."""

from __future__ import annotations

import json

import nibabel as nib
import numpy as np
import pytest
import tifffile
import zarr
from nibabel.affines import apply_affine

from clipvol.bricking.pipeline import brick_volume
from clipvol.tools.cli import main

SHAPE = (19, 22, 17)  # (z, y, x), odd sizes
AFFINE = np.array([[-0.75, 0.0, 0.0, 30.0], [0.0, 0.8, 0.0, -41.0], [0.0, 0.0, 1.25, 12.0], [0.0, 0.0, 0.0, 1.0]])


def mean2(a: np.ndarray) -> np.ndarray:
    """2x2x2 mean with edge replication on odd axes (the mean of the voxels that exist), float64."""
    out = a.astype(np.float64)
    for axis in range(3):
        if out.shape[axis] % 2:
            out = np.concatenate([out, np.take(out, [out.shape[axis] - 1], axis=axis)], axis=axis)
        lo = [slice(None)] * 3
        hi = [slice(None)] * 3
        lo[axis], hi[axis] = slice(0, None, 2), slice(1, None, 2)
        out = (out[tuple(lo)] + out[tuple(hi)]) / 2
    return out


@pytest.fixture(scope="module")
def scan(tmp_path_factory):
    d = tmp_path_factory.mktemp("export")
    data = np.random.default_rng(11).normal(0.0, 1.0, SHAPE).astype(np.float32)
    nib.save(nib.Nifti1Image(data.T.copy(), AFFINE), d / "scan.nii.gz")
    brick_volume(str(d / "scan.nii.gz"), d / "scan.zarr", brick=8, progress=False, summary=False)
    return d, data, nib.load(d / "scan.nii.gz").affine


def read(path):
    name = str(path)
    if name.endswith(".npy"):
        return np.load(path)
    if name.endswith((".tif", ".tiff")):
        return tifffile.imread(path)
    if name.endswith((".nii", ".nii.gz")):
        return np.asarray(nib.load(path).dataobj).T  # NIfTI (x, y, z) -> (z, y, x)
    g = zarr.open_group(str(path), mode="r")
    return g[g.attrs["ome"]["multiscales"][0]["datasets"][0]["path"]][...]


@pytest.mark.parametrize("suffix", [".npy", ".tif", ".nii", ".nii.gz", ".zarr"])
def test_level0_export_is_the_source_box(scan, tmp_path, suffix):
    d, data, _ = scan
    out = tmp_path / f"region{suffix}"
    assert main(["export", str(d / "scan.zarr"), "--box", "0:9,5:22,3:15", "--out", str(out), "--quiet"]) == 0
    np.testing.assert_array_equal(read(out), data[3:15, 5:22, 0:9])
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([out.name] + ([out.name + ".json"] if suffix == ".npy" else []))


@pytest.mark.parametrize("suffix", [".npy", ".nii.gz"])
def test_coarse_level_export_is_the_numpy_mean(scan, tmp_path, suffix):
    d, data, _ = scan
    out = tmp_path / f"coarse{suffix}"
    # level-0 box z 5:14, y 2:21, x 4:17 -> level-1 voxels z 2:7, y 1:11, x 2:9 (those overlapping it)
    assert main(["export", str(d / "scan.zarr"), "--box", "4:17,2:21,5:14", "--level", "1", "--out", str(out),
                 "--quiet"]) == 0
    np.testing.assert_allclose(read(out), mean2(data)[2:7, 1:11, 2:9], rtol=1e-6)


def test_nifti_affine_puts_voxel_0_at_the_box_corner(scan, tmp_path):
    d, _, src_aff = scan
    out = tmp_path / "r.nii.gz"
    assert main(["export", str(d / "scan.nii.gz"), "--store", str(d / "scan.zarr"), "--box", "2:11,6:20,4:10",
                 "--out", str(out), "--quiet"]) == 0
    img = nib.load(out)
    corner = apply_affine(src_aff, [2, 6, 4])  # nibabel's (i, j, k) = (x, y, z)
    np.testing.assert_allclose(apply_affine(img.affine, [0, 0, 0]), corner, atol=1e-4)
    np.testing.assert_allclose(img.affine[:3, :3], src_aff[:3, :3], atol=1e-6)
    assert img.header["sform_code"] == 1 and img.header.get_xyzt_units()[0] == "mm"
    # level 1: voxel (0, 0, 0) of the export is the centre of the 2x2x2 level-0 block it averages
    out1 = tmp_path / "r1.nii"
    assert main(["export", str(d / "scan.zarr"), "--box", "2:11,6:20,4:10", "--level", "1", "--out", str(out1),
                 "--quiet"]) == 0
    img1 = nib.load(out1)
    np.testing.assert_allclose(apply_affine(img1.affine, [0, 0, 0]), apply_affine(src_aff, [2.5, 6.5, 4.5]), atol=1e-4)
    np.testing.assert_allclose(np.linalg.norm(img1.affine[:3, :3], axis=0), 2 * np.array([0.75, 0.8, 1.25]), atol=1e-6)


def test_npy_sidecar_and_zarr_store_keep_the_geometry(scan, tmp_path):
    d, _, src_aff = scan
    for name in ("r.npy", "r.zarr"):
        assert main(["export", str(d / "scan.zarr"), "--box", "3:12,2:10,1:9", "--out", str(tmp_path / name),
                     "--quiet"]) == 0
    side = json.loads((tmp_path / "r.npy.json").read_text())
    np.testing.assert_allclose(apply_affine(np.array(side["affine"]), [0, 0, 0]), apply_affine(src_aff, [3, 2, 1]), atol=1e-4)
    g = zarr.open_group(str(tmp_path / "r.zarr"), mode="r")
    ds = g.attrs["ome"]["multiscales"][0]["datasets"][0]["coordinateTransformations"]
    scale = next(t["scale"] for t in ds if t["type"] == "scale")
    np.testing.assert_allclose(scale, [1.25, 0.8, 0.75], atol=1e-6)  # (z, y, x)
    # translation: the corner's world position along the array axes (docs/format.md: R^-1 t; x is flipped)
    cx, cy, cz = apply_affine(src_aff, [3, 2, 1])
    translation = next(t["translation"] for t in ds if t["type"] == "translation")
    np.testing.assert_allclose(translation, [cz, cy, -cx], atol=1e-4)
    assert main(["info", str(tmp_path / "r.zarr")]) == 0


def test_world_box_selects_the_voxel_centres_inside(scan, tmp_path):
    d, data, src_aff = scan
    lo, hi = np.array([20.0, -36.0, 15.0]), np.array([26.0, -30.5, 24.0])
    out = tmp_path / "w.npy"
    assert main(["export", str(d / "scan.zarr"), "--box-world", ",".join(map(str, [*hi[:1], *lo[1:], *lo[:1], *hi[1:]])),
                 "--out", str(out), "--quiet"]) == 0
    ijk = np.stack(np.meshgrid(*[np.arange(n) for n in SHAPE[::-1]], indexing="ij"), -1).reshape(-1, 3)
    world = apply_affine(src_aff, ijk)
    inside = ijk[np.all((world >= lo - 1e-6) & (world <= hi + 1e-6), axis=1)]
    (x0, y0, z0), (x1, y1, z1) = inside.min(0), inside.max(0) + 1
    np.testing.assert_array_equal(np.load(out), data[z0:z1, y0:y1, x0:x1])


@pytest.mark.parametrize("args, words", [
    (["--box", "3:15,5:22"], ["--box", "three"]),
    (["--box", "0:4,5:99,3:15"], ["--box", "y", "22"]),
    (["--box", "0:4,5:9,3:a"], ["--box"]),
    (["--box", "1:5,1:5,1:5", "--level", "7"], ["--level", "0..2"]),
    (["--box-world", "1,2,3"], ["--box-world", "six"]),
    (["--box-world=-900,-900,-900,-800,-800,-800"], ["--box-world", "no voxel"]),
    (["--box", "1:5,1:5,1:5", "--c", "1"], ["--c", "no 'c' axis"]),
])
def test_bad_input_exits_2_naming_the_parameter(scan, tmp_path, capsys, args, words):
    d, _, _ = scan
    rc = main(["export", str(d / "scan.zarr"), *args, "--out", str(tmp_path / "x.npy"), "--quiet"])
    err = capsys.readouterr().err
    assert rc == 2 and err.count("\n") == 1, err
    assert all(w in err for w in words), err
    assert not list(tmp_path.iterdir())


def test_bad_output_names_and_existing_outputs(scan, tmp_path, capsys):
    d, data, _ = scan
    base = ["export", str(d / "scan.zarr"), "--box", "0:4,0:4,0:4", "--quiet", "--out"]
    assert main(base + [str(tmp_path / "x.png")]) == 2 and "--out" in capsys.readouterr().err
    assert main(base + [str(tmp_path / "nowhere" / "x.npy")]) == 2 and "does not exist" in capsys.readouterr().err
    (tmp_path / "x.npy").write_bytes(b"keep")  # not a .npy: never replaced, --overwrite not suggested
    assert main(base + [str(tmp_path / "x.npy")]) == 2 and "--overwrite" not in capsys.readouterr().err
    assert main(base + [str(tmp_path / "x.npy"), "--overwrite"]) == 2 and "not a .npy" in capsys.readouterr().err
    assert (tmp_path / "x.npy").read_bytes() == b"keep"
    np.save(tmp_path / "x.npy", np.zeros(3))  # a .npy: replaced with --overwrite
    assert main(base + [str(tmp_path / "x.npy")]) == 2 and "--overwrite" in capsys.readouterr().err
    assert main(base + [str(tmp_path / "x.npy"), "--overwrite"]) == 0
    np.testing.assert_array_equal(np.load(tmp_path / "x.npy"), data[:4, :4, :4])


@pytest.mark.parametrize("suffix", [".nii.gz", ".zarr"])
def test_an_interrupted_export_leaves_nothing(scan, tmp_path, monkeypatch, suffix):
    import clipvol.app.export as export

    d, _, _ = scan
    real, calls = export.copy_brick, []

    def stop_on_third(*a, **k):
        calls.append(1)
        if len(calls) == 3:
            raise KeyboardInterrupt
        return real(*a, **k)

    monkeypatch.setattr(export, "copy_brick", stop_on_third)
    rc = main(["export", str(d / "scan.zarr"), "--box", "0:17,0:22,0:19", "--out", str(tmp_path / f"r{suffix}"), "--quiet"])
    assert rc == 130 and len(calls) == 3
    assert not list(tmp_path.iterdir())


def test_a_channel_set_exports_the_channel_named(tmp_path, capsys):
    data = np.random.default_rng(3).integers(0, 200, (2, 10, 12, 14)).astype(np.uint16)
    np.save(tmp_path / "cells.npy", data)
    assert main(["brick", str(tmp_path / "cells.npy"), str(tmp_path / "cells.zarr"), "--brick", "8", "--quiet"]) == 0
    base = ["export", str(tmp_path / "cells.zarr"), "--box", "3:11,:,2:9", "--quiet", "--out"]
    assert main(base + [str(tmp_path / "c.npy")]) == 2 and "--c" in capsys.readouterr().err
    assert main(base + [str(tmp_path / "c.npy"), "--c", "1"]) == 0
    np.testing.assert_array_equal(np.load(tmp_path / "c.npy"), data[1, 2:9, :, 3:11])
    assert main(base + [str(tmp_path / "d.npy"), "--c", "2"]) == 2 and "0..1" in capsys.readouterr().err


def test_an_unverified_store_is_exported_only_when_asked(scan, tmp_path, capsys):
    import shutil

    d, data, _ = scan
    copy = tmp_path / "u.zarr"
    shutil.copytree(d / "scan.zarr", copy)
    shutil.rmtree(copy / "clipvol_manifest")  # the root of trust gone: the store no longer verifies
    args = ["export", str(copy), "--box", "0:7,0:6,0:5", "--out", str(tmp_path / "u.npy"), "--quiet"]
    assert main(args) == 2
    assert "--unverified" in capsys.readouterr().err and not (tmp_path / "u.npy").exists()
    assert main(args + ["--unverified"]) == 0
    np.testing.assert_array_equal(np.load(tmp_path / "u.npy"), data[:5, :6, :7])


def test_export_region_refuses_a_region_past_the_level(scan, tmp_path):
    import clipvol
    from clipvol.app.export import Region, export_region
    from clipvol.errors import ParameterError

    d, _, _ = scan
    vol = clipvol.open(d / "scan.zarr")
    with pytest.raises(ParameterError, match="reaches past level 1"):
        export_region(vol, Region(1, (0, 0, 0), (5, 5, 10)), tmp_path / "x.npy")  # level 1 is 10x11x9
    with pytest.raises(ParameterError, match="Region"):
        Region(0, (3, 0, 0), (2, 5, 5))
    assert not list(tmp_path.iterdir())


@pytest.mark.parametrize("suffix", [".npy", ".tif", ".nii", ".nii.gz", ".zarr"])
def test_a_full_disk_at_the_reservation_is_one_line_and_leaves_nothing(scan, tmp_path, monkeypatch, capsys, suffix):
    """A memory-mapped write to a page the file system cannot back is a SIGBUS (the process dies, the
    hidden partial file stays): each mapped file's blocks are reserved first, so a full disk is an
    ENOSPC there, one line and no leftover. The full disk is simulated at ``posix_fallocate``."""
    import errno
    import os

    if not hasattr(os, "posix_fallocate"):
        pytest.skip("no posix_fallocate on this platform")
    d, _, _ = scan
    calls = []

    def full(fd, offset, length):
        calls.append(length)
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(os, "posix_fallocate", full)
    out = tmp_path / f"r{suffix}"
    assert main(["export", str(d / "scan.zarr"), "--box", "0:17,0:22,0:19", "--out", str(out), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "No space left on device" in err and out.name in err, err
    assert calls and not list(tmp_path.iterdir())  # no hidden partial file, no sidecar, no lock


def test_an_export_larger_than_the_free_space_is_refused_before_writing(scan, tmp_path, monkeypatch, capsys):
    import shutil
    from collections import namedtuple

    d, data, _ = scan
    usage = namedtuple("usage", "total used free")
    need = data[:10].nbytes
    monkeypatch.setattr(shutil, "disk_usage", lambda p: usage(10 * need, 9 * need, need - 1))
    out = tmp_path / "r.npy"
    assert main(["export", str(d / "scan.zarr"), "--box", ":,:,0:10", "--out", str(out), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "free" in err and "r.npy" in err, err
    assert not list(tmp_path.iterdir())
    monkeypatch.setattr(shutil, "disk_usage", lambda p: usage(10 * need, 9 * need, need))  # exactly enough
    assert main(["export", str(d / "scan.zarr"), "--box", ":,:,0:10", "--out", str(out), "--quiet"]) == 0
    np.testing.assert_array_equal(np.load(out), data[:10])
