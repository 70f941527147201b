"""Database decomposition: the kd split tiles the volume with convex boxes on brick faces, the
visibility order agrees with a brute-force depth comparison, and compositing partial images
equals compositing whole rays (numpy references)."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from clipvol.bricking.pyramid import Pyramid
from clipvol.errors import ParameterError
from clipvol.scene.camera import Camera
from clipvol.scene.decompose import back_to_front, composite_max, composite_over, kd_split


def _pyr(shape=(40, 70, 100), brick=(16, 16, 16), spacing=(2.0, 1.0, 0.5)) -> Pyramid:
    return Pyramid.build(shape, brick, spacing, "mean", np.dtype(np.uint16), (0.0, 1.0), 0.0)


@pytest.mark.parametrize("n", [1, 2, 3, 4, 5, 8])
def test_kd_split_tiles_the_volume_on_brick_faces(n):
    pyr = _pyr()
    leaves = kd_split(pyr, n).leaves()
    assert sorted(leaf.group for leaf in leaves) == list(range(n))
    vlo, vhi = pyr.volume_box()
    vol = float(np.prod(vhi - vlo))
    boxes = [(np.array(leaf.lo), np.array(leaf.hi)) for leaf in leaves]
    assert sum(float(np.prod(hi - lo)) for lo, hi in boxes) == pytest.approx(vol)
    for (alo, ahi), (blo, bhi) in itertools.combinations(boxes, 2):  # interiors disjoint
        assert np.any(np.minimum(ahi, bhi) - np.maximum(alo, blo) <= 1e-9)
    sp = np.array(pyr.spacing[::-1])
    B = np.array(pyr.brick_shape[::-1])
    n_vox = np.array(pyr.shape[::-1])
    for lo, hi in boxes:  # every face is a level-0 brick face (or the volume's edge)
        for v in (lo, hi):
            vox = v / sp + 0.5
            assert np.all((np.abs(vox / B - np.round(vox / B)) < 1e-9) | (np.abs(vox - n_vox) < 1e-9))
    with pytest.raises(ParameterError, match="workers"):
        kd_split(_pyr((16, 16, 32)), 3)


def _depth_order_ok(leaves, order, eye) -> bool:
    """Brute force: of two groups facing each other across a plane, the one on the eye's side is
    in front and must come later in the back-to-front order."""
    pos = {g: i for i, g in enumerate(order)}
    box = {leaf.group: (np.array(leaf.lo), np.array(leaf.hi)) for leaf in leaves}
    for a, b in itertools.permutations(box, 2):
        (alo, ahi), (blo, bhi) = box[a], box[b]
        for ax in range(3):
            if abs(ahi[ax] - blo[ax]) > 1e-9:  # a just below b along ax?
                continue
            if not all(min(ahi[k], bhi[k]) > max(alo[k], blo[k]) for k in range(3) if k != ax):
                continue  # they do not face each other
            front, back = (a, b) if eye[ax] < ahi[ax] else (b, a)
            if pos[front] < pos[back]:
                return False
    return True


def test_visibility_order_from_many_eyes():
    pyr = _pyr()
    tree = kd_split(pyr, 6)
    leaves = tree.leaves()
    rng = np.random.default_rng(0)
    vlo, vhi = pyr.volume_box()
    for _ in range(200):
        eye = vlo + (vhi - vlo) * rng.uniform(-1.0, 2.0, 3)
        if np.allclose(eye, (vlo + vhi) / 2):
            continue
        cam = Camera.perspective(tuple(eye), tuple((vlo + vhi) / 2), size=(8, 8))
        order = back_to_front(tree, cam)
        assert sorted(order) == list(range(6))
        assert _depth_order_ok(leaves, order, eye)
        # orthographic: the side the view comes from is in front (an eye far back along -direction)
        d = rng.normal(size=3)
        ortho = Camera.orthographic(tuple((vlo + vhi) / 2), tuple(d), (0.0, 1.0, 0.0) if abs(d[1]) < 0.9 * np.linalg.norm(d)
                                    else (1.0, 0.0, 0.0), 10.0, 10.0, size=(8, 8))
        far_eye = (vlo + vhi) / 2 - ortho.forward * 1e6
        assert _depth_order_ok(leaves, back_to_front(tree, ortho), far_eye)


def test_composite_over_equals_whole_ray_compositing():
    rng = np.random.default_rng(1)
    n, h, w = 12, 3, 4
    colour = rng.random((n, h, w, 3))
    alpha = rng.random((n, h, w, 1)) * 0.4
    samples = np.concatenate([colour * alpha, alpha], axis=-1)  # premultiplied, front sample first

    def front_to_back(s):  # the textbook loop: C += (1 - A) c, A += (1 - A) a
        acc = np.zeros(s.shape[1:])
        for x in s:
            acc = acc + (1.0 - acc[..., 3:4]) * x
        return acc

    whole = front_to_back(samples)
    cuts = [0, 3, 7, 12]
    parts = [front_to_back(samples[a:b]) for a, b in zip(cuts, cuts[1:])]
    np.testing.assert_allclose(composite_over(parts[::-1]), whole, rtol=1e-12, atol=1e-12)
    np.testing.assert_array_equal(composite_max([np.array([1.0, 5.0]), np.array([3.0, 2.0])]), [3.0, 5.0])
