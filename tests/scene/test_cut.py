"""The crop box and clip planes in the store's terms (``clipvol.scene.cut``) against direct numpy geometry.

The reference is written out here, independently of the module: a world point ``w`` of a store with
voxel-to-world affine ``A`` sits at level-0 voxel index ``A^-1 w`` and at render position
``index * spacing``; a point is inside the cut when its *world* position lies in the world box and
on the kept side of every world plane. Random points must agree with ``Shape.contains``.
"""

from __future__ import annotations

import numpy as np
import pytest

from clipvol.bricking.pyramid import Pyramid
from clipvol.bricking.worldframe import WorldFrame
from clipvol.errors import ParameterError
from clipvol.scene.cut import CutEditor, cut_shape, render_to_world

SHAPE, SPACING = (20, 24, 28), (2.0, 1.5, 0.75)  # z, y, x


def pyramid():
    from clipvol.loaders.numpy_array import NumpyLoader

    return NumpyLoader(np.zeros(SHAPE, np.float32), brick=8, spacing=SPACING).pyramid


def frames():
    sp = np.array(SPACING[::-1])
    perm = np.array([[-1.0, 0, 0], [0, 0, 1.0], [0, 1.0, 0]])  # x flipped, y and z swapped: aligned
    c, s = np.cos(0.4), np.sin(0.4)
    rot = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])  # oblique
    out = []
    for r, t in ((np.eye(3), (5.0, -3.0, 2.0)), (perm, (10.0, 0.0, -7.0)), (rot, (-4.0, 6.0, 1.0))):
        a = np.eye(4)
        a[:3, :3] = r * sp
        a[:3, 3] = t
        out.append(WorldFrame(tuple(map(tuple, a)), "RAS"))
    return out


def _render_points(rng, n=4000):
    lo = -0.5 * np.array(SPACING[::-1])
    hi = (np.array(SHAPE[::-1]) - 0.5) * np.array(SPACING[::-1])
    return rng.uniform(lo - 2, hi + 2, size=(n, 3))


@pytest.mark.parametrize("k", range(3))
def test_world_box_and_planes_cut_the_same_points_as_world_geometry(k, rng):
    frame = frames()[k]
    pyr = pyramid()
    a = np.array(frame.affine)
    p = _render_points(rng)
    index = p / np.array(SPACING[::-1])
    world = index @ a[:3, :3].T + a[:3, 3]  # independent: index -> world through the affine
    centre = world.mean(axis=0)
    box = (centre - (8.0, 9.0, 6.0), centre + (10.0, 6.0, 9.0))
    plane = (*centre, 0.3, -1.0, 0.2)
    planes = [plane] if k < 2 else []  # an oblique store's box takes all six planes
    shape = cut_shape(pyr, frame, crop=(tuple(box[1]), tuple(box[0])), clip_planes=planes)  # corners in any order
    want = np.all((world >= box[0]) & (world <= box[1]), axis=1)
    if planes:
        want &= (world - centre) @ np.array(plane[3:]) >= 0
    got = shape.contains(p)
    assert want.sum() > 50 and (~want).sum() > 50
    # points within a float rounding of a face may go either way
    near = np.min(np.abs(np.concatenate([world - box[0], world - box[1]], axis=1)), axis=1) < 1e-9
    assert np.array_equal(got[~near], want[~near])
    assert (shape.box is None) == (k == 2) and len(shape.planes) == (1 if k < 2 else 6)


def test_oblique_box_takes_six_planes_and_leaves_no_room():
    pyr = pyramid()
    frame = frames()[2]
    s = cut_shape(pyr, frame, crop=((0, 0, 0), (5, 5, 5)))
    assert s.box is None and len(s.planes) == 6
    with pytest.raises(ParameterError, match="at most 6"):
        cut_shape(pyr, frame, crop=((0, 0, 0), (5, 5, 5)), clip_planes=[(0, 0, 0, 1, 0, 0)])
    aligned = cut_shape(pyr, frames()[1], crop=((-20, 0, -7), (5, 5, 5)))
    assert aligned.box is not None and aligned.planes == ()


def test_voxel_crop_is_the_cells_of_those_voxels(rng):
    pyr = pyramid()
    s = cut_shape(pyr, None, crop_voxels=((2, 3, 4), (10, 20, 27)))
    p = _render_points(rng)
    index = p / np.array(SPACING[::-1])  # x, y, z voxel coordinates; voxel i's cell is [i - 0.5, i + 0.5]
    want = np.all((index >= np.array([4, 3, 2]) - 0.5) & (index <= np.array([27, 20, 10]) - 0.5), axis=1)
    assert np.array_equal(s.contains(p), want)


@pytest.mark.parametrize("kw, match", [
    (dict(crop_voxels=((0, 0, 0), (21, 5, 5))), "z range 0:21"),
    (dict(crop_voxels=((3, 0, 0), (3, 5, 5))), "z range 3:3"),
    (dict(crop=((1e6, 1e6, 1e6), (2e6, 2e6, 2e6))), "outside the volume"),
    (dict(crop=((0, 0, 0), (1, 1, 1)), crop_voxels=((0, 0, 0), (1, 1, 1))), "both"),
    (dict(clip_planes=[(0, 0, 0, 0, 0, 0)]), "non-zero normal"),
    (dict(clip_planes=[(0, 0, 0, 1, 0, 0)] * 7), "at most 6"),
])
def test_bad_cuts_are_refused_by_name(kw, match):
    with pytest.raises(ParameterError, match=match):
        cut_shape(pyramid(), None, **kw)


def test_no_cut_is_none_and_world_is_render_without_a_frame():
    pyr = pyramid()
    assert cut_shape(pyr, None) is None
    assert np.array_equal(render_to_world(pyr, None), np.eye(4))


def test_editor_moves_faces_within_the_volume_and_planes_along_their_normal():
    pyr = pyramid()
    ed = CutEditor.for_pyramid(pyr, steps=10)
    lo, hi = pyr.volume_box()
    assert ed.shape() is None
    assert ed.select() == "box x-"
    ed.move(-2)  # inwards by two steps
    assert ed.shape().box[0][0] == pytest.approx(lo[0] + 2 * ed.step)
    ed.move(+100)  # outwards, stops at the volume
    assert ed.box_lo[0] == pytest.approx(lo[0])
    ed.select()  # x+
    ed.move(-1000)  # inwards, stops at the opposite face
    assert ed.box_hi[0] == pytest.approx(ed.box_lo[0])
    ed.remove_selected()
    assert ed.shape() is None
    centre = (lo + hi) / 2
    assert ed.add_plane(centre, (0.0, 0.0, 1.0)) and ed.selected_name() == "plane 1"
    s = ed.shape()
    assert s.contains(centre + (0, 0, 0.1)) and not s.contains(centre - (0, 0, 0.1))
    ed.move(1)  # the plane moves one step along +z: the centre is now cut away
    assert not ed.shape().contains(centre + (0, 0, 0.5 * ed.step))
    assert ed.shape().contains(centre + (0, 0, 1.5 * ed.step))
    for _ in range(5):
        assert ed.add_plane(centre, (1.0, 0.0, 0.0))
    assert not ed.add_plane(centre, (1.0, 0.0, 0.0))  # six at most
    assert "6 plane(s)" in ed.describe()


def test_editor_describes_the_box_in_world_units():
    pyr = pyramid()
    frame = frames()[1]  # x flipped, y and z swapped
    ed = CutEditor.for_pyramid(pyr, steps=10)
    ed.select()
    ed.move(-1)  # x- face in by one step
    m = render_to_world(pyr, frame)
    a = np.array(frame.affine)
    corners = (np.stack([ed.box_lo, ed.box_hi]) / np.array(SPACING[::-1])) @ a[:3, :3].T + a[:3, 3]  # index -> world
    lo, hi = corners.min(axis=0), corners.max(axis=0)
    line = ed.describe(m, "mm")
    assert line.startswith("cut: box x,y,z ") and "mm" in line and "box x-" in line
    assert ",".join(f"{a:.4g}:{b:.4g}" for a, b in zip(lo, hi)) in line
    assert "(" in CutEditor.describe(ed, render_to_world(pyr, frames()[2]))  # oblique: corners
