"""Shape culling and containment against point sampling (numpy reference)."""

from __future__ import annotations

import numpy as np
import pytest

from clipvol.errors import ParameterError
from clipvol.scene.geometry import Shape

SHAPES = [
    Shape(),
    Shape(box=((0, 0, 0), (4, 3, 2))),
    Shape(planes=[(1, 1, 0, -2), (0, 0, -1, 1.5)]),
    Shape(box=((-1, -1, -1), (3, 3, 3)), planes=[(1, -2, 0.5, 0.25)] * 6),
]


def _sample(lo, hi, rng, k=400):
    s = rng.uniform(size=(1, k, 3))
    corners = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], dtype=float)
    s = np.concatenate([s, np.broadcast_to(corners, (1, 8, 3))], axis=1)
    return lo[:, None] + s * (hi - lo)[:, None]


@pytest.mark.parametrize("si", range(len(SHAPES)))
def test_boxes_outside_is_conservative_and_culls(si):
    shape = SHAPES[si]
    rng = np.random.default_rng(si)
    lo = rng.uniform(-6, 6, size=(500, 3))
    hi = lo + rng.uniform(0.05, 2, size=(500, 3))
    out = shape.boxes_outside(lo, hi)
    seen = shape.contains(_sample(lo, hi, rng)).any(axis=1)
    assert not np.any(out & seen)
    if not shape.is_everything:
        assert out.sum() > 50
    if si == 1:  # box only: exact interval overlap test
        blo, bhi = np.array(shape.box[0]), np.array(shape.box[1])
        ref = np.any((hi < blo) | (lo > bhi), axis=1)
        np.testing.assert_array_equal(out, ref)


def test_contains_matches_inequalities():
    rng = np.random.default_rng(5)
    pts = rng.uniform(-4, 4, size=(7, 11, 3))
    shape = SHAPES[3]
    ref = np.all((pts >= -1) & (pts <= 3), axis=-1) & (pts @ np.array([1, -2, 0.5]) + 0.25 >= 0)
    np.testing.assert_array_equal(shape.contains(pts), ref)
    assert shape.contains(pts).shape == (7, 11)


def test_arrays_for_shaders_pad_with_always_true_planes():
    box, planes, n = SHAPES[2].box_and_planes_arrays()
    assert n == 2 and planes.shape == (6, 4) and box.shape == (2, 3)
    pts = np.random.default_rng(0).uniform(-100, 100, size=(1000, 3))
    inside = np.all(pts @ planes[:, :3].T + planes[:, 3] >= 0, axis=1) & np.all((pts >= box[0]) & (pts <= box[1]), axis=1)
    np.testing.assert_array_equal(inside, SHAPES[2].contains(pts))
    assert np.all(np.isfinite(box.astype(np.float32)))


@pytest.mark.parametrize(
    "kw",
    [
        dict(box=((0, 0, 0), (1, -1, 1))),
        dict(box=((0, 0), (1, 1))),
        dict(box=((0, 0, np.inf), (1, 1, 1))),
        dict(planes=[(0, 0, 0, 1)]),
        dict(planes=[(1, 0, 0, 0)] * 7),
        dict(planes=[(1, 0, np.nan, 0)]),
    ],
)
def test_invalid_shapes_raise(kw):
    with pytest.raises(ParameterError):
        Shape(**kw)
