"""The zarr loader's faster checksum path still verifies every byte of every chunk on every read.

What changed for speed, each tested against an independent reference: the CRC-32C package (the
fastest installed, checked here against google-crc32c, zarr-python's own, and the standard's check
value), and the chunk read into a per-thread buffer (checked against the file's bytes and the
source array). Corruption is done to the chunk files in the test, after good reads through the
same buffer, with each installed package.
"""

from __future__ import annotations

import zlib
from concurrent.futures import ThreadPoolExecutor

import google_crc32c
import numpy as np
import pytest
import zarr

from clipvol.errors import BrickIntegrityError
from clipvol.loaders import zarr_crc
from clipvol.loaders.zarr_store import CRC32C_PACKAGES, ZarrLoader, crc32c_implementation

B = 16


@pytest.fixture(scope="module")
def vol():
    """12-bit data with detail in every brick, some bricks smooth (small chunks), some noisy (large)."""
    rng = np.random.default_rng(7)
    z, y, _ = np.indices((40, 48, 44))
    v = 2000 + 1500 * np.sin(z / 4.0) * np.cos(y / 6.0)
    v[16:32] += rng.normal(0, 300, v[16:32].shape)  # noisy middle slab: chunks several times larger
    return np.clip(v, 0, 4095).astype(np.uint16)


def _chunk(path, L, idx):
    return path / str(L) / "c" / str(idx[0]) / str(idx[1]) / str(idx[2])


def _interior(path):
    loader = ZarrLoader(path)
    return loader, [(bz, by, bx) for bz in range(2) for by in range(2) for bx in range(2)]


@pytest.mark.parametrize("package", CRC32C_PACKAGES)
def test_each_crc32c_package_agrees_with_google_crc32c_on_chunk_bytes(store, package):
    fn = zarr_crc._crc32c_function(package)
    if fn is None:
        pytest.skip(f"{package} is not installed")
    assert zarr_crc._computes_crc32c(fn)
    for idx in [(0, 0, 0), (1, 1, 1), (2, 2, 2)]:
        data = _chunk(store, 0, idx).read_bytes()
        want = google_crc32c.value(data[:-4])
        assert want == int.from_bytes(data[-4:], "little")  # the codec's trailer, as zarr-python wrote it
        buf = bytearray(data)
        assert fn(data[:-4]) == fn(memoryview(buf)[:-4]) == want
        assert fn(memoryview(buf)) == zarr_crc._CRC32C_RESIDUE


def test_a_function_that_is_not_crc32c_is_never_chosen(monkeypatch):
    assert not zarr_crc._computes_crc32c(zlib.crc32)  # CRC-32 (IEEE): another polynomial
    assert not zarr_crc._computes_crc32c(lambda data: zarr_crc._CRC32C_CHECK)  # right answer, wrong function
    real = zarr_crc._crc32c_function
    crc32c_implementation.cache_clear()
    try:
        monkeypatch.setattr(zarr_crc, "_crc32c_function", lambda p: zlib.crc32 if p != "google-crc32c" else real(p))
        assert crc32c_implementation()[0] == "google-crc32c"
        crc32c_implementation.cache_clear()
        monkeypatch.setattr(zarr_crc, "_crc32c_function", lambda p: None)
        with pytest.raises(ImportError, match="no working CRC-32C"):
            crc32c_implementation()
    finally:
        crc32c_implementation.cache_clear()


@pytest.mark.parametrize("package", CRC32C_PACKAGES)
def test_a_flipped_byte_is_refused_after_good_reads_through_the_same_buffer(store, vol, package):
    """Each brick read once intact (the buffer then holds good bytes of the same length), then one
    byte of one chunk flipped on disk: the next read of that brick fails, naming brick and file;
    nothing is remembered between reads."""
    fn = zarr_crc._crc32c_function(package)
    if fn is None:
        pytest.skip(f"{package} is not installed")
    loader, keys = _interior(store)
    loader._crc32c = fn
    out = np.empty((B, B, B), np.uint16)
    for idx in keys:
        loader.read_brick_into(0, idx, out)
        np.testing.assert_array_equal(out, vol[tuple(slice(16 * i, 16 * i + 16) for i in idx)])
    chunk = _chunk(store, 0, (1, 1, 1))
    data = bytearray(chunk.read_bytes())
    data[len(data) // 3] ^= 0x10
    chunk.write_bytes(bytes(data))
    with pytest.raises(ValueError):  # the independent reader agrees the chunk is bad
        zarr.open_array(str(store / "0"), mode="r")[16:32, 16:32, 16:32]
    for read in (lambda: loader.read_brick_into(0, (1, 1, 1), out), lambda: loader.read_brick(0, (1, 1, 1))):
        with pytest.raises(BrickIntegrityError, match=r"\(level 0, 1, 1, 1\).*0/c/1/1/1.*crc32c checksum mismatch"):
            read()
    loader.read_brick_into(0, (1, 1, 0), out)  # the others still read, through the same buffer
    np.testing.assert_array_equal(out, vol[16:32, 16:32, 0:16])


def test_a_shorter_chunk_after_a_longer_one_is_refused(store):
    """The buffer is larger than the file (it held a larger chunk): only the file's own bytes are checked."""
    loader, _ = _interior(store)
    out = np.empty((B, B, B), np.uint16)
    big = max([(1, 1, 1), (1, 0, 0), (0, 0, 0)], key=lambda i: _chunk(store, 0, i).stat().st_size)
    loader.read_brick_into(0, big, out)
    chunk = _chunk(store, 0, (0, 1, 1))
    chunk.write_bytes(chunk.read_bytes()[:-9])
    with pytest.raises(BrickIntegrityError, match=r"\(level 0, 0, 1, 1\).*0/c/0/1/1"):
        loader.read_brick_into(0, (0, 1, 1), out)


def test_buffered_reads_equal_the_files_and_the_source_across_threads(store, vol):
    loader, keys = _interior(store)
    for L in range(loader.pyramid.num_levels):
        for idx in np.ndindex(*loader.pyramid.grid(L)):
            got = loader._chunk_into_buffer(L, idx)
            path = _chunk(store, L, idx)
            assert (got is None) == (not path.exists())
            if got is not None:
                assert bytes(got) == path.read_bytes() == loader._chunk_bytes(L, idx)

    def load(idx):
        out = np.empty((B, B, B), np.uint16)
        for _ in range(5):
            loader.read_brick_into(0, idx, out)
        return idx, out

    with ThreadPoolExecutor(4) as pool:
        for idx, out in pool.map(load, keys * 4):
            np.testing.assert_array_equal(out, vol[tuple(slice(16 * i, 16 * i + 16) for i in idx)])


def test_a_subclass_that_fetches_elsewhere_is_used_and_still_verified(store, vol):
    """The remote-store seam: overriding _chunk_bytes bypasses the local buffer read, not the checks."""
    damaged = {(1, 1, 1)}

    class Elsewhere(ZarrLoader):
        def _chunk_bytes(self, level, index):
            data = bytearray(_chunk(store, level, index).read_bytes())
            if tuple(index) in damaged:
                data[40] ^= 0x01
            return bytes(data)

    loader = Elsewhere(store)
    assert loader._fetch == loader._chunk_bytes
    out = np.empty((B, B, B), np.uint16)
    loader.read_brick_into(0, (1, 0, 1), out)
    np.testing.assert_array_equal(out, vol[16:32, 0:16, 16:32])
    with pytest.raises(BrickIntegrityError, match=r"\(level 0, 1, 1, 1\).*0/c/1/1/1"):
        loader.read_brick_into(0, (1, 1, 1), out)


def test_a_file_whose_size_changes_under_the_read_is_read_whole_and_verified(store, vol, monkeypatch):
    """``fstat`` reporting fewer bytes than the file holds (it grew between fstat and read): the
    buffered read sees the mismatch and the whole file is read again, then verified as usual."""
    import os

    real = os.fstat

    class Short:
        def __init__(self, st):
            self.st_size, self.st_mode = st.st_size - 10, st.st_mode

    monkeypatch.setattr(os, "fstat", lambda fd: Short(real(fd)))
    loader, _ = _interior(store)
    with pytest.raises(BrickIntegrityError, match=r"0/c/1/1/1: truncated or corrupt: \d+ bytes, but the store's manifest says"):
        loader._chunk_into_buffer(0, (1, 1, 1))  # a verified store knows each chunk's exact size
    loader._sizes = [None] * len(loader._sizes)  # a store without one reads on, bounded by the cap
    assert loader._chunk_into_buffer(0, (1, 1, 1)) == _chunk(store, 0, (1, 1, 1)).read_bytes()
    out = np.empty((B, B, B), np.uint16)
    loader.read_brick_into(0, (1, 1, 1), out)
    np.testing.assert_array_equal(out, vol[16:32, 16:32, 16:32])
    chunk = _chunk(store, 0, (1, 1, 1))
    data = bytearray(chunk.read_bytes())
    data[-1] ^= 0x80  # the stored checksum itself
    chunk.write_bytes(bytes(data))
    with pytest.raises(BrickIntegrityError, match=r"\(level 0, 1, 1, 1\).*0/c/1/1/1"):
        loader.read_brick_into(0, (1, 1, 1), out)
