"""Label pyramids: the mode filter against a per-block count written here, and labels bricked into
the image store's OME-Zarr ``labels/`` group read back with zarr itself."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from clipvol.bricking.pyramid import downsample
from clipvol.errors import InputFormatError


def mode_reference(a: np.ndarray) -> np.ndarray:
    """Per 2x2x2 block (ceil at odd edges, only the voxels that exist): most frequent value,
    smallest among ties - a plain loop with np.unique, nothing shared with the code under test."""
    out = np.empty(tuple((s + 1) // 2 for s in a.shape), dtype=a.dtype)
    for z, y, x in itertools.product(*(range(s) for s in out.shape)):
        block = a[2 * z : 2 * z + 2, 2 * y : 2 * y + 2, 2 * x : 2 * x + 2].ravel()
        vals, counts = np.unique(block, return_counts=True)
        out[z, y, x] = vals[np.argmax(counts)]  # np.unique sorts: the first maximum is the smallest
    return out


@pytest.mark.parametrize("shape", [(8, 8, 8), (7, 10, 13), (1, 5, 2), (3, 3, 3)])
@pytest.mark.parametrize("dtype", [np.uint8, np.int16, np.uint32, np.int64])
def test_mode_filter_equals_the_per_block_count(shape, dtype):
    rng = np.random.default_rng(sum(shape))
    a = rng.integers(0, 4, size=shape).astype(dtype)  # few ids: many ties and clear majorities
    np.testing.assert_array_equal(downsample(a, "mode"), mode_reference(a))


def test_mode_never_invents_an_id():
    a = np.zeros((4, 4, 4), np.uint16)
    a[:, :, :3] = 3
    a[:, :, 3:] = 5  # the second block along x holds 3 and 5 half and half
    assert set(np.unique(downsample(a, "mode"))) == {3}  # a tie: the smaller id
    assert 4 in np.unique(downsample(a, "mean"))  # the mean invents id 4, which is not in the data


def test_mode_ties_take_the_smallest_id():
    a = np.array([[[7, 2], [7, 2]], [[9, 9], [2, 7]]], np.int32)  # 7 x3, 2 x3, 9 x2
    assert downsample(a, "mode")[0, 0, 0] == 2


@pytest.fixture
def image_and_labels(tmp_path):
    from clipvol.bricking.pipeline import brick_volume

    rng = np.random.default_rng(1)
    img = rng.random((20, 24, 30), dtype=np.float32)
    lab = np.zeros(img.shape, np.uint16)
    lab[5:15, 4:20, 3:25] = 1
    lab[8:12, 8:16, 10:20] = 2
    lab[rng.random(img.shape) < 0.05] = 3  # speckle: the mode must not let it take over blocks
    np.save(tmp_path / "img.npy", img)
    np.save(tmp_path / "seg.npy", lab)
    brick_volume(tmp_path / "img.npy", tmp_path / "img.zarr", brick=8, progress=False, spacing=(2.0, 1.0, 1.0))
    return tmp_path, img, lab


def test_labels_are_bricked_into_the_ome_labels_group(image_and_labels):
    import zarr

    from clipvol.bricking.labels import brick_labels, label_names

    tmp, img, lab = image_and_labels
    meta = brick_labels(tmp / "img.zarr", tmp / "seg.npy", "seg", progress=False)
    assert meta.pyramid.filter == "mode" and meta.pyramid.spacing == (2.0, 1.0, 1.0)
    assert label_names(tmp / "img.zarr") == ["seg"]
    labels_group = zarr.open_group(str(tmp / "img.zarr" / "labels"), mode="r")
    assert labels_group.attrs["ome"]["labels"] == ["seg"]
    seg = zarr.open_group(str(tmp / "img.zarr" / "labels" / "seg"), mode="r")
    assert seg.attrs["ome"]["image-label"]["source"]["image"] == "../../"
    # read back with zarr, level by level, against the mode reference applied repeatedly
    ref = lab
    for L in range(meta.pyramid.num_levels):
        np.testing.assert_array_equal(np.asarray(seg[str(L)][...]), ref, err_msg=f"level {L}")
        ref = mode_reference(ref)
    # the image store is untouched and still opens
    from clipvol.paging.open import open_store

    loader = open_store(tmp / "img.zarr")
    np.testing.assert_array_equal(loader.read_brick(0, (0, 0, 0))[:8, :8, :8], img[:8, :8, :8])


def test_bad_label_volumes_are_refused_by_name(image_and_labels):
    from clipvol.bricking.labels import brick_labels

    tmp, img, lab = image_and_labels
    np.save(tmp / "small.npy", lab[:10])
    with pytest.raises(InputFormatError, match="small.npy.*shape"):
        brick_labels(tmp / "img.zarr", tmp / "small.npy", "x", progress=False)
    np.save(tmp / "float.npy", lab.astype(np.float32))
    with pytest.raises(InputFormatError, match="float.npy.*integer"):
        brick_labels(tmp / "img.zarr", tmp / "float.npy", "y", progress=False)
    assert not (tmp / "img.zarr" / "labels" / "x").exists()


@pytest.mark.slow
def test_cli_brick_with_labels(image_and_labels):
    from clipvol.tools.cli import main

    tmp, img, lab = image_and_labels
    rc = main(["brick", str(tmp / "img.npy"), str(tmp / "two.zarr"), "--brick", "8", "--quiet",
               "--labels", f"{tmp / 'seg.npy'}:organs"])
    assert rc == 0
    from clipvol.bricking.labels import label_names

    assert label_names(tmp / "two.zarr") == ["organs"]
    np.save(tmp / "bad.npy", lab[:, :3])
    rc = main(["brick", str(tmp / "img.npy"), str(tmp / "three.zarr"), "--brick", "8", "--quiet",
               "--labels", str(tmp / "bad.npy")])
    assert rc == 2


@pytest.mark.slow
def test_info_lists_the_label_images(image_and_labels, capsys):
    # the reference: the names given to `brick --labels` (and none for a store without)
    from clipvol.tools.cli import main

    tmp, img, lab = image_and_labels
    np.save(tmp / "vessels.npy", lab)
    assert main(["brick", str(tmp / "img.npy"), str(tmp / "seg.zarr"), "--brick", "8", "--quiet",
                 "--labels", f"{tmp / 'seg.npy'}:organs", "--labels", f"{tmp / 'vessels.npy'}"]) == 0
    capsys.readouterr()
    assert main(["info", str(tmp / "seg.zarr")]) == 0
    lines = [ln for ln in capsys.readouterr().out.splitlines() if ln.startswith("labels")]
    assert len(lines) == 1 and "organs, vessels" in lines[0] and "--label-overlay" in lines[0], lines
    assert main(["brick", str(tmp / "img.npy"), str(tmp / "plain.zarr"), "--brick", "8", "--quiet"]) == 0
    capsys.readouterr()
    assert main(["info", str(tmp / "plain.zarr")]) == 0
    assert not [ln for ln in capsys.readouterr().out.splitlines() if ln.startswith("labels")]
