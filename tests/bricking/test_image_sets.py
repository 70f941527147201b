"""A 2-channel stack and a 3-step time series bricked by ``clipvol brick`` are each one OME-Zarr 0.5
image with a ``c`` / ``t`` axis: zarr-python, ome-zarr-py, ome-zarr-models, tensorstore and the
napari reader open the root as 4-D with the values of the numpy source; clipvol's loader (local and
over HTTP), ``info`` and ``check`` take it with per-member integrity; a set of the older layout
(one store per member) still opens.

References: the numpy arrays the stacks were saved from, and the other libraries' own readers.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
import zarr

from clipvol.paging.open import open_store
from clipvol.tools.cli import main

from optional import REMOTE_HTTP, needs


def _stacks():
    z, y, x = np.mgrid[0:20, 0:18, 0:22].astype(np.float32)
    chans = np.stack([np.exp(-((z - 8) ** 2 + (y - 7) ** 2 + (x - 6) ** 2) / 20),
                      3 * np.exp(-((z - 12) ** 2 + (y - 9) ** 2 + (x - 14) ** 2) / 15)]).astype(np.float32)
    rng = np.random.default_rng(5)
    steps = rng.integers(0, 4000, (3, 20, 18, 22)).astype(np.uint16)
    steps[1, :9] = 0  # empty bricks (absent chunks) in one step only
    steps[2] //= 2  # a dimmer step: its own range is narrower than the series'
    return chans, steps


@pytest.fixture(scope="module")
def sets(tmp_path_factory):
    d = tmp_path_factory.mktemp("sets")
    chans, steps = _stacks()
    np.save(d / "chans.npy", chans)
    np.save(d / "steps.npy", steps)
    assert main(["brick", str(d / "chans.npy"), str(d / "chans.zarr"), "--brick", "8", "--quiet"]) == 0
    assert main(["brick", str(d / "steps.npy"), str(d / "steps.zarr"), "--brick", "8", "--axes", "tzyx",
                 "--quiet"]) == 0
    return {"c": (d / "chans.zarr", chans), "t": (d / "steps.zarr", steps)}


AXES = ["c", "t"]


def _assemble(loader) -> np.ndarray:
    """Level 0 of ``loader`` from its bricks (the valid part of each)."""
    pyr = loader.pyramid
    out = np.zeros(pyr.levels[0].shape, pyr.dtype)
    for idx in np.ndindex(pyr.grid(0)):
        s, e = pyr.brick_voxel_box(0, idx)
        out[tuple(slice(a, b) for a, b in zip(s, e))] = \
            loader.read_brick(0, idx)[tuple(slice(0, b - a) for a, b in zip(s, e))]
    return out


@pytest.mark.parametrize("axis", AXES)
def test_zarr_python_reads_the_root_as_one_4d_image(sets, axis):
    root, src = sets[axis]
    g = zarr.open_group(str(root), mode="r")
    ms = g.attrs["ome"]["multiscales"][0]
    assert [a["name"] for a in ms["axes"]] == [axis, "z", "y", "x"]
    assert ms["axes"][0]["type"] == ("channel" if axis == "c" else "time")
    for L, ds in enumerate(ms["datasets"]):
        a = g[ds["path"]]
        assert a.shape[0] == src.shape[0] and a.chunks[0] == 1
        assert tuple(a.metadata.dimension_names) == (axis, "z", "y", "x")
        assert ds["coordinateTransformations"][0]["scale"][:2] == [1.0, 2.0 ** L]
    np.testing.assert_array_equal(g["0"][...], src)


@needs("ome_zarr")
@pytest.mark.parametrize("axis", AXES)
def test_ome_zarr_py_finds_one_4d_image(sets, axis):
    from ome_zarr.io import parse_url
    from ome_zarr.reader import Reader

    root, src = sets[axis]
    nodes = list(Reader(parse_url(str(root)))())
    assert len(nodes) == 1
    node = nodes[0]
    assert [a["name"] for a in node.metadata["axes"]] == [axis, "z", "y", "x"]
    assert len(node.data) == 3 and node.data[0].shape == src.shape
    np.testing.assert_array_equal(np.asarray(node.data[0]), src)
    if axis == "c":  # omero: one window per channel, each that channel's own range
        want = [[float(src[k].min()), float(src[k].max())] for k in range(2)]
        np.testing.assert_allclose(node.metadata["contrast_limits"], want, rtol=1e-6)
    else:  # one window over every step (brightness comparable across t)
        np.testing.assert_allclose(node.metadata["contrast_limits"], [[src.min(), src.max()]])


@needs("ome_zarr_models")
@pytest.mark.parametrize("axis", AXES)
def test_ome_zarr_models_validates_the_root_as_an_image(sets, axis):
    from ome_zarr_models import open_ome_zarr
    from ome_zarr_models.v05.image import Image

    root, _ = sets[axis]
    model = open_ome_zarr(zarr.open_group(str(root), mode="r"))
    assert isinstance(model, Image)
    assert [a.name for a in model.ome_attributes.multiscales[0].axes] == [axis, "z", "y", "x"]


@needs("tensorstore")
@pytest.mark.parametrize("axis", AXES)
def test_tensorstore_reads_every_level(sets, axis):
    import tensorstore as ts

    root, src = sets[axis]
    a = ts.open({"driver": "zarr3", "kvstore": {"driver": "file", "path": str(root / "0")}}).result()
    assert a.shape == src.shape and tuple(a.domain.labels) == (axis, "z", "y", "x")
    np.testing.assert_array_equal(a.read().result(), src)
    coarse = ts.open({"driver": "zarr3", "kvstore": {"driver": "file", "path": str(root / "1")}}).result()
    assert coarse.shape == (src.shape[0], 10, 9, 11)


@needs("dask")
@pytest.mark.parametrize("axis", AXES)
def test_napari_reader_gives_the_4d_image(sets, axis):
    from clipvol.napari_plugin import napari_get_reader

    root, src = sets[axis]
    reader = napari_get_reader(str(root))
    assert reader is not None
    [(levels, kwargs, kind)] = reader(str(root))
    assert kind == "image" and levels[0].shape == src.shape
    np.testing.assert_array_equal(np.asarray(levels[0]), src)
    if axis == "c":
        assert kwargs["channel_axis"] == 0 and len(kwargs["name"]) == 2
        np.testing.assert_allclose(kwargs["contrast_limits"][1], (src[1].min(), src[1].max()), rtol=1e-6)
    else:
        assert kwargs["axis_labels"] == ("t", "z", "y", "x") and len(kwargs["scale"]) == 4
        assert kwargs["contrast_limits"] == (src.min(), src.max())


@pytest.mark.parametrize("axis", AXES)
def test_clipvol_loader_reads_each_member_verified(sets, axis):
    root, src = sets[axis]
    for k in range(src.shape[0]):
        ld = open_store(root, **{axis: k})
        assert ld.axes == (axis,) and ld.lead_shape == (src.shape[0],) and ld.verified
        assert ld.pyramid.value_range == (float(src[k].min()), float(src[k].max()))  # statistics per member
        np.testing.assert_array_equal(_assemble(ld), src[k])
    with pytest.raises(Exception, match=f"0..{src.shape[0] - 1}"):
        open_store(root, **{axis: src.shape[0]})
    other = "t" if axis == "c" else "c"
    with pytest.raises(Exception, match=f"no '{other}' axis"):
        open_store(root, **{other: 1})


def test_a_member_group_is_refused_naming_the_root(sets, capsys):
    root, _ = sets["c"]
    assert main(["info", str(root / "clipvol_members" / "c" / "1")]) == 2
    err = capsys.readouterr().err
    assert "image set" in err and "c=1" in err


@pytest.mark.parametrize("axis", AXES)
def test_info_and_check_of_the_root(sets, axis, capsys):
    root, src = sets[axis]
    assert main(["info", str(root)]) == 0
    out = capsys.readouterr().out
    assert out.count("complete   yes") == src.shape[0] and f"--- {axis} = {src.shape[0] - 1}" in out
    assert out.count("verified: manifest") == src.shape[0]
    assert main(["check", str(root), "--all", "--quiet"]) == 0
    assert capsys.readouterr().out.count(": ok (") == src.shape[0]


def test_check_names_the_member_of_a_damaged_chunk(sets, tmp_path, capsys):
    import shutil

    root = tmp_path / "copy.zarr"
    shutil.copytree(sets["c"][0], root)
    chunk = root / "0" / "c" / "1" / "1" / "1" / "1"  # channel 1, brick (1, 1, 1)
    raw = bytearray(chunk.read_bytes())
    raw[len(raw) // 2] ^= 0xFF
    chunk.write_bytes(bytes(raw))
    assert main(["check", str(root), "--all", "--quiet"]) == 1
    captured = capsys.readouterr()
    assert "(c = 0): ok" in captured.out
    assert "(c = 1)" in captured.err and "(1, 1, 1)" in captured.err


@pytest.mark.slow
@REMOTE_HTTP
def test_the_root_over_http(sets, capsys):
    from remote_servers import serve_directory

    root, src = sets["t"]
    with serve_directory(root.parent) as (url, _):
        ld = open_store(f"{url}/{root.name}", t=2)
        assert ld.verified and ld.axes == ("t",)
        np.testing.assert_array_equal(_assemble(ld), src[2])
        ld.close()
        assert main(["info", f"{url}/{root.name}"]) == 0
        assert capsys.readouterr().out.count("complete   yes") == 3
        assert main(["check", f"{url}/{root.name}"]) == 0


def test_a_set_of_the_older_layout_still_opens(tmp_path):
    """One complete store per member under an OME-Zarr collection root, as ``clipvol brick`` wrote
    a 4-D input before the 4-D layout (version 1 of the set attributes)."""
    from clipvol.bricking.pipeline import brick_volume

    chans, _ = _stacks()
    root = tmp_path / "old.zarr"
    for k in range(2):
        brick_volume(chans[k], root / "c" / str(k), brick=8, progress=False, summary=False)
    (root / "OME").mkdir()
    (root / "OME" / "zarr.json").write_text(json.dumps({"zarr_format": 3, "node_type": "group", "attributes": {
        "ome": {"version": "0.5", "series": ["c/0", "c/1"]}}}))
    (root / "zarr.json").write_text(json.dumps({"zarr_format": 3, "node_type": "group", "attributes": {
        "ome": {"version": "0.5", "bioformats2raw.layout": 3}, "clipvol_channels": {"version": 1, "channels": 2}}}))
    ld = open_store(root, c=1)
    assert ld.axes == ("c",) and ld.lead_shape == (2,)
    np.testing.assert_array_equal(_assemble(ld), chans[1])
    assert main(["check", str(root), "--quiet"]) == 0


def test_an_interrupted_set_build_resumes(tmp_path, monkeypatch):
    """A build stopped after the first member is adopted resumes: the second member is built, and
    the result reads as the source."""
    from clipvol.bricking import channels

    chans, _ = _stacks()
    calls = {"n": 0}
    real = channels._adopt

    def stop_after_first(root, member, axis, k, n):
        real(root, member, axis, k, n)
        calls["n"] += 1
        if k == 0:
            raise KeyboardInterrupt

    monkeypatch.setattr(channels, "_adopt", stop_after_first)
    with pytest.raises(KeyboardInterrupt):
        channels.brick_set(chans, tmp_path / "r.zarr", brick=8, progress=False)
    assert channels.image_set(tmp_path / "r.zarr") is None  # not a set until the last write
    channels.brick_set(chans, tmp_path / "r.zarr", brick=8, progress=False)
    assert calls["n"] == 2  # member 0 was not adopted again
    np.testing.assert_array_equal(zarr.open_array(str(tmp_path / "r.zarr" / "0"), mode="r")[...], chans)


@pytest.mark.slow
def test_summarize_of_a_root_builds_every_members_tables(sets, tmp_path):
    """``clipvol brick --no-summary`` then ``clipvol summarize ROOT``: each member's tables, read
    from the 4-D arrays, equal those the brick built from the member's own 3-D store."""
    root, src = sets["c"]
    np.save(tmp_path / "c.npy", src)
    late = tmp_path / "late.zarr"
    assert main(["brick", str(tmp_path / "c.npy"), str(late), "--brick", "8", "--quiet", "--no-summary"]) == 0
    assert not (late / "clipvol_members" / "c" / "1" / "clipvol_summary").exists()
    assert main(["summarize", str(late), "--quiet"]) == 0
    for k in range(2):
        a = zarr.open_group(str(root / "clipvol_members" / "c" / str(k) / "clipvol_summary"), mode="r")
        b = zarr.open_group(str(late / "clipvol_members" / "c" / str(k) / "clipvol_summary"), mode="r")
        assert b.attrs["complete"] and sorted(a.group_keys()) == sorted(b.group_keys())
        for L in a.group_keys():
            for name in a[L].array_keys():
                np.testing.assert_array_equal(a[L][name][...], b[L][name][...], err_msg=f"c={k} {L}/{name}")
