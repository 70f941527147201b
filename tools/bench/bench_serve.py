"""``clipvol serve`` in a browser: time to the first frame after the page opens, and drag frame rate.

What a user of ``clipvol serve`` on a machine without a GPU (EGL, Mesa llvmpipe) feels, measured
in a headless Chromium driven over the DevTools protocol (``tests/browser_harness.py``) against a
real ``clipvol serve`` process on 127.0.0.1, on the 256^3 float32 fractal store (32^3 bricks):

* **first frame**: the page is opened (``Page.navigate``) and the page itself notes when its first
  frame arrived (``performance.now()`` counts from the navigation's start): the page and scripts
  load, the WebSocket opens, the server reads the view's bricks and draws the converged frame, PNG
  goes over the socket. ``cold``: the first page after the server started (no brick in memory);
  ``warm``: a page opened again (the bricks resident, shared by every view of the store).
* **drag**: the pointer orbits the view, a move every 16 ms for ``--seconds``; frames shown per
  second while it moves (the server draws them at adaptive quality, JPEG).

Each is stated as a ratio to a reference outside clipvol's path, measured in the same run:

* first frame against a **naive viewer's first frame**: the whole of level 0 read with zarr-python
  (``zarr.open(store)["0"][:]``), put in one 3D texture and drawn once by the plain one-texture
  ray caster (``common.RawCaster``) at the same view, size and step;
* drag fps against the **same one-texture caster's frame rate at full quality** (512x512, the base
  step, read back; no encoding, no network): what a plain caster without adaptive quality gives.

``python tools/bench/bench_serve.py`` (builds the store under ``bench-data/`` if missing;
``--quick`` for a 128^3 smoke run). Adds a row to ``tools/bench/results/bench_serve.csv`` (with the
load average it ran at: on the shared two-core machine the load decides much of what is measured).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import re
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from common import REPO, RESULTS, RawCaster, fractal_store, save_rows  # noqa: E402  (tools/bench/common.py)

sys.path.insert(0, str(REPO / "tests"))
from browser_harness import Chromium, chromium_binary  # noqa: E402

SIZE = (512, 512)


def _serve(store: Path):
    proc = subprocess.Popen([sys.executable, "-m", "clipvol.tools.cli", "serve", str(store), "--port", "0",
                             "--size", f"{SIZE[0]}x{SIZE[1]}"], stdout=subprocess.PIPE, stderr=subprocess.DEVNULL,
                            text=True, env=dict(os.environ, PYTHONUNBUFFERED="1"))
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline:
        line = proc.stdout.readline()
        m = re.search(r"(http://\S+)", line or "")
        if m:
            return proc, m.group(1)
        if proc.poll() is not None:
            break
    proc.kill()
    raise RuntimeError("clipvol serve printed no URL")


def _wait(b, expr: str, timeout: float = 120.0):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        v = b.eval(expr)
        if v:
            return v
        time.sleep(0.02)
    raise TimeoutError(expr)


def _first_frame(b, url: str) -> float:
    b.page("Page.navigate", url="about:blank")
    b.page("Page.navigate", url=url)
    return float(_wait(b, "window.clipvol && window.clipvol.firstFrameMs")) / 1000.0


def _drag(b, seconds: float) -> tuple[float, int]:
    """Frames per second shown while the pointer orbits for ``seconds`` (moves every 16 ms)."""
    r = json.loads(b.eval("JSON.stringify(document.querySelector('#view img').getBoundingClientRect())"))
    x0, y0 = r["x"] + r["width"] / 2, r["y"] + r["height"] / 2
    b.mouse("mouseMoved", x0, y0)
    b.mouse("mousePressed", x0, y0, button="left", buttons=1, clickCount=1)
    n0, m0 = b.eval("[window.clipvol.frames, window.clipvol.moving]")
    t0 = time.perf_counter()
    k = 0
    while time.perf_counter() - t0 < seconds:
        k += 1
        b.mouse("mouseMoved", x0 + 60 * math.sin(k / 20), y0 + 5 * math.cos(k / 30),
                button="left", buttons=1)
        time.sleep(0.016)
    n1, m1 = b.eval("[window.clipvol.frames, window.clipvol.moving]")
    dt = time.perf_counter() - t0
    b.mouse("mouseReleased", x0, y0, button="left", buttons=0, clickCount=1)
    return (n1 - n0) / dt, (n1 - n0) - (m1 - m0)


def _references(store: Path, repeat: int) -> tuple[float, float]:
    """(naive first frame s, one-texture caster full-quality fps) at the served view."""
    import zarr

    from clipvol.app.serve.state import orbit_camera
    from clipvol.paging.open import open_store
    from clipvol.render.context import create_context
    from clipvol.scene.auto_tf import auto_transfer_function

    loader = open_store(str(store))
    cam = orbit_camera(loader.pyramid, "iso", SIZE)
    tf = auto_transfer_function(loader)
    ctx = create_context()
    keep = ctx.simple_framebuffer((1, 1))  # the binding RawCaster gives back after its frame
    keep.use()
    try:
        t0 = time.perf_counter()
        vol = zarr.open(str(store), mode="r")["0"][:]
        raw = RawCaster(ctx, vol, loader.pyramid.value_range)
        raw.render(cam, tf, 0.5)
        naive = time.perf_counter() - t0
        times = []
        for _ in range(repeat):
            t = time.perf_counter()
            raw.render(cam, tf, 0.5)
            times.append(time.perf_counter() - t)
        raw.release()
        return naive, 1.0 / statistics.median(times)
    finally:
        keep.release()
        ctx.release()


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="a 128^3 store")
    ap.add_argument("--rounds", type=int, default=3, help="warm first frames and drags measured (default 3)")
    ap.add_argument("--seconds", type=float, default=4.0, help="length of each drag (default 4 s)")
    ap.add_argument("--out", type=Path, default=RESULTS / "bench_serve.csv")
    args = ap.parse_args(argv)
    n = 128 if args.quick else 256
    store = fractal_store(str(n), 32)
    load = open("/proc/loadavg").read().split()[0]
    naive, raw_fps = _references(store, 5)
    proc, url = _serve(store)
    try:
        with tempfile.TemporaryDirectory() as profile, Chromium(chromium_binary(), Path(profile), timeout=120,
                                                                 size=(SIZE[0] + 40, SIZE[1] + 140)) as b:
            cold = _first_frame(b, url)
            warm, fps, full_in_drag = [], [], []
            for _ in range(args.rounds):
                warm.append(_first_frame(b, url))
                _wait(b, "window.clipvol.full >= 1")
                f, still = _drag(b, args.seconds)
                fps.append(f)
                full_in_drag.append(still)
                naive_r, raw_r = _references(store, 3)  # interleaved: the machine's load hits both alike
                naive, raw_fps = min(naive, naive_r), max(raw_fps, raw_r)
    finally:
        proc.send_signal(signal.SIGINT)
        proc.wait(timeout=60)
    drag = statistics.median(fps)
    row = {"date": time.strftime("%Y-%m-%d"), "store": f"fractal {n}^3 float32, 32^3 bricks", "size": f"{SIZE[0]}x{SIZE[1]}",
           "load_avg": load, "first_frame_cold_s": f"{cold:.3f}", "first_frame_warm_s": f"{statistics.median(warm):.3f}",
           "naive_first_frame_s": f"{naive:.3f}", "first_frame_cold_ratio": f"{cold / naive:.2f}",
           "drag_fps": f"{drag:.1f}", "full_frames_in_drags": sum(full_in_drag), "raw_full_fps": f"{raw_fps:.1f}", "drag_fps_ratio": f"{drag / raw_fps:.2f}",
           "exit_status": proc.returncode}
    for k, v in row.items():
        print(f"{k}: {v}")
    rows = []
    if args.out.exists():  # the rows of earlier runs stay: the load changes what a run measures
        import csv

        with open(args.out, newline="") as f:
            rows = [r for r in csv.DictReader(f) if list(r) == list(row)]
    return save_rows(args.out, rows + [row])


if __name__ == "__main__":
    sys.exit(main())
