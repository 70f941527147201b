"""Procedural generators: every level equals the mean filter of level 0; URL errors are clear."""

from __future__ import annotations

import numpy as np
import pytest

from clipvol.errors import ParameterError
from clipvol.bricking.generators import parse_procedural
from clipvol.bricking.pyramid import downsample


@pytest.mark.parametrize("url", ["procedural:fractal?size=13x9x17&seed=3", "procedural:sparse?size=21x18x11&seed=1&count=5"])
def test_levels_equal_downsampled_level0(url):
    gen = parse_procedural(url)
    ref = gen.region(0, (0, 0, 0), gen.shape).astype(np.float64)
    for level in range(1, 5):
        ref = downsample(ref, "mean")
        shp = gen.level_shape(level)
        assert shp == ref.shape
        got = gen.region(level, (0, 0, 0), shp)
        np.testing.assert_allclose(got, ref, atol=2e-6)


def test_region_is_a_window_of_the_whole():
    gen = parse_procedural("procedural:fractal?size=19&seed=2")
    whole = gen.region(1, (0, 0, 0), gen.level_shape(1))
    part = gen.region(1, (2, 3, 1), (9, 10, 7))
    np.testing.assert_allclose(part, whole[2:9, 3:10, 1:7], atol=1e-6)


def test_values_in_unit_range_and_sparse_mostly_empty():
    f = parse_procedural("procedural:fractal?size=24")
    v = f.region(0, (0, 0, 0), f.shape)
    assert v.dtype == np.float32 and v.min() >= 0 and v.max() <= 1
    s = parse_procedural("procedural:sparse?size=64&count=4")
    w = s.region(0, (0, 0, 0), s.shape)
    assert (w == 0).mean() > 0.9


@pytest.mark.parametrize(
    "url,needle",
    [
        ("fractal?size=8", "procedural:fractal"),
        ("procedural:nope?size=8", "nope"),
        ("procedural:fractal?size=abc", "size"),
        ("procedural:fractal?size=1x2", "size"),
        ("procedural:fractal?seed=x", "seed"),
        ("procedural:fractal?count=3", "count"),
        ("procedural:sparse?bogus=1", "bogus"),
        ("procedural:fractal?size=0", "size"),
    ],
)
def test_url_errors_name_the_part(url, needle):
    with pytest.raises(ParameterError, match=needle):
        parse_procedural(url)
