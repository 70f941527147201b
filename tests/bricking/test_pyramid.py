"""Pyramid geometry and filters against independent references (Python ints, plain numpy loops)."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from clipvol.errors import ParameterError
from clipvol.bricking.pyramid import Pyramid, downsample, level_shapes, level_transform, pad_to_brick, validate_dtype

INT_DTYPES = ["int8", "uint8", "int16", "uint16", "int32", "uint32", "int64", "uint64"]
FLOAT_DTYPES = ["float16", "float32", "float64"]
SHAPES = [(1, 1, 1), (1, 5, 7), (3, 1, 2), (7, 11, 13), (2, 4, 6), (5, 3, 1)]


def _blocks(shape):
    """For every output voxel, the list of input indices (per axis) of its 2x2x2 block, edge-clipped."""
    out = tuple((s + 1) // 2 for s in shape)
    for o in itertools.product(*(range(n) for n in out)):
        axes = [[2 * i, min(2 * i + 1, s - 1)] for i, s in zip(o, shape)]  # edge replication
        yield o, list(itertools.product(*axes))


def ref_downsample(a: np.ndarray, filter: str) -> np.ndarray:
    """Independent, slow reference: Python ints for integer means, float64 + NaN handling for floats."""
    out = np.empty(tuple((s + 1) // 2 for s in a.shape), dtype=a.dtype)
    for o, idx in _blocks(a.shape):
        vals = [a[i] for i in idx]
        if filter == "subsample":
            out[o] = a[tuple(2 * v for v in o)]
        elif filter == "max":
            fin = [v for v in vals if not (a.dtype.kind == "f" and np.isnan(v))]
            out[o] = max(fin) if fin else np.nan
        elif a.dtype.kind in "iu":
            s = sum(int(v) for v in vals)
            out[o] = (s + 4) // 8  # floor((S+4)/8) with Python's exact integers
        else:
            fin = [float(v) for v in vals if not np.isnan(v)]
            out[o] = sum(fin) / len(fin) if fin else np.nan
    return out


@pytest.mark.parametrize("dtype", INT_DTYPES)
@pytest.mark.parametrize("filter", ["mean", "max", "subsample"])
def test_downsample_integers_match_reference(dtype, filter, rng):
    info = np.iinfo(dtype)
    for shape in SHAPES:
        a = rng.integers(info.min, info.max, size=shape, dtype=dtype, endpoint=True)
        got = downsample(a, filter)
        assert got.dtype == a.dtype
        np.testing.assert_array_equal(got, ref_downsample(a, filter))


@pytest.mark.parametrize("dtype", ["uint64", "int64"])
def test_mean_64bit_extremes_exact(dtype):
    info = np.iinfo(dtype)
    a = np.full((2, 2, 3), info.max, dtype=dtype)
    a[0, 0, 0] = info.max - 7
    np.testing.assert_array_equal(downsample(a, "mean"), ref_downsample(a, "mean"))
    b = np.full((3, 2, 2), info.min, dtype=dtype)
    np.testing.assert_array_equal(downsample(b, "mean"), ref_downsample(b, "mean"))


@pytest.mark.parametrize("dtype", FLOAT_DTYPES)
@pytest.mark.parametrize("filter", ["mean", "max", "subsample"])
def test_downsample_floats_with_nan(dtype, filter, rng):
    for shape in SHAPES:
        a = rng.normal(size=shape).astype(dtype)
        a[rng.random(shape) < 0.2] = np.nan
        got = downsample(a, filter)
        ref = ref_downsample(a, filter)
        assert got.dtype == a.dtype
        np.testing.assert_allclose(got.astype(np.float64), ref.astype(np.float64), rtol=1e-6 if dtype != "float16" else 1e-3, equal_nan=True)


def test_all_nan_block_stays_nan():
    a = np.full((2, 2, 2), np.nan, dtype=np.float32)
    assert np.isnan(downsample(a, "mean")).all()
    assert np.isnan(downsample(a, "max")).all()


def test_slabwise_downsample_equals_whole(rng):
    a = rng.integers(0, 1000, size=(13, 9, 10)).astype(np.uint16)
    whole = downsample(a, "mean")
    parts = np.concatenate([downsample(a[z : z + 4], "mean") for z in range(0, 13, 4)])
    np.testing.assert_array_equal(parts, whole)


@pytest.mark.parametrize("shape,brick", [((100, 37, 1), (16, 16, 16)), ((1, 1, 1), (8, 8, 8)), ((257, 64, 65), (64, 64, 64))])
def test_level_shapes_halve_until_one_brick(shape, brick):
    shapes = level_shapes(shape, brick)
    assert shapes[0] == shape
    for a, b in zip(shapes, shapes[1:]):
        assert b == tuple(-(-s // 2) for s in a)
    assert all(s <= b for s, b in zip(shapes[-1], brick))
    assert len(shapes) == 1 or any(s > b for s, b in zip(shapes[-2], brick))


@pytest.mark.parametrize("filter,offset", [("mean", 1), ("max", 1), ("subsample", 0)])
def test_level_transform(filter, offset):
    sc, tr = level_transform(3, (2.0, 1.0, 0.5), filter)
    assert sc == (16.0, 8.0, 4.0)
    assert tr == tuple(offset * 3.5 * s for s in (2.0, 1.0, 0.5))


def test_node_boxes_tile_parent_and_volume():
    pyr = Pyramid.build((37, 20, 70), (8, 8, 8), spacing=(2.0, 1.0, 0.5))
    vlo, vhi = pyr.volume_box()
    np.testing.assert_allclose(vlo, [-0.25, -0.5, -1.0])
    np.testing.assert_allclose(vhi, [70 * 0.5 - 0.25, 20 - 0.5, 37 * 2 - 1.0])
    for L in range(1, pyr.num_levels):
        g = pyr.grid(L)
        for idx in itertools.product(*(range(n) for n in g)):
            lo, hi = pyr.node_box(L, idx)
            kids = list(pyr.children(L, idx))
            vol = sum(np.prod(np.subtract(*reversed(pyr.node_box(L - 1, c)))) for c in kids)
            np.testing.assert_allclose(vol, np.prod(hi - lo))
            for c in kids:
                clo, chi = pyr.node_box(L - 1, c)
                assert np.all(clo >= lo - 1e-12) and np.all(chi <= hi + 1e-12)
    top_lo, top_hi = pyr.node_box(pyr.num_levels - 1, (0, 0, 0))
    np.testing.assert_allclose(top_lo, vlo)
    np.testing.assert_allclose(top_hi, vhi)


def test_pad_to_brick_edge_replicates():
    a = np.arange(6, dtype=np.int16).reshape(1, 2, 3)
    p = pad_to_brick(a, (2, 3, 4))
    assert p.shape == (2, 3, 4)
    np.testing.assert_array_equal(p[1], p[0])
    np.testing.assert_array_equal(p[:, 2], p[:, 1])
    np.testing.assert_array_equal(p[..., 3], p[..., 2])


@pytest.mark.parametrize("bad", ["complex64", "bool", "object", "U4", [("a", "i4")]])
def test_unsupported_dtypes_refused(bad):
    with pytest.raises(ParameterError, match="dtype"):
        validate_dtype(bad)
