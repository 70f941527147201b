"""Every bundled loader through the conformance suite, plus the zarr loader's specific cases."""

from __future__ import annotations

import json
import pickle
import shutil
from pathlib import Path

import numpy as np
import pytest
import zarr
from zarr.codecs import BloscCodec, BytesCodec, Crc32cCodec, GzipCodec, ZstdCodec

from clipvol.errors import BrickIntegrityError, ClipvolError, InputFormatError, InputNotFoundError, ParameterError, StoreFormatError, StoreIncompleteError
from clipvol.loaders.numpy_array import NumpyLoader, finite_range
from clipvol.loaders.procedural import ProceduralLoader
from clipvol.loaders.zarr_store import ZarrLoader
from clipvol.paging.open import open_store
from clipvol.bricking.generators import parse_procedural
from clipvol.bricking.pyramid import Pyramid, downsample
from clipvol.bricking.store import STATS_GROUP, clipvol_metadata, ome_metadata
from clipvol.testing import LoaderTests

SHAPE = (37, 50, 45)  # odd and even, not multiples of the brick
BRICK = (16, 16, 16)


def make_volume(dtype="uint16", shape=SHAPE, seed=0) -> np.ndarray:
    """Smooth-ish data with an empty (zero) corner so that some bricks are never written."""
    rng = np.random.default_rng(seed)
    z, y, x = np.indices(shape)
    v = 1000 + 800 * np.sin(z / 5.0) * np.cos(y / 7.0) + 300 * np.sin(x / 3.0) + rng.normal(0, 50, shape)
    v[: shape[0] // 2, : shape[1] // 2, : shape[2] // 2] = 0
    v = v.astype(dtype)
    if v.dtype.kind == "f":
        v[-1, -1, -3:] = np.nan
    return v


def pyramid_levels(vol: np.ndarray, brick, filter="mean") -> list[np.ndarray]:
    pyr = Pyramid.build(vol.shape, brick, filter=filter, dtype=vol.dtype, value_range=(0, 1))
    out = [vol]
    for _ in range(pyr.num_levels - 1):
        out.append(downsample(out[-1], filter))
    return out


def _compressors(codec: str, dtype: np.dtype):
    return {
        "lz4": [BloscCodec(cname="lz4", clevel=5, shuffle="shuffle", typesize=dtype.itemsize)],
        "blosc-zstd": [BloscCodec(cname="zstd", clevel=1, shuffle="shuffle", typesize=dtype.itemsize)],
        "bitshuffle": [BloscCodec(cname="lz4", clevel=5, shuffle="bitshuffle", typesize=dtype.itemsize)],
        "zstd": [ZstdCodec(level=1)],
        "gzip": [GzipCodec(level=1)],
        "crc32c": [Crc32cCodec()],  # verified and decoded on the fast path
        "none": None,
    }[codec]


def write_store(path: Path, vol: np.ndarray, brick=BRICK, *, codec="lz4", filter="mean", complete=True,
                clipvol=True, endian="little", spacing=(1.0, 1.0, 1.0)) -> Path:
    """A minimal clipvol store (or plain OME-Zarr 0.5 image when ``clipvol=False``) written with zarr."""
    levels = pyramid_levels(vol, brick, filter)
    pyr = Pyramid.build(vol.shape, brick, spacing, filter, vol.dtype, finite_range(vol), 0.0)
    g = zarr.open_group(str(path), mode="w", zarr_format=3)
    attrs = {"ome": ome_metadata(pyr)}
    if clipvol:
        attrs["clipvol"] = clipvol_metadata(pyr, unit="micrometer", codec=codec, complete=complete)
    g.attrs.update(attrs)
    for L, d in enumerate(levels):
        a = g.create_array(str(L), shape=d.shape, chunks=brick, dtype=d.dtype, compressors=_compressors(codec, d.dtype),
                           serializer=BytesCodec(endian=endian), fill_value=0, dimension_names=("z", "y", "x"),
                           config={"write_empty_chunks": False})
        a[...] = d
        if clipvol:
            grid = pyr.grid(L)
            mn, mx = np.zeros(grid), np.zeros(grid)
            for idx in np.ndindex(*grid):
                s, e = pyr.brick_voxel_box(L, idx)
                b = d[tuple(slice(i, j) for i, j in zip(s, e))].astype(np.float64)
                b = b[np.isfinite(b)]
                mn[idx], mx[idx] = (b.min(), b.max()) if b.size else (np.nan, np.nan)
            sg = g.require_group(f"{STATS_GROUP}/{L}")
            sg.create_array("min", data=mn)
            sg.create_array("max", data=mx)
    return path


def write_ome04_v2(path: Path, vol: np.ndarray, brick=BRICK, nlevels=None) -> Path:
    """A plain OME-Zarr 0.4 image in zarr v2 format, 5-D (t, c, z, y, x) with singleton t and c."""
    levels = pyramid_levels(vol, brick)[:nlevels]
    g = zarr.open_group(str(path), mode="w", zarr_format=2)
    datasets = []
    for L, d in enumerate(levels):
        a = g.create_array(str(L), shape=(1, 1) + d.shape, chunks=(1, 1) + tuple(brick), dtype=d.dtype, fill_value=0,
                           compressors=__import__("numcodecs").Blosc(cname="lz4", shuffle=1))
        a[...] = d[None, None]
        f = 2.0**L
        datasets.append({"path": str(L), "coordinateTransformations": [
            {"type": "scale", "scale": [1.0, 1.0, f, f, f]},
            {"type": "translation", "translation": [0.0, 0.0] + [(f - 1) / 2] * 3}]})
    g.attrs.update({
        "multiscales": [{"version": "0.4", "axes": [{"name": "t", "type": "time"}, {"name": "c", "type": "channel"}]
                         + [{"name": n, "type": "space"} for n in "zyx"], "datasets": datasets}],
        "omero": {"channels": [{"window": {"min": 0, "max": 4000, "start": 0, "end": 4000}}]},
    })
    return path


def zarr_reference_brick(path: Path, level: int, idx, pyr: Pyramid, lead: int = 0) -> np.ndarray:
    """Independent reference: zarr-python indexing, then numpy edge padding."""
    a = zarr.open_array(str(path / str(level)), mode="r")
    s, e = pyr.brick_voxel_box(level, idx)
    block = np.asarray(a[(0,) * lead + tuple(slice(i, j) for i, j in zip(s, e))])
    return np.pad(block, [(0, b - (j - i)) for i, j, b in zip(s, e, pyr.brick_shape)], mode="edge")


# -- conformance: every bundled loader ----------------------------------------------------------

class TestZarrClipvolStore(LoaderTests):
    @pytest.fixture(scope="class")
    @classmethod
    def reference(cls):
        return make_volume("uint16")

    @pytest.fixture(scope="class")
    @classmethod
    def loader(cls, reference, tmp_path_factory):
        return ZarrLoader(write_store(tmp_path_factory.mktemp("z") / "s.zarr", reference))


class TestZarrFloatBigEndian(LoaderTests):
    @pytest.fixture(scope="class")
    @classmethod
    def reference(cls):
        return make_volume("float32")

    @pytest.fixture(scope="class")
    @classmethod
    def loader(cls, reference, tmp_path_factory):
        return ZarrLoader(write_store(tmp_path_factory.mktemp("z") / "s.zarr", reference, codec="zstd", endian="big"))


class TestZarrPlainOme05(LoaderTests):
    @pytest.fixture(scope="class")
    @classmethod
    def reference(cls):
        return make_volume("int16")

    @pytest.fixture(scope="class")
    @classmethod
    def loader(cls, reference, tmp_path_factory):
        return ZarrLoader(write_store(tmp_path_factory.mktemp("z") / "s.zarr", reference, clipvol=False))


class TestZarrOme04V2DerivedLevels(LoaderTests):
    """zarr v2, 5-D with singleton t/c, only two stored levels: the coarser ones are derived."""

    @pytest.fixture(scope="class")
    @classmethod
    def reference(cls):
        return make_volume("uint8", shape=(40, 70, 66))

    @pytest.fixture(scope="class")
    @classmethod
    def loader(cls, reference, tmp_path_factory):
        return ZarrLoader(write_ome04_v2(tmp_path_factory.mktemp("z") / "s.zarr", reference, nlevels=2))


class TestNumpy(LoaderTests):
    @pytest.fixture(scope="class")
    @classmethod
    def reference(cls):
        return make_volume("float32")

    @pytest.fixture(scope="class")
    @classmethod
    def loader(cls, reference):
        return NumpyLoader(reference, brick=BRICK, spacing=(2.0, 1.0, 1.0), cache_bytes=0)


class TestNumpyMemmapMax(LoaderTests):
    @pytest.fixture(scope="class")
    @classmethod
    def reference(cls, tmp_path_factory):
        p = tmp_path_factory.mktemp("n") / "v.npy"
        np.save(p, make_volume("uint16"))
        return np.load(p, mmap_mode="r")

    @pytest.fixture(scope="class")
    @classmethod
    def loader(cls, reference):
        return NumpyLoader(reference.filename, brick=(16, 8, 16), filter="max")


class TestProceduralFractal(LoaderTests):
    @pytest.fixture(scope="class")
    @classmethod
    def reference(cls):
        g = parse_procedural("procedural:fractal?size=45x38x50&seed=3")
        return g.region(0, (0, 0, 0), g.shape)

    @pytest.fixture(scope="class")
    @classmethod
    def loader(cls):
        return ProceduralLoader("procedural:fractal?size=45x38x50&seed=3", brick=16)


class TestProceduralSparse(LoaderTests):
    @pytest.fixture(scope="class")
    @classmethod
    def reference(cls):
        g = parse_procedural("procedural:sparse?size=70&seed=2&count=12")
        return g.region(0, (0, 0, 0), g.shape)

    @pytest.fixture(scope="class")
    @classmethod
    def loader(cls):
        return ProceduralLoader("procedural:sparse?size=70&seed=2&count=12", brick=16)


class TestProceduralHuge(LoaderTests):
    """2**20 voxels per axis: only a few bricks per level are ever evaluated."""

    bricks_per_level = 9

    @pytest.fixture(scope="class")
    @classmethod
    def loader(cls):
        return ProceduralLoader(f"procedural:fractal?size={2**20}&seed=1", brick=32)


class TestBrickWriterStore(LoaderTests):
    """A store written by ``clipvol brick`` itself (skipped until that module is available)."""

    @pytest.fixture(scope="class")
    @classmethod
    def reference(cls):
        return make_volume("uint16", shape=(30, 41, 36))

    @pytest.fixture(scope="class")
    @classmethod
    def loader(cls, reference, tmp_path_factory):
        brick = pytest.importorskip("clipvol.bricking.pipeline")
        out = tmp_path_factory.mktemp("b") / "s.zarr"
        brick.brick_volume(reference, out, brick=16, progress=False, workers=1)
        return ZarrLoader(out)


# -- the zarr loader ----------------------------------------------------------------------------

@pytest.mark.parametrize("codec", ["lz4", "blosc-zstd", "zstd", *(pytest.param(c, marks=pytest.mark.slow) for c in ("gzip", "none")),
                                   "crc32c"])
@pytest.mark.parametrize("dtype", ["uint8", "float32"])
def test_fast_path_equals_zarr_indexing(tmp_path, codec, dtype):
    vol = make_volume(dtype, shape=(20, 34, 29))
    if dtype == "uint8" and codec == "lz4":
        codec = "bitshuffle"  # 8-bit data with bit shuffle, as clipvol brick writes it
    path = write_store(tmp_path / "s.zarr", vol, codec=codec)
    loader = ZarrLoader(path)
    assert loader._arrays[0].fast and loader._arrays[0].checksum == (codec == "crc32c")
    pyr = loader.pyramid
    n = 0
    for L in range(pyr.num_levels):
        for idx in np.ndindex(*pyr.grid(L)):
            got = loader.read_brick(L, idx)
            ref = zarr_reference_brick(path, L, idx, pyr)
            np.testing.assert_array_equal(got, ref, err_msg=f"{codec} {L} {idx}")
            slot = np.full(pyr.brick_shape, 77, dtype=pyr.dtype)  # a reused slot holds old data
            loader.read_brick_into(L, idx, slot)
            np.testing.assert_array_equal(slot, ref, err_msg=f"read_brick_into {codec} {L} {idx}")
            n += 1
    assert n > 10


def test_big_endian_gives_native_values(tmp_path):
    vol = make_volume("float32")
    path = write_store(tmp_path / "s.zarr", vol, codec="none", endian="big")
    raw = (path / "0" / "c" / "1" / "1" / "1").read_bytes()
    assert np.frombuffer(raw, ">f4")[0] == vol[16, 16, 16]  # really stored big-endian
    loader = ZarrLoader(path)
    b = loader.read_brick(0, (1, 1, 1))
    assert b.dtype == np.dtype("float32") and b.dtype.isnative
    np.testing.assert_array_equal(b, vol[16:32, 16:32, 16:32])


def test_missing_chunk_is_fill_only_where_statistics_say_empty(tmp_path):
    vol = make_volume("uint16")
    path = write_store(tmp_path / "s.zarr", vol)
    assert not (path / "0" / "c" / "0" / "0" / "0").exists()  # the empty corner was never written
    chunk = path / "0" / "c" / "1" / "2" / "1"
    chunk.unlink()
    loader = ZarrLoader(path)
    np.testing.assert_array_equal(loader.read_brick(0, (0, 0, 0)), np.zeros(BRICK, np.uint16))
    slot = np.full(BRICK, 9, np.uint16)
    loader.read_brick_into(0, (0, 0, 0), slot)
    np.testing.assert_array_equal(slot, np.zeros(BRICK, np.uint16))
    # a deleted chunk whose statistics say it holds data is a failure, never an empty brick
    for read in (lambda: loader.read_brick(0, (1, 2, 1)), lambda: loader.read_brick_into(0, (1, 2, 1), slot)):
        with pytest.raises(BrickIntegrityError, match=r"\(level 0, 1, 2, 1\).*missing"):
            read()


@pytest.mark.parametrize("codec", ["lz4", "zstd", "none"])
@pytest.mark.parametrize("damage", ["truncate", "garbage"])
def test_corrupt_chunk_names_level_and_brick(tmp_path, codec, damage):
    path = write_store(tmp_path / "s.zarr", make_volume("uint16"), codec=codec)
    chunk = path / "1" / "c" / "0" / "1" / "1"
    data = chunk.read_bytes()
    chunk.write_bytes(data[: len(data) // 2] if damage == "truncate" else b"\x07" * 40)
    loader = ZarrLoader(path)
    with pytest.raises(InputFormatError) as e:
        loader.read_brick(1, (0, 1, 1))
    msg = str(e.value)
    assert "level 1" in msg and "(level 1, 0, 1, 1)" in msg and str(path) in msg
    loader.read_brick(1, (0, 0, 1))  # other bricks still read


def test_incomplete_store_refused(tmp_path):
    path = write_store(tmp_path / "s.zarr", make_volume("uint16"), complete=False)
    with pytest.raises(StoreIncompleteError, match="clipvol brick"):
        ZarrLoader(path)


def _edit_json(p: Path, fn) -> None:
    doc = json.loads(p.read_text())
    fn(doc)
    p.write_text(json.dumps(doc))


def test_object_dtype_refused_nothing_unpickled(tmp_path):
    marker = tmp_path / "UNPICKLED"

    class Boom:
        def __reduce__(self):
            return (open, (str(marker), "w"))

    root = tmp_path / "evil.zarr"
    (root / "0").mkdir(parents=True)
    (root / ".zgroup").write_text(json.dumps({"zarr_format": 2}))
    (root / ".zattrs").write_text(json.dumps({"multiscales": [{"version": "0.4", "datasets": [{"path": "0", "coordinateTransformations": [{"type": "scale", "scale": [1, 1, 1]}]}]}]}))
    (root / "0" / ".zarray").write_text(json.dumps({
        "zarr_format": 2, "shape": [4, 4, 4], "chunks": [4, 4, 4], "dtype": "|O", "compressor": None,
        "filters": [{"id": "pickle"}], "fill_value": None, "order": "C"}))
    (root / "0" / "0.0.0").write_bytes(pickle.dumps(np.array([Boom()] * 64, dtype=object)))
    with pytest.raises(InputFormatError, match="dtype"):
        open_store(root)
    # structured dtype, same refusal
    _edit_json(root / "0" / ".zarray", lambda d: d.update(dtype=[["a", "<i4"], ["b", "<f4"]], filters=None))
    with pytest.raises(InputFormatError, match="dtype"):
        ZarrLoader(root)
    assert not marker.exists()


def test_string_dtype_in_clipvol_store_refused(tmp_path):
    path = write_store(tmp_path / "s.zarr", make_volume("uint16"))
    _edit_json(path / "2" / "zarr.json", lambda d: d.update(data_type="string"))
    with pytest.raises(InputFormatError, match="data_type"):
        ZarrLoader(path)
    _edit_json(path / "zarr.json", lambda d: d["attributes"]["clipvol"].update(dtype="object"))
    with pytest.raises(StoreFormatError, match="dtype"):
        ZarrLoader(path)


def test_absurd_metadata_refused(tmp_path):
    path = write_store(tmp_path / "s.zarr", make_volume("uint16"), clipvol=False)
    _edit_json(path / "0" / "zarr.json", lambda d: d.update(shape=[2**40] * 3))
    with pytest.raises(InputFormatError, match="shape"):
        ZarrLoader(path)
    _edit_json(path / "0" / "zarr.json", lambda d: d.update(shape=[64] * 3) or d["chunk_grid"]["configuration"].update(chunk_shape=[4096] * 3))
    with pytest.raises(InputFormatError, match="chunk shape"):
        ZarrLoader(path)
    path2 = write_store(tmp_path / "t.zarr", make_volume("uint16"))
    _edit_json(path2 / "zarr.json", lambda d: d["attributes"]["clipvol"].update(levels=[[2**41] * 3]))
    with pytest.raises(StoreFormatError):
        ZarrLoader(path2)
    _edit_json(path2 / "zarr.json", lambda d: d["attributes"]["clipvol"].update(levels=[[37, 50, 45], [19, 25, 23]]))
    with pytest.raises(StoreFormatError, match="levels"):
        ZarrLoader(path2)


def _tczyx_store(root, chunks):
    """A 5-D OME-Zarr (t=3, c=2) written with zarr itself, every (t, c) volume different."""
    g = zarr.open_group(str(root), mode="w")
    rng = np.random.default_rng(5)
    data = rng.integers(0, 60000, size=(3, 2, 12, 16, 10), dtype=np.uint16)
    g.create_array("0", shape=data.shape, chunks=chunks, dtype="uint16")[...] = data
    axes = [{"name": "t", "type": "time"}, {"name": "c", "type": "channel"}] + \
        [{"name": n, "type": "space"} for n in ("z", "y", "x")]
    g.attrs.update({"ome": {"version": "0.5", "multiscales": [{"axes": axes, "datasets": [
        {"path": "0", "coordinateTransformations": [{"type": "scale", "scale": [1, 1, 2, 1, 1]}]}]}],
        "omero": {"channels": [{"window": {"min": 0, "max": 1000}}, {"window": {"min": 10, "max": 50000}}]}}})
    return data


@pytest.mark.parametrize("chunks", [(1, 1, 8, 8, 8), (2, 2, 8, 8, 8)])
def test_ome_time_and_channel_axes_select_one_volume(tmp_path, chunks):
    root = tmp_path / "tc.zarr"
    data = _tczyx_store(root, chunks)
    for t, c in [(0, 0), (2, 1), (1, 0)]:
        loader = ZarrLoader(root, t=t, c=c)
        assert loader.axes == ("t", "c") and loader.lead_shape == (3, 2)
        assert loader.pyramid.levels[0].shape == (12, 16, 10) and loader.pyramid.spacing == (2.0, 1.0, 1.0)
        assert loader.pyramid.value_range == ((0.0, 1000.0) if c == 0 else (10.0, 50000.0))  # the channel's window
        vol = data[t, c]
        for idx in [(0, 0, 0), (1, 1, 1), (0, 1, 0)]:
            b = loader.read_brick(0, idx)
            sl = tuple(slice(8 * i, min(8 * i + 8, n)) for i, n in zip(idx, vol.shape))
            np.testing.assert_array_equal(b[tuple(slice(0, s.stop - s.start) for s in sl)], vol[sl])
    assert np.array_equal(ZarrLoader(root).read_brick(0, (0, 0, 0))[:8, :8, :8], data[0, 0, :8, :8, :8])


def test_ome_time_and_channel_out_of_range_are_named(tmp_path):
    root = tmp_path / "tc.zarr"
    _tczyx_store(root, (1, 1, 8, 8, 8))
    with pytest.raises(ParameterError, match="t: expected 0..2"):
        ZarrLoader(root, t=3)
    with pytest.raises(ParameterError, match="c: expected 0..1"):
        ZarrLoader(root, c=-1)
    one = tmp_path / "c.zarr"
    g = zarr.open_group(str(one), mode="w")
    g.create_array("0", shape=(8, 8, 8), chunks=(8, 8, 8), dtype="uint8")
    g.attrs.update({"ome": {"version": "0.5", "multiscales": [{"datasets": [{"path": "0", "coordinateTransformations": [{"type": "scale", "scale": [1, 1, 1]}]}]}]}})
    with pytest.raises(ParameterError, match="no 't' axis"):
        ZarrLoader(one, t=1)


def test_ome_derived_levels_equal_global_downsample(tmp_path):
    vol = make_volume("uint8", shape=(40, 70, 66))
    loader = ZarrLoader(write_ome04_v2(tmp_path / "s.zarr", vol, nlevels=1))
    assert loader.stored_levels == 1 and loader.pyramid.num_levels == 4
    assert loader.pyramid.value_range == (0.0, 4000.0)  # omero.window
    levels = pyramid_levels(vol, BRICK)
    pyr = loader.pyramid
    for L in range(1, pyr.num_levels):
        for idx in np.ndindex(*pyr.grid(L)):
            s, e = pyr.brick_voxel_box(L, idx)
            want = np.pad(levels[L][tuple(slice(i, j) for i, j in zip(s, e))], [(0, b - (j - i)) for i, j, b in zip(s, e, BRICK)], mode="edge")
            np.testing.assert_array_equal(loader.read_brick(L, idx), want)


def test_nonconforming_ome_level_is_recomputed(tmp_path):
    vol = make_volume("float32", shape=(30, 33, 35))
    path = write_store(tmp_path / "s.zarr", vol, clipvol=False)
    # level 1 rewritten with another chunk shape: it and the levels above it are computed instead
    shutil.rmtree(path / "1")
    g = zarr.open_group(str(path), mode="r+")
    g.create_array("1", data=np.zeros((15, 17, 18), np.float32), chunks=(8, 8, 8))
    loader = ZarrLoader(path)
    assert loader.stored_levels == 1
    lv = pyramid_levels(vol, BRICK)
    np.testing.assert_allclose(loader.read_brick(1, (0, 1, 1))[:15, :1, :2], lv[1][:15, 16:17, 16:18], rtol=1e-6)
    # floats without omero: finite range of the coarsest *stored* level (here level 0, few bricks:
    # all read), never of a derived level (that would read the whole volume)
    lo, hi = loader.pyramid.value_range
    assert (lo, hi) == finite_range(lv[0])


def test_brick_statistics_and_ranges(tmp_path):
    vol = make_volume("uint16")
    loader = ZarrLoader(write_store(tmp_path / "s.zarr", vol))
    st = loader.brick_statistics(0)
    assert st["min"].shape == loader.pyramid.grid(0)
    r = loader.brick_ranges(0, np.array([[2, 3, 2], [0, 0, 0]]))
    b = vol[32:, 48:, 32:]
    assert r[0, 0] == b.min() and r[0, 1] == b.max() and r[1, 0] == 0 and r[1, 1] == 0
    assert ZarrLoader(write_store(tmp_path / "o.zarr", vol, clipvol=False)).brick_ranges(0, np.zeros((1, 3), int)) is None


# -- the numpy loader ---------------------------------------------------------------------------

@pytest.mark.parametrize("filter", ["mean", "max", "subsample"])
@pytest.mark.parametrize("cache_bytes", [0, 2**30])
@pytest.mark.parametrize("dtype", ["uint16", "float64"])
def test_numpy_levels_equal_recursive_downsample(filter, cache_bytes, dtype):
    vol = make_volume(dtype, shape=(45, 23, 34))
    loader = NumpyLoader(vol, brick=(8, 4, 8), filter=filter, cache_bytes=cache_bytes)
    levels = pyramid_levels(vol, (8, 4, 8), filter)
    pyr = loader.pyramid
    assert pyr.num_levels == len(levels) >= 4
    for L in range(pyr.num_levels):
        for idx in np.ndindex(*pyr.grid(L)):
            s, e = pyr.brick_voxel_box(L, idx)
            want = np.pad(levels[L][tuple(slice(i, j) for i, j in zip(s, e))], [(0, b - (j - i)) for i, j, b in zip(s, e, pyr.brick_shape)], mode="edge")
            # integers exact; floats to rounding (numpy's summation order depends on the block's shape)
            np.testing.assert_allclose(loader.read_brick(L, idx), want, rtol=1e-12 if dtype == "float64" else 0, equal_nan=True)


def test_numpy_value_range_and_errors(tmp_path):
    vol = make_volume("float32")
    vol[3, 3, 3] = np.inf
    fin = vol[np.isfinite(vol)]
    assert NumpyLoader(vol, brick=16).pyramid.value_range == (float(fin.min()), float(fin.max()))
    assert NumpyLoader(vol, brick=16, value_range=(0, 1)).pyramid.value_range == (0.0, 1.0)
    with pytest.raises(ClipvolError, match="3 dimensions"):
        NumpyLoader(np.zeros((4, 4)))
    with pytest.raises(ClipvolError, match="dtype"):
        NumpyLoader(np.zeros((4, 4, 4), complex))
    with pytest.raises(InputNotFoundError):
        NumpyLoader(tmp_path / "nope.npy")
    be = make_volume("float32").astype(">f4")
    b = NumpyLoader(be, brick=16).read_brick(0, (0, 1, 1))
    assert b.dtype.isnative and np.array_equal(b, be[:16, 16:32, 16:32])


# -- open_store -----------------------------------------------------------------------------------

def test_open_store_dispatch(tmp_path):
    vol = make_volume("uint16")
    store = write_store(tmp_path / "s.zarr", vol)
    npy = tmp_path / "v.npy"
    np.save(npy, vol)
    assert isinstance(open_store(store), ZarrLoader)
    assert isinstance(open_store(str(store / "zarr.json")), ZarrLoader)
    assert isinstance(open_store(str(npy), brick=16), NumpyLoader)
    assert isinstance(open_store("procedural:sparse?size=40", brick=16), ProceduralLoader)
    # the bundled entry points (pyproject's clipvol.loaders group) take scheme-prefixed URLs
    via_ep = open_store(f"numpy:{npy}", brick=16)
    assert isinstance(via_ep, NumpyLoader)
    np.testing.assert_array_equal(via_ep.read_brick(0, (1, 1, 1)), vol[16:32, 16:32, 16:32])
    assert isinstance(open_store(f"zarr:{store}"), ZarrLoader)
    with pytest.raises(InputNotFoundError, match="nope"):
        open_store(tmp_path / "nope.zarr")
    (tmp_path / "x.tif").write_bytes(b"II*\x00")
    with pytest.raises(InputFormatError, match="unknown format") as e:
        open_store(tmp_path / "x.tif")
    for named in ("Zarr", ".npy", "NIfTI", ".nii.gz", "DICOM", "HDF5", "MRC", "OME-TIFF", "clipvol brick"):
        assert named in str(e.value), named  # what the commands read instead, not only zarr and .npy
    (tmp_path / "empty").mkdir()
    with pytest.raises(InputFormatError, match="zarr"):
        open_store(tmp_path / "empty")
    with pytest.raises(InputFormatError, match="no loader for the scheme"):
        open_store("s3x:bucket/thing")


def test_open_store_third_party_plugin(monkeypatch):
    from importlib.metadata import EntryPoint

    import clipvol.paging.open as op

    ep = EntryPoint(name="fake", value="clipvol.loaders.procedural:ProceduralLoader", group="clipvol.loaders")
    monkeypatch.setattr(op, "entry_points", lambda group: [ep] if group == "clipvol.loaders" else [])
    calls = []

    class Spy:
        def __init__(self, url, **kw):
            calls.append((url, kw))

    monkeypatch.setattr(EntryPoint, "load", lambda self: Spy)
    op.open_store("fake:anything?x=1", brick=8)
    assert calls == [("fake:anything?x=1", {"brick": 8})]


def test_empty_bricks_are_filled_without_a_read_but_nan_bricks_are_read(tmp_path):
    """[fill, fill] bounds mean empty (never read); a brick of fill value plus NaN is not empty."""
    from clipvol.bricking.pipeline import brick_volume
    from clipvol.paging.cliptexture import ClipTexture

    vol = np.zeros((32, 32, 32), dtype=np.float32)
    vol[:16, :16, 16:] = 0.5                     # one brick with data
    vol[16:, 16:, 16:][3, 4, 5] = np.nan        # one brick of zeros plus one NaN
    out = tmp_path / "s.zarr"
    brick_volume(vol, out, brick=16, progress=False, workers=1)
    inner = ZarrLoader(out)
    ranges = inner.brick_ranges(0, np.array([[0, 0, 1], [1, 1, 1], [0, 0, 0]]))
    assert np.isnan(ranges[1]).all() and ranges[2].tolist() == [0.0, 0.0]

    reads: list = []

    class Counting:
        pyramid = inner.pyramid
        brick_ranges = staticmethod(inner.brick_ranges)

        def read_brick(self, level, index):
            reads.append((level, tuple(index)))
            return inner.read_brick(level, index)

    with ClipTexture(Counting(), "64MB", threads=1) as tex:
        assert tex.wait_until_idle(10)
        assert set(reads) == {(0, (0, 0, 1)), (0, (1, 1, 1)), (1, (0, 0, 0))}
        assert tex.stats.empty_skipped == 6
        for L, idx in tex.resident_bricks():
            got = tex.get_brick(L, idx)
            np.testing.assert_array_equal(got, inner.read_brick(L, idx))
