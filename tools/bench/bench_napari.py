"""Memory of looking at a store in 3D: napari's volume view against clipvol's; and streamed NIfTI input.

Two measurements, each in fresh processes so peak resident memory (``VmHWM`` of the process, read
from ``/proc/self/status``) belongs to one task:

1. **3D view of a store** (procedural fractal, float32, N^3 for N in ``--sizes``). napari (run
   with ``--napari-python``, under ``xvfb-run``: napari needs a Qt window) opens the store through
   clipvol's reader plug-in, switches to 3D and takes a screenshot, once letting napari pick the
   level and once pinned to full resolution (``locked_data_level=0``). clipvol renders one
   converged 256x256 frame of the same store offscreen with 64 MB memory and texture budgets.
   Reported: the level each shows, peak RSS, and the ratio of napari's full-resolution peak to
   clipvol's peak (same store, same run).
2. **Bricking a .nii.gz**: peak RSS of ``clipvol brick`` against nibabel loading the same file
   whole (``np.asarray(img.dataobj)``, the baseline outside our code path), for growing sizes.

Results: ``tools/bench/results/bench_napari.csv``, ``tools/bench/results/bench_napari.png``; summary in ``docs/benchmarks.md``.
Run: ``python tools/bench/bench_napari.py --napari-python /path/to/napari/venv/bin/python``.
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

from common import REPO, RESULTS  # noqa: E402  (tools/bench/common.py)

_CLIPVOL_CHILD = r"""
def _hwm():
    # VmHWM: this process image's own peak RSS (ru_maxrss would keep the forking parent's after exec)
    for line in open("/proc/self/status"):
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) / 1024
import json, resource, sys
import numpy as np
from clipvol.render.context import create_context
from clipvol.app.session import RenderSession
from clipvol.scene.params import RenderParams
from clipvol.scene.paths import turntable
store, budget = sys.argv[1], sys.argv[2]
ctx = create_context()
s = RenderSession(store, ctx, memory_budget=budget, texture_budget=budget, params=RenderParams(mode="mip"), tf="grey")
base = _hwm()
cam, coi = next(turntable(s.pyramid, 1, size=(256, 256), elevation=20))
img = s.render(cam, coi, wait=True, timeout=600)
fs = s.frame_stats
drawn = fs.bricks_drawn if isinstance(fs.bricks_drawn, dict) else dict(enumerate(fs.bricks_drawn))
levels = sorted(int(k) for k, v in drawn.items() if v)
out = {"peak_rss_mb": _hwm(), "base_rss_mb": base,
       "levels": "+".join(f"L{k}:{int(drawn[k])}" for k in levels), "finest": levels[0] if levels else -1,
       "converged": bool(fs.converged), "coverage": float((img[..., 3] > 0).mean())}
s.close(); ctx.release()
print("RESULT", json.dumps(out))
"""

_NAPARI_CHILD = r"""
def _hwm():
    # VmHWM: this process image's own peak RSS (ru_maxrss would keep the forking parent's after exec)
    for line in open("/proc/self/status"):
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) / 1024
import json, resource, sys, time
sys.path.insert(0, sys.argv[3])
import napari
from qtpy.QtWidgets import QApplication
from clipvol.napari_plugin import read_store
store, lock = sys.argv[1], int(sys.argv[2])
v = napari.Viewer(show=True)
base = _hwm()
[(levels, kw, kind)] = read_store(store)
kw.pop("units", None); kw.pop("axis_labels", None)
if lock >= 0:
    kw["locked_data_level"] = lock
layer = v.add_image(levels, **kw)
v.dims.ndisplay = 3
v.reset_view()
for _ in range(20):
    QApplication.processEvents(); time.sleep(0.05)
img = v.screenshot(canvas_only=True, size=(256, 256))
out = {"peak_rss_mb": _hwm(), "base_rss_mb": base,
       "levels": f"L{layer.data_level}:{'x'.join(map(str, levels[layer.data_level].shape))}",
       "finest": int(layer.data_level), "converged": True, "coverage": float((img[..., :3].max(-1) > 0).mean())}
v.close()
print("RESULT", json.dumps(out))
"""

_NIB_CHILD = r"""
def _hwm():
    # VmHWM: this process image's own peak RSS (ru_maxrss would keep the forking parent's after exec)
    for line in open("/proc/self/status"):
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) / 1024
import json, resource, sys
import numpy as np, nibabel as nib
a = np.asarray(nib.load(sys.argv[1]).dataobj)
print("RESULT", json.dumps({"peak_rss_mb": _hwm(), "sum": float(a[::7, ::7, ::7].sum())}))
"""

_BRICK_CHILD = r"""
def _hwm():
    # VmHWM: this process image's own peak RSS (ru_maxrss would keep the forking parent's after exec)
    for line in open("/proc/self/status"):
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) / 1024
import json, resource, sys
from clipvol.bricking.pipeline import brick_volume
brick_volume(sys.argv[1], sys.argv[2], brick=64, progress=False, workers=2)
print("RESULT", json.dumps({"peak_rss_mb": _hwm()}))
"""


def _run(cmd: list[str], env=None) -> dict:
    p = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=1200)
    for line in p.stdout.splitlines():
        if line.startswith("RESULT "):
            return json.loads(line[7:])
    raise RuntimeError(f"{' '.join(cmd[:3])}...: no result (rc {p.returncode}): {p.stderr[-800:]}")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="128,256,512", help="store edge lengths N (N^3 float32)")
    ap.add_argument("--nifti-sizes", default="128,256,384", help=".nii.gz edge lengths (int16)")
    ap.add_argument("--napari-python", default=None, help="python of an environment with napari[pyqt5] (skip napari if absent)")
    ap.add_argument("--budget", default="64MB", help="clipvol memory and texture budgets")
    ap.add_argument("--out", default=str(RESULTS), help="where the CSV and PNG go")
    ap.add_argument("--work", default=None, help="scratch directory (default: a temporary one)")
    args = ap.parse_args(argv)

    from clipvol.bricking.pipeline import brick_volume

    root = REPO
    work = Path(args.work or tempfile.mkdtemp(prefix="clipvol-bench-napari-"))
    work.mkdir(parents=True, exist_ok=True)
    rows = []
    for n in (int(v) for v in args.sizes.split(",")):
        store = work / f"fractal{n}.zarr"
        if not (store / "zarr.json").exists():
            brick_volume(f"procedural:fractal?size={n}", store, brick=64, progress=False, overwrite=True)
        level0_mb = n**3 * 4 / 2**20
        r = _run([sys.executable, "-c", _CLIPVOL_CHILD, str(store), args.budget])
        rows.append({"part": "view3d", "size": n, "level0_mb": round(level0_mb, 1), "tool": "clipvol", "mode": f"budget {args.budget}", **r})
        print(rows[-1], flush=True)
        if args.napari_python and shutil.which("xvfb-run"):
            for lock, mode in ((-1, "napari picks level"), (0, "locked_data_level=0")):
                cmd = ["xvfb-run", "-a", "-s", "-screen 0 1024x768x24", args.napari_python, "-c", _NAPARI_CHILD, str(store), str(lock), str(root)]
                try:
                    r = _run(cmd)
                except (RuntimeError, subprocess.TimeoutExpired) as e:
                    r = {"peak_rss_mb": float("nan"), "levels": f"failed: {str(e)[:120]}", "finest": -1}
                rows.append({"part": "view3d", "size": n, "level0_mb": round(level0_mb, 1), "tool": "napari", "mode": mode, **r})
                print(rows[-1], flush=True)
    try:
        import nibabel as nib
        import numpy as np
    except ImportError:
        nib = None
    if nib is not None:
        for n in (int(v) for v in args.nifti_sizes.split(",")):
            p = work / f"vol{n}.nii.gz"
            if not p.exists():
                from clipvol.bricking.generators import parse_procedural

                g = parse_procedural(f"procedural:fractal?size={n}")
                a = (g.region(0, (0, 0, 0), g.shape) * 3000).astype(np.int16)
                nib.save(nib.Nifti1Image(a.transpose(2, 1, 0), np.eye(4)), p)
                del a
            mb = n**3 * 2 / 2**20
            r = _run([sys.executable, "-c", _NIB_CHILD, str(p)])
            rows.append({"part": "nifti", "size": n, "level0_mb": round(mb, 1), "tool": "nibabel load (baseline)", "mode": "whole file", **r})
            print(rows[-1], flush=True)
            out = work / f"vol{n}.zarr"
            shutil.rmtree(out, ignore_errors=True)
            r = _run([sys.executable, "-c", _BRICK_CHILD, str(p), str(out)])
            rows.append({"part": "nifti", "size": n, "level0_mb": round(mb, 1), "tool": "clipvol brick", "mode": "streamed", **r})
            print(rows[-1], flush=True)
    outdir = Path(args.out)
    outdir.mkdir(parents=True, exist_ok=True)
    cols = ["part", "size", "level0_mb", "tool", "mode", "levels", "finest", "peak_rss_mb", "base_rss_mb", "coverage", "converged"]
    with open(outdir / "bench_napari.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=cols, extrasaction="ignore")
        w.writeheader()
        for r in rows:
            w.writerow({k: (round(v, 1) if isinstance(v, float) else v) for k, v in r.items()})
    _plot(rows, outdir / "bench_napari.png")
    _summary(rows)
    if not args.work:
        shutil.rmtree(work, ignore_errors=True)
    return 0


def _summary(rows) -> None:
    by = {}
    for r in rows:
        by[(r["part"], r["size"], r["tool"], r["mode"])] = r["peak_rss_mb"]
    for (part, n, tool, mode), v in sorted(by.items()):
        if part == "view3d" and tool == "napari" and mode.startswith("locked"):
            c = next(r["peak_rss_mb"] for r in rows if r["part"] == part and r["size"] == n and r["tool"] == "clipvol")
            print(f"N={n}: napari full-resolution 3D peak RSS / clipvol peak RSS = {v / c:.2f}")
        if part == "nifti" and tool == "clipvol brick":
            b = by[(part, n, "nibabel load (baseline)", "whole file")]
            print(f"N={n}: clipvol brick peak RSS / nibabel whole-file load peak RSS = {v / b:.2f}")


def _plot(rows, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    for ax, part, title in ((axes[0], "view3d", "3D view of an N^3 float32 store"), (axes[1], "nifti", "input of an N^3 int16 .nii.gz")):
        series = {}
        for r in rows:
            if r["part"] == part:
                series.setdefault(f"{r['tool']} ({r['mode']})", []).append((r["level0_mb"], r["peak_rss_mb"]))
        for label, pts in series.items():
            pts.sort()
            ax.plot([p[0] for p in pts], [p[1] for p in pts], "o-", label=label)
        ax.set_xlabel("level-0 size (MiB)")
        ax.set_ylabel("peak resident memory (MiB)")
        ax.set_title(title)
        ax.legend(fontsize=8)
        ax.grid(alpha=0.3)
    fig.suptitle("Peak RSS of each tool in its own process (absolute; the ratios are in docs/benchmarks.md)")
    fig.tight_layout()
    fig.savefig(path, dpi=100)


if __name__ == "__main__":
    os.environ.setdefault("PYTHONUNBUFFERED", "1")
    raise SystemExit(main())
