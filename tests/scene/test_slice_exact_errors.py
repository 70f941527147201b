"""Where a slice's coarser data looks the same (clipvol.scene.slice_exact) and how the cover uses it.

References outside the code under test: each level's voxels read with zarr-python, every voxel
paired with the parent voxel above it, CIE L* of a grey from its formula (a grey has u* = v* = 0,
so Delta E between greys is the difference of their L*), the weighted quantile from
``np.percentile(..., method="inverted_cdf")``; for the cover, the pixel points of the plane and the
brute-force reach of tests/slice_reference.py.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from clipvol.bricking.pyramid import Pyramid
from clipvol.scene.params import RenderParams
from clipvol.scene.plane import Plane, default_size
from clipvol.scene.slice_cover import slice_cover
from clipvol.scene.slice_exact import (QUANTILE, accumulated_errors, brick_differences, code_distances, bin_colour_boxes,
                                       grey_window_colours, stand_ins)

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from slice_reference import cover_levels, finest_in_reach, off_faces  # noqa: E402


def _lstar(values, center, width):
    """CIE L* of the 8-bit grey a window gives ``values`` (sRGB decoding, Y of a grey = its linear value)."""
    g = np.rint(np.clip((np.asarray(values, dtype=np.float64) - (center - width / 2)) / width, 0, 1) * 255) / 255
    y = np.where(g <= 0.04045, g / 12.92, ((g + 0.055) / 1.055) ** 2.4)
    return np.where(y > (6 / 29) ** 3, 116 * np.cbrt(y) - 16, (29 / 3) ** 3 * y)


def _store(tmp_path, vol, brick=8):
    import zarr

    from clipvol.bricking.pipeline import brick_volume
    from clipvol.bricking.summary import open_summary

    path = tmp_path / "s.zarr"
    brick_volume(vol, path, brick=brick, progress=False)
    tables = open_summary(path)
    levels = [np.asarray(zarr.open_array(str(path / str(L)), mode="r")[...]) for L in range(tables.pyramid.num_levels)]
    return tables, levels


def _reference_differences(levels, L, brick, center, width, q=100 * QUANTILE):
    """Per brick of level ``L`` (grid-shaped) D: the inverted-CDF percentile of |L*(voxel) - L*(the
    parent voxel above it)| over the brick's voxels."""
    child, parent = levels[L], levels[L + 1]
    up = _lstar(parent, center, width)[np.ix_(*(np.arange(n) // 2 for n in child.shape))]
    d = np.abs(_lstar(child, center, width) - up)
    out = np.zeros(tuple(-(-n // brick) for n in child.shape))
    for c in np.ndindex(*out.shape):
        box = tuple(slice(i * brick, (i + 1) * brick) for i in c)
        out[c] = np.percentile(d[box].reshape(-1), q, method="inverted_cdf")
    return out


def _reference_errors(levels, brick, center, width, q=100 * QUANTILE):
    """Per level (grid-shaped) E: 0 at level 0, E(parent) the largest E(child) + D(child)."""
    E = [np.zeros(tuple(-(-n // brick) for n in levels[0].shape))]
    for L in range(1, len(levels)):
        D = _reference_differences(levels, L - 1, brick, center, width, q)
        e = np.zeros(tuple(-(-n // brick) for n in levels[L].shape))
        for c in np.ndindex(*D.shape):
            p = tuple(i // 2 for i in c)
            e[p] = max(e[p], E[L - 1][c] + D[c])
        E.append(e)
    return E


def _smooth_and_lines(shape=(24, 40, 56)):
    """uint8: a gentle gradient with grain in x < half, thin bright lines (1/16 of the voxels) beyond."""
    z, y, x = np.ogrid[: shape[0], : shape[1], : shape[2]]
    rng = np.random.default_rng(7)
    vol = (90 + 20 * x / shape[2] + rng.integers(0, 2, size=shape)).astype(np.uint8)
    half = shape[2] // 2
    lines = (z % 4 == 0) & (y % 4 == 0) & (x >= half)
    return np.where(lines, 240, vol).astype(np.uint8)


@pytest.mark.parametrize("quantile", [QUANTILE, 0.99])
@pytest.mark.parametrize("window", [(165.0, 150.0), (100.0, 12.0)])
def test_accumulated_errors_match_the_voxels(tmp_path, window, quantile):
    """An 8-bit store's codes are its values: E is the voxels' own quantiles (the default: their
    largest), summed up the levels."""
    vol = _smooth_and_lines()
    tables, levels = _store(tmp_path, vol)
    got = accumulated_errors(tables, grey_window_colours(*window), quantile=quantile)
    want = _reference_errors(levels, 8, *window, q=100 * quantile)
    assert len(got) == len(want) == tables.pyramid.num_levels
    for g, w in zip(got, want):
        np.testing.assert_allclose(g, w, atol=1e-9)
    assert want[1].max() > 6 and want[1].min() < 1.5  # the lines differ, the gradient does not


def test_a_wide_code_bin_under_a_narrow_window_is_not_hidden(tmp_path):
    """A float store's code is a bin of 1/256 of its range; under a window 1/50 of the range one bin
    spans several grey levels. D bounds the voxels' own quantile however the values sit in their bins
    (a bound from the bins' centres alone would not)."""
    rng = np.random.default_rng(3)
    # values spread over one code bin [128/256, 129/256): every pair has the same codes
    vol = (0.5 + rng.uniform(0.01, 0.99, (16, 16, 32)) / 256).astype(np.float32)
    vol[0, 0, 0], vol[-1, -1, -1] = 0.0, 1.0  # the value range, so the bins are 1/256 wide
    tables, levels = _store(tmp_path, vol)
    window = (0.5 + 0.5 / 256, 0.02)
    dist = code_distances(*bin_colour_boxes(tables.quantiser, grey_window_colours(*window)))
    got = brick_differences(tables, 0, dist).reshape(tables.pyramid.grid(0))
    want = _reference_differences(levels, 0, 8, *window)
    assert np.median(want) > 6  # the window shows what the codes cannot
    assert np.all(got >= want - 1e-9), (got, want)


def test_stand_ins_are_closed_under_descent():
    pyr = Pyramid.build((40, 48, 64), (8, 8, 8), (1.0, 1.0, 1.0), "mean", "float32", (0.0, 1.0))
    rng = np.random.default_rng(1)
    E = [np.zeros(pyr.grid(0))]
    for L in range(1, pyr.num_levels):
        e = np.zeros(pyr.grid(L))
        for c in np.ndindex(*pyr.grid(L - 1)):
            p = tuple(v // 2 for v in c)
            e[p] = max(e[p], E[L - 1][c] + rng.uniform(0, 2))
        E.append(e)
    st = stand_ins(E, 2.5)
    assert not st[0].any() and st[1].any() and not st[-1].all()
    for L in range(2, pyr.num_levels):
        for c in np.ndindex(*pyr.grid(L - 1)):
            if st[L][tuple(v // 2 for v in c)]:
                assert st[L - 1][c]


SHAPE = (48, 80, 112)
BRICK = 8


@pytest.mark.parametrize("origin,normal,df", [
    ((40.3, 37.7, 20.2), (0, 0, 1), 2.0),
    ((60.2, 50.1, 30.3), (0.3, -0.5, 0.8), 1.0),
])
def test_the_cover_draws_a_parent_where_it_may_stand_for_its_children(origin, normal, df):
    """Each point of the plane is drawn once, from the coarser of the finest level in reach and the
    highest level whose brick there may stand for its children."""
    pyr = Pyramid.build(SHAPE, (BRICK,) * 3, (1.0, 1.0, 1.0), "mean", "float32", (0.0, 1.0))
    E = [np.zeros(pyr.grid(0))]
    for L in range(1, pyr.num_levels):  # children in x < 56 differ by 0.5 from their parents, others by 5
        e = np.zeros(pyr.grid(L))
        for c in np.ndindex(*pyr.grid(L - 1)):
            p = tuple(v // 2 for v in c)
            e[p] = max(e[p], E[L - 1][c] + (0.5 if (c[2] + 0.5) * BRICK * 2 ** (L - 1) < 56 else 5.0))
        E.append(e)
    st = stand_ins(E, 2.0)
    plane = Plane.through(origin, normal)
    params = RenderParams(policy="plane", focus=origin, distance_factor=df)
    q = plane.pixel_points(default_size(pyr, plane, 1.0), 1.0).reshape(-1, 3)
    q = q[np.all((q > -0.5 + 1e-6) & (q < np.array(SHAPE[::-1]) - 0.5 - 1e-6), axis=1)]
    q = q[off_faces(q, BRICK, pyr.num_levels)]
    reach = finest_in_reach(q, np.asarray(origin, dtype=np.float64), df, SHAPE, BRICK, pyr.num_levels)
    stands = np.zeros(len(q), dtype=int)
    vox = np.rint(q[:, ::-1]).astype(int)  # (z, y, x) of the voxel holding each point
    for L in range(1, pyr.num_levels):
        b = vox // (BRICK * 2**L)
        stands = np.where(st[L][b[:, 0], b[:, 1], b[:, 2]], L, stands)
    want = np.maximum(reach, stands)
    plain = slice_cover(pyr, plane, params, 1.0)
    cover = slice_cover(pyr, plane, params, 1.0, stand_in=st)
    levels = []
    for cov in (plain, cover):
        count, level = cover_levels(cov, q, SHAPE, BRICK)
        assert np.all(count == 1)
        levels.append(level)
    np.testing.assert_array_equal(levels[0], reach)
    np.testing.assert_array_equal(levels[1], want)
    assert np.any(want > reach) and np.any(want == 0)  # the rule coarsens some points, not all
    # never more bricks than the cover by distance alone
    assert sum(len(b) for b in cover.bricks()) < sum(len(b) for b in plain.bricks())
