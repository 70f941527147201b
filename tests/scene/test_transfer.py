"""Transfer functions against independent references (np.interp, float64 powers, matplotlib)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from clipvol.errors import ParameterError
from clipvol.scene.transfer import (
    TransferFunction,
    correct_opacity,
    transparency_filter,
)

EDGE_ALPHAS = np.array([0.0, 1e-7, 1e-3, 0.5, 1 - 1e-7, 1.0])
RATIOS = np.logspace(-3, 3, 25)


def _interp_ref(tf, t):
    """GL_LINEAR + CLAMP_TO_EDGE of the table = np.interp over the texel centres."""
    n = len(tf.table)
    x = (np.arange(n) + 0.5) / n
    return np.stack([np.interp(t, x, tf.table[:, k].astype(np.float64)) for k in range(4)], axis=-1)


def test_correct_opacity_edge_values_are_finite_monotone_and_exact():
    a, r = np.meshgrid(EDGE_ALPHAS, RATIOS, indexing="ij")
    out = correct_opacity(a, r)
    assert np.all(np.isfinite(out)) and np.all((out >= 0) & (out <= 1))
    assert np.all(np.diff(out, axis=0) >= 0) and np.all(np.diff(out, axis=1) >= 0)
    np.testing.assert_array_equal(out[0], 0.0)
    np.testing.assert_array_equal(out[-1], 1.0)
    ref = 1.0 - (1.0 - a) ** r
    # float64 reference loses ~1e-16/alpha relative accuracy at tiny alpha; ours is better
    np.testing.assert_allclose(out, ref, rtol=1e-8, atol=1e-15)
    # near 0 the expansion alpha * ratio is the truth
    np.testing.assert_allclose(correct_opacity(1e-12, RATIOS), 1e-12 * RATIOS, rtol=1e-9)
    assert correct_opacity(0.3, 1.0) == pytest.approx(0.3, rel=1e-15)


@settings(max_examples=200, deadline=None)
@given(st.floats(0.0, 1.0), st.floats(1e-3, 1e3))
def test_correct_opacity_matches_power_form(a, r):
    got = correct_opacity(a, r)
    ref = 1.0 - (1.0 - a) ** r
    assert np.isfinite(got) and 0.0 <= got <= 1.0
    assert got == pytest.approx(ref, rel=1e-7, abs=1e-12)
    assert correct_opacity(a, r * 1.5) >= got


@pytest.mark.parametrize("name", TransferFunction.names())
def test_lookup_equals_np_interp_reference(name):
    tf = TransferFunction.preset(name, n=64)
    rng = np.random.default_rng(0)
    v = np.concatenate([rng.uniform(-20, 120, 2000), [-1e30, 1e30, 0, 100, 50]])
    t = np.clip((v - 0) / 100, 0, 1)
    np.testing.assert_allclose(tf.lookup(v, (0, 100)), _interp_ref(tf, t), atol=1e-12)
    np.testing.assert_allclose(tf.normalise(v, (0, 100)), t)


def test_value_range_overrides_data_range_and_nan_maps_to_zero():
    tf = TransferFunction.preset("grey", value_range=(10, 20))
    np.testing.assert_allclose(tf.normalise([5, 15, 25], (0, 1000)), [0, 0.5, 1])
    assert tf.normalise(np.nan, (0, 1)) == 0.0
    with pytest.raises(ParameterError):
        TransferFunction.preset("grey").normalise([1.0], None)


def test_zero_width_range_is_a_step_without_division():
    tf = TransferFunction.preset("grey")
    with np.errstate(all="raise"):
        t = tf.normalise([-1.0, 3.0, 3.0, 7.0], (3.0, 3.0))
        rgba = tf.lookup([-1.0, 3.0, 7.0], (3.0, 3.0))
    np.testing.assert_array_equal(t, [0, 0.5, 0.5, 1])
    np.testing.assert_allclose(rgba, _interp_ref(tf, np.array([0, 0.5, 1])))
    m = tf.transparent_mask([[-5, -1], [3, 3]], (3.0, 3.0))
    ref = [np.all(tf.lookup(np.array([-5, -1]), (3.0, 3.0))[:, 3] == 0), False]
    np.testing.assert_array_equal(m, ref)


@pytest.mark.parametrize("name", ["bone", "custom"])
def test_transparent_mask_is_exact_against_brute_force(name):
    if name == "bone":
        tf = TransferFunction.preset("bone", n=64)
    else:
        tf = TransferFunction.from_points(
            [(0, (1, 1, 1, 0)), (0.3, (1, 1, 1, 0)), (0.31, (1, 0, 0, 0.5)), (0.33, (1, 0, 0, 0)),
             (0.7, (0, 0, 0, 0)), (0.71, (0, 1, 0, 1)), (0.72, (0, 0, 0, 0)), (1, (0, 0, 0, 0))], n=100)
    rng = np.random.default_rng(1)
    lo = rng.uniform(-0.1, 1.1, 3000)
    hi = lo + rng.exponential(0.03, 3000)
    ranges = np.stack([lo, hi], axis=1)
    got = tf.transparent_mask(ranges, (0.0, 1.0))
    n = len(tf.table)
    centres = (np.arange(n) + 0.5) / n
    brute = np.empty(len(ranges), dtype=bool)
    for i, (a, b) in enumerate(ranges):
        # endpoints, every texel centre inside and dense samples: the alpha is piecewise linear
        # between centres, so its maximum over [a, b] is attained at one of these points
        pts = np.concatenate([[a, b], centres[(centres > a) & (centres < b)], np.linspace(a, b, 50)])
        brute[i] = np.all(tf.lookup(pts, (0.0, 1.0))[:, 3] == 0)
    np.testing.assert_array_equal(got, brute)
    assert got.any() and (~got).any()
    assert not tf.transparent_mask([[np.nan, np.nan]], (0, 1))[0]


def test_presets_follow_matplotlib_and_bone_is_ct_like():
    mpl = pytest.importorskip("matplotlib")
    x = (np.arange(256) + 0.5) / 256
    for name in ("viridis", "magma", "inferno", "plasma"):
        tf = TransferFunction.preset(name)
        ref = mpl.colormaps[name](x)[:, :3]
        assert np.abs(tf.table[:, :3] - ref).max() < 0.03, name  # 17-point piecewise-linear fit
        # the gentle ramp: 0.6 t^2 at the texel centres, entry 0 exactly 0
        np.testing.assert_allclose(tf.table[1:, 3], 0.6 * x[1:] ** 2, atol=1e-6)
        assert tf.table[0, 3] == 0.0
    g = TransferFunction.preset("grey")
    np.testing.assert_allclose(g.table[:, :3], np.repeat(x[:, None], 3, axis=1), atol=1e-6)
    bone = TransferFunction.preset("bone")
    assert bone.transparent_mask([[0.0, 0.2]], (0, 1))[0]
    top = bone.lookup([1.0], (0, 1))[0]
    assert top[3] > 0.99 and top[:3].min() > 0.99
    mid = bone.lookup([0.4], (0, 1))[0]
    assert 0 < mid[3] < 0.3 and mid[0] > mid[2]  # translucent, warm
    assert bone.table.dtype == np.float32 and not bone.table.flags.writeable


@pytest.mark.parametrize(
    "make",
    [
        lambda: TransferFunction.preset("nope"),
        lambda: TransferFunction.from_points([]),
        lambda: TransferFunction.from_points([(0.5, (1, 1, 1, 1)), (0.2, (0, 0, 0, 0))]),
        lambda: TransferFunction.from_points([(0.0, (2, 0, 0, 0))]),
        lambda: TransferFunction.from_points([(0.0, (1, 0, 0, 0))], n=0),
        lambda: TransferFunction.preset("grey", value_range=(2, 1)),
        lambda: TransferFunction(np.zeros((4, 3))),
        lambda: correct_opacity(0.5, -1.0),
    ],
)
def test_invalid_input_raises_parameter_error(make):
    with pytest.raises(ParameterError):
        make()


def test_transparency_filter_uses_brick_ranges_over_the_sampling_footprint():
    """A brick is transparent only if it and its neighbours are: samples near its faces
    interpolate the neighbours' edge voxels."""
    z_ranges = {0: (0.0, 10.0), 1: (0.0, 10.0), 2: (0.0, 90.0), 3: (0.0, 10.0)}

    class L:
        class pyramid:
            value_range = (0.0, 100.0)

            @staticmethod
            def grid(level):
                return (4, 1, 1)

        def brick_ranges(self, level, idx):
            return np.array([z_ranges[int(z)] for z in idx[:, 0]]) if level == 0 else None

    tf = TransferFunction.preset("bone")
    f = transparency_filter(tf, L())
    idx = np.array([[0, 0, 0], [1, 0, 0], [3, 0, 0]])
    # footprints by hand: {0, 1} -> [0, 10]; {0, 1, 2} -> [0, 90]; {2, 3} -> [0, 90]
    ref = tf.transparent_mask([[0, 10], [0, 90], [0, 90]], (0, 100))
    np.testing.assert_array_equal(f(0, idx), ref)
    assert ref.tolist() == [True, False, False]
    np.testing.assert_array_equal(f(1, idx), [False, False, False])
    assert transparency_filter(tf, object()) is None


# -- presets honour their window; points, opacity curves, JSON (issue: the first five minutes) -----


@pytest.mark.parametrize("name", [n for n in TransferFunction.names() if n != "diverging"])
@pytest.mark.parametrize("opacity", [None, "ramp", "flat", "step"])
def test_every_preset_is_exactly_transparent_at_and_below_its_window(name, opacity):
    tf = TransferFunction.preset(name, value_range=(100.0, 300.0), opacity=opacity)
    below = np.array([-1e30, -5.0, 0.0, 99.0, 99.999, 100.0, np.nan])
    np.testing.assert_array_equal(tf.lookup(below)[:, 3], 0.0)
    # and the same through the renderer's texture: entry 0 (what GL_LINEAR/CLAMP gives below lo)
    assert tf.table[0, 3] == 0.0
    # something inside the window is visible (else the preset would show nothing)
    assert tf.lookup(np.linspace(100, 300, 101))[:, 3].max() > 0.1
    # the empty-space test agrees: a brick entirely below the window is skipped
    assert tf.transparent_mask([[0.0, 100.0]])[0]


def test_opacity_curves_against_their_formulas():
    x = (np.arange(256) + 0.5) / 256
    tf = TransferFunction.preset("grey", value_range=(0, 1), opacity="flat")
    np.testing.assert_allclose(tf.table[1:, 3], 0.15)
    tf = TransferFunction.preset("grey", value_range=(0, 1), opacity="step")
    np.testing.assert_array_equal(tf.table[:, 3], np.where(x >= 0.5, 1.0, 0.0))
    with pytest.raises(ParameterError, match="opacity"):
        TransferFunction.preset("grey", opacity="wobbly")


def test_diverging_is_transparent_around_the_centre_and_visible_at_both_ends():
    tf = TransferFunction.preset("diverging", value_range=(-10.0, 10.0))
    rgba = tf.lookup(np.array([-50.0, -10.0, -1.5, 0.0, 1.5, 10.0, 50.0]))
    np.testing.assert_array_equal(rgba[2:5, 3], 0.0)  # |v| < 20 % of the half-width
    assert rgba[0, 3] > 0.5 and rgba[-1, 3] > 0.5
    assert rgba[0, 2] > rgba[0, 0] and rgba[-1, 0] > rgba[-1, 2]  # blue below, red above
    assert tf.transparent_mask([[-1.5, 1.5]])[0] and not tf.transparent_mask([[-1.5, 3.0]])[0]


def test_value_points_hold_exactly_outside_and_interpolate_inside():
    tf = TransferFunction.parse_points("0:0,0,0,0; 500:1,0.5,0.25,0.2; 1500:1,1,1,1")
    assert tf.value_range == (0.0, 1500.0) and tf.name == "points"
    np.testing.assert_array_equal(tf.lookup([-100.0, 0.0])[:, 3], 0.0)
    np.testing.assert_allclose(tf.lookup([2000.0])[0], [1, 1, 1, 1])
    # between texel centres the curve is np.interp of the points (to half a texel)
    v = np.array([250.0, 500.0, 1000.0])
    ref = np.interp(v, [0, 500, 1500], [0, 0.2, 1.0])
    np.testing.assert_allclose(tf.lookup(v)[:, 3], ref, atol=1.0 / 256)
    for bad in ("0:0,0,0", "x:0,0,0,0", "5:0,0,0,0;1:1,1,1,1", "0:0,0,0,2"):
        with pytest.raises(ParameterError):
            TransferFunction.parse_points(bad)


@pytest.mark.parametrize("name", ["viridis", "bone", "diverging"])
def test_save_then_load_round_trips_exactly(tmp_path, name):
    import json

    tf = TransferFunction.preset(name, value_range=(-3.5, 7.25))
    p = tf.save(tmp_path / "tf.json")
    doc = json.loads(p.read_text())  # a plain JSON document another tool can read
    assert doc["format"] == "clipvol-transfer-function" and doc["value_range"] == [-3.5, 7.25]
    back = TransferFunction.load(p)
    np.testing.assert_array_equal(back.table, tf.table)
    assert back.value_range == tf.value_range and back.name == tf.name
    # a hand-written file in data values
    (tmp_path / "hand.json").write_text(json.dumps(
        {"format": "clipvol-transfer-function", "value_points": [[10, 0, 0, 0, 0], [20, 1, 1, 1, 1]]}))
    hand = TransferFunction.load(tmp_path / "hand.json")
    assert hand.value_range == (10.0, 20.0)
    np.testing.assert_allclose(hand.lookup([5.0, 20.0])[:, 3], [0.0, 1.0])


def test_load_errors_name_the_file(tmp_path):
    with pytest.raises(ParameterError, match="nope.json"):
        TransferFunction.load(tmp_path / "nope.json")
    (tmp_path / "bad.json").write_text("{not json")
    with pytest.raises(ParameterError, match="bad.json"):
        TransferFunction.load(tmp_path / "bad.json")
    (tmp_path / "pts.json").write_text('{"points": [[0.5, 1, 1]]}')
    with pytest.raises(ParameterError, match="pts.json"):
        TransferFunction.load(tmp_path / "pts.json")
    with pytest.raises(ParameterError, match="folder"):
        TransferFunction.preset("grey").save(tmp_path / "missing" / "tf.json")


def test_footprint_ranges_span_each_brick_and_its_neighbours_inside_the_grid():
    """Against a plain loop over the 3x3x3 neighbourhood (clipped to the grid) of each brick."""
    from clipvol.scene.transfer import footprint_ranges

    rng = np.random.default_rng(0)
    grid = (7, 5, 9)
    tab = np.sort(rng.random(grid + (2,)), axis=-1)
    tab[3, 2, 4, 0] = np.nan  # an unknown bound propagates to every brick beside it

    def ranges(level, idx):
        return tab[idx[:, 0], idx[:, 1], idx[:, 2]]

    idx = np.stack([rng.integers(0, n, 300) for n in grid], axis=1)
    got = footprint_ranges(ranges, grid, 0, idx)
    for (z, y, x), (lo, hi) in zip(idx, got):
        nb = tab[max(z - 1, 0):z + 2, max(y - 1, 0):y + 2, max(x - 1, 0):x + 2].reshape(-1, 2)
        want_lo = np.nan if np.isnan(nb[:, 0]).any() else nb[:, 0].min()
        np.testing.assert_equal([lo, hi], [want_lo, nb[:, 1].max()])
    assert footprint_ranges(lambda level, idx: None, grid, 0, idx) is None
