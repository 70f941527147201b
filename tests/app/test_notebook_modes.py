"""clipvol.show with the render modes: an iso-surface from the start, the projections from the
widget's menu, and a mode that lacks its value reported in the widget."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("moderngl")
pytest.importorskip("anywidget")


def _sphere(n=32):
    z, y, x = np.mgrid[0:n, 0:n, 0:n].astype(np.float64)
    c = (n - 1) / 2.0
    return (20.0 - np.sqrt((x - c) ** 2 + (y - c) ** 2 + (z - c) ** 2)).astype(np.float32)  # >= 10 within radius 10


def test_iso_view_then_projections_from_the_menu():
    import clipvol

    v = clipvol.show(_sphere(), size=(48, 48), mode="iso", iso_value=10.0, tf="grey", brick=16, threads=2)
    try:
        img = v.snapshot()
        a = img[..., 3]
        assert ((a == 0) | (a == 255)).all() and (a == 255).sum() > 50  # an opaque surface, nothing else
        v.widget.mode = "average"  # what the menu sets
        assert v.session.params.mode == "average"
        avg = v.snapshot()[..., 3]
        assert (avg > 0).sum() > (a == 255).sum()  # every ray through the box, not only the sphere's
        v.widget.mode = "minip"
        assert v.session.params.mode == "minip"
    finally:
        v.close()


def test_iso_without_a_value_shows_the_error_in_the_widget():
    import clipvol

    v = clipvol.show(_sphere(), size=(32, 32), mode="mip", tf="grey", brick=16, threads=2)
    try:
        v.widget.mode = "iso"
        assert "iso_value" in v.widget.error
        assert v.session.params.mode == "mip"
    finally:
        v.close()
