"""The zarr loader as one class over its job modules: the plug-in entry point, the names other
code imports from ``clipvol.loaders.zarr_store``, where the unverified-store warning points, and
a remote-style loader that swaps only the raw fetch.

References are independent of the loader: the installed package's entry-point metadata, this test
file's own path, and the source array and chunk files.
"""

from __future__ import annotations

import importlib.metadata
from pathlib import Path

import numpy as np
import pytest

from clipvol.bricking.manifest import MANIFEST_DIR
from clipvol.loaders.zarr_store import UnverifiedStoreWarning, ZarrLoader

B = 16


@pytest.fixture(scope="module")
def vol():
    z, y, x = np.indices((40, 36, 33))
    return (1000 + 30 * z - 7 * y + 3 * x).astype(np.uint16)


def test_the_zarr_entry_point_is_the_composed_loader():
    eps = [ep for ep in importlib.metadata.entry_points(group="clipvol.loaders") if ep.name == "zarr"]
    assert len(eps) == 1 and eps[0].load() is ZarrLoader


def test_names_imported_from_zarr_store_are_those_of_the_job_modules():
    from clipvol.loaders import zarr_chunks, zarr_crc, zarr_integrity, zarr_levels, zarr_meta, zarr_store

    assert zarr_store.crc32c_implementation is zarr_crc.crc32c_implementation
    assert zarr_store._crc32c_function is zarr_crc._crc32c_function
    assert zarr_store.UnverifiedStoreWarning is zarr_integrity.UnverifiedStoreWarning
    assert zarr_store._UNREAD is zarr_integrity._UNREAD
    assert zarr_store.DERIVED_CACHE_BYTES == zarr_levels.DERIVED_CACHE_BYTES
    assert zarr_store.inside is zarr_meta.inside
    assert issubclass(ZarrLoader, zarr_chunks.ChunkReader) and issubclass(ZarrLoader, zarr_integrity.IntegrityChecks)


def test_the_unverified_store_warning_names_the_line_that_opened_the_store(store):
    """The warning points at the caller of ``ZarrLoader(...)``, not at a line inside the loader."""
    (store / MANIFEST_DIR / "manifest.json").unlink()
    with pytest.warns(UnverifiedStoreWarning, match="manifest.json is missing") as rec:
        loader = ZarrLoader(store)
    assert not loader.verified
    assert Path(rec[0].filename).resolve() == Path(__file__).resolve()


def test_a_subclass_that_replaces_only_the_raw_fetch_reads_through_it(store, vol):
    """Remote storage overrides ``_chunk_bytes`` alone: the loader then reads every chunk through it
    (not the local per-thread buffer), and checksum, decode and statistics checks still apply."""
    seen = []

    class Fetching(ZarrLoader):
        def _chunk_bytes(self, level, index):
            seen.append((level, tuple(index)))
            p = self.path / str(level) / "c" / "/".join(str(i) for i in index)
            return p.read_bytes() if p.exists() else None

    loader = Fetching(store)
    out = np.empty((B, B, B), np.uint16)
    loader.read_brick_into(0, (1, 1, 1), out)
    np.testing.assert_array_equal(out, vol[16:32, 16:32, 16:32])
    edge = loader.read_brick(0, (2, 2, 2))
    np.testing.assert_array_equal(edge[:8, :4, :1], vol[32:40, 32:36, 32:33])
    assert seen == [(0, (1, 1, 1)), (0, (2, 2, 2))]


def test_no_zarr_loader_module_is_over_500_lines():
    import clipvol.loaders as pkg

    root = Path(pkg.__file__).parent
    sizes = {p.name: len(p.read_text().splitlines()) for p in root.glob("zarr_*.py")}
    assert "zarr_store.py" in sizes and "zarr_chunks.py" in sizes
    assert {n: s for n, s in sizes.items() if s > 500} == {}
