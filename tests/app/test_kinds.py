"""Data kinds (clipvol.app.kinds): a new kind is one object and one registry line, and the
commands and ``clipvol.show`` hand its sources to it; volumes and points keep their own paths."""

from __future__ import annotations

import json

import numpy as np
import pytest
from PIL import Image

import clipvol
from clipvol.app.kinds import KINDS, DataKind, kind_of, open_data
from clipvol.errors import InputFormatError, ParameterError
from clipvol.tools.cli import main

MARKER = "MARKER.kind"


class _MarkerCommands:
    """The fake kind's command-line hooks: info prints the marker's text, render paints the
    marker's grey level into a PNG of the requested size."""

    def __init__(self):
        self.calls = []

    def info(self, args) -> int:
        self.calls.append(("info", args.store))
        print(f"marker store says {(_marker(args.store)).read_text().strip()}")
        return 0

    def render(self, args) -> int:
        self.calls.append(("render", args.source))
        grey = int(_marker(args.source).read_text())
        w, h = args.size
        Image.fromarray(np.full((h, w, 4), grey, np.uint8), "RGBA").save(args.out)
        return 0


def _marker(folder):
    from pathlib import Path

    return Path(folder) / MARKER


class MarkerKind:
    """A trivial data kind: a folder holding a marker file. No loader, no session, no view."""

    name = "marker"

    def __init__(self):
        self.cli = _MarkerCommands()

    def claims(self, source) -> bool:
        try:
            return _marker(source).is_file()
        except TypeError:
            return False

    def open(self, source, **kwargs):
        return _marker(source).read_text()

    def session(self, source, ctx, **kwargs):
        raise NotImplementedError

    show = None


@pytest.fixture
def marker_store(tmp_path):
    folder = tmp_path / "thing.marker"
    folder.mkdir()
    (folder / MARKER).write_text("77\n")
    return folder


def test_a_new_kind_is_one_registry_line(marker_store, tmp_path, monkeypatch, capsys):
    # without the registry line the folder is nothing clipvol knows: the volume opener says so
    assert main(["info", str(marker_store)]) == 2
    assert "expected a zarr" in capsys.readouterr().err
    kind = MarkerKind()
    monkeypatch.setitem(KINDS, "marker", kind)
    assert kind_of(str(marker_store)) is kind
    assert main(["info", str(marker_store)]) == 0
    assert "marker store says 77" in capsys.readouterr().out
    png = tmp_path / "m.png"
    assert main(["render", str(marker_store), "--out", str(png), "--size", "24x16"]) == 0
    img = np.asarray(Image.open(png))
    assert img.shape == (16, 24, 4) and np.all(img == 77)  # the grey level written in the marker file
    assert kind.cli.calls == [("info", str(marker_store)), ("render", str(marker_store))]
    # a command the kind has no hook for is refused in one line naming the source and the kind
    assert main(["check", str(marker_store)]) == 2
    err = capsys.readouterr().err
    assert str(marker_store) in err and "marker" in err and "check" in err
    # clipvol.show: the kind has no notebook view
    with pytest.raises(InputFormatError, match="marker"):
        clipvol.show(str(marker_store))
    # the default kind still takes everything else
    assert kind_of(np.zeros((4, 4, 4), np.float32)) is KINDS["volume"]
    assert kind_of("procedural:fractal?size=32") is KINDS["volume"]


def test_point_and_volume_stores_go_to_their_kinds(tmp_path, rng, capsys):
    pts = rng.random((500, 4))
    np.save(tmp_path / "p.npy", pts)
    store = tmp_path / "p.zarr"
    assert main(["brick-points", str(tmp_path / "p.npy"), str(store), "--max-points", "16", "--quiet"]) == 0
    assert kind_of(str(store)) is KINDS["points"] and kind_of(store) is KINDS["points"]
    kind, loader = open_data(str(store))
    assert kind.name == "points"
    assert loader.meta.num_points == 500  # the input's row count
    lo, hi = loader.world_box()
    assert np.all(np.asarray(lo) <= pts[:, :3].min(axis=0) + 1e-9) and np.all(np.asarray(hi) >= pts[:, :3].max(axis=0) - 1e-9)
    with pytest.raises(ParameterError, match="brick"):
        open_data(str(store), brick=32)  # a point store's nodes were fixed when it was built
    assert all(isinstance(k, DataKind) for k in KINDS.values())
    # the volume opener refuses another kind's store, naming it, instead of misreading it
    with pytest.raises(InputFormatError, match="points store"):
        clipvol.open_store(store)
    with pytest.raises(InputFormatError, match="points"):
        clipvol.show(str(store))
    vol = tmp_path / "v.npy"
    np.save(vol, np.zeros((8, 8, 8), np.float32))
    kind, loader = open_data(str(vol))
    assert kind.name == "volume" and loader.pyramid.levels[0].shape == (8, 8, 8)
    # a volume store written by clipvol brick carries no clipvol.kind: the default kind takes it
    assert main(["brick", str(vol), str(tmp_path / "v.zarr"), "--quiet"]) == 0
    attrs = json.loads((tmp_path / "v.zarr" / "zarr.json").read_text())["attributes"]["clipvol"]
    assert "kind" not in attrs and kind_of(str(tmp_path / "v.zarr")) is KINDS["volume"]
