"""Slab geometry: the bricks a slab around a plane covers, against a brute-force enumeration.

The reference visits every brick of the level, takes the signed distances of its node box's eight
corners to the plane (from the box written out from the spacing and brick shape here, not from
``Pyramid.node_box``) and keeps the bricks whose distance interval meets ``(-h, h)``.
"""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from clipvol.bricking.pyramid import Pyramid
from clipvol.errors import ParameterError
from clipvol.paging.slab import slab_bricks, slab_mask


def _boxes(shape_zyx, brick_zyx, spacing_zyx, level):
    """Every brick of ``level`` with its node box, computed from first principles (x, y, z)."""
    sp = np.array(spacing_zyx[::-1], dtype=float)
    ext = np.array(brick_zyx[::-1], dtype=float) * 2**level
    n = np.array(shape_zyx[::-1], dtype=float)
    level_shape = list(shape_zyx)
    for _ in range(level):
        level_shape = [(s + 1) // 2 for s in level_shape]
    grid = [math.ceil(s / b) for s, b in zip(level_shape, brick_zyx)]
    out = []
    for bz, by, bx in itertools.product(*[range(g) for g in grid]):
        b = np.array([bx, by, bz], dtype=float)
        lo = np.maximum(b * ext * sp - sp / 2, -sp / 2)
        hi = np.minimum((b + 1) * ext * sp - sp / 2, (n - 0.5) * sp)
        out.append(((bz, by, bx), lo, hi))
    return out


def _brute(shape, brick, spacing, level, origin, normal, h, point=None, radius=math.inf):
    n = np.asarray(normal, float) / np.linalg.norm(normal)
    keep = []
    for key, lo, hi in _boxes(shape, brick, spacing, level):
        corners = np.array(list(itertools.product(*zip(lo, hi))))
        d = (corners - np.asarray(origin, float)) @ n
        if not (d.max() > -h and d.min() < h):
            continue
        if point is not None and np.isfinite(radius):
            p = np.asarray(point, float)
            if np.linalg.norm(np.minimum(np.maximum(p, lo), hi) - p) >= radius:
                continue
        keep.append(key)
    return sorted(keep)


pyramids = st.sampled_from([
    ((37, 50, 29), (8, 8, 8), (1.0, 1.0, 1.0)),
    ((64, 40, 100), (16, 8, 16), (2.0, 0.5, 1.0)),
    ((23, 23, 23), (4, 4, 4), (1.0, 1.0, 3.0)),
])
unit = st.floats(-1.0, 1.0, allow_nan=False)


@settings(max_examples=60, deadline=None)
@given(pyr=pyramids, level=st.integers(0, 2), normal=st.tuples(unit, unit, unit),
       frac=st.tuples(*[st.floats(0.0, 1.0)] * 3), h=st.floats(0.05, 12.0), use_ball=st.booleans(),
       radius=st.floats(0.5, 60.0))
def test_slab_bricks_equal_brute_force(pyr, level, normal, frac, h, use_ball, radius):
    shape, brick, spacing = pyr
    if np.linalg.norm(normal) < 1e-3:
        normal = (0.0, 0.0, 1.0)
    p = Pyramid.build(shape, brick, spacing, dtype="float32")
    level = min(level, p.num_levels - 1)
    lo, hi = p.volume_box()
    origin = lo + np.asarray(frac) * (hi - lo)
    point = origin + 3.0 if use_ball else None
    got = slab_bricks(p, level, origin, normal, h, point=point, radius=radius if use_ball else math.inf)
    want = _brute(shape, brick, spacing, level, origin, normal, h, point, radius if use_ball else math.inf)
    assert [tuple(k) for k in got.tolist()] == want
    if len(got):
        assert slab_mask(p, level, got, origin, normal, h).all()


def test_axis_plane_through_voxel_centres_takes_one_layer_between_them_two():
    p = Pyramid.build((64, 64, 64), (16, 16, 16), dtype="uint8")
    # z = 20 is a voxel centre inside brick layer 1 (voxels 16..31): half a voxel reaches no other layer
    one = slab_bricks(p, 0, (30.0, 30.0, 20.0), (0, 0, 1), 0.5)
    assert sorted({int(k[0]) for k in one}) == [1] and len(one) == 16
    # z = 31.5 lies between voxels 31 and 32, which sit in layers 1 and 2: both are read
    two = slab_bricks(p, 0, (30.0, 30.0, 31.5), (0, 0, 1), 0.5)
    assert sorted({int(k[0]) for k in two}) == [1, 2] and len(two) == 32


def test_bad_parameters_are_named():
    p = Pyramid.build((32, 32, 32), (8, 8, 8), dtype="uint8")
    with pytest.raises(ParameterError, match="normal"):
        slab_bricks(p, 0, (0, 0, 0), (0, 0, 0), 1.0)
    with pytest.raises(ParameterError, match="half_thickness"):
        slab_bricks(p, 0, (0, 0, 0), (0, 0, 1), float("nan"))
    with pytest.raises(ParameterError, match="radius"):
        slab_bricks(p, 0, (0, 0, 0), (0, 0, 1), 1.0, point=(0, 0, 0), radius=-1.0)
