"""The build lock (issue 40, item 4): a lock that is empty, unreadable or names a dead process is
taken over with a note; a live holder is refused; a full disk while the lock is written leaves no
file behind, so the next build is not blocked ("pid None").

References: the lock file's bytes and existence on disk, and a real process that has exited (its pid
is dead by construction).
"""

from __future__ import annotations

import errno
import json
import os
import socket
import subprocess
import sys

import numpy as np
import pytest

from clipvol.bricking.build_lock import lock_path, output_lock
from clipvol.errors import OutputLockedError
from clipvol.tools.cli import main


def _dead_pid() -> int:
    p = subprocess.Popen([sys.executable, "-c", "pass"])
    p.wait()
    return p.pid


@pytest.mark.parametrize("content", [b"", b"{not json", b'{"pid": null, "host": "x"}', b"\xff\xfe"],
                         ids=["empty", "garbage", "pid-none", "not-utf8"])
def test_a_lock_that_names_no_process_is_taken_over_with_a_note(tmp_path, capsys, content):
    np.save(tmp_path / "v.npy", np.arange(8 * 8 * 8, dtype=np.uint16).reshape(8, 8, 8))
    out = tmp_path / "o.zarr"
    lock_path(out).write_bytes(content)  # what a crash (or a full disk) during the lock's write left
    assert main(["brick", str(tmp_path / "v.npy"), str(out), "--quiet", "--brick", "8"]) == 0
    err = capsys.readouterr().err
    assert "stale build lock" in err and "o.zarr.lock" in err, err
    assert not lock_path(out).exists()
    assert json.loads((out / "zarr.json").read_text())["attributes"]["clipvol"]["complete"] is True


def test_a_dead_holder_on_this_host_is_taken_over(tmp_path, capsys):
    out = tmp_path / "o.zarr"
    pid = _dead_pid()
    lock_path(out).write_text(json.dumps({"pid": pid, "host": socket.gethostname()}))
    with output_lock(out):
        assert json.loads(lock_path(out).read_text())["pid"] == os.getpid()
    assert f"pid {pid}" in capsys.readouterr().err
    assert not lock_path(out).exists()


def test_a_live_holder_is_refused_and_its_lock_kept(tmp_path):
    out = tmp_path / "o.zarr"
    child = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(30)"])
    try:
        held = json.dumps({"pid": child.pid, "host": socket.gethostname()}).encode()
        lock_path(out).write_bytes(held)
        with pytest.raises(OutputLockedError, match=f"pid {child.pid}"):
            with output_lock(out):
                pass
        assert lock_path(out).read_bytes() == held
    finally:
        child.kill()
        child.wait()


def test_a_full_disk_while_writing_the_lock_leaves_no_file(tmp_path, monkeypatch):
    out = tmp_path / "o.zarr"
    real_write = os.write

    def full(fd, data):
        if os.readlink(f"/proc/self/fd/{fd}").endswith(".lock"):
            raise OSError(errno.ENOSPC, "No space left on device")
        return real_write(fd, data)

    if not os.path.exists("/proc/self/fd"):
        pytest.skip("needs /proc to tell the lock's descriptor")
    monkeypatch.setattr(os, "write", full)
    with pytest.raises(OSError, match="No space left"):
        with output_lock(out):
            pass
    monkeypatch.undo()
    assert list(tmp_path.iterdir()) == []  # neither the lock nor its temporary
    with output_lock(out):  # the next build is not blocked
        assert lock_path(out).exists()
