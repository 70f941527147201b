"""Slice benchmark: multiresolution cutting planes against full resolution, and against a 2D texture.

Every figure is a ratio measured in one run on this machine (Mesa llvmpipe, no GPU). One axial
slice (level-0 voxel ``round(0.45 * nz)``) with its point of interest at 30 % / 35 % of the x / y
extent, one pixel a level-0 voxel, the whole plane in view; per store:

* **bytes** - the full-resolution slice (``level=0``) and the multiresolution slice (the per-brick
  cover of :mod:`clipvol.scene.slice_cover`) at each of ``--distance-factors``, each from a cold
  clip-texture paging the slice's slab region, converged, its queue drained: the bytes the slice's
  bricks hold in memory (``SliceStats.bytes_needed``: distinct bricks x brick size, computed) and
  the bytes the loader read from storage (counted where they are read,
  :mod:`clipvol.paging.readcount`). Ratios: the full-resolution slice's over the multiresolution
  one's. Target >= 8x fewer (LaMar, Hamann & Joy's Table 1: 56 MB -> 7 MB).
* **quality** - % of pixels with CIELUV Delta E >= 6 against the exact slice (outside our code
  path: the generator's values for a virtual store, zarr-python's read of the level-0 planes for
  a store on disk; grey window over the value range), inside the focus radius (the disc around
  the point of interest drawn from level 0) and overall, the largest Delta E, PSNR. Target <= 1 %.
* **frame time** - a warm frame of :class:`SliceAction` (cut, upload, draw, read-back, grey
  mapping) at full resolution and at each factor, interleaved with the reference outside our
  code path: the exact slice held as one prepared 2D ``r32f`` texture, one textured quad drawn with
  moderngl, read back and mapped the same way. Medians of ``--repeat``.
* **stepping** (``--steps`` > 0, the first store only) - slices per second while stepping the axial
  plane through the volume at ``distance_factor`` 0.5 (the point of interest follows it), each
  slice converged, with the texture budget held (the largest texture footprint against it).

The stores (``--bricks`` and ``--size`` by default, no bricking):

* **virtual** - a procedural fractal ``--size``^3 float32 evaluated per brick at each of
  ``--bricks``, each brick read counted as the size of its chunk encoded with the codec
  ``clipvol brick`` writes (:class:`bench_slice_io.EncodedFractal`): the bytes a store on disk
  would hold, without bricking one;
* ``--store PATH ...`` - stores on disk instead (e.g. the MNI template bricked by ``clipvol brick``
  at 16 and 32); their manifests price the slice's region in chunk bytes, so the slice action draws
  full resolution where that reads no more bytes (reported as ``drawn`` ``full``);
* ``--bricked`` - the 640^3 store ``bench-data/fractal-640-b64.zarr`` (1.05 GB, bricked with
  ``clipvol brick`` first if missing), as a store on disk;
* ``--quick`` - a 256^3 virtual store at 32^3 bricks, factor 0.5, no stepping (smoke run).

Flags: ``--budget`` / ``--full-budget`` (the clip-texture's memory for the multiresolution and the
full-resolution slices: their windows must hold the slab), ``--repeat`` (timed frames),
``--steps``, ``--threads``, ``--name`` (the CSV's and plot's file name, default ``bench_slice``),
``--images DIR`` (where the compared slices of the first store go: ``slice_full.png``,
``slice_multires.png`` at factor 0.5 and ``slice_levels.png``, its tiles tinted by level; default
``tools/bench/results/images``), ``--out-dir``. Run from the repository root::

    python tools/bench/bench_slice.py                                  # 1024^3 virtual, 64^3 and 32^3
    python tools/bench/bench_slice.py --store mni16.zarr mni32.zarr --steps 0

Writes ``tools/bench/results/NAME.csv`` and ``NAME.png``.

References
----------
E. LaMar, M. A. Duchaineau, B. Hamann, K. I. Joy, "Multiresolution techniques for interactive
texture-based rendering of arbitrarily oriented cutting planes", Joint Eurographics - IEEE TCVG
Symposium on Visualization (VisSym), 2000.
"""

from __future__ import annotations

import argparse
import csv
import statistics
import sys
import time
from pathlib import Path

import numpy as np

from bench_slice_io import TEXTURE_BUDGET, EncodedFractal, _slice, _zarr_plane, exact_axial_values  # noqa: E402
from common import RESULTS, big_fractal_store  # noqa: E402  (tools/bench/common.py)

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
    """The reference: a finished slice as one 2D float texture, drawn as one quad and read back
    (into the float target the actions draw into, :class:`clipvol.render.target.FloatTarget`,
    which binds back what was bound before)."""

    def __init__(self, ctx, values: np.ndarray) -> None:
        import moderngl

        from clipvol.render.target import FloatTarget

        h, w = values.shape
        self.ctx, self.size = ctx, (w, h)
        self.tex = ctx.texture((w, h), 1, np.ascontiguousarray(values[::-1], dtype=np.float32).tobytes(), dtype="f4")
        self.tex.filter = (moderngl.LINEAR, moderngl.LINEAR)
        self.prog = ctx.program(vertex_shader=_QUAD_VS, fragment_shader=_QUAD_FS)
        self.vbo = ctx.buffer(np.array([-1, -1, 1, -1, -1, 1, 1, 1], dtype=np.float32).tobytes())
        self.vao = ctx.vertex_array(self.prog, [(self.vbo, "2f", "in_pos")])
        self.target = FloatTarget(ctx)
        self._mgl = moderngl

    def render(self, window) -> np.ndarray:
        from clipvol.render.slice_action import window_level_grey

        w, h = self.size
        previous = self.ctx.fbo
        fbo = self.target.ensure((w, h))
        fbo.use()
        self.ctx.viewport = (0, 0, w, h)
        fbo.clear(0.0, 0.0, 0.0, 0.0)
        self.tex.use(0)
        self.vao.render(self._mgl.TRIANGLE_STRIP)
        self.ctx.finish()
        raw = self.target.read()
        self.target.restore(previous)
        v = np.where(raw[..., 1] > 0.5, raw[..., 0], np.nan)
        return window_level_grey(v, *window)

    def release(self) -> None:
        for o in (self.vao, self.vbo, self.prog, self.tex):
            o.release()
        self.target.release()


FIELDS = ["store", "brick", "what", "distance_factor", "drawn", "tiles", "bytes_needed", "bytes_read", "chunks_read",
          "converged", "fewer_bytes_needed", "fewer_bytes_read", "pct_de6_vs_exact", "pct_de6_inside_focus",
          "focus_radius", "max_de_vs_exact", "psnr_db", "frame_ms", "texture_ms", "frame_vs_texture", "slices_per_s", "texture_of_budget"]


def _stores(args) -> list:
    """``(name, make_loader, exact_values)`` per store: ``make_loader()`` a loader (a fresh one per
    slice for a store on disk; the same counted virtual store), ``exact_values(plane)`` the exact
    axial slice's values outside our code path."""
    from clipvol.paging.open import open_store

    if args.store:
        paths = list(args.store)
    elif args.bricked:
        store = big_fractal_store()
        if store is None:
            return []
        paths = [str(store)]
    else:
        out = []
        for b in args.bricks:
            ld = EncodedFractal(args.size, b)
            out.append((f"fractal {args.size}^3 float32 (virtual)", lambda ld=ld: ld,
                        lambda plane, ld=ld: exact_axial_values(ld, plane)))
        return out
    return [(Path(p).name, lambda p=p: open_store(p),
             lambda plane, p=p, pyr=open_store(p).pyramid: _zarr_plane(p, plane.origin[2] / pyr.spacing[0])[2])
            for p in paths]


def _plane_and_poi(pyr):
    from clipvol.scene.plane import Plane

    nz, ny, nx = pyr.shape
    sp = np.array(pyr.spacing[::-1])
    plane = Plane.axis(pyr, "axial", min(round(0.45 * nz), nz - 1))
    poi = np.array([0.3 * (nx - 1), 0.35 * (ny - 1), 0.0]) * sp
    poi[2] = plane.origin[2]
    return plane, poi


def measure(ctx, args, name, make_loader, exact_values, log) -> tuple[list, dict]:
    """The rows of one store (module docstring) and, for the images and the plot, the slices drawn."""
    from clipvol.render.slice_action import window_level_grey
    from clipvol.scene.metrics import delta_e_luv, psnr
    from clipvol.scene.plane import default_pixel_size

    pyr = make_loader().pyramid
    plane, poi = _plane_and_poi(pyr)
    lo_v, hi_v = pyr.value_range
    window = ((lo_v + hi_v) / 2.0, max(hi_v - lo_v, 1e-300))
    exact_v = exact_values(plane)
    exact = window_level_grey(exact_v, *window)
    log(f"{name}: level 0 {pyr.shape}, bricks {pyr.brick_shape}, {pyr.num_levels} levels; axial slice "
        f"z={plane.origin[2]:g}, point of interest {tuple(poi.round(1).tolist())}")
    configs = [("full resolution", None, dict(level=0), args.full_budget)]
    configs += [("multiresolution", df, dict(focus=tuple(poi.tolist()), distance_factor=df), args.budget)
                for df in args.distance_factors]
    ref = TextureSlice(ctx, exact_v.astype(np.float32))
    assert np.mean(np.abs(ref.render(window).astype(int) - exact.astype(int))) < 1.0  # it shows the exact slice
    got: dict = {}
    try:
        for what, df, params, budget in configs:
            out: dict = {}
            timed: dict = {}
            rgba, b_read, n_read, ok = _slice(ctx, make_loader(), plane, budget, threads=args.threads, follow=True,
                                              out=out, then=lambda sa: timed.update(_warm_frames(sa, ref, plane,
                                                                                                 window, args.repeat)),
                                              **params)
            got[df] = dict(rgba=rgba, read=b_read, chunks=n_read, converged=ok, **out, **timed)
    finally:
        ref.release()
    full = got[None]
    h, w = exact_v.shape
    pts = plane.pixel_points((w, h), default_pixel_size(pyr, plane))
    dist = np.linalg.norm(pts - poi, axis=-1)
    rows = []
    for what, df, params, _ in configs:
        g = got[df]
        st, levels = g["stats"], g["levels"]
        coarse = (levels != 0) & (levels >= 0)
        radius = float(dist[coarse].min()) if coarse.any() else float("inf")
        de = delta_e_luv(g["rgba"], exact)
        inside = dist < radius
        g.update(pct=100.0 * float(np.mean(de >= 6)), radius=radius,
                 pct_in=100.0 * float(np.mean(de[inside] >= 6)) if inside.any() else 0.0,
                 de_max=float(de.max()), psnr=float(psnr(g["rgba"], exact)))
        drawn = "full" if g["params"].level == 0 else "multiresolution"
        rows.append(dict(store=name, brick=pyr.brick_shape[0], what=what, distance_factor="" if df is None else df,
                         drawn=drawn, tiles=st.tiles, bytes_needed=st.bytes_needed, bytes_read=g["read"],
                         chunks_read=g["chunks"], converged=g["converged"],
                         fewer_bytes_needed=round(full["stats"].bytes_needed / max(st.bytes_needed, 1), 3),
                         fewer_bytes_read=round(full["read"] / max(g["read"], 1), 3),
                         pct_de6_vs_exact=round(g["pct"], 3), pct_de6_inside_focus=round(g["pct_in"], 3),
                         focus_radius=round(radius, 1), max_de_vs_exact=round(g["de_max"], 2),
                         psnr_db=round(g["psnr"], 2), frame_ms=round(1e3 * g["frame"], 1),
                         texture_ms=round(1e3 * g["texture"], 1), frame_vs_texture=round(g["frame"] / g["texture"], 2)))
        log(f"  {what}{'' if df is None else f' distance_factor {df}'}: {st.tiles} tiles {st.tiles_per_level}, "
            f"needs {st.bytes_needed / 1e6:.1f} MB ({rows[-1]['fewer_bytes_needed']:.1f}x fewer), read "
            f"{g['read'] / 1e6:.2f} MB in {g['chunks']} chunks ({rows[-1]['fewer_bytes_read']:.1f}x fewer), drawn "
            f"{drawn}; dE>=6 against the exact slice on {g['pct']:.2f} % of pixels ({g['pct_in']:.2f} % inside the "
            f"focus radius {radius:.0f}), max dE {g['de_max']:.1f}" + ("" if g["converged"] else " (NOT CONVERGED)")
            + f"; warm frame {1e3 * g['frame']:.1f} ms, one 2D texture {1e3 * g['texture']:.1f} ms "
            f"({g['frame'] / g['texture']:.2f}x)")
    return rows, dict(got=got, exact=exact, plane=plane, poi=poi, window=window)


def _warm_frames(sa, ref, plane, window, repeat: int) -> dict:
    """Median seconds of a warm slice frame and of the 2D texture's, drawn in turn ``repeat`` times."""
    t_slice, t_ref = [], []
    for _ in range(repeat):
        t0 = time.perf_counter()
        sa.render(plane, window=window)
        t_slice.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        ref.render(window)
        t_ref.append(time.perf_counter() - t0)
    return dict(frame=statistics.median(t_slice), texture=statistics.median(t_ref))


def stepping(ctx, args, make_loader, log) -> dict:
    """Converged slices per second stepping the axial plane through the volume (module docstring)."""
    from clipvol.paging.cliptexture import ClipTexture
    from clipvol.render.slice_action import SliceAction
    from clipvol.scene.params import RenderParams
    from clipvol.scene.plane import Plane
    from clipvol.units import parse_bytes

    loader = make_loader()
    pyr = loader.pyramid
    nz = pyr.shape[0]
    _, poi = _plane_and_poi(pyr)
    zs = np.linspace(0.1 * (nz - 1), 0.9 * (nz - 1), args.steps)
    peak_tex, n_conv = 0, 0
    with ClipTexture(loader, args.budget, args.threads, center=poi) as clip, \
            SliceAction(ctx, clip, texture_budget=TEXTURE_BUDGET) as sa:
        t0 = time.perf_counter()
        for z in zs:
            pl = Plane.axis(pyr, "axial", float(z))
            p = poi.copy()
            p[2] = pl.origin[2]
            clip.set_center(p)
            sa.set_params(RenderParams(policy="plane", focus=tuple(p), distance_factor=0.5,
                                       texture_budget=TEXTURE_BUDGET))
            sa.render(pl, wait=True, timeout=600)
            n_conv += sa.last_stats.converged
            peak_tex = max(peak_tex, sa.cache.texture_bytes)
        dt = time.perf_counter() - t0
    budget = parse_bytes(TEXTURE_BUDGET)
    log(f"  stepping: {len(zs)} slices in {dt:.2f} s = {len(zs) / dt:.2f} slices/s ({n_conv} converged), textures "
        f"{peak_tex / 1e6:.0f} MB of {budget / 1e6:.0f} MB")
    return dict(what=f"stepping {len(zs)} slices", distance_factor=0.5, drawn="multiresolution",
                converged=f"{n_conv}/{len(zs)}", frame_ms=round(1e3 * dt / len(zs), 1),
                slices_per_s=round(len(zs) / dt, 3), texture_of_budget=round(peak_tex / budget, 3))


def save_images(img_dir: Path, shown: dict) -> None:
    """The full-resolution slice, the multiresolution one at factor 0.5 and its tiles tinted by level
    (white: level 0, then red, green, yellow, blue, violet; the paper's Fig. 6b), at most 512 pixels
    a side."""
    from PIL import Image

    got = shown["got"]
    if 0.5 not in got:
        return
    img_dir.mkdir(parents=True, exist_ok=True)
    full = got[None]["rgba"]
    k = max(1, -(-max(full.shape[:2]) // 512))

    def save(img, name):
        Image.fromarray(np.ascontiguousarray(img[::k, ::k]), "RGBA").save(img_dir / name)

    save(full, "slice_full.png")
    save(got[0.5]["rgba"], "slice_multires.png")
    tint = np.array([[255, 255, 255], [255, 120, 120], [120, 255, 120], [255, 230, 90], [120, 160, 255],
                     [220, 120, 255]], dtype=np.float64)
    lv = np.clip(got[0.5]["levels"], 0, len(tint) - 1)
    over = got[0.5]["rgba"].astype(np.float64)
    over[..., :3] = over[..., :3] * tint[lv] / 255.0
    save(np.rint(over).astype(np.uint8), "slice_levels.png")


def plot(path: Path, rows: list) -> None:
    """Bytes read, fewer than the full-resolution slice, per store and factor, with the error beside."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:  # pragma: no cover
        return
    multi = [r for r in rows if r["what"] == "multiresolution"]
    labels = [f"{r['store'].split(' float32')[0].removesuffix('.zarr')}\nb{r['brick']} f={r['distance_factor']}"
              for r in multi]
    fig, ax = plt.subplots(figsize=(max(6.0, 1.1 * len(multi)), 3.6))
    x = np.arange(len(multi))
    ax.bar(x, [r["fewer_bytes_read"] for r in multi], color="tab:green")
    for i, r in enumerate(multi):
        ax.text(i, r["fewer_bytes_read"], f"{r['fewer_bytes_read']:.1f}x\nΔE≥6 {r['pct_de6_vs_exact']:.1f} %",
                ha="center", va="bottom", fontsize=7)
    ax.axhline(8, color="grey", ls="--", lw=0.8)
    ax.set_xticks(x, labels, fontsize=7)
    ax.set_ylabel("bytes read: full resolution / multiresolution")
    ax.set_title("multiresolution slice: fewer bytes read than the full-resolution slice")
    ax.set_ylim(0, max(r["fewer_bytes_read"] for r in multi) * 1.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", type=int, default=1024, help="edge of the virtual store (voxels)")
    ap.add_argument("--bricks", nargs="+", type=int, default=[64, 32], help="brick edges of the virtual stores")
    ap.add_argument("--store", nargs="+", default=None, metavar="PATH", help="stores on disk instead")
    ap.add_argument("--bricked", action="store_true", help="the 640^3 store in bench-data/, bricked if missing")
    ap.add_argument("--quick", action="store_true", help="a 256^3 virtual store, 32^3 bricks (smoke run)")
    ap.add_argument("--distance-factors", nargs="+", type=float, default=[1.0, 0.5, 0.25])
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--steps", type=int, default=24, help="slices of the stepping test (0: none)")
    ap.add_argument("--budget", default="1GB", help="memory budget of the multiresolution slices and the stepping")
    ap.add_argument("--full-budget", default="2GB", help="memory budget of the full-resolution slice (holds its slab)")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--name", default="bench_slice", help="file name of the CSV and the plot")
    ap.add_argument("--images", type=Path, default=None, help="where the first store's compared slices go")
    ap.add_argument("--out-dir", type=Path, default=RESULTS)
    args = ap.parse_args(argv)
    if args.quick:
        args.size, args.bricks, args.distance_factors, args.steps, args.repeat = 256, [32], [0.5], 0, 2
    from clipvol.render import create_context

    log = lambda *a: print(*a, file=sys.stderr, flush=True)  # noqa: E731
    stores = _stores(args)
    if not stores:
        return 2
    ctx = create_context()
    rows: list = []
    try:
        for i, (name, make_loader, exact_values) in enumerate(stores):
            got, shown = measure(ctx, args, name, make_loader, exact_values, log)
            rows += got
            if i == 0:
                save_images(args.images or args.out_dir / "images", shown)
                if args.steps > 0:
                    rows.append(dict(store=name, brick=make_loader().pyramid.brick_shape[0],
                                     **stepping(ctx, args, make_loader, log)))
    finally:
        ctx.release()
    args.out_dir.mkdir(parents=True, exist_ok=True)
    with open(args.out_dir / f"{args.name}.csv", "w", newline="") as fh:
        wr = csv.DictWriter(fh, FIELDS)
        wr.writeheader()
        wr.writerows(rows)
    plot(args.out_dir / f"{args.name}.png", rows)
    return 0


if __name__ == "__main__":
    sys.exit(main())
