"""Named views in the patient's frame: the eye side, head up, the same picture for any storage order.

Reference: nibabel (``aff2axcodes`` for what each copy's axes are, ``apply_affine`` for where the
marker voxel of each copy lies); the camera's own projection only turns a world point into a pixel.
"""

from __future__ import annotations

import numpy as np
import pytest

from clipvol.bricking.worldframe import WorldFrame
from clipvol.errors import ParameterError
from clipvol.scene.views import ALIASES, mirrored, preset_camera, view_directions, edge_labels

nib = pytest.importorskip("nibabel")
from nibabel.affines import apply_affine  # noqa: E402

SHAPE = (20, 16, 12)  # (i, j, k) as nibabel holds it
RAS = np.array([[2.0, 0, 0, -19], [0, 2.5, 0, -18], [0, 0, 3.0, -15], [0, 0, 0, 1]])
#: the marker voxel of the RAS volume: patient's left (low i), anterior (high j), superior (high k)
MARKER = np.array([1.0, SHAPE[1] - 2.0, SHAPE[2] - 2.0])


def copies():
    """``name -> (affine, shape)`` of RAS, LAS (x flipped) and permuted-axes copies of one volume."""
    n = SHAPE
    flip = np.array([[-1.0, 0, 0, n[0] - 1], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]])
    perm = np.array([[0.0, 1, 0, 0], [0, 0, 1, 0], [1, 0, 0, 0], [0, 0, 0, 1]])  # new (a, b, c) = old (k, i, j)
    return {"RAS": (RAS, n), "LAS": (RAS @ flip, n), "permuted": (RAS @ perm, (n[2], n[0], n[1]))}


def test_copies_are_what_nibabel_says():
    codes = {k: nib.aff2axcodes(a) for k, (a, _) in copies().items()}
    assert codes == {"RAS": ("R", "A", "S"), "LAS": ("L", "A", "S"), "permuted": ("S", "R", "A")}


def _pixel_side(affine, shape, view):
    """(horizontal, vertical) side of the image where the marker lands: -1 left/bottom, +1 right/top."""
    frame = WorldFrame(tuple(map(tuple, affine)), "RAS")
    world = apply_affine(RAS, MARKER)  # the marker's patient position
    index = apply_affine(np.linalg.inv(affine), world)  # the same point in this copy's voxels
    sp = np.linalg.norm(affine[:3, :3], axis=0)
    lo, hi = -0.5 * sp, (np.array(shape) - 0.5) * sp
    cam = preset_camera(lo, hi, view, (64, 64), frame=frame)
    clip = cam.view_projection() @ np.append(index * sp, 1.0)
    x, y = clip[:2] / clip[3]
    if mirrored(frame):  # what every entry point does to the image of a mirrored store
        x = -x
    return int(np.sign(x)), int(np.sign(y))


#: where the left-anterior-superior marker must appear, seen from each side with the head (or, from
#: above and below, the face) up
EXPECTED = {"anterior": (1, 1), "posterior": (-1, 1), "left": (-1, 1), "right": (1, 1),
            "superior": (-1, 1), "inferior": (1, 1)}


@pytest.mark.parametrize("name", ["RAS", "LAS", "permuted"])
@pytest.mark.parametrize("view", sorted(EXPECTED))
def test_marker_lands_in_the_anatomical_quadrant(name, view):
    affine, shape = copies()[name]
    assert _pixel_side(affine, shape, view) == EXPECTED[view]


@pytest.mark.parametrize("name", ["RAS", "LAS", "permuted"])
def test_anterior_view_is_labelled_like_a_facing_patient(name):
    affine, shape = copies()[name]
    frame = WorldFrame(tuple(map(tuple, affine)), "RAS")
    sp = np.linalg.norm(affine[:3, :3], axis=0)
    cam = preset_camera(-0.5 * sp, (np.array(shape) - 0.5) * sp, "anterior", (32, 32), frame=frame)
    assert edge_labels(cam, frame) == {"right": "L", "left": "R", "top": "S", "bottom": "I"}
    cam = preset_camera(-0.5 * sp, (np.array(shape) - 0.5) * sp, "iso", (32, 32), frame=frame)
    lab = edge_labels(cam, frame)
    assert lab["top"][0] == "S" and set(lab["right"]) == {"L", "A"}  # from anterior-right-superior


def test_mirrored_only_for_a_flipped_patient_frame():
    c = copies()
    assert not mirrored(WorldFrame(tuple(map(tuple, c["RAS"][0])), "RAS"))
    assert mirrored(WorldFrame(tuple(map(tuple, c["LAS"][0])), "RAS"))
    assert not mirrored(WorldFrame(tuple(map(tuple, c["permuted"][0])), "RAS"))  # a cyclic permutation keeps hands
    assert not mirrored(WorldFrame(tuple(map(tuple, c["LAS"][0])), ""))  # not a patient: nothing to mirror
    assert not mirrored(None)


@pytest.mark.parametrize("alias", sorted(ALIASES))
def test_old_names_mean_the_anatomical_view_where_there_is_a_frame(alias):
    frame = WorldFrame(tuple(map(tuple, copies()["LAS"][0])), "RAS")
    a, b = view_directions(alias, frame), view_directions(ALIASES[alias], frame)
    np.testing.assert_allclose(a, b)


def test_array_views_without_a_frame_and_anatomical_names_refused():
    fwd, up = view_directions("front")
    np.testing.assert_allclose(fwd, [0, 0, 1])
    np.testing.assert_allclose(up, [0, -1, 0])
    with pytest.raises(ParameterError, match="--view anterior: expected a store with a patient frame"):
        view_directions("anterior", None)
    with pytest.raises(ParameterError, match="--view: expected one of"):
        view_directions("sideways", None)


def test_oblique_acquisition_is_viewed_in_the_patient_frame():
    # a grid tilted 20 degrees about the left-right axis: the anterior view still faces the patient,
    # head up (nibabel's apply_affine places the marker; the camera only projects it)
    t = np.radians(20.0)
    tilt = np.array([[1.0, 0, 0, 0], [0, np.cos(t), -np.sin(t), 0], [0, np.sin(t), np.cos(t), 0], [0, 0, 0, 1]])
    affine = tilt @ RAS
    frame = WorldFrame(tuple(map(tuple, affine)), "RAS")
    assert frame.oblique and nib.aff2axcodes(affine) == ("R", "A", "S")
    fwd, up = view_directions("anterior", frame)
    np.testing.assert_allclose(frame.directions @ fwd, [0, -1, 0], atol=1e-12)  # looking posteriorly
    np.testing.assert_allclose(frame.directions @ up, [0, 0, 1], atol=1e-12)  # superior up
    world = apply_affine(affine, MARKER)
    index = apply_affine(np.linalg.inv(affine), world)
    sp = np.linalg.norm(affine[:3, :3], axis=0)
    cam = preset_camera(-0.5 * sp, (np.array(SHAPE) - 0.5) * sp, "anterior", (64, 64), frame=frame)
    clip = cam.view_projection() @ np.append(index * sp, 1.0)
    assert clip[0] / clip[3] > 0 and clip[1] / clip[3] > 0  # left-anterior-superior: top right
    assert edge_labels(cam, frame) == {"right": "L", "left": "R", "top": "S", "bottom": "I"}


def test_camera_paths_of_a_patient_store_are_head_up_and_turn_the_worlds_way():
    """patient_path: superior and anterior of the affine (nibabel's axis codes name them) become the
    path's up and front; an LAS store (a mirror image) turns mirrored; a store without a patient
    frame keeps the path and its defaults."""
    import nibabel as nib

    from clipvol.bricking.worldframe import WorldFrame
    from clipvol.scene.views import patient_path

    assert patient_path("fly", None) == ("fly", {})
    assert patient_path("orbit", WorldFrame(tuple(map(tuple, np.eye(4))), "")) == ("orbit", {})
    # array x -> anterior (A), y -> superior (S), z -> patient's left (L): a mirror image of RAS
    aff = np.array([[0, 0, -2, 0], [3, 0, 0, 0], [0, 1, 0, 0], [0, 0, 0, 1]], dtype=float)
    assert nib.aff2axcodes(aff) == ("A", "S", "L")
    name, kw = patient_path("orbit", WorldFrame(tuple(map(tuple, aff)), "RAS"))
    assert name == "turntable" and kw["elevation"] == 25.0 and kw["mirror"] is True
    np.testing.assert_allclose(kw["up"], (0, 1, 0), atol=1e-12)     # superior is array y
    np.testing.assert_allclose(kw["front"], (1, 0, 0), atol=1e-12)  # anterior is array x
    name, kw = patient_path("zoom", WorldFrame(tuple(map(tuple, np.eye(4))), "RAS"))
    assert name == "zoom" and kw["mirror"] is False
    np.testing.assert_allclose(kw["up"], (0, 0, 1), atol=1e-12)
