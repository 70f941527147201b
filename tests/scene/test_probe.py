"""The probe (first visible sample along a ray) and the ruler against analytic volumes and numpy.

A ball of known centre and radius is the only visible thing (the transfer function is transparent
below 0.5); a ray aimed at its centre must stop at its surface, and the value reported must be the
array's value at the voxel reported. Distances of the ruler are numpy's Euclidean distances of the
two world points.
"""

from __future__ import annotations

import numpy as np
import pytest

from clipvol.bricking.worldframe import WorldFrame
from clipvol.errors import ParameterError
from clipvol.loaders.numpy_array import NumpyLoader
from clipvol.scene.camera import Camera
from clipvol.scene.geometry import Shape
from clipvol.scene.probe import Prober, Ruler, pixel_ray
from clipvol.scene.transfer import TransferFunction

N, CENTRE, RADIUS = 48, np.array([24.0, 22.0, 26.0]), 10.0  # centre (x, y, z) in voxels
STEP_TF = TransferFunction.from_points([(0.0, (1, 1, 1, 0.0)), (0.49, (1, 1, 1, 0.0)), (0.51, (1, 1, 1, 1.0)),
                                        (1.0, (1, 1, 1, 1.0))])


def ball(spacing=(1.0, 1.0, 1.0)):
    z, y, x = np.mgrid[0:N, 0:N, 0:N].astype(np.float64)
    r = np.sqrt((x - CENTRE[0]) ** 2 + (y - CENTRE[1]) ** 2 + (z - CENTRE[2]) ** 2)
    vol = np.where(r <= RADIUS, 0.6 + 0.3 * (x / N), 0.1 * (y / N)).astype(np.float32)  # values vary inside
    return vol, NumpyLoader(vol, brick=8, spacing=spacing, value_range=(0.0, 1.0))


class Counting:
    """A loader wrapper that counts ``read_brick`` calls."""

    def __init__(self, inner):
        self.inner, self.pyramid, self.reads = inner, inner.pyramid, []

    def read_brick(self, level, index):
        self.reads.append((level, tuple(index)))
        return self.inner.read_brick(level, index)


@pytest.mark.parametrize("direction", [(1, 0, 0), (0, -1, 0), (0.3, 0.5, -0.8)])
def test_first_visible_sample_is_on_the_ball_and_its_value_is_the_array_at_that_voxel(direction):
    vol, loader = ball()
    d = np.asarray(direction, dtype=np.float64)
    d /= np.linalg.norm(d)
    origin = CENTRE - 40.0 * d
    hit = Prober(loader).pick(origin, d, STEP_TF, step=0.25)
    assert hit is not None
    # the surface: distance from the centre within a voxel of the radius (nearest-voxel samples)
    assert abs(np.linalg.norm(hit.position - CENTRE) - RADIUS) <= 1.0
    assert abs(hit.distance - (40.0 - RADIUS)) <= 1.0
    z, y, x = hit.voxel
    assert hit.value == vol[z, y, x]
    assert np.all(np.abs(np.array([x, y, z]) - hit.position) <= 0.5)  # the voxel holds the sample
    assert np.linalg.norm(np.array([x, y, z]) - CENTRE) <= RADIUS  # a voxel of the ball
    assert hit.level == 0 and hit.opacity >= 0.05


def test_a_ray_that_misses_sees_nothing_and_reads_only_its_bricks():
    _, loader = ball()
    c = Counting(loader)
    pr = Prober(c)
    assert pr.pick((-5.0, 2.0, 2.0), (1.0, 0.0, 0.0), STEP_TF) is None  # along a corner row, outside the ball
    assert set(c.reads) == {(0, (0, 0, i)) for i in range(N // 8)}  # the row of bricks it crosses, no more


def test_world_position_goes_through_the_store_affine():
    vol, loader = ball(spacing=(2.0, 1.0, 0.5))
    a = np.array([[0.0, 0.0, 2.0, 100.0], [0.0, -1.0, 0.0, 50.0], [0.5, 0.0, 0.0, -20.0], [0, 0, 0, 1.0]])
    loader.frame = WorldFrame(tuple(map(tuple, a)), "RAS")
    sp = np.array([0.5, 1.0, 2.0])
    hit = Prober(loader).pick(CENTRE * sp - (60.0, 0, 0), (1.0, 0.0, 0.0), STEP_TF, step=0.25)
    index = hit.position / sp
    assert np.allclose(hit.world, a[:3, :3] @ index + a[:3, 3])
    z, y, x = hit.voxel
    assert hit.value == vol[z, y, x]


def test_the_cut_hides_the_near_side_and_the_probe_sees_behind_it():
    vol, loader = ball()
    d = np.array([1.0, 0.0, 0.0])
    cut = Shape(planes=((1.0, 0.0, 0.0, -CENTRE[0]),))  # keep x >= centre: the ball's near half is cut away
    hit = Prober(loader).pick(CENTRE - 40 * d, d, STEP_TF, step=0.25, shape=cut)
    assert abs(hit.position[0] - CENTRE[0]) <= 0.25  # the first visible sample is on the cut face
    assert hit.value == vol[hit.voxel]
    boxed = Shape(box=((0.0, 0.0, 0.0), (10.0, 47.0, 47.0)))  # a box that holds no part of the ball
    assert Prober(loader).pick(CENTRE - 40 * d, d, STEP_TF, shape=boxed) is None


def test_coarser_levels_report_their_own_voxel():
    vol, loader = ball()
    hit = Prober(loader).pick(CENTRE - (40.0, 0, 0), (1.0, 0.0, 0.0), STEP_TF, level=1)
    lvl1 = loader.read_brick(1, loader.pyramid.world_to_brick(1, hit.position))
    assert hit.level == 1
    b = np.array(loader.pyramid.brick_shape)
    local = np.array(hit.voxel) - (np.array(hit.voxel) // b) * b
    assert hit.value == lvl1[tuple(local)]


def test_pixel_rays_are_the_camera_rays_at_pixel_centres():
    cam = Camera.perspective((-30.0, -10.0, -40.0), (24.0, 24.0, 24.0), size=(20, 16), fov_y=40)
    origins, dirs = cam.rays()
    for x, y in [(0, 0), (19, 15), (7, 3)]:
        o, d, tmin = pixel_ray(cam, x + 0.5, y + 0.5)
        assert np.allclose(o, origins[y, x]) and np.allclose(d, dirs[y, x]) and tmin == 0.0
    with pytest.raises(ParameterError, match="pixel"):
        pixel_ray(cam, 21, 3)


def test_ruler_length_is_the_numpy_distance_of_its_ends(rng):
    r = Ruler()
    assert r.length is None and r.describe() == "ruler: -"
    a, b = rng.normal(size=3) * 50, rng.normal(size=3) * 50
    r.add(a)
    assert r.length is None and "other end" in r.describe("mm")
    r.add(b)
    assert r.length == pytest.approx(float(np.sqrt(((a - b) ** 2).sum())))
    assert f"{r.length:.4g} mm" in r.describe("mm")
    r.add(b)  # a third pick starts a new ruler
    assert r.length is None
    with pytest.raises(ParameterError, match="ruler"):
        r.add((1.0, np.nan, 0.0))


def test_long_rays_are_marched_in_chunks_and_stop_at_the_first_hit(monkeypatch):
    import clipvol.scene.probe as probe

    vol, loader = ball()
    monkeypatch.setattr(probe, "SAMPLES_PER_CHUNK", 7)  # many chunks, a brick's samples split between them
    d = np.array([0.3, 0.5, -0.8])
    d /= np.linalg.norm(d)
    hit = Prober(loader).pick(CENTRE - 40.0 * d, d, STEP_TF, step=0.25)
    monkeypatch.setattr(probe, "SAMPLES_PER_CHUNK", 1 << 20)
    whole = Prober(loader).pick(CENTRE - 40.0 * d, d, STEP_TF, step=0.25)
    assert hit.voxel == whole.voxel and hit.distance == whole.distance and hit.value == vol[hit.voxel]
