"""Property-based fuzz of store metadata: every store opens correctly or raises a clipvol error.

Hypothesis writes a store's JSON (zarr v3 group and arrays; a clipvol store or a plain OME-Zarr
image) with random shapes, chunk shapes, dtypes, codec chains, scales, dataset paths and level
counts, plus random chunk bytes, then opens it with :class:`ZarrLoader` and reads bricks. Allowed
outcomes: a correct open (the pyramid matches the metadata, a brick has the brick shape and dtype)
or a :class:`ClipvolError`. Never another exception, a hang (hypothesis' deadline), more than a
bounded amount of memory (tracemalloc peak), or a read outside the store: a sentinel array beside
the store holds a value no store array holds, and no brick may contain it.
"""

from __future__ import annotations

import json
import shutil
import tempfile
import tracemalloc
import warnings
from pathlib import Path

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from clipvol.errors import ClipvolError
from clipvol.loaders.zarr_store import ZarrLoader

SENTINEL = 7777
PEAK_BYTES = 96 * 2**20

ints = st.one_of(st.integers(-2, 70), st.sampled_from([0, 2**31, 2**40, 2**62, 2**63 + 5]))
shapes = st.lists(ints, min_size=0, max_size=5)
dtypes = st.sampled_from(["uint16", "float32", "uint8", "uint16", "int32", "float32", "float64", "bool", "complex64", "|O", "<U4",
                          "V8", "r16", "datetime64", 5, None])
codec = st.sampled_from([
    {"name": "bytes", "configuration": {"endian": "little"}},
    {"name": "bytes", "configuration": {"endian": "big"}},
    {"name": "blosc", "configuration": {"cname": "lz4", "clevel": 5, "shuffle": "shuffle", "typesize": 2, "blocksize": 0}},
    {"name": "zstd", "configuration": {"level": 1, "checksum": False}},
    {"name": "gzip", "configuration": {"level": 1}},
    {"name": "crc32c"},
    {"name": "transpose", "configuration": {"order": [2, 1, 0]}},
    {"name": "sharding_indexed", "configuration": {"chunk_shape": [2, 2, 2], "codecs": [{"name": "bytes"}],
                                                   "index_codecs": [{"name": "bytes"}, {"name": "crc32c"}]}},
    {"name": "pickle"},
    "bytes",
])
codecs = st.one_of(st.lists(codec, min_size=0, max_size=4),
                   st.tuples(st.just({"name": "bytes", "configuration": {"endian": "little"}}), codec).map(list))
floats = st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.integers(-3, 3), st.text(max_size=3))
scales = st.one_of(st.just([1.0, 1.0, 1.0]), st.just([2.0, 0.5, 1e-3]), st.lists(floats, max_size=4))
#: dataset paths that leave the store ("{ABS}" becomes the sentinel array's absolute path)
escaping = st.sampled_from(["../outside/0", "0/../../outside/0", "{ABS}", "./../outside/0"])
paths = st.one_of(escaping, st.sampled_from(["0", "1", "2", "../outside", "/etc", ".", "", "0/c", "clipvol_stats"]),
                  st.text(max_size=8))


@st.composite
def stores(draw):
    clipvol = draw(st.sampled_from([True, False, False]))
    nlev = draw(st.integers(1, 3))
    shape = draw(st.one_of(st.lists(st.integers(1, 40), min_size=3, max_size=3), shapes))
    chunks = draw(st.one_of(st.lists(st.sampled_from([8, 16]), min_size=3, max_size=3), shapes))
    dtype = draw(dtypes)
    arrays, datasets = [], []
    for L in range(nlev):
        s = [max(1, -(-v // 2**L)) if isinstance(v, int) and v > 0 else v for v in shape]
        arrays.append({"zarr_format": 3, "node_type": draw(st.sampled_from(["array", "array", "group"])),
                       "shape": s, "data_type": dtype, "fill_value": draw(st.sampled_from([0, "NaN", None, "x", 1.5])),
                       "chunk_grid": {"name": draw(st.sampled_from(["regular", "regular", "rectilinear"])),
                                      "configuration": {"chunk_shape": chunks}},
                       "chunk_key_encoding": draw(st.sampled_from([{"name": "default"}, {"name": "v2"},
                                                                   {"name": "default", "configuration": {"separator": "."}}])),
                       "codecs": draw(st.one_of(st.just([{"name": "bytes"}]), codecs)), "attributes": {}})
        datasets.append({"path": draw(st.one_of(st.just(str(L)), st.just(str(L)), paths)),
                         "coordinateTransformations": [{"type": "scale", "scale": draw(scales)},
                                                       {"type": "translation", "translation": [0, 0, 0]}]})
    attrs = {"ome": {"version": "0.5", "multiscales": [{"axes": [{"name": a, "type": "space"} for a in "zyx"],
                                                         "datasets": datasets}]}}
    if clipvol:
        attrs["clipvol"] = {"format_version": draw(st.sampled_from([1, 1, 2])), "brick_shape": chunks,
                            "filter": draw(st.sampled_from(["mean", "max", "median"])), "dtype": dtype,
                            "value_range": [0, draw(floats)], "fill_value": 0, "spacing": [1, 1, 1],
                            "levels": [[max(1, -(-v // 2**L)) if isinstance(v, int) and v > 0 else v for v in shape]
                                       for L in range(draw(st.integers(0, 4)))],
                            "complete": draw(st.booleans())}
    chunk_bytes = draw(st.one_of(st.binary(max_size=64), st.binary(min_size=8192, max_size=8192)))
    return attrs, arrays, chunk_bytes


def _write(root: Path, attrs, arrays, chunk_bytes) -> Path:
    store = root / "store.zarr"
    store.mkdir()
    text = json.dumps({"zarr_format": 3, "node_type": "group", "attributes": attrs})
    (store / "zarr.json").write_text(text.replace("{ABS}", str(root / "outside" / "0")))
    for L, meta in enumerate(arrays):
        d = store / str(L)
        (d / "c" / "0" / "0").mkdir(parents=True)
        (d / "zarr.json").write_text(json.dumps(meta))
        (d / "c" / "0" / "0" / "0").write_bytes(chunk_bytes)
    return store


def _outside(root: Path) -> None:
    """A valid array beside the store, full of SENTINEL: reading it would be a read outside the store."""
    import zarr

    g = zarr.open_group(str(root / "outside"), mode="w", zarr_format=3)
    g.create_array("0", data=np.full((16, 16, 16), SENTINEL, np.uint16), chunks=(16, 16, 16))


@settings(max_examples=60, deadline=2000, suppress_health_check=[HealthCheck.too_slow])
@given(stores())
def test_metadata_fuzz_opens_or_raises_a_clipvol_error(case):
    attrs, arrays, chunk_bytes = case
    root = Path(tempfile.mkdtemp(prefix="clipvol-fuzz-"))
    try:
        _outside(root)
        store = _write(root, attrs, arrays, chunk_bytes)
        tracemalloc.start()
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                loader = ZarrLoader(store)
                pyr = loader.pyramid
                for L in {0, pyr.num_levels - 1}:
                    for idx in {(0, 0, 0), tuple(g - 1 for g in pyr.grid(L))}:
                        b = loader.read_brick(L, idx)
                        assert b.shape == pyr.brick_shape and b.dtype == pyr.dtype
                        assert not (b == SENTINEL).any(), "read outside the store"
        except ClipvolError:
            pass
        finally:
            peak = tracemalloc.get_traced_memory()[1]
            tracemalloc.stop()
        assert peak < PEAK_BYTES, f"peak {peak} bytes"
    finally:
        shutil.rmtree(root, ignore_errors=True)
