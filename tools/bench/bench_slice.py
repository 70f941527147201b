"""Slice benchmark: multiresolution cutting planes against full resolution, and against a 2D texture.

Every figure is a ratio measured in one run on this machine (Mesa llvmpipe, no GPU):

* **bytes for a slice** - the distinct bricks a multiresolution slice with a point of interest
  needs (its tiles and the parents its blending samples: ``SliceStats.bytes_needed``, computed as
  bricks x brick size, not bytes read: the clip-texture loads whole windows) against the
  same slice at full resolution (``--level 0``: every level-0 brick the plane crosses). Target
  >= 8x fewer (LaMar, Hamann & Joy's Table 1: 56 MB -> 7 MB), at <= 1 % of pixels with CIELUV
  Delta E >= 6 against the full-resolution slice and 0 % inside the focus radius (the disc around
  the point of interest drawn from level 0). Swept over ``distance_factor`` (1, 0.5, 0.25).
* **slice frame time** - a warm multiresolution frame of :class:`SliceAction` (selection,
  balancing, ratios, draw, read-back, grey mapping) against a reference outside our code path:
  the full-resolution slice held as one 2D ``r32f`` texture, one textured quad drawn with
  moderngl, read back and mapped the same way. Median of ``--repeat``.
* **stepping** - slices per second while stepping the axial plane through the volume (the point of
  interest and the clip-texture's centre follow it), each slice converged (``wait=True``), with
  the texture budget held (the largest texture footprint is reported against the budget).

Run ``python tools/bench/bench_slice.py`` (uses ``bench-data/fractal-640-b64.zarr``, 640^3
float32 = 1.05 GB, bricking it with ``clipvol brick`` first if missing) or ``--quick`` for a small
smoke run. Writes ``tools/bench/results/bench_slice.csv``, ``tools/bench/results/bench_slice.png`` and the compared slices
``docs/images/slice_full.png`` / ``docs/images/slice_multires.png``.

References
----------
E. LaMar, B. Hamann, K. I. Joy, "Multiresolution cutting planes".
"""

from __future__ import annotations

import argparse
import csv
import statistics
import sys
import time
from pathlib import Path

import numpy as np

from common import RESULTS, STORE, big_fractal_store  # noqa: E402  (tools/bench/common.py)

_QUAD_VS = """#version 330
in vec2 in_pos;
out vec2 v_uv;
void main() { v_uv = in_pos * 0.5 + 0.5; gl_Position = vec4(in_pos, 0.0, 1.0); }
"""
_QUAD_FS = """#version 330
uniform sampler2D u_tex;
in vec2 v_uv;
out vec4 f_color;
void main() { f_color = vec4(texture(u_tex, v_uv).r, 1.0, 0.0, 0.0); }
"""


class TextureSlice:
    """The reference: a finished slice as one 2D float texture, drawn as one quad and read back."""

    def __init__(self, ctx, values: np.ndarray) -> None:
        import moderngl

        h, w = values.shape
        self.ctx, self.size = ctx, (w, h)
        self.tex = ctx.texture((w, h), 1, np.ascontiguousarray(values[::-1], dtype=np.float32).tobytes(), dtype="f4")
        self.tex.filter = (moderngl.LINEAR, moderngl.LINEAR)
        self.prog = ctx.program(vertex_shader=_QUAD_VS, fragment_shader=_QUAD_FS)
        self.vbo = ctx.buffer(np.array([-1, -1, 1, -1, -1, 1, 1, 1], dtype=np.float32).tobytes())
        self.vao = ctx.vertex_array(self.prog, [(self.vbo, "2f", "in_pos")])
        self.color = ctx.texture((w, h), 4, dtype="f4")
        self.fbo = ctx.framebuffer(color_attachments=[self.color])
        self._mgl = moderngl

    def render(self, window) -> np.ndarray:
        from clipvol.render.slice_action import window_level_grey

        w, h = self.size
        previous = self.ctx.fbo
        self.fbo.use()
        self.ctx.viewport = (0, 0, w, h)
        self.fbo.clear(0.0, 0.0, 0.0, 0.0)
        self.tex.use(0)
        self.vao.render(self._mgl.TRIANGLE_STRIP)
        self.ctx.finish()
        raw = np.frombuffer(self.fbo.read(components=4, dtype="f4"), dtype=np.float32).reshape(h, w, 4)[::-1]
        if previous is not None:
            previous.use()
        v = np.where(raw[..., 1] > 0.5, raw[..., 0], np.nan)
        return window_level_grey(v, *window)

    def release(self) -> None:
        for o in (self.vao, self.vbo, self.prog, self.tex, self.fbo, self.color):
            o.release()


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--source", default=None, help="a store or source (default: bench-data/" + STORE + ")")
    ap.add_argument("--quick", action="store_true", help="a small procedural volume (smoke run)")
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--steps", type=int, default=24, help="slices of the stepping test")
    ap.add_argument("--texture-budget", default="1100MB", help="GPU cache budget (its cubic windows must hold a full-resolution plane: 10^3 level-0 bricks here)")
    ap.add_argument("--memory-budget", default="1200MB", help="clip-texture budget (likewise)")
    ap.add_argument("--out-dir", type=Path, default=RESULTS)
    args = ap.parse_args(argv)

    from PIL import Image

    from clipvol.paging.cliptexture import ClipTexture
    from clipvol.paging.open import open_store
    from clipvol.render import create_context
    from clipvol.render.slice_action import SliceAction
    from clipvol.scene.metrics import delta_e_luv, psnr
    from clipvol.scene.params import RenderParams
    from clipvol.scene.plane import Plane
    from clipvol.units import parse_bytes

    if args.quick:
        source, kw = "procedural:fractal?size=96x192x192", {"brick": 16}
    elif args.source:
        source, kw = args.source, {}
    else:
        store = big_fractal_store()
        if store is None:
            return 2
        source, kw = str(store), {}
    log = lambda *a: print(*a, file=sys.stderr, flush=True)  # noqa: E731
    loader = open_store(source, **kw)
    pyr = loader.pyramid
    nz, ny, nx = pyr.shape
    sp = np.array(pyr.spacing[::-1])
    plane = Plane.axis(pyr, "axial", round(0.45 * nz))
    poi = np.array([0.3 * (nx - 1), 0.35 * (ny - 1), 0.0]) * sp
    poi[2] = plane.origin[2]
    lo_v, hi_v = pyr.value_range
    window = ((lo_v + hi_v) / 2.0, hi_v - lo_v)
    log(f"source {source}: level 0 {pyr.shape}, bricks {pyr.brick_shape}, "
        f"{pyr.num_bricks(0) * pyr.brick_nbytes / 2**30:.2f} GiB; axial slice z={plane.origin[2]:g}, "
        f"point of interest {tuple(poi.round(1))}")
    ctx = create_context()
    rows: list[tuple] = []
    clip = ClipTexture(loader, args.memory_budget, center=poi)
    sa = SliceAction(ctx, clip, texture_budget=args.texture_budget)
    try:
        # -- full resolution, then multiresolution at several distance factors (cold -> converged)
        sa.set_params(RenderParams(policy="plane", level=0, texture_budget=args.texture_budget))
        full, v_full = sa.render(plane, window=window, wait=True, timeout=180, return_values=True)
        st_full = sa.last_stats
        log(f"full resolution: {st_full.tiles} tiles, {st_full.bytes_needed / 1e6:.1f} MB, {st_full.times['total']:.2f} s")
        h, w = v_full.shape
        yy, xx = np.mgrid[0:h, 0:w]
        pts = plane.pixel_points((w, h), float(sp[:2].min()))
        dist = np.linalg.norm(pts - poi, axis=-1)
        results = {}
        for f in (1.0, 0.5, 0.25):
            sa.set_params(RenderParams(policy="plane", focus=tuple(poi), distance_factor=f,
                                       texture_budget=args.texture_budget))
            img, v = sa.render(plane, window=window, wait=True, timeout=180, return_values=True)
            st = sa.last_stats
            levels = sa.last_levels
            radius = float(dist[(levels != 0) & (levels >= 0)].min()) if np.any((levels != 0) & (levels >= 0)) else np.inf
            de = delta_e_luv(img, full)
            inside = dist < radius
            pct = 100.0 * float(np.mean(de >= 6))
            pct_in = 100.0 * float(np.mean(de[inside] >= 6)) if inside.any() else 0.0
            ratio = st_full.bytes_needed / st.bytes_needed
            ps = psnr(img, full)
            results[f] = (img, st, pct, pct_in, radius, ratio, levels.copy(), ps)
            log(f"distance_factor {f}: {st.tiles} tiles {st.tiles_per_level}, {st.bytes_needed / 1e6:.1f} MB "
                f"({ratio:.1f}x fewer), {pct:.2f} % pixels dE>=6 ({pct_in:.2f} % inside the focus radius {radius:.0f}), "
                f"PSNR {ps:.1f} dB")
            rows.append((f"bytes, multires distance_factor={f}", st.bytes_needed, "full-resolution slice",
                         st_full.bytes_needed, ratio, ">= 8x fewer", ratio >= 8))
            rows.append((f"PSNR dB, distance_factor={f}", round(ps, 2), "full-resolution slice", "", None, "report", ""))
            rows.append((f"% pixels dE>=6, distance_factor={f} (inside focus radius {radius:.0f})",
                         round(pct, 3), "full-resolution slice", round(pct_in, 3), None, "<= 1 % (0 % inside)",
                         pct <= 1.0 and pct_in == 0.0))
        # -- warm frame time against one 2D texture of the full-resolution slice
        sa.set_params(RenderParams(policy="plane", focus=tuple(poi), distance_factor=0.5,
                                   texture_budget=args.texture_budget))
        sa.render(plane, window=window, wait=True, timeout=180)
        ref = TextureSlice(ctx, v_full)
        t_multi, t_ref = [], []
        for _ in range(args.repeat):
            t0 = time.perf_counter()
            sa.render(plane, window=window)
            t_multi.append(time.perf_counter() - t0)
            t0 = time.perf_counter()
            ref_img = ref.render(window)
            t_ref.append(time.perf_counter() - t0)
        assert np.mean(np.abs(ref_img.astype(int) - full.astype(int))) < 1.0  # the reference shows the same slice
        ref.release()
        tm, tr = statistics.median(t_multi), statistics.median(t_ref)
        log(f"warm frame: multires slice {tm * 1000:.1f} ms, one 2D texture {tr * 1000:.1f} ms ({tm / tr:.2f}x)")
        rows.append(("warm frame time (s), multires slice", tm, "one 2D texture of the full-res slice", tr, tm / tr,
                     "report", ""))
        # -- stepping through the volume with the budget held
        zs = np.linspace(0.1 * (nz - 1), 0.9 * (nz - 1), args.steps)
        peak_tex = 0
        t0 = time.perf_counter()
        loaded0 = clip.stats.bytes_loaded
        n_conv = 0
        for z in zs:
            pl = Plane.axis(pyr, "axial", float(z))
            p = poi.copy()
            p[2] = pl.origin[2]
            clip.set_center(p)
            sa.set_params(RenderParams(policy="plane", focus=tuple(p), distance_factor=0.5,
                                       texture_budget=args.texture_budget))
            sa.render(pl, window=window, wait=True, timeout=120)
            n_conv += sa.last_stats.converged
            peak_tex = max(peak_tex, sa.cache.texture_bytes)
        dt = time.perf_counter() - t0
        budget = parse_bytes(args.texture_budget)
        log(f"stepping: {len(zs)} slices in {dt:.2f} s = {len(zs) / dt:.1f} slices/s ({n_conv} converged), "
            f"textures {peak_tex / 1e6:.0f} MB of {budget / 1e6:.0f} MB, loaded {(clip.stats.bytes_loaded - loaded0) / 1e6:.0f} MB")
        rows.append(("stepping, converged slices per second", len(zs) / dt, "texture bytes / budget",
                     peak_tex / budget, None, "budget held", peak_tex <= budget))
    finally:
        sa.close()
        clip.close()
        ctx.release()

    args.out_dir.mkdir(parents=True, exist_ok=True)
    with open(args.out_dir / "bench_slice.csv", "w", newline="") as fh:
        wr = csv.writer(fh)
        wr.writerow(["date", time.strftime("%Y-%m-%d %H:%M")])
        wr.writerow(["metric", "value", "reference", "reference_value", "ratio", "target", "met"])
        for r in rows:
            wr.writerow([r[0], f"{r[1]:.6g}" if isinstance(r[1], float) else r[1], r[2],
                         f"{r[3]:.6g}" if isinstance(r[3], float) else r[3],
                         f"{r[4]:.3f}" if isinstance(r[4], float) else "", r[5], r[6]])
    img_dir = args.out_dir / "images"
    img_dir.mkdir(exist_ok=True)
    k = max(1, -(-max(full.shape[:2]) // 512))  # at most 512 pixels a side in the docs

    def save(img, name):
        Image.fromarray(np.ascontiguousarray(img[::k, ::k]), "RGBA").save(img_dir / name)

    save(full, "slice_full.png")
    save(results[0.5][0], "slice_multires.png")
    # the tiles' levels as a tint over the multiresolution slice (the paper's Fig. 6b)
    tint = np.array([[255, 255, 255], [255, 120, 120], [120, 255, 120], [255, 230, 90], [120, 160, 255],
                     [220, 120, 255]], dtype=np.float64)
    lv = np.clip(results[0.5][6], 0, len(tint) - 1)
    over = results[0.5][0].astype(np.float64)
    over[..., :3] = over[..., :3] * tint[lv] / 255.0
    save(np.rint(over).astype(np.uint8), "slice_levels.png")
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fs = sorted(results, reverse=True)
        fig, ax = plt.subplots(1, 2, figsize=(9, 3.4))
        ax[0].bar([f"multires\nf={f}" for f in fs] + ["full res"],
                  [results[f][1].bytes_needed / 1e6 for f in fs] + [st_full.bytes_needed / 1e6],
                  color=["tab:green"] * len(fs) + ["tab:blue"])
        for i, f in enumerate(fs):
            ax[0].text(i, results[f][1].bytes_needed / 1e6, f"{results[f][5]:.1f}x fewer", ha="center", va="bottom")
        ax[0].set_ylabel("MB the slice reads")
        ax[0].set_title("bytes: ratio to the full-resolution slice")
        ax[1].bar([f"f={f}" for f in fs], [results[f][7] for f in fs], color="tab:orange")
        for i, f in enumerate(fs):
            ax[1].text(i, results[f][7], f"ΔE≥6: {results[f][2]:.2f} %\n(inside: {results[f][3]:.2f} %)",
                       ha="center", va="bottom", fontsize=8)
        ax[1].set_ylabel("PSNR (dB) vs the full-resolution slice")
        ax[1].set_ylim(0, max(results[f][7] for f in fs) * 1.25)
        ax[1].set_title("error against the full-resolution slice")
        fig.suptitle(f"multiresolution slice; warm frame {tm / tr:.2f}x the time of one 2D texture")
        fig.tight_layout()
        fig.savefig(args.out_dir / "bench_slice.png", dpi=110)
    except ImportError:  # pragma: no cover
        log("matplotlib missing: no plot")
    for r in rows:
        print(",".join(str(x) for x in r))
    return 0


if __name__ == "__main__":
    sys.exit(main())
