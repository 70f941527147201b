"""`clipvol brick` never destroys what it does not write, never marks a store complete that mixes two
inputs, and turns the machine's refusals (disk full, read-only file system) into one line.

References: the files on disk (existence, bytes) and the store's own ``zarr.json`` read with json.
"""

from __future__ import annotations

import errno
import json
import os

import numpy as np
import pytest

import clipvol.bricking.pipeline as brick_mod
from clipvol.errors import OutputExistsError, OutputWriteError, ParameterError, SourceChangedError
from clipvol.tools.cli import main
from build_hooks import after_each_brick
from test_cli_brick import _one_error_line  # one line, no traceback, naming what is wrong


def _complete(store) -> bool:
    return bool(json.loads((store / "zarr.json").read_text())["attributes"]["clipvol"].get("complete"))


@pytest.fixture
def vol(tmp_path, rng):
    v = rng.integers(0, 1000, size=(24, 16, 16)).astype(np.uint16)
    np.save(tmp_path / "v.npy", v)
    np.save(tmp_path / "lab.npy", (v % 3).astype(np.uint8))
    return tmp_path


@pytest.mark.parametrize("name", ["..", "", "a/b", *(pytest.param(n, marks=pytest.mark.slow) for n in (".", "../x", ".hidden", "/abs"))])
def test_label_names_that_are_not_one_plain_folder_are_refused_before_any_work(vol, capsys, name):
    out = vol / "o.zarr"
    assert main(["brick", str(vol / "v.npy"), str(out), "--quiet", "--brick", "8"]) == 0
    before = sorted(p.relative_to(out) for p in out.rglob("*"))
    rc = main(["brick", str(vol / "v.npy"), str(out), "--quiet", "--brick", "8", "--overwrite",
               "--labels", f"{vol / 'lab.npy'}:{name}"])
    assert rc == 2
    _one_error_line(capsys, "--labels", "labels name")
    # the existing store is untouched: the reported bug deleted it (labels/.. is the image itself)
    assert sorted(p.relative_to(out) for p in out.rglob("*")) == before and _complete(out)


@pytest.mark.parametrize("name", ["..", ".", "", "a/b"])
def test_brick_labels_refuses_a_path_as_name(vol, name):
    from clipvol.bricking.labels import brick_labels

    assert main(["brick", str(vol / "v.npy"), str(vol / "o.zarr"), "--quiet", "--brick", "8"]) == 0
    with pytest.raises(ParameterError, match="labels name"):
        brick_labels(vol / "o.zarr", vol / "lab.npy", name, overwrite=True, progress=False)
    assert _complete(vol / "o.zarr")


def test_labels_with_overwrite_build_both(vol):
    from clipvol.bricking.labels import label_names

    out = vol / "o.zarr"
    for _ in range(2):  # the second run replaces the complete store and its labels
        assert main(["brick", str(vol / "v.npy"), str(out), "--quiet", "--brick", "8", "--overwrite",
                     "--labels", f"{vol / 'lab.npy'}:seg"]) == 0
    assert label_names(out) == ["seg"] and _complete(out)


def test_overwrite_refuses_an_output_that_holds_the_input(vol, capsys):
    out = vol / "o.zarr"
    assert main(["brick", str(vol / "v.npy"), str(out), "--quiet", "--brick", "8"]) == 0
    inner = out / "v.npy"
    inner.write_bytes((vol / "v.npy").read_bytes())
    assert main(["brick", str(inner), str(out), "--quiet", "--brick", "8", "--overwrite"]) == 2
    _one_error_line(capsys, "holds the input", "v.npy")
    assert inner.read_bytes() == (vol / "v.npy").read_bytes()


def test_source_overwritten_during_the_build_leaves_the_store_incomplete(vol, capsys, monkeypatch):
    src = vol / "v.npy"
    size = src.stat().st_size
    done = []

    def rewrite(level, index):  # after the first brick: other voxels, in place (same file, same size)
        if not done:
            done.append(1)
            with open(src, "r+b") as f:
                f.seek(size - 4096)
                f.write(np.arange(2048, dtype=np.uint16).tobytes())

    after_each_brick(monkeypatch, rewrite)
    out = vol / "o.zarr"
    with pytest.raises(SourceChangedError, match="changed while it was being bricked"):
        brick_mod.brick_volume(src, out, brick=8, progress=False, workers=1)
    assert not _complete(out)
    done.clear()
    assert main(["brick", str(src), str(vol / "c.zarr"), "--quiet", "--brick", "8", "--threads", "1"]) == 2
    _one_error_line(capsys, "c.zarr", "changed while it was being bricked")
    assert not _complete(vol / "c.zarr")


def test_source_replaced_by_an_identical_copy_is_still_a_change(vol, monkeypatch):
    """Same bytes, same mtime: only the inode tells that the file was swapped (a rename over it)."""
    src = vol / "v.npy"
    done = []

    def swap(level, index):
        if not done:
            done.append(1)
            copy = vol / "copy.npy"
            copy.write_bytes(src.read_bytes())
            st = os.stat(src)
            os.utime(copy, ns=(st.st_atime_ns, st.st_mtime_ns))
            os.replace(copy, src)

    after_each_brick(monkeypatch, swap)
    with pytest.raises(SourceChangedError, match="replaced"):
        brick_mod.brick_volume(src, vol / "o.zarr", brick=8, progress=False, workers=1)
    assert not _complete(vol / "o.zarr")


def test_disk_full_while_bricking_is_one_line_and_resumable(vol, capsys, monkeypatch):
    def full(level, index):
        if level == 1:
            raise OSError(errno.ENOSPC, "No space left on device", str(vol / "o.zarr" / "1" / "c"))

    after_each_brick(monkeypatch, full)
    out = vol / "o.zarr"
    with pytest.raises(OutputWriteError, match="No space left on device"):
        brick_mod.brick_volume(vol / "v.npy", out, brick=8, progress=False, workers=1)
    assert main(["brick", str(vol / "v.npy"), str(out), "--quiet", "--brick", "8", "--threads", "1"]) == 2
    _one_error_line(capsys, "o.zarr", "No space left on device", "re-run")
    assert not _complete(out) and not (vol / "o.zarr.lock").exists()
    after_each_brick(monkeypatch, None)  # space freed: the same command resumes
    assert main(["brick", str(vol / "v.npy"), str(out), "--quiet", "--brick", "8", "--threads", "1"]) == 0
    assert _complete(out)


def test_read_only_file_system_at_the_lock_is_one_line(vol, capsys, monkeypatch):
    real_open = os.open

    def read_only(path, flags, *a, **k):
        if str(path).endswith(".lock") and flags & os.O_CREAT:
            raise OSError(errno.EROFS, "Read-only file system", str(path))
        return real_open(path, flags, *a, **k)

    monkeypatch.setattr(os, "open", read_only)
    assert main(["brick", str(vol / "v.npy"), str(vol / "o.zarr"), "--quiet", "--brick", "8"]) == 2
    _one_error_line(capsys, "o.zarr", "Read-only file system")
    assert not (vol / "o.zarr").exists()


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes into a read-only folder anyway")
def test_read_only_folder_is_one_line(vol, capsys):
    ro = vol / "ro"
    ro.mkdir()
    ro.chmod(0o555)
    try:
        assert main(["brick", str(vol / "v.npy"), str(ro / "o.zarr"), "--quiet", "--brick", "8"]) == 2
        _one_error_line(capsys, "o.zarr", "ermission denied")
    finally:
        ro.chmod(0o755)


def test_disk_full_writing_a_png_is_one_line(tmp_path, capsys, monkeypatch):
    from PIL import Image

    def full(self, fp, *a, **k):
        raise OSError(errno.ENOSPC, "No space left on device", str(fp))

    monkeypatch.setattr(Image.Image, "save", full)
    rc = main(["render", "procedural:fractal?size=16", "--brick", "8", "--size", "16x16", "-o", str(tmp_path / "a.png")])
    assert rc == 2
    _one_error_line(capsys, "No space left on device", "a.png")


def test_brick_points_overwrite_refuses_an_output_that_holds_the_input(tmp_path, capsys):
    out = tmp_path / "p.zarr"
    out.mkdir()
    pts = out / "pts.npy"
    np.save(pts, np.random.default_rng(0).random((100, 4)))
    assert main(["brick-points", str(pts), str(out), "--overwrite", "--quiet"]) == 2
    _one_error_line(capsys, "holds the input", "pts.npy")
    assert pts.exists()
