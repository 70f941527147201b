"""``clipvol demo --quick``: bricks the demo volume, writes the GIFs, the CSVs and the report."""

from __future__ import annotations

import csv

import numpy as np
import pytest

pytest.importorskip("moderngl")


def test_demo_quick(tmp_path, capsys):
    import zarr
    from PIL import Image

    from clipvol.tools.cli import main
    from clipvol.tools.cmd_demo import demo_volume

    out = tmp_path / "demo"
    try:
        rc = main(["demo", "--quick", "--out", str(out)])
    except Exception as e:  # pragma: no cover
        if "EGL" in str(e) or "OpenGL" in str(e):
            pytest.skip(f"no offscreen GL context: {e}")
        raise
    assert rc == 0
    text = capsys.readouterr().out
    store = out / "fractal-ball.zarr"
    for p in (store / "zarr.json", out / "orbit.gif", out / "orbit.gif.csv", out / "zoom.gif", out / "zoom.gif.csv",
              out / "report" / "report.md", out / "report" / "report.csv", out / "report" / "error_vs_time.png"):
        assert p.is_file(), p
        assert str(p.parent if p.name == "zarr.json" else p) in text or p.suffix in (".csv", ".png")
    # the store holds the demo volume exactly (independent read with zarr)
    level0 = zarr.open_group(str(store), mode="r")["0"][...]
    np.testing.assert_array_equal(level0, demo_volume(40))
    # one GIF frame and one CSV row per orbit frame; the orbit is converged and not blank
    with Image.open(out / "orbit.gif") as gif:
        assert gif.n_frames == 4
        first = np.asarray(gif.convert("RGB"))
    assert first.max() > 0
    with open(out / "orbit.gif.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert [int(r["frame"]) for r in rows] == [0, 1, 2, 3]
    assert all(r["converged"] == "1" for r in rows)
    # re-running reuses the finished store
    assert main(["demo", "--quick", "--out", str(out), "--no-report"]) == 0
    assert "reusing" in capsys.readouterr().out


def test_offscreen_path_to_png_dir_and_ctrl_c(tmp_path):
    """--offscreen writes one PNG and one CSV row per frame; Ctrl-C leaves closed files and no threads."""
    import threading

    from PIL import Image

    from clipvol.loaders.procedural import ProceduralLoader
    from clipvol.tools.cli import main
    from clipvol.app.flythrough import CSV_BASE_COLUMNS, render_path

    out = tmp_path / "frames"
    rc = main(["view", "procedural:fractal?size=32", "--brick", "16", "--offscreen", "--path", "fly", "--frames", "3",
               "--size", "40x30", "--out", str(out)])
    assert rc == 0
    pngs = sorted(out.glob("frame_*.png"))
    assert [p.name for p in pngs] == ["frame_0000.png", "frame_0001.png", "frame_0002.png"]
    assert np.asarray(Image.open(pngs[0])).shape == (30, 40, 4)
    with open(out / "frames.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == 3
    assert list(rows[0])[: len(CSV_BASE_COLUMNS)] == list(CSV_BASE_COLUMNS)
    assert {"bricks_L0", "bricks_L1"} <= set(rows[0])
    # per-frame loads add up to the running total; bricks per level add up to the total drawn
    total = 0
    for r in rows:
        total += int(r["bytes_loaded"])
        assert total == int(r["bytes_loaded_total"])
        assert sum(int(v) for k, v in r.items() if k.startswith("bricks_L")) == int(r["bricks_drawn"])

    before = {t.ident for t in threading.enumerate()}
    calls = []

    def interrupt(row):
        calls.append(row)
        if len(calls) == 2:
            raise KeyboardInterrupt

    gif = tmp_path / "anim.gif"
    with pytest.raises(KeyboardInterrupt):
        render_path(ProceduralLoader("procedural:fractal?size=32", brick=16), gif, frames=10, size=(32, 32),
                    progress=interrupt)
    with Image.open(gif) as g:
        assert g.n_frames == 2  # the frames rendered before Ctrl-C
    with open(gif.with_name(gif.name + ".csv"), newline="") as fh:
        assert len(list(csv.DictReader(fh))) == 2
    leftover = [t for t in threading.enumerate() if t.ident not in before and t.name.startswith("clipvol")]
    assert leftover == []
