"""LabelColors: the id -> RGBA table of label overlays, its spellings (CLI, JSON, CSV) and its errors."""

from __future__ import annotations

import numpy as np
import pytest

from clipvol.errors import ParameterError
from clipvol.scene.label_colors import LabelColors, palette_color


def test_given_default_hidden_and_background_colours():
    c = LabelColors({3: (1.0, 0.0, 0.0, 0.5), 4: 0.8, 7: None}, default_opacity=0.25)
    t = c.table([0, 3, 4, 7, 9])
    np.testing.assert_allclose(t[0], [0, 0, 0, 0])  # background
    np.testing.assert_allclose(t[1], [1, 0, 0, 0.5])
    np.testing.assert_allclose(t[2], [*palette_color(4), 0.8])
    assert t[3, 3] == 0.0 and c.hidden == {7}
    np.testing.assert_allclose(t[4], [*palette_color(9), 0.25])
    # the default palette gives neighbouring ids clearly different colours
    cols = np.array([palette_color(i) for i in range(1, 13)])
    d = np.linalg.norm(cols[:, None] - cols[None], axis=-1)
    assert d[~np.eye(12, dtype=bool)].min() > 0.05


def test_parse_spellings(tmp_path):
    c = LabelColors.parse("3=#ff0000:0.5, 7=hide, 12=0.8")
    assert c.rgba(3) == pytest.approx((1.0, 0.0, 0.0, 0.5))
    assert c.rgba(7)[3] == 0.0 and c.rgba(12)[3] == pytest.approx(0.8)
    (tmp_path / "c.json").write_text('{"3": "#00ff00", "4": [0, 0, 1, 0.25], "5": "hide"}')
    j = LabelColors.parse(str(tmp_path / "c.json"), default_opacity=0.4)
    assert j.rgba(3) == pytest.approx((0.0, 1.0, 0.0, 0.4)) and j.rgba(4) == pytest.approx((0, 0, 1, 0.25))
    assert j.rgba(5)[3] == 0.0
    (tmp_path / "c.csv").write_text("id,r,g,b,a\n3,0,0,1,0.5\n8,1,1,0,1\n")
    v = LabelColors.parse(str(tmp_path / "c.csv"))
    assert v.rgba(8) == pytest.approx((1, 1, 0, 1)) and v.rgba(3) == pytest.approx((0, 0, 1, 0.5))


@pytest.mark.parametrize("spec,match", [("3", "ID="), ("x=#ff0000", "integer label id"), ("3=#ff00", "#RRGGBB"),
                                        ("3=#ff0000:2", "opacity"), ("3=1.5", r"\[0, 1\]")])
def test_bad_specs_name_the_part(spec, match):
    with pytest.raises(ParameterError, match=match):
        LabelColors.parse(spec)


def test_bad_files(tmp_path):
    with pytest.raises(ParameterError, match="no such"):
        LabelColors.parse(str(tmp_path / "missing.json"))
    (tmp_path / "b.csv").write_text("3,1,0\n")
    with pytest.raises(ParameterError, match="b.csv.*id,r,g,b"):
        LabelColors.parse(str(tmp_path / "b.csv"))
    (tmp_path / "n.csv").write_text("3,1,0,x\n")
    with pytest.raises(ParameterError, match="n.csv"):
        LabelColors.parse(str(tmp_path / "n.csv"))
