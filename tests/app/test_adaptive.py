"""The adaptive-quality controller on a synthetic slow path.

The path is a model of a ray caster: a frame costs ``overhead + full_s * rays x samples`` (times a
little noise). Its steady state is known in closed form, ``cost* = (target - overhead) / full_s``,
independently of the controller, and the frame times the controller reaches are measured on it.
"""

from __future__ import annotations

import numpy as np
import pytest

from clipvol.app.adaptive import FULL, AdaptiveQuality, Quality
from clipvol.errors import ParameterError


class SlowPath:
    def __init__(self, full_s: float, overhead_s: float, noise: float = 0.05, seed: int = 0) -> None:
        self.full_s, self.overhead_s, self.noise = full_s, overhead_s, noise
        self.rng = np.random.default_rng(seed)

    def frame(self, q: Quality, size=(960, 640)) -> float:
        w, h = q.size(size)
        rays = w * h / (size[0] * size[1])
        samples = 1.0 / q.step_factor
        return (self.overhead_s + self.full_s * rays * samples) * (1 + self.noise * self.rng.standard_normal())


@pytest.mark.parametrize("full_s,overhead_s", [(0.6, 0.01), (2.0, 0.03), (0.3, 0.05)])
def test_holds_the_target_frame_time_while_moving(full_s, overhead_s):
    path = SlowPath(full_s, overhead_s)
    aq = AdaptiveQuality(0.1)
    now, times = 0.0, []
    for _ in range(40):
        q = aq.next(True, now)
        assert q is not None and not q.full
        t = path.frame(q)
        aq.done(q, t)
        times.append(t)
        now += t
    # it aims below the target (headroom for noise): the frames stay under the target
    aim = aq.headroom * 0.1
    assert 0.5 <= aq.headroom < 1
    steady = np.array(times[-15:])
    assert abs(np.mean(steady) / aim - 1) < 0.15, steady
    assert np.mean(steady) <= 0.1 and np.mean(steady <= 0.1) >= 0.8
    # it gets there from a standing start within ~10 frames
    assert abs(np.mean(times[10:20]) / aim - 1) < 0.3
    # and sits at the model's closed-form cost (pixel rounding aside)
    assert aq.cost == pytest.approx((aim - overhead_s) / full_s, rel=0.2)


def test_fixed_overhead_above_the_target_settles_at_the_lowest_quality():
    path = SlowPath(1.0, 0.15, noise=0.0)
    aq = AdaptiveQuality(0.1, min_scale=0.25, max_step_factor=2.0)
    for i in range(30):
        q = aq.next(True, i * 0.2)
        aq.done(q, path.frame(q))
    assert aq.cost == pytest.approx(0.25 ** 2 / 2.0)
    q = aq.quality_for(aq.cost)
    assert q.scale == pytest.approx(0.25) and q.step_factor == pytest.approx(2.0)


def test_refines_to_full_quality_once_still_and_then_rests():
    path = SlowPath(0.8, 0.01, noise=0.0)
    aq = AdaptiveQuality(0.1, settle_s=0.2)
    now = 0.0
    for _ in range(10):
        q = aq.next(True, now)
        aq.done(q, path.frame(q))
        now += 0.05
    assert aq.state == "interactive"
    cost = aq.cost
    assert aq.next(False, now + 0.1) is not None and not aq.next(False, now + 0.1).full  # not settled yet
    q = aq.next(False, now + 0.25)
    assert q is FULL and aq.state == "interactive"  # what is on screen until the full frame is drawn
    aq.done(q, path.frame(q))
    assert aq.state == "refined"
    assert aq.next(False, now + 0.3) is None and aq.next(False, now + 5.0) is None
    # moving again starts from the cost motion measured, not from full quality
    q = aq.next(True, now + 6.0)
    assert not q.full and q.cost == pytest.approx(cost)
    aq.invalidate()
    assert aq.next(False, now + 10.0) is FULL


def test_cost_maps_to_scale_and_step_within_bounds():
    aq = AdaptiveQuality(0.1, min_scale=0.2, max_step_factor=3.0)
    costs = np.logspace(-3, 0, 50)
    qs = [aq.quality_for(c) for c in costs]
    for c, q in zip(costs, qs):
        assert 0.2 <= q.scale <= 1.0 and 1.0 <= q.step_factor <= 3.0
        assert q.cost == pytest.approx(max(c, aq.min_cost), rel=1e-9)
    assert all(b.cost >= a.cost for a, b in zip(qs, qs[1:]))
    # the step takes a few values only (its tables and a kept cut's parameters are then reused)
    assert {q.step_factor for q in qs} <= {1.0, 1.5, 2.0, 3.0}
    assert [aq.quality_for(c).step_factor for c in (1.0, 0.29, 0.12, 0.03)] == [1.0, 1.5, 2.0, 3.0]
    free = AdaptiveQuality(0.1, min_scale=0.2, max_step_factor=3.0, step_rungs=None)
    assert free.quality_for(0.12).step_factor == pytest.approx(0.12 ** (-1 / 3))
    assert aq.quality_for(1.0) == Quality(1.0, 1.0, False, 2.0)
    assert Quality(0.5, 2.0, False).size((960, 640)) == (480, 320) and FULL.size((960, 640)) == (960, 640)


def test_interactive_frames_draw_one_whole_level_and_full_frames_keep_the_users_parameters():
    """An orthographic view of a 64^3 store (levels of 1, 2, 4 voxels) 0.3 pixels a voxel wide: a
    level-``L`` voxel covers ``0.3 * 2**L`` pixels, so at threshold 1 x ``preview_lod`` 2 the coarsest
    level within 2 pixels is 2 (1.2 px), at ``preview_lod`` 1 it is 1 (0.6 px): worked by hand."""
    from clipvol.app.adaptive import frame_params, preview_level
    from clipvol.loaders.numpy_array import NumpyLoader
    from clipvol.scene.camera import Camera

    pyr = NumpyLoader(np.zeros((64, 64, 64), dtype=np.uint8), brick=16).pyramid
    assert [max(lv.scale) for lv in pyr.levels][:3] == [1.0, 2.0, 4.0]
    cam = Camera.orthographic((32, 32, 32), (0, 0, -1), (0, 1, 0), width=100.0, height=100.0, size=(30, 30))
    assert preview_level(pyr, cam, 2.0) == 2 and preview_level(pyr, cam, 1.0) == 1
    assert preview_level(pyr, cam, 0.1) == 0  # even level 0 is too coarse: the finest there is

    aq = AdaptiveQuality()
    assert aq.target_s == pytest.approx(1 / 15)
    q = aq.next(True, 0.0)
    assert not q.full and q.lod_factor == 2.0
    user = dict(step=0.5, lod_threshold=1.0, policy="projected-size", level=None)
    assert frame_params(FULL, pyr, cam, **user) == user  # a still frame: the user's own parameters
    moving = frame_params(Quality(0.5, 3.0, False, 2.0), pyr, cam, max_step=1.0, **user)
    assert moving == dict(step=1.0, lod_threshold=1.0, policy="fixed", level=2)  # step capped at max_step
    assert frame_params(Quality(0.5, 3.0, False, 1.0), pyr, cam, **user)["level"] == 1
    # the level of the frame before is kept while it is that level or one coarser, not two
    q1 = Quality(0.5, 3.0, False, 1.0)
    assert [frame_params(q1, pyr, cam, previous=p, **user)["level"] for p in (0, 1, 2, 3)] == [1, 1, 2, 1]
    # never finer than the user's own fixed level
    fixed3 = dict(user, policy="fixed", level=3)
    assert frame_params(Quality(0.5, 2.0, False, 2.0), pyr, cam, **fixed3)["level"] == 3
    assert aq.next(False, 1.0) is FULL and FULL.lod_factor == 1.0
    assert AdaptiveQuality(preview_lod=1.0).quality_for(0.05).lod_factor == 1.0


@pytest.mark.parametrize("kw", [{"target_s": 0}, {"target_s": float("nan")}, {"min_scale": 0}, {"min_scale": 2},
                                {"max_step_factor": 0.5}, {"gain": 0}, {"headroom": 1.5}, {"preview_lod": 0.5},
                                {"preview_lod": float("inf")}])
def test_bad_parameters_raise(kw):
    with pytest.raises(ParameterError):
        AdaptiveQuality(**kw)
