"""`clipvol check --all`, `clipvol repair`, a resume against a changed source, the build lock."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import threading

import numpy as np
import pytest
import zarr

from clipvol.bricking.pipeline import brick_volume
from clipvol.errors import OutputLockedError
from clipvol.tools.cli import main
from build_hooks import after_each_brick


@pytest.fixture
def npy(tmp_path):
    z, y, x = np.indices((36, 40, 34))
    vol = np.clip(2000 + 1500 * np.sin(z / 4.0) * np.cos(y / 5.0) + 400 * np.sin(x / 3.0), 0, 4095).astype(np.uint16)
    p = tmp_path / "v.npy"
    np.save(p, vol)
    return p, vol


def _chunk(path, L, idx):
    return path / str(L) / "c" / "/".join(map(str, idx))


def _chunk_files(path):
    return {str(p.relative_to(path)): p.read_bytes() for p in sorted(path.glob("[0-9]*/c/**/*")) if p.is_file()}


def _damage(out):
    """Five bricks damaged five ways; returns their (level, index)."""
    flip = _chunk(out, 0, (0, 1, 1))
    d = bytearray(flip.read_bytes())
    d[len(d) // 3] ^= 0x06  # two bits
    flip.write_bytes(bytes(d))
    _chunk(out, 0, (1, 0, 1)).unlink()  # deleted
    pay = _chunk(out, 1, (0, 1, 0))
    d = bytearray(pay.read_bytes())
    d[16:-4] = np.random.default_rng(3).integers(0, 256, len(d) - 20, dtype=np.uint8).tobytes()
    pay.write_bytes(bytes(d))  # random payload after a valid blosc header
    _chunk(out, 0, (2, 2, 0)).write_bytes(_chunk(out, 0, (0, 0, 0)).read_bytes())  # substituted
    tr = _chunk(out, 0, (1, 1, 2))
    tr.write_bytes(tr.read_bytes()[:50])  # truncated
    return {(0, (0, 1, 1)), (0, (1, 0, 1)), (1, (0, 1, 0)), (0, (2, 2, 0)), (0, (1, 1, 2))}


def test_check_all_names_every_bad_brick_and_repair_restores_the_store(tmp_path, npy, capsys):
    p, vol = npy
    out = tmp_path / "o.zarr"
    assert main(["brick", str(p), str(out), "--brick", "16", "--quiet"]) == 0
    pristine = _chunk_files(out)
    bad = _damage(out)
    capsys.readouterr()
    assert main(["check", str(out), "--all"]) == 1
    err = capsys.readouterr().err
    summary = [ln for ln in err.splitlines() if "bricks checked are bad" in ln]
    assert len(summary) == 1 and "Traceback" not in err
    for L, idx in bad:
        assert f"level {L} brick {idx}" in summary[0], summary[0]
    assert summary[0].split(": ", 2)[2].startswith(f"{len(bad)} of ")

    assert main(["repair", str(out), "--source", str(p), "--quiet"]) == 0
    assert "rebuilt" in capsys.readouterr().out
    assert _chunk_files(out) == pristine  # byte for byte what the undamaged build wrote
    np.testing.assert_array_equal(zarr.open_array(str(out / "0"), mode="r")[...], vol)  # zarr-python verifies the crc
    assert main(["check", str(out), "--all", "--quiet"]) == 0


def test_repair_refuses_another_input(tmp_path, npy, capsys):
    p, vol = npy
    out = tmp_path / "o.zarr"
    assert main(["brick", str(p), str(out), "--brick", "16", "--quiet"]) == 0
    other = tmp_path / "w.npy"
    np.save(other, vol[::-1].copy())
    capsys.readouterr()
    assert main(["repair", str(out), "--source", str(other), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "not the input" in err and "content" in err


def _interrupted(p, out, monkeypatch):
    def crash(level, index):
        if index != (0, 0, 0):
            raise RuntimeError("power cut")

    after_each_brick(monkeypatch, crash)
    with pytest.raises(RuntimeError):
        main(["brick", str(p), str(out), "--quiet", "--brick", "16", "--threads", "1"])
    after_each_brick(monkeypatch, None)


@pytest.mark.parametrize("keep_mtime", [False, True])
def test_resume_against_a_changed_source_refuses(tmp_path, npy, capsys, monkeypatch, keep_mtime):
    p, vol = npy
    out = tmp_path / "o.zarr"
    _interrupted(p, out, monkeypatch)
    st = os.stat(p)
    np.save(p, (4095 - vol).astype(np.uint16))  # same shape, dtype and size; other data
    if keep_mtime:
        os.utime(p, ns=(st.st_atime_ns, st.st_mtime_ns))  # only the sampled content tells
    capsys.readouterr()
    assert main(["brick", str(p), str(out), "--quiet", "--brick", "16"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "--overwrite" in err and "content" in err
    assert ("modification time" in err) != keep_mtime
    assert not json.loads((out / "zarr.json").read_text())["attributes"]["clipvol"]["complete"]
    assert main(["brick", str(p), str(out), "--quiet", "--brick", "16", "--overwrite"]) == 0
    np.testing.assert_array_equal(zarr.open_array(str(out / "0"), mode="r")[...], 4095 - vol)


def test_resume_with_the_same_source_completes(tmp_path, npy, monkeypatch):
    p, vol = npy
    out = tmp_path / "o.zarr"
    _interrupted(p, out, monkeypatch)
    assert main(["brick", str(p), str(out), "--quiet", "--brick", "16"]) == 0
    np.testing.assert_array_equal(zarr.open_array(str(out / "0"), mode="r")[...], vol)


def test_second_writer_is_refused_while_the_first_builds(tmp_path, npy, monkeypatch):
    p, vol = npy
    out = tmp_path / "o.zarr"
    inside, release = threading.Event(), threading.Event()

    def hold(level, index):
        inside.set()
        release.wait(30)

    after_each_brick(monkeypatch, hold)
    first = threading.Thread(target=brick_volume, args=(p, out), kwargs={"brick": 16, "progress": False, "workers": 1})
    first.start()
    try:
        assert inside.wait(30)
        with pytest.raises(OutputLockedError, match=f"pid {os.getpid()}"):
            brick_volume(p, out, brick=16, progress=False, overwrite=True)
    finally:
        release.set()
        after_each_brick(monkeypatch, None)
        first.join(30)
    assert not first.is_alive()
    np.testing.assert_array_equal(zarr.open_array(str(out / "0"), mode="r")[...], vol)
    assert not (tmp_path / "o.zarr.lock").exists()


def test_lock_of_a_live_process_refuses_and_a_dead_ones_is_taken_over(tmp_path, npy, capsys):
    import socket

    p, vol = npy
    out = tmp_path / "o.zarr"
    lock = tmp_path / "o.zarr.lock"
    live = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        lock.write_text(json.dumps({"pid": live.pid, "host": socket.gethostname()}))
        assert main(["brick", str(p), str(out), "--quiet", "--brick", "16"]) == 2
        err = capsys.readouterr().err
        assert f"pid {live.pid}" in err and "o.zarr.lock" in err and "Traceback" not in err
        assert not out.exists()
    finally:
        live.kill()
        live.wait(10)
    # the holder is now dead: its lock is stale and taken over
    assert main(["brick", str(p), str(out), "--quiet", "--brick", "16"]) == 0
    assert not lock.exists()
    np.testing.assert_array_equal(zarr.open_array(str(out / "0"), mode="r")[...], vol)


def test_check_on_an_interrupted_store_reports_no_bogus_mismatch(tmp_path, npy, capsys, monkeypatch):
    p, _ = npy
    out = tmp_path / "o.zarr"
    _interrupted(p, out, monkeypatch)
    capsys.readouterr()
    assert main(["check", str(out), "--all", "--quiet"]) == 1
    err = capsys.readouterr().err
    assert "incomplete" in err and "histogram" not in err and "stored" not in err, err


def test_info_counts_a_deleted_chunk_as_lost_not_empty(tmp_path, npy, capsys):
    p, vol = npy
    out = tmp_path / "o.zarr"
    assert main(["brick", str(p), str(out), "--brick", "16", "--quiet"]) == 0
    assert main(["info", str(out)]) == 0
    capsys.readouterr()
    _chunk(out, 0, (1, 1, 1)).unlink()
    assert main(["info", str(out)]) == 1
    err = capsys.readouterr().err
    assert "level 0: 1 bricks hold data" in err and "Traceback" not in err


def test_a_store_without_checksums_opens_with_a_one_line_note(tmp_path, npy, capsys):
    """A store written before checksums (its chains without crc32c, rewritten here with zarr-python)."""
    p, vol = npy
    out = tmp_path / "o.zarr"
    assert main(["brick", str(p), str(out), "--brick", "16", "--quiet"]) == 0
    for L in range(len(list(out.glob("[0-9]*")))):
        data = zarr.open_array(str(out / str(L)), mode="r")[...]
        meta = json.loads((out / str(L) / "zarr.json").read_text())
        shutil.rmtree(out / str(L) / "c")
        meta["codecs"] = meta["codecs"][:-1]
        (out / str(L) / "zarr.json").write_text(json.dumps(meta))
        zarr.open_array(str(out / str(L)), mode="r+")[...] = data
    shutil.rmtree(out / "clipvol_stats" / "0" / "chunk_crc32c")
    root = json.loads((out / "zarr.json").read_text())  # nor a manifest: those came after checksums
    del root["attributes"]["clipvol"]["manifest"]
    (out / "zarr.json").write_text(json.dumps(root))
    shutil.rmtree(out / "clipvol_manifest")
    capsys.readouterr()
    assert main(["check", str(out), "--all", "--quiet"]) == 1  # nothing vouches for it: check fails
    cap = capsys.readouterr()
    notes = [ln for ln in cap.err.splitlines() if "unverified" in ln]
    assert len(notes) == 1 and "Traceback" not in cap.err and "warnings.warn" not in cap.err
    assert "written before chunk checksums" in notes[0] and "ok" not in cap.out
    assert main(["info", str(out)]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert "unverified" in lines[0] and any("none: written before chunk checksums" in ln for ln in lines)
