"""The manifest is the root of trust, and store files are what they claim to be.

Faults are made to stores written by ``brick_volume``: chunks swapped or removed, a statistics
chunk replaced by another valid one, the statistics deleted, the manifest missing or tampered with,
chunks and metadata that are symbolic links out of the store, FIFOs, devices and oversize files.
References: the source array (numpy), the chunk files' own bytes, ``os.stat``.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import warnings

import numpy as np
import pytest
import zarr

from clipvol.bricking.manifest import MANIFEST_DIR, TABLE_DTYPE
from clipvol.errors import BrickIntegrityError, InputFormatError, StoreFormatError
from clipvol.loaders.zarr_store import UnverifiedStoreWarning, ZarrLoader

from bounded_call import bounded

B = 16


@pytest.fixture(scope="module")
def vol():
    """Structure in every brick, and a first slab of bricks that is empty (zeros: no chunks)."""
    z, y, x = np.indices((48, 48, 40))
    v = 2000 + 1500 * np.sin(z / 4.0) * np.cos(y / 6.0) + 500 * np.sin(x / 3.0)
    v = np.clip(v, 1, 4095).astype(np.uint16)
    v[:16] = 0
    return v


def _chunk(path, L, idx):
    return path / str(L) / "c" / str(idx[0]) / str(idx[1]) / str(idx[2])


def _ref(vol, idx):
    return vol[idx[0] * B:(idx[0] + 1) * B, idx[1] * B:(idx[1] + 1) * B, idx[2] * B:(idx[2] + 1) * B]


def _valid(loader, L, idx):
    start, stop = loader.pyramid.brick_voxel_box(L, idx)
    return loader.read_brick(L, idx)[tuple(slice(0, b - a) for a, b in zip(start, stop))]


def _grid0(vol):
    return tuple(-(-n // B) for n in vol.shape)


def _unverified(path):
    with pytest.warns(UnverifiedStoreWarning) as rec:
        loader = ZarrLoader(path)
    assert not loader.verified
    return loader, str(rec[0].message)


def test_the_manifest_pins_each_bricks_chunk_and_bounds(store, vol):
    loader = ZarrLoader(store)
    assert loader.verified and "verified" in loader.trust
    t = loader.manifest.tables[0]
    for idx in np.ndindex(*_grid0(vol)):
        ref = _ref(vol, idx)
        chunk = _chunk(store, 0, idx)
        assert tuple(t["index"][idx]) == idx
        if not ref.any():  # empty bricks are not written
            assert not chunk.exists() and t["crc32c"][idx] == -1 and t["nbytes"][idx] == 0
            continue
        data = chunk.read_bytes()
        assert t["nbytes"][idx] == os.stat(chunk).st_size == len(data)
        assert t["crc32c"][idx] == int.from_bytes(data[-4:], "little")  # the crc32c codec's trailer
        assert (t["min"][idx], t["max"][idx]) == (ref.min(), ref.max())


def test_swapped_chunks_are_caught_with_the_statistics_deleted(store, vol):
    a, b = _chunk(store, 0, (1, 1, 1)), _chunk(store, 0, (2, 0, 1))
    da, db = a.read_bytes(), b.read_bytes()
    a.write_bytes(db)
    b.write_bytes(da)
    shutil.rmtree(store / "clipvol_stats")
    loader = ZarrLoader(store)
    for idx in ((1, 1, 1), (2, 0, 1)):
        for read in (lambda: loader.read_brick(0, idx), lambda: loader.read_brick_into(0, idx, np.empty((B,) * 3, np.uint16))):
            with pytest.raises(BrickIntegrityError, match=rf"0/c/{idx[0]}/{idx[1]}/{idx[2]}"):
                read()
    np.testing.assert_array_equal(_valid(loader, 0, (1, 0, 0)), _ref(vol, (1, 0, 0)))


def test_a_removed_chunk_is_lost_data_not_an_empty_brick_without_statistics(store, vol):
    _chunk(store, 0, (2, 2, 1)).unlink()
    shutil.rmtree(store / "clipvol_stats")
    loader = ZarrLoader(store)
    with pytest.raises(BrickIntegrityError, match=r"missing.*holds data"):
        loader.read_brick(0, (2, 2, 1))
    np.testing.assert_array_equal(loader.read_brick(0, (0, 1, 1)), 0)  # truly empty: the manifest says so
    np.testing.assert_array_equal(_valid(loader, 0, (2, 2, 0)), _ref(vol, (2, 2, 0)))


def test_a_statistics_chunk_replaced_by_another_valid_one_is_caught(store, vol):
    """Row z=1 of level 0's ``max`` replaced by row z=0 (all zeros, intact on its own): read alone,
    16 bricks with data would look empty. The ranges a renderer culls by come from the manifest,
    and the replaced array is refused, naming it."""
    c = store / "clipvol_stats" / "0" / "max" / "c"
    shutil.copyfile(c / "0" / "0" / "0", c / "1" / "0" / "0")
    assert zarr.open_array(str(store / "clipvol_stats" / "0" / "max"), mode="r")[1].max() == 0  # zarr reads it as valid
    loader = ZarrLoader(store)
    idx = np.array(list(np.ndindex(*_grid0(vol))))
    ranges = loader.brick_ranges(0, idx)
    ref = np.array([[_ref(vol, tuple(i)).min(), _ref(vol, tuple(i)).max()] for i in idx], dtype=np.float64)
    np.testing.assert_array_equal(ranges, ref)
    with pytest.raises(StoreFormatError, match=r"clipvol_stats/0/max differs from the manifest"):
        loader.brick_statistics(0)
    np.testing.assert_array_equal(_valid(loader, 0, (1, 2, 2)), _ref(vol, (1, 2, 2)))


def test_deleted_statistics_are_reported_not_silently_skipped(store, vol):
    shutil.rmtree(store / "clipvol_stats")
    loader = ZarrLoader(store)
    assert loader.verified
    with pytest.raises(StoreFormatError, match=r"clipvol_stats/0 is missing"):
        loader.brick_statistics(0)
    r = loader.brick_ranges(0, np.array([[1, 1, 1], [0, 0, 0]]))
    np.testing.assert_array_equal(r, [[_ref(vol, (1, 1, 1)).min(), _ref(vol, (1, 1, 1)).max()], [0, 0]])


def test_a_store_without_a_manifest_is_unverified_with_advice(store):
    g = zarr.open_group(str(store), mode="r+")
    g.attrs["clipvol"] = {k: v for k, v in g.attrs["clipvol"].items() if k != "manifest"}
    loader, message = _unverified(store)
    assert "no manifest" in message and "clipvol repair" in message and loader.manifest is None


@pytest.mark.parametrize("damage", ["table byte", "manifest.json edited", "manifest.json deleted", "table deleted"])
def test_a_damaged_manifest_makes_the_store_unverified(store, damage):
    m = store / MANIFEST_DIR
    if damage == "table byte":
        data = bytearray((m / "0.bin").read_bytes())
        data[100] ^= 1
        (m / "0.bin").write_bytes(bytes(data))
        want = "0.bin does not match its checksum"
    elif damage == "manifest.json edited":
        (m / "manifest.json").write_bytes((m / "manifest.json").read_bytes().replace(b'"format": 1', b'"format": 2'))
        want = "does not match the checksum recorded"
    elif damage == "manifest.json deleted":
        (m / "manifest.json").unlink()
        want = "manifest.json is missing"
    else:
        (m / "1.bin").unlink()
        want = "1.bin is missing"
    _, message = _unverified(store)
    assert want in message


def test_a_record_moved_to_another_brick_is_refused_even_with_consistent_digests(store):
    """Two records swapped and every digest recomputed to match (as a careless tool might): the
    index each record carries no longer matches its place."""
    m = store / MANIFEST_DIR
    t = np.frombuffer((m / "0.bin").read_bytes(), dtype=TABLE_DTYPE).copy()
    t[[5, 6]] = t[[6, 5]]
    (m / "0.bin").write_bytes(t.tobytes())
    doc = json.loads((m / "manifest.json").read_text())
    doc["levels"][0]["table_sha256"] = hashlib.sha256(t.tobytes()).hexdigest()
    raw = json.dumps(doc).encode()
    (m / "manifest.json").write_bytes(raw)
    g = zarr.open_group(str(store), mode="r+")
    cv = dict(g.attrs["clipvol"])
    cv["manifest"] = {"sha256": hashlib.sha256(raw).hexdigest(), "bytes": len(raw)}
    g.attrs["clipvol"] = cv
    _, message = _unverified(store)
    assert "not at its brick's place" in message


def test_a_chunk_linked_inside_the_store_is_read_and_one_linked_outside_is_refused(store, vol, tmp_path):
    chunk = _chunk(store, 0, (1, 1, 1))
    (store / "spare").mkdir()
    inside = store / "spare" / "c111"
    shutil.move(chunk, inside)
    chunk.symlink_to(inside)
    np.testing.assert_array_equal(_valid(ZarrLoader(store), 0, (1, 1, 1)), _ref(vol, (1, 1, 1)))
    outside = tmp_path / "elsewhere"
    shutil.copyfile(inside, outside)
    chunk.unlink()
    chunk.symlink_to(outside)
    loader = ZarrLoader(store)
    for read in (lambda: loader.read_brick(0, (1, 1, 1)), lambda: loader.read_brick_into(0, (1, 1, 1), np.empty((B,) * 3, np.uint16))):
        with pytest.raises(BrickIntegrityError, match=r"0/c/1/1/1: a symbolic link to .*elsewhere, outside the store"):
            read()


def test_a_chunk_folder_linked_outside_is_refused(store, tmp_path):
    folder = store / "0" / "c" / "2" / "1"
    shutil.copytree(folder, tmp_path / "row")
    shutil.rmtree(folder)
    folder.symlink_to(tmp_path / "row")
    with pytest.raises(BrickIntegrityError, match=r"0/c/2/1/0: .*outside the store"):
        ZarrLoader(store).read_brick(0, (2, 1, 0))


def test_a_level_zarr_json_linked_outside_is_refused(store, tmp_path):
    meta = store / "1" / "zarr.json"
    shutil.copyfile(meta, tmp_path / "zarr.json")
    meta.unlink()
    meta.symlink_to(tmp_path / "zarr.json")
    with pytest.raises(InputFormatError, match=r"level 1: .*zarr\.json: a symbolic link to .*, outside the store"):
        ZarrLoader(store)


def _bounded(fn, seconds=60):
    """What ``fn`` raised (None if it returned); a hang fails the test instead of blocking the run."""
    return bounded(fn, seconds, "the read blocked")[0]


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no FIFOs on this platform")
def test_a_fifo_chunk_is_refused_without_blocking(store):
    chunk = _chunk(store, 0, (1, 1, 1))
    chunk.unlink()
    os.mkfifo(chunk)
    loader = ZarrLoader(store)
    for read in (lambda: loader.read_brick(0, (1, 1, 1)), lambda: loader.read_brick_into(0, (1, 1, 1), np.empty((B,) * 3, np.uint16))):
        e = _bounded(read)
        assert isinstance(e, BrickIntegrityError) and "0/c/1/1/1: a FIFO, not a regular file" in str(e), e


@pytest.mark.skipif(not os.path.exists("/dev/zero"), reason="no /dev/zero")
def test_dev_zero_as_a_chunk_is_refused_without_reading_it(store, tmp_path):
    chunk = _chunk(store, 0, (1, 1, 1))
    chunk.unlink()
    chunk.symlink_to("/dev/zero")
    e = _bounded(lambda: ZarrLoader(store).read_brick(0, (1, 1, 1)))
    assert isinstance(e, BrickIntegrityError) and "/dev/zero, outside the store" in str(e), e
    # even where the store's own folder holds the device (a store at the file-system root), the
    # file kind refuses it: a link inside a store rooted at /dev
    from clipvol.bricking.store_files import check_opened, open_inside

    fd = open_inside("/dev/zero", "/dev")
    try:
        with pytest.raises(InputFormatError, match="/dev/zero: a character device, not a regular file"):
            check_opened(fd, "/dev/zero", 1 << 20)
    finally:
        os.close(fd)


def test_an_oversize_chunk_is_refused_by_its_size(store, vol):
    chunk = _chunk(store, 0, (1, 1, 1))
    with open(chunk, "ab") as f:
        f.write(b"\0" * 10)
    with pytest.raises(BrickIntegrityError, match=r"0/c/1/1/1: truncated or corrupt: \d+ bytes, but the store's manifest says \d+"):
        ZarrLoader(store).read_brick(0, (1, 1, 1))
    # without a manifest, the cap from the chunk shape (decoded size + 1/8 + 64 KiB)
    g = zarr.open_group(str(store), mode="r+")
    g.attrs["clipvol"] = {k: v for k, v in g.attrs["clipvol"].items() if k != "manifest"}
    with open(chunk, "ab") as f:
        f.write(b"\0" * (B ** 3 * 2 + 70000))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UnverifiedStoreWarning)
        loader = ZarrLoader(store)
    with pytest.raises(BrickIntegrityError, match=r"0/c/1/1/1: \d+ bytes, more than the \d+ a file of this kind may hold"):
        loader.read_brick(0, (1, 1, 1))


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no FIFOs on this platform")
def test_a_fifo_in_the_statistics_is_refused_before_zarr_opens_it(store):
    c = store / "clipvol_stats" / "0" / "min" / "c" / "1" / "0" / "0"
    c.unlink()
    os.mkfifo(c)
    loader = ZarrLoader(store)
    e = _bounded(lambda: loader.brick_statistics(0))
    assert isinstance(e, StoreFormatError) and "a FIFO, not a regular file" in str(e), e


def test_a_foreign_ome_zarr_is_unverified_foreign_without_a_warning(tmp_path, vol):
    g = zarr.open_group(str(tmp_path / "img.zarr"), mode="w", zarr_format=3)
    g.create_array("0", data=vol[16:48], chunks=(B, B, B))
    g.attrs["ome"] = {"version": "0.5", "multiscales": [{"axes": [{"name": a, "type": "space"} for a in "zyx"],
                      "datasets": [{"path": "0", "coordinateTransformations": [{"type": "scale", "scale": [1, 1, 1]}]}]}]}
    with warnings.catch_warnings():
        warnings.simplefilter("error", UnverifiedStoreWarning)
        loader = ZarrLoader(tmp_path / "img.zarr")
    assert not loader.verified and loader.trust.startswith("unverified, foreign")
    np.testing.assert_array_equal(_valid(loader, 0, (0, 1, 1)), _ref(vol, (1, 1, 1)))


def test_a_foreign_images_level_metadata_linked_outside_is_refused_not_skipped(tmp_path, vol):
    """A plain OME-Zarr image's level 1 ``zarr.json`` linked out of the store: refused, not taken as
    a level that is simply absent (which would be derived and drawn)."""
    g = zarr.open_group(str(tmp_path / "img.zarr"), mode="w", zarr_format=3)
    g.create_array("0", data=vol[:32, :32, :32], chunks=(B, B, B))
    g.create_array("1", data=vol[:32:2, :32:2, :32:2], chunks=(B, B, B))
    g.attrs["ome"] = {"version": "0.5", "multiscales": [{"axes": [{"name": a, "type": "space"} for a in "zyx"],
                      "datasets": [{"path": str(L), "coordinateTransformations": [{"type": "scale", "scale": [2 ** L] * 3}]}
                                   for L in (0, 1)]}]}
    meta = tmp_path / "img.zarr" / "1" / "zarr.json"
    shutil.copyfile(meta, tmp_path / "outside.json")
    meta.unlink()
    meta.symlink_to(tmp_path / "outside.json")
    with pytest.raises(InputFormatError, match=r"level 1: .*zarr\.json: a symbolic link to .*outside\.json, outside the store"):
        ZarrLoader(tmp_path / "img.zarr")
