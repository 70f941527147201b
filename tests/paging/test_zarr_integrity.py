"""The zarr loader never returns wrong data as if right: checksums, statistics, missing chunks, paths.

Stores are written by ``brick_volume``; damage is done to the chunk files in the test; the
references are the source array itself and zarr-python's own reader (which verifies the crc32c
codec independently of our code).
"""

from __future__ import annotations

import json
import shutil
import warnings

import numpy as np
import pytest
import zarr

from clipvol.bricking.pipeline import brick_volume
from clipvol.bricking.pyramid import pad_to_brick
from clipvol.errors import BrickIntegrityError, ClipvolError, InputFormatError
from clipvol.loaders.zarr_store import UnverifiedStoreWarning, ZarrLoader
from clipvol.paging.cliptexture import BrickState, ClipTexture

B = 16


@pytest.fixture(scope="module")
def vol():
    """12-bit CT-like data (max 4095) with structure in every brick."""
    z, y, x = np.indices((40, 48, 44))
    v = 2000 + 1500 * np.sin(z / 4.0) * np.cos(y / 6.0) + 500 * np.sin(x / 3.0)
    return np.clip(v, 0, 4095).astype(np.uint16)


def _chunk(path, L, idx):
    return path / str(L) / "c" / str(idx[0]) / str(idx[1]) / str(idx[2])


def test_every_chunk_carries_a_crc32c_that_zarr_python_verifies(store, vol):
    meta = json.loads((store / "0" / "zarr.json").read_text())
    assert [c["name"] for c in meta["codecs"]][-1] == "crc32c"
    np.testing.assert_array_equal(zarr.open_array(str(store / "0"), mode="r")[...], vol)
    loader = ZarrLoader(store)
    assert loader.checksummed
    np.testing.assert_array_equal(loader.read_brick(0, (1, 1, 1)), vol[16:32, 16:32, 16:32])


@pytest.mark.parametrize("damage", ["two-bit flip", "payload after a valid blosc header", "truncated"])
def test_corruption_inside_a_chunk_is_refused(store, vol, damage):
    chunk = _chunk(store, 0, (1, 1, 1))
    data = bytearray(chunk.read_bytes())
    if damage == "two-bit flip":
        data[len(data) // 2] ^= 0x03
    elif damage == "payload after a valid blosc header":
        data[16:-4] = np.random.default_rng(0).integers(0, 256, len(data) - 20, dtype=np.uint8).tobytes()
    else:
        data = data[: len(data) // 2]
    chunk.write_bytes(bytes(data))
    with pytest.raises(ValueError):  # the independent reader agrees the chunk is bad
        zarr.open_array(str(store / "0"), mode="r")[16:32, 16:32, 16:32]
    loader = ZarrLoader(store)
    for read in (lambda: loader.read_brick(0, (1, 1, 1)),
                 lambda: loader.read_brick_into(0, (1, 1, 1), np.empty((B, B, B), np.uint16))):
        with pytest.raises(BrickIntegrityError, match=r"\(level 0, 1, 1, 1\).*0/c/1/1/1"):
            read()
    np.testing.assert_array_equal(loader.read_brick(0, (1, 1, 0)), vol[16:32, 16:32, 0:16])  # others still read


def test_deleted_chunk_with_data_fails_not_zeros(store, vol):
    _chunk(store, 0, (0, 1, 1)).unlink()
    loader = ZarrLoader(store)
    assert loader.brick_statistics(0)["max"][0, 1, 1] == vol[0:16, 16:32, 16:32].max() > 0
    with pytest.raises(BrickIntegrityError, match="missing.*holds data"):
        loader.read_brick(0, (0, 1, 1))


def test_chunk_substituted_by_another_bricks_valid_chunk_fails(store):
    """A chunk file copied over another passes its own checksum; the size and crc32c the manifest
    records for the brick catch it, and deleting the statistics arrays changes nothing."""
    _chunk(store, 0, (1, 1, 1)).write_bytes(_chunk(store, 0, (0, 0, 0)).read_bytes())
    with pytest.raises(BrickIntegrityError, match="manifest says|not the one written for this brick"):
        ZarrLoader(store).read_brick(0, (1, 1, 1))
    shutil.rmtree(store / "clipvol_stats")
    with pytest.raises(BrickIntegrityError, match="manifest says|not the one written for this brick"):
        ZarrLoader(store).read_brick(0, (1, 1, 1))


def test_substitution_between_bricks_with_equal_bounds_is_caught(tmp_path):
    """Saturated CT bricks share min 0 and max 4095: only the per-brick checksum tells them apart."""
    rng = np.random.default_rng(5)
    v = rng.integers(0, 4096, (32, 32, 32)).astype(np.uint16)
    v[::16, ::16, ::16] = 0
    v[1::16, 1::16, 1::16] = 4095
    path = tmp_path / "sat.zarr"
    brick_volume(v, path, brick=B, progress=False, workers=1)
    st = ZarrLoader(path).brick_statistics(0)
    assert st["min"][0, 0, 0] == st["min"][1, 1, 1] == 0 and st["max"][0, 0, 0] == st["max"][1, 1, 1] == 4095
    _chunk(path, 0, (1, 1, 1)).write_bytes(_chunk(path, 0, (0, 0, 0)).read_bytes())
    loader = ZarrLoader(path)
    for read in (lambda: loader.read_brick(0, (1, 1, 1)),
                 lambda: loader.read_brick_into(0, (1, 1, 1), np.empty((B, B, B), np.uint16))):
        with pytest.raises(BrickIntegrityError, match="another brick"):
            read()


def test_a_chunk_where_none_was_written_is_caught(tmp_path, vol):
    v = vol.copy()
    v[:16, :16, :16] = 0  # an empty brick: no chunk written
    path = tmp_path / "e.zarr"
    brick_volume(v, path, brick=B, progress=False, workers=1)
    assert not _chunk(path, 0, (0, 0, 0)).exists()
    loader = ZarrLoader(path)
    np.testing.assert_array_equal(loader.read_brick(0, (0, 0, 0)), 0)
    _chunk(path, 0, (0, 0, 0)).parent.mkdir(parents=True, exist_ok=True)
    _chunk(path, 0, (0, 0, 0)).write_bytes(_chunk(path, 0, (1, 1, 1)).read_bytes())
    with pytest.raises(BrickIntegrityError, match="no chunk was written"):
        ZarrLoader(path).read_brick(0, (0, 0, 0))


def test_old_store_without_checksum_opens_unverified_and_statistics_still_catch_garbage(tmp_path, vol):
    """A store written before checksums (the chain without crc32c, rewritten here with zarr-python)."""
    path = tmp_path / "old.zarr"
    brick_volume(vol, path, brick=B, progress=False, workers=1)
    for L in range(len(list(path.glob("[0-9]*")))):
        arr_meta = json.loads((path / str(L) / "zarr.json").read_text())
        data = zarr.open_array(str(path / str(L)), mode="r")[...]
        for c in (path / str(L) / "c").rglob("*"):
            if c.is_file():
                c.unlink()
        arr_meta["codecs"] = arr_meta["codecs"][:-1]
        (path / str(L) / "zarr.json").write_text(json.dumps(arr_meta))
        a = zarr.open_array(str(path / str(L)), mode="r+")
        a[...] = data
    g = zarr.open_group(str(path), mode="r+")  # written before checksums, so before manifests too
    g.attrs["clipvol"] = {k: v for k, v in g.attrs["clipvol"].items() if k != "manifest"}
    with pytest.warns(UnverifiedStoreWarning, match="unverified"):
        loader = ZarrLoader(path)
    assert not loader.checksummed
    np.testing.assert_array_equal(loader.read_brick(0, (1, 1, 1)), vol[16:32, 16:32, 16:32])
    chunk = _chunk(path, 0, (1, 1, 1))
    data = bytearray(chunk.read_bytes())
    data[16:] = np.random.default_rng(1).integers(0, 256, len(data) - 16, dtype=np.uint8).tobytes()
    chunk.write_bytes(bytes(data))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UnverifiedStoreWarning)
        loader = ZarrLoader(path)
    with pytest.raises(BrickIntegrityError):
        loader.read_brick(0, (1, 1, 1))


class _SwappingDecoder:
    """A codec that decodes right and then swaps the bytes of every value: what a decoder set up
    with the wrong byte order gives. ``rows``: only these z-planes go wrong (a fault in one blosc
    block); None: all of them."""

    def __init__(self, inner, rows=None):
        self.inner, self.rows = inner, rows

    def decode(self, buf, out=None):
        raw = np.frombuffer(self.inner.decode(buf), dtype=np.uint16).reshape(B, B, B).copy()
        sel = slice(None) if self.rows is None else self.rows
        raw[sel] = raw[sel].byteswap()
        if out is not None:
            np.asarray(out).reshape(-1)[:] = raw.view(np.uint8).reshape(-1)
            return out
        return raw.tobytes()


@pytest.mark.parametrize("rows", [None, slice(B // 2, B)], ids=["whole brick", "second half"])
def test_a_proven_brick_whose_decode_goes_wrong_is_caught(store, vol, rows):
    """Intact stored bytes (their crc32c is the one recorded for the brick) still have their decode
    checked on a sample of the decoded voxels: a decoder that returns wrong values is refused."""
    import dataclasses

    loader = ZarrLoader(store)
    slot = np.empty((B, B, B), dtype=np.uint16)
    loader.read_brick_into(0, (1, 1, 1), slot)  # the right decoder: proven, decoded, checked
    np.testing.assert_array_equal(slot, vol[16:32, 16:32, 16:32])
    am = loader._arrays[0]
    loader._arrays[0] = dataclasses.replace(am, decoder=_SwappingDecoder(am.decoder, rows))
    with pytest.raises(BrickIntegrityError, match="sample"):
        loader.read_brick_into(0, (1, 1, 1), slot)
    with pytest.raises(BrickIntegrityError):
        loader.read_brick(0, (1, 1, 1))


@pytest.mark.parametrize("damage", ["another brick's chunk", "two-bit flip", "deleted"])
def test_a_brick_whose_decode_is_on_record_is_still_checked_on_every_later_load(store, vol, damage):
    """On a verified store the sampled decode check runs once per brick (``_check_loaded``); every
    later load of that brick leans on the per-load checks alone. Each fault they must catch,
    introduced after the record is made, is refused on the next load by the same loader."""
    loader = ZarrLoader(store)
    assert loader.verified
    slot = np.empty((B, B, B), dtype=np.uint16)
    for _ in range(2):
        loader.read_brick_into(0, (1, 1, 1), slot)
        np.testing.assert_array_equal(slot, vol[16:32, 16:32, 16:32])
    assert loader._decode_on_record(0, (1, 1, 1))  # the sampled check is skipped from here on
    chunk = _chunk(store, 0, (1, 1, 1))
    if damage == "another brick's chunk":
        chunk.write_bytes(_chunk(store, 0, (0, 0, 0)).read_bytes())
    elif damage == "two-bit flip":
        data = bytearray(chunk.read_bytes())
        data[len(data) // 2] ^= 0x03
        chunk.write_bytes(bytes(data))
    else:
        chunk.unlink()
    try:  # the independent reader: refuses the chunk, or reads values other than the brick's
        got = zarr.open_array(str(store / "0"), mode="r")[16:32, 16:32, 16:32]
    except ValueError:
        got = None
    assert got is None or not np.array_equal(got, vol[16:32, 16:32, 16:32])
    for read in (lambda: loader.read_brick_into(0, (1, 1, 1), slot), lambda: loader.read_brick(0, (1, 1, 1))):
        with pytest.raises(BrickIntegrityError, match=r"\(level 0, 1, 1, 1\)"):
            read()


def test_an_unverified_store_checks_the_decode_on_every_load(store, vol):
    """Without a verified manifest nothing pins the bytes between loads, so no decode check is
    taken as done: a decoder gone wrong after a good load is caught on the next one."""
    g = zarr.open_group(str(store), mode="r+")
    g.attrs["clipvol"] = {k: v for k, v in g.attrs["clipvol"].items() if k != "manifest"}
    with pytest.warns(UnverifiedStoreWarning, match="no manifest"):
        loader = ZarrLoader(store)
    slot = np.empty((B, B, B), dtype=np.uint16)
    loader.read_brick_into(0, (1, 1, 1), slot)
    np.testing.assert_array_equal(slot, vol[16:32, 16:32, 16:32])
    assert not loader._decode_on_record(0, (1, 1, 1))
    am = loader._arrays[0]
    object.__setattr__(am, "decoder", _SwappingDecoder(am.decoder))  # the same level object, a wrong decode
    with pytest.raises(BrickIntegrityError, match="statistics"):
        loader.read_brick_into(0, (1, 1, 1), slot)


def test_float_nan_bricks_pass_and_a_lost_nan_is_caught(tmp_path):
    v = np.linspace(0, 1, 32 ** 3, dtype=np.float32).reshape(32, 32, 32)
    v[3, 4, 5] = np.nan
    v[20, 20, 20] = np.inf
    path = tmp_path / "f.zarr"
    brick_volume(v, path, brick=B, progress=False, workers=1)
    loader = ZarrLoader(path)
    np.testing.assert_array_equal(loader.read_brick(0, (0, 0, 0)), v[:16, :16, :16])
    np.testing.assert_array_equal(loader.read_brick(0, (1, 1, 1)), v[16:, 16:, 16:])
    # a store without a manifest and without per-brick crc32c records: unproven bytes, the full check applies
    shutil.rmtree(path / "clipvol_stats" / "0" / "chunk_crc32c")
    g = zarr.open_group(str(path), mode="r+")
    g.attrs["clipvol"] = {k: v for k, v in g.attrs["clipvol"].items() if k != "manifest"}
    with pytest.warns(UnverifiedStoreWarning, match="no manifest"):
        stale = ZarrLoader(path)
    st = stale.brick_statistics(0)
    st["nan_count"].setflags(write=True)
    st["nan_count"][0, 0, 0] = 0  # the statistics now disagree with the data
    with pytest.raises(BrickIntegrityError, match="1 NaN"):
        stale.read_brick(0, (0, 0, 0))


@pytest.mark.parametrize("bad", ["../other.zarr/0", "/abs/other.zarr/0", "0/../../other.zarr/0", "."])
def test_ome_dataset_paths_must_stay_inside_the_store(tmp_path, vol, bad):
    other = zarr.open_group(str(tmp_path / "other.zarr"), mode="w", zarr_format=3)
    other.create_array("0", data=vol, chunks=(B, B, B))
    img = tmp_path / "img.zarr"
    g = zarr.open_group(str(img), mode="w", zarr_format=3)
    g.create_array("0", data=np.zeros((16, 16, 16), np.uint16), chunks=(B, B, B))
    if bad.startswith("/abs"):
        bad = str(tmp_path / "other.zarr" / "0")
    g.attrs["ome"] = {"version": "0.5", "multiscales": [{"axes": [{"name": a, "type": "space"} for a in "zyx"],
                      "datasets": [{"path": bad, "coordinateTransformations": [{"type": "scale", "scale": [1, 1, 1]}]}]}]}
    with pytest.raises(InputFormatError, match="dataset path"):
        ZarrLoader(img)


def test_symlinked_level_outside_the_store_is_refused(tmp_path, vol):
    other = zarr.open_group(str(tmp_path / "other.zarr"), mode="w", zarr_format=3)
    other.create_array("0", data=vol, chunks=(B, B, B))
    img = tmp_path / "img.zarr"
    g = zarr.open_group(str(img), mode="w", zarr_format=3)
    g.attrs["ome"] = {"version": "0.5", "multiscales": [{"axes": [{"name": a, "type": "space"} for a in "zyx"],
                      "datasets": [{"path": "0", "coordinateTransformations": [{"type": "scale", "scale": [1, 1, 1]}]}]}]}
    (img / "0").symlink_to(tmp_path / "other.zarr" / "0")
    with pytest.raises(InputFormatError, match="outside the store"):
        ZarrLoader(img)


def test_cliptexture_marks_a_corrupt_brick_failed_at_once_and_never_shows_it(store, vol):
    data = bytearray(_chunk(store, 0, (1, 1, 1)).read_bytes())
    data[100] ^= 0x10
    _chunk(store, 0, (1, 1, 1)).write_bytes(bytes(data))
    loader = ZarrLoader(store)
    errors = []
    with ClipTexture(loader, "64MB", threads=2, retries=3, retry_backoff=0.01,
                     on_error=lambda k, e: errors.append((k, e))) as ct:
        assert ct.wait_until_idle(timeout=30)
        assert ct.state(0, (1, 1, 1)) == BrickState.FAILED
        assert ct.get_brick(0, (1, 1, 1)) is None
        assert ct.stats.retries == 0  # deterministic corruption is not retried
        assert [(k.level, k.index) for k, _ in errors] == [(0, (1, 1, 1))]
        assert isinstance(errors[0][1], BrickIntegrityError)
        # its ancestor is sound and resident, so the renderer can draw it there instead
        assert ct.state(1, (0, 0, 0)) == BrickState.RESIDENT
        for idx in [(0, 0, 0), (1, 1, 0), (2, 2, 2)]:
            got = ct.get_brick(0, idx)
            assert got is not None
            s = tuple(slice(i * B, (i + 1) * B) for i in idx)
            np.testing.assert_array_equal(got, pad_to_brick(vol[s], (B, B, B)))


def test_every_failure_is_a_clipvol_error(store):
    _chunk(store, 1, (0, 0, 0)).write_bytes(b"\x00" * 3)
    with pytest.raises(ClipvolError):
        ZarrLoader(store).read_brick(1, (0, 0, 0))
