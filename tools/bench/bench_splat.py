"""Benchmark the point octree: build throughput and memory, frame time and error against tolerance.

Usage::

    python tools/bench/bench_splat.py [--build-sizes 1e6,4e6,16e6] [--render-points 4e6] [--size 256]
    python tools/bench/bench_splat.py --build-only --build-sizes 4e6,16e6,50e6 --out tools/bench/results/bench_splat_build.csv

Data: :class:`clipvol.bricking.point_sources.ClusteredPointSource` (64 Gaussian clusters of varied
width plus 20 % uniform background, like the particles of a simulation), generated chunk by chunk,
so no input file is needed and the build streams it like a file larger than memory.

1. **Build**, each size in its own child process (peak resident memory ``VmHWM`` is that run's
   alone): :func:`clipvol.bricking.point_store.build_point_store` (max 64 points per node,
   ``memory_points`` 2 M), against the baseline *outside our code*: the same points streamed from the
   same source into one zarr array (same chunks, same codec) - what writing the input costs
   without any octree. Ratio = baseline seconds / build seconds.
2. **Frames** on the ``--render-points`` store, one perspective view of the whole cloud,
   ``--size`` pixels: :class:`clipvol.render.splat.SplatRenderAction` at tolerances from 1 px to 20 %
   of the screen, warm (the clip-texture holds the cut: rendered once with ``wait=True``, then the
   median of 3 timed frames). Baseline outside our code: a 40-line moderngl program in this file
   that draws *every* point as a Gaussian splat of the finest leaves' size, sorted back to front
   with numpy (the brute-force way to draw a point cloud). Ratio = baseline frame time / our frame
   time. Image error: % of pixels with Delta E >= 6 against the every-point frame (each point drawn
with its leaf's splat size: the full-detail picture), beside the yardstick ``blur_pct_de6``: the error of
the every-point frame blurred by one tolerance-sized splat's Gaussian footprint (sigma = tolerance / 2),
detail no picture of splats that large can hold. ``tools/bench/results/bench_splat_frames.png``: the
every-point frame, then ours at the finest, a middle and the coarsest tolerance.

Results: ``tools/bench/results/bench_splat.csv`` (+ ``.png``) and the point section of ``docs/benchmarks.md``.
"""

from __future__ import annotations

import argparse
import csv
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from common import REPO, RESULTS  # noqa: E402  (tools/bench/common.py)
ROOT = REPO

_HWM = r"""
def _hwm_mb():
    for line in open("/proc/self/status"):
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) / 1024.0
"""

_BUILD_CHILD = _HWM + r"""
import json, sys, time
import tqdm, zarr
from clipvol.bricking.point_sources import ClusteredPointSource
from clipvol.bricking.point_store import build_point_store
a = json.loads(sys.argv[1])
t = time.perf_counter()
m = build_point_store(ClusteredPointSource(a["n"], seed=1), a["out"], max_points=64, overwrite=True, progress=False,
                      representative=a.get("representative", "nearest"))
print(json.dumps({"seconds": time.perf_counter() - t, "rss_mb": _hwm_mb(), "nodes": m.num_nodes, "depth": m.depth,
                  "stored": m.num_stored}))
"""

_ZARR_CHILD = _HWM + r"""
import json, sys, time
import numpy as np, zarr
from clipvol.bricking.point_sources import ClusteredPointSource
a = json.loads(sys.argv[1])
t = time.perf_counter()
src = ClusteredPointSource(a["n"], seed=1)
g = zarr.open_group(a["out"], mode="w")
xyz = g.create_array("xyz", shape=(a["n"], 3), chunks=(4096, 3), dtype="float32")
val = g.create_array("values", shape=(a["n"], 1), chunks=(4096, 1), dtype="float32")
i = 0
for x, v in src.chunks():
    xyz[i:i + len(x)] = x.astype(np.float32)
    val[i:i + len(x)] = v
    i += len(x)
print(json.dumps({"seconds": time.perf_counter() - t, "rss_mb": _hwm_mb()}))
"""


def _child(code: str, args: dict) -> dict:
    proc = subprocess.run([sys.executable, "-c", code, json.dumps(args)], capture_output=True, text=True)
    if proc.returncode:
        raise SystemExit(f"benchmark child failed:\n{proc.stderr}")
    return json.loads(proc.stdout.strip().splitlines()[-1])


class BruteSplats:
    """Every point, one Gaussian splat each, sorted back to front: the baseline (not clipvol code)."""

    VS = """#version 330
    in vec3 p; in float v; in float hh; uniform mat4 mvp; uniform float size_k;
    out float vt; out float vs; out float vh;
    void main(){ vec4 c = mvp * vec4(p, 1.0); gl_Position = c; float px = hh * size_k / c.w;
                 gl_PointSize = clamp(3.0 * px, 1.0, 255.0); vs = max(0.5 * px, 1e-3); vt = v; vh = hh; }"""
    FS = """#version 330
    in float vt; in float vs; in float vh; uniform sampler2D tf; uniform float unit; out vec4 o;
    void main(){ vec2 d = (gl_PointCoord - 0.5) * max(6.0 * vs, 1.0); float r2 = dot(d, d) / (vs * vs);
                 if (r2 > 9.0) discard; vec4 c = texture(tf, vec2(clamp(vt, 0.0, 1.0), 0.5));
                 float w = 0.6366 * exp(-0.5 * r2);
                 float a = 1.0 - exp(w * vh / unit * log(max(1.0 - c.a, 1e-6)));  // not pow: coarse near 1 on llvmpipe
                 o = vec4(c.rgb * a, a); }"""

    def __init__(self, ctx, xyz: np.ndarray, vals: np.ndarray, h: np.ndarray, unit: float, table: np.ndarray) -> None:
        import moderngl

        self.ctx, self.mgl = ctx, moderngl
        self.prog = ctx.program(vertex_shader=self.VS, fragment_shader=self.FS)
        self.xyz, self.vals, self.h, self.unit = xyz, vals.astype(np.float32), h, unit
        self.tf = ctx.texture((len(table), 1), 4, np.ascontiguousarray(table, np.float32).tobytes(), dtype="f4")
        self.tf.filter = (moderngl.LINEAR, moderngl.LINEAR)
        self.tf.repeat_x = self.tf.repeat_y = False

    def render(self, cam) -> np.ndarray:
        ctx, mgl = self.ctx, self.mgl
        rel = self.xyz - cam.eye
        V = cam.view_matrix().copy()
        V[:3, 3] = 0
        depth = -(rel @ V[2, :3])
        o = np.argsort(-depth)
        data = np.empty((len(o), 5), np.float32)
        data[:, :3] = rel[o]
        data[:, 3] = self.vals[o]
        data[:, 4] = self.h[o]
        w, h = cam.size
        fbo = ctx.framebuffer(color_attachments=[ctx.texture((w, h), 4, dtype="f4")])
        prev = ctx.fbo
        fbo.use()
        fbo.clear(0, 0, 0, 0)
        ctx.enable(mgl.BLEND)
        ctx.enable_direct(0x8642)
        ctx.blend_func = mgl.ONE, mgl.ONE_MINUS_SRC_ALPHA
        self.prog["mvp"].write((cam.projection_matrix() @ V).T.astype(np.float32).tobytes())
        self.prog["size_k"].value = float(cam.pixels_per_unit(1.0))
        self.prog["unit"].value = self.unit
        self.prog["tf"].value = 0
        self.tf.use(0)
        buf = ctx.buffer(data.tobytes())
        vao = ctx.vertex_array(self.prog, [(buf, "3f 1f 1f", "p", "v", "hh")])
        vao.render(mgl.POINTS)
        ctx.finish()
        img = np.frombuffer(fbo.read(components=4, dtype="f4"), np.float32).reshape(h, w, 4)[::-1].copy()
        (prev if prev is not None else ctx.detect_framebuffer(0)).use()
        vao.release()
        buf.release()
        fbo.color_attachments[0].release()
        fbo.release()
        return img


def _frames(store: Path, size: int, tolerances: list[str], frames_png: Path) -> list[dict]:
    from clipvol.loaders.point_store import PointStoreLoader
    from clipvol.paging.cliptexture import ClipTexture
    from clipvol.render import create_context
    from clipvol.render.paths.setup import premultiplied_to_uint8
    from clipvol.render.splat import SplatRenderAction
    from clipvol.scene.camera import Camera
    from clipvol.scene.metrics import percent_delta_e
    from clipvol.scene.transfer import TransferFunction

    loader = PointStoreLoader(store)
    lo, hi = loader.world_box()
    c = (lo + hi) / 2
    cam = Camera.perspective(tuple(c + np.array([0.9, 0.7, 1.4]) * loader.meta.edge), tuple(c), fov_y=35, size=(size, size))
    tf = TransferFunction.preset("inferno", value_range=(0.0, 1.0))
    tab = tf.table.copy()
    tab[:, 3] *= 0.08
    tf = TransferFunction(tab, (0.0, 1.0))
    ctx = create_context()
    rows, images = [], []
    with ClipTexture(loader, "1GB", 2, center=loader.to_paging(c)) as ct, SplatRenderAction(ctx, ct) as act:
        for tol in tolerances:
            act.tolerance = tol
            act.render(cam, tf, wait=True, timeout=600)
            times = []
            for _ in range(3):
                t = time.perf_counter()
                img = act.render(cam, tf)
                times.append(time.perf_counter() - t)
            st = act.last_frame_stats
            images.append(img)
            rows.append({"what": f"splats tol {tol}", "tolerance_px": round(st.tolerance_px, 2), "points": st.points_drawn,
                         "nodes": st.nodes_drawn, "frame_s": float(np.median(times)), "converged": st.converged,
                         "select_s": st.times["select"],
                         "gather_s": st.times["gather"], "draw_s": st.times["draw"]})
            print(rows[-1], flush=True)
    # the baseline: every point, leaf-sized splats, one sorted draw call
    xs, vs = [], []
    n = loader.nodes
    leaf = np.flatnonzero(n.child_mask == 0)
    import zarr

    g = zarr.open_group(str(store), mode="r")
    xyz_all = np.asarray(g["points/xyz"][:], np.float64) + np.asarray(loader.meta.origin)
    val_all = np.asarray(g["points/values"][:, 0])
    rows_idx = np.concatenate([np.arange(o, o + k) for o, k in zip(n.offset[leaf], n.count[leaf])])
    xs, vs = xyz_all[rows_idx], val_all[rows_idx]
    del xyz_all, val_all
    h_leaf = np.repeat(n.edges(leaf) / np.cbrt(n.count[leaf]), n.count[leaf])  # each point its leaf's splat size
    brute = BruteSplats(ctx, xs, vs, h_leaf, loader.meta.point_spacing, tf.table)
    brute.render(cam)
    times = []
    for _ in range(3):
        t = time.perf_counter()
        raw = brute.render(cam)
        times.append(time.perf_counter() - t)
    ref = premultiplied_to_uint8(raw.astype(np.float64))
    from clipvol.app.point_report import footprint_blur

    for r, img in zip(rows, images):
        r["pct_de6_vs_every_point"] = percent_delta_e(img, ref, premultiplied=False)
        # the yardstick: the every-point frame through one tolerance-sized splat's footprint
        r["blur_pct_de6"] = percent_delta_e(footprint_blur(ref, 0.5 * r["tolerance_px"]), ref, premultiplied=False)
    rows.append({"what": "baseline: every point", "tolerance_px": 0, "points": len(xs), "nodes": 0,
                 "frame_s": float(np.median(times)), "converged": True, "pct_de6_vs_every_point": 0.0,
                 "select_s": 0, "gather_s": 0, "draw_s": 0})
    from PIL import Image

    Image.fromarray(np.concatenate([ref] + [images[i] for i in (0, len(images) // 2, len(images) - 1)], axis=1)).save(
        frames_png)
    print(rows[-1], flush=True)
    ctx.release()
    return rows


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--build-sizes", default="1e6,4e6,16e6", help="points per build run (comma-separated)")
    p.add_argument("--render-points", type=float, default=4e6, help="points of the store the frames are timed on")
    p.add_argument("--size", type=int, default=256, help="image edge in pixels")
    p.add_argument("--tolerances", default="1px,2px,4px,0.02,0.05,0.1,0.2")
    p.add_argument("--representative", choices=("nearest", "mean"), default="nearest", help="inner nodes' values")
    p.add_argument("--frames-png", default=str(RESULTS / "bench_splat_frames.png"))
    p.add_argument("--out", default=str(RESULTS / "bench_splat.csv"))
    p.add_argument("--build-only", action="store_true",
                   help="time the builds only (no frames); rows go to --out (e.g. tools/bench/results/bench_splat_build.csv)")
    a = p.parse_args(argv)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        render_store = None
        for n in sorted({int(float(s)) for s in a.build_sizes.split(",")} | {int(a.render_points)}):
            out = Path(tmp) / f"p{n}"
            b = _child(_BUILD_CHILD, {"n": n, "out": str(out), "representative": a.representative})
            z = _child(_ZARR_CHILD, {"n": n, "out": str(Path(tmp) / "z")})
            r = {"what": f"build {n:,} points", "points": n, "build_s": b["seconds"], "build_rss_mb": b["rss_mb"],
                 "zarr_s": z["seconds"], "zarr_rss_mb": z["rss_mb"], "ratio": z["seconds"] / b["seconds"],
                 "points_per_s": n / b["seconds"], "nodes": b["nodes"], "depth": b["depth"]}
            print(r, flush=True)
            rows.append(r)
            if n == int(a.render_points):
                render_store = out
            else:
                import shutil

                shutil.rmtree(out)
        frames = [] if a.build_only else _frames(render_store, a.size, a.tolerances.split(","), Path(a.frames_png))
    base = frames[-1]["frame_s"] if frames else 0.0
    for f in frames:
        f["speedup_vs_every_point"] = base / f["frame_s"]
    keys = sorted({k for r in rows + frames for k in r})
    with open(a.out, "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=keys)
        w.writeheader()
        for r in rows + frames:
            w.writerow(r)
    if frames:
        _plot(frames, Path(a.out).with_suffix(".png"), int(a.render_points))
    print(f"wrote {a.out}")
    return 0


def _plot(frames: list[dict], path: Path, n: int) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fr = [f for f in frames if f["tolerance_px"] > 0]
    tol = [f["tolerance_px"] for f in fr]
    fig, ax = plt.subplots(1, 2, figsize=(10, 4))
    ax[0].loglog(tol, [1.0 / f["frame_s"] for f in fr], "o-", label="splats (warm)")
    ax[0].axhline(1.0 / frames[-1]["frame_s"], color="k", ls="--", label="every point (baseline)")
    ax[0].set_xlabel("tolerance (pixels, largest splat)")
    ax[0].set_ylabel("frames per second")
    ax[0].set_title(f"{n:,} clustered points, llvmpipe")
    ax[0].legend()
    ax[1].semilogx(tol, [f["pct_de6_vs_every_point"] for f in fr], "o-", label="splats at the tolerance")
    ax[1].semilogx(tol, [f["blur_pct_de6"] for f in fr], "k:", label="every point, blurred by one splat's footprint")
    ax[1].legend(fontsize=8)
    ax[1].set_xlabel("tolerance (pixels)")
    ax[1].set_ylabel("% pixels with ΔE ≥ 6 vs every point drawn")
    fig.tight_layout()
    fig.savefig(path, dpi=100)


if __name__ == "__main__":
    sys.exit(main())
