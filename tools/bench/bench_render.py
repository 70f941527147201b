"""Render benchmark: multiresolution against full resolution, bricks against one texture, sub-loads.

Every figure is a ratio measured in one run on this machine (Mesa llvmpipe, no GPU), so the
noise of a shared machine cancels as far as it can:

* **multiresolution vs full resolution** - the same view of a >= 1 GiB store rendered with
  ``policy="projected-size", lod_threshold=1`` and with ``policy="fixed", level=0``;
  warm frames (every brick already on the GPU), median of ``--repeat``. Target >= 5x faster at
  <= 5 % of pixels with CIELUV Delta E >= 6 (``clipvol.scene.metrics``), PSNR reported too.
* **bytes loaded for the view** - the bricks the multiresolution view wants (what a cold
  clip-texture must load before the frame converges) against the level-0 bricks in the frustum.
  Target >= 8x fewer. The clip-texture's own ``bytes_loaded`` at convergence (it also pre-loads
  its windows around the centre) is reported beside it.
* **texture sub-load throughput** - MB/s of the cache's upload path (residency bookkeeping,
  conversion, one ``texture.write(viewport=...)`` per brick) re-uploading the full-resolution
  frame's bricks, against bare ``texture.write(viewport=...)`` calls of the same bricks into the
  same slots. Target >= 0.8. One big ``texture.write`` of as many bytes into one texture is
  reported beside it (what llvmpipe's memcpy reaches without sub-image addressing).
* **bricks vs one texture** - the full-resolution frame drawn as bricks against clipvol's *own*
  shader with the whole level 0 as a single brick in a single 3D texture (one draw), same view and
  step. Target <= 1.5x the time.
* **against a raw caster** - the full-resolution frame and clipvol's own one-texture frame, each
  divided by :class:`RawCaster`'s time (a plain one-texture caster outside clipvol's render path,
  same volume, view, step and table), timed in every round at two stops: 0.9995, the raw
  caster's own (``*_over_raw``), and clipvol's ``OPAQUE`` (``*_over_raw_same_stop``:
  the same samples as clipvol). Targets <= 1.1x and <= 1.05x. ``--vs-raw 256,512`` runs
  only this comparison on procedural volumes, ``--fly-only N`` only the fly-path frame times,
  ``--vs-raw-large 1024`` a 1024^3 uint8 volume (1 GiB: a float32 one would not fit beside the raw
  caster's texture) against the raw caster (per-brick and single-pass frames), with a virtual
  4096^3 multiresolution frame beside it.
* **where a ray stops** - ``--vs-stop N``: the full-resolution frame of the fractal and of the
  CT-like head (``N``³) stopping rays at 0.9995 and at clipvol's ``OPAQUE`` (1 - 0.5/255): time
  ratio and the largest 8-bit difference of the two images (``tools/bench/results/bench_render_stop.csv``).
* **the two draw paths on image-LOD cuts** - ``--vs-lod``: the head, views and cuts of
  ``tools/bench/bench_lod.py`` (full resolution and the image policy at ``--block-budget`` blocks), drawn
  by a per-brick and a single-pass session over the same store, interleaved; every ratio is the
  single pass's time over the per-brick path's (``tools/bench/results/bench_render_lod.csv``).

Run ``python tools/bench/bench_render.py`` (uses ``bench-data/fractal-640-b64.zarr``, 640^3
float32 = 1.05 GB, bricking it with ``clipvol brick`` first if it is missing) or ``--quick`` for a
small smoke run. (Mesa's llvmpipe refuses single 3D textures of about 2 GiB, which bounds the
one-texture reference caster, hence not the 2 GiB paging store.) Writes ``tools/bench/results/bench_render.csv``, ``tools/bench/results/bench_render.png`` and
the two compared images ``tools/bench/results/bench_render_full.png`` / ``tools/bench/results/bench_render_multires.png``.
"""

from __future__ import annotations

import argparse
import csv
import statistics
import sys
import time
from pathlib import Path

import numpy as np

from common import (  # noqa: E402  (tools/bench/common.py: paths, data sets, the raw caster)
    DATA, RAW_OPAQUE, RESULTS, RawCaster, WholeVolume, big_fractal_store, fractal_scene, interleaved_medians,
    ratio_columns, raw_ratio_line, raw_stops, stop_ratios, time_raw, write_rows,
)


def _frames(action, cam, tf, repeat: int) -> tuple[float, float, np.ndarray]:
    """Median total and draw seconds of ``repeat`` warm frames, and the last image."""
    tot, draw = [], []
    img = None
    for _ in range(repeat):
        img = action.render(cam, tf, wait=False)
        st = action.last_frame_stats
        tot.append(st.times["total"])
        draw.append(st.times["draw"])
    return statistics.median(tot), statistics.median(draw), img


def _raw_write_mbps(ctx, nbytes: int, brick_shape, repeat: int = 3) -> float:
    """MB/s of one ``texture.write`` of ``nbytes`` (float32) into one 3D texture of that size."""
    bz, by, bx = brick_shape
    n = max(1, nbytes // (bz * by * bx * 4))
    side = 1
    while (side * 2) ** 2 <= n and side * 2 * bx <= 2048:
        side *= 2
    depth = -(-n // (side * side))
    size = (side * bx, side * by, depth * bz)
    data = np.random.default_rng(0).random(size[::-1], dtype=np.float32)
    tex = ctx.texture3d(size, 1, dtype="f4")
    best = 0.0
    for _ in range(repeat):
        ctx.finish()
        t = time.perf_counter()
        tex.write(data, alignment=1)
        ctx.finish()
        best = max(best, data.nbytes / (time.perf_counter() - t) / 1e6)
    tex.release()
    return best


def _subload_vs_raw(action, clip, repeat: int = 3) -> tuple[float, float]:
    """MB/s of the cache's commit of the frame's bricks (re-uploaded) vs bare ``texture.write`` calls.

    Both write the same bricks into the same slots of the same (warm) textures; the cache path adds
    the residency bookkeeping, the dtype conversion and the slot arithmetic.
    """
    cache = action.cache
    B = cache.pyramid.brick_shape
    keys = sorted({(it.level, tuple(it.index)) for it in action.last_selection.items})
    datas = [(L, k, clip.get_brick(L, k)) for L, k in keys]
    datas = [d for d in datas if d[2] is not None]
    nbytes = sum(d[2].nbytes for d in datas)
    best_cache = best_raw = 0.0
    for _ in range(repeat):
        for L, k, _d in datas:  # forget them, so that the cache uploads them again
            slot = tuple(int(i) % w for i, w in zip(k, cache.windows[L]))
            cache._slot_key[L][slot] = -1
        cache.begin_frame(clip, None)
        action.ctx.finish()
        t = time.perf_counter()
        for L in sorted({d[0] for d in datas}):
            cache.resident_mask(L, np.array([d[1] for d in datas if d[0] == L]))
        cache.commit()
        action.ctx.finish()
        best_cache = max(best_cache, nbytes / (time.perf_counter() - t) / 1e6)
        t = time.perf_counter()
        for L, k, d in datas:
            slot = tuple(int(i) % w for i, w in zip(k, cache.windows[L]))
            cache.textures[L].write(d, viewport=(slot[2] * B[2], slot[1] * B[1], slot[0] * B[0], B[2], B[1], B[0]),
                                    alignment=1)
        action.ctx.finish()
        best_raw = max(best_raw, nbytes / (time.perf_counter() - t) / 1e6)
    return best_cache, best_raw


def _p(values, q: float) -> float:
    return float(np.percentile(np.asarray(values, dtype=np.float64), q))


def fly_stability(ctx, loader, tf, image: int, step: float, budget: int, frames: int, texels_per_frame: int,
                  log=print) -> dict:
    """Frame times along the ``fly`` path from a cold clip-texture, uploads limited per frame
    (``texels_per_frame``), multiresolution, jitter on (the viewer's settings): median, 95th
    percentile, frames above twice the median, wall and process CPU time, and the upload share."""
    from clipvol.paging.cliptexture import ClipTexture
    from clipvol.render.action import ClipRenderAction
    from clipvol.scene.paths import make_path

    clip = ClipTexture(loader, budget, threads=2)
    fly = ClipRenderAction(ctx, clip, lod_threshold=1.0, texels_per_frame=texels_per_frame, jitter=True, step=step,
                           texture_budget=budget)
    ft, cpu, up, upt = [], [], [], []
    cams = [fcam for fcam, _ in make_path("fly", loader.pyramid, frames, size=(image, image))]
    for fcam in cams:
        c = time.process_time()
        fly.render(fcam, tf, wait=False)
        cpu.append(time.process_time() - c)
        st = fly.last_frame_stats
        ft.append(st.times["total"])
        up.append(st.bricks_uploaded)
        upt.append(st.times["upload"])
    # the same cameras again, warm: the path's own cost per view (it draws 3x more near its end than
    # at its start), so a frame's time over its warm time is what loading added to it
    warm = []
    for fcam in cams:
        fly.render(fcam, tf, wait=False)
        warm.append(fly.last_frame_stats.times["total"])
    fly.close()
    clip.close()
    m, mc = statistics.median(ft), statistics.median(cpu)
    over = [a / b for a, b in zip(ft, warm)]
    out = dict(fly_frames=frames, fly_median_s=m, fly_p95_s=_p(ft, 95), fly_max_s=max(ft),
               fly_hitches_over_2x_median=int(sum(t > 2 * m for t in ft)), fly_cpu_median_s=mc,
               fly_cpu_p95_s=_p(cpu, 95), fly_cpu_hitches_over_2x_median=int(sum(t > 2 * mc for t in cpu)),
               fly_upload_max_s=max(upt), fly_bricks_uploaded=int(sum(up)), fly_max_bricks_per_frame=max(up),
               texels_per_frame=texels_per_frame, fly_warm_median_s=statistics.median(warm),
               fly_over_warm_median=statistics.median(over), fly_over_warm_max=max(over),
               fly_hitches_over_2x_warm=int(sum(r > 2 for r in over)))
    log(f"fly path, {frames} frames, texels_per_frame {texels_per_frame}: wall median {m:.3f} s, p95 {_p(ft, 95):.3f} s, "
        f"{out['fly_hitches_over_2x_median']} frames > 2x median; CPU median {mc:.3f} s, p95 {_p(cpu, 95):.3f} s, "
        f"{out['fly_cpu_hitches_over_2x_median']} > 2x; uploads {sum(up)} bricks, at most {max(up)} and "
        f"{max(upt) * 1e3:.0f} ms in a frame; each frame over the same view warm: median {statistics.median(over):.2f}, "
        f"max {max(over):.2f}, {out['fly_hitches_over_2x_warm']} > 2x")
    return out


def vs_raw(sizes, image: int, repeat: int, step: float, out_dir: Path, fly_frames: int = 48,
           texels_per_frame: int = 8 * 64**3, log=print) -> list[dict]:
    """clipvol's full-resolution frame (single pass and per-brick), its own shader on one texture,
    and the multiresolution frame, each as a ratio to :class:`RawCaster` on the same volume, view,
    step and table; interleaved rounds, medians of ``repeat``. Then the fly path's frame times
    (median, 95th percentile) on a cold clip-texture with uploads limited per frame.

    Volumes: ``procedural:fractal?size=N`` (float32), generated in memory.
    """
    from clipvol.loaders.numpy_array import NumpyLoader
    from clipvol.paging.cliptexture import ClipTexture
    from clipvol.render import create_context
    from clipvol.render.action import ClipRenderAction
    from clipvol.render.paths.setup import premultiplied_to_uint8

    ctx = create_context()
    rows = []
    for n in sizes:
        vol, loader, cam, tf, budget, clip = fractal_scene(n, image, log)
        pyr = loader.pyramid
        one_loader = NumpyLoader(vol, brick=n, value_range=pyr.value_range)
        clip1 = ClipTexture(one_loader, vol.nbytes + (16 << 20), threads=1)
        common = dict(step=step, texture_budget=budget)
        actions = {
            "single-pass": ClipRenderAction(ctx, clip, policy="fixed", level=0, path="single-pass", **common),
            "bricks": ClipRenderAction(ctx, clip, policy="fixed", level=0, path="bricks", **common),
            "own shader, one texture": ClipRenderAction(ctx, clip1, policy="fixed", level=0, path="bricks", step=step,
                                                        texture_budget=vol.nbytes + (16 << 20)),
            "multiresolution": ClipRenderAction(ctx, clip, lod_threshold=1.0, **common),
        }
        raw = RawCaster(ctx, vol, pyr.value_range)
        imgs = {}
        for name, a in actions.items():
            imgs[name] = a.render(cam, tf, wait=True, timeout=1800)
        raw.render(cam, tf, step)
        times = {k: [] for k in [*actions, *raw_stops()]}
        cpu = {k: [] for k in times}  # process CPU seconds (all llvmpipe threads): steadier
        for _ in range(repeat):  # interleaved: the shared machine's load hits every configuration alike
            raw_img = time_raw(raw, cam, tf, step, times, cpu)
            imgs["raw"] = premultiplied_to_uint8(raw_img.astype(np.float64))  # for the image check, not timed
            for name, a in actions.items():
                c = time.process_time()
                imgs[name] = a.render(cam, tf, wait=False)
                cpu[name].append(time.process_time() - c)
                times[name].append(a.last_frame_stats.times["total"])
        med = {k: statistics.median(v) for k, v in times.items()}
        mcpu = {k: statistics.median(v) for k, v in cpu.items()}
        diff = {k: int(np.abs(imgs[k].astype(int) - imgs["raw"].astype(int)).max()) for k in actions}
        row = dict(size=n, image=image, repeat=repeat, raw_s=med["raw"],
                   **{f"{k}_s": med[k] for k in actions},
                   raw_cpu_s=mcpu["raw"], raw_same_stop_s=med["raw_same_stop"],
                   **stop_ratios(med, mcpu, actions),
                   multires_over_full=med["multiresolution"] / med["bricks"],  # both on the default path
                   single_over_bricks=med["single-pass"] / med["bricks"],
                   **{f"maxdiff_{k}_vs_raw": diff[k] for k in actions},
                   multires_levels=str(actions["multiresolution"].last_frame_stats.bricks_drawn))
        log(f"{n}^3 at {image}^2 (median of {repeat}): raw {med['raw']:.3f} s (same stop "
            f"{med['raw_same_stop']:.3f} s); " + ", ".join(
                f"{k} {med[k]:.3f} s = {med[k] / med['raw']:.2f}x raw, CPU {mcpu[k] / mcpu['raw']:.2f}x; same stop "
                f"{med[k] / med['raw_same_stop']:.2f}x, CPU {mcpu[k] / mcpu['raw_same_stop']:.2f}x "
                f"(max |diff| {diff[k]})" for k in actions))
        for a in actions.values():
            a.close()
        raw.release()
        clip1.close()
        clip.close()
        row.update(fly_stability(ctx, loader, tf, image, step, budget, fly_frames, texels_per_frame, log))
        rows.append(row)
        del vol, loader, one_loader
    out_dir.mkdir(parents=True, exist_ok=True)
    keys = list(rows[0])
    with open(out_dir / "bench_render_raw.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=keys)
        w.writeheader()
        for r in rows:
            w.writerow({k: (f"{v:.4g}" if isinstance(v, float) else v) for k, v in r.items()})
    ctx.release()
    return rows


def vs_lod(size: int, brick: int, image: int, repeat: int, out_dir: Path, block_budget: int = 96,
           log=print) -> list[dict]:
    """The two draw paths on the image-LOD benchmark's cuts, in one run: the CT-like head of
    ``tools/bench/bench_lod.py`` (``size``^3 uint8, ``brick``^3 bricks, summary tables), its face, side and
    overview views, each drawn at full resolution (``policy="fixed", level=0``) and with the image
    policy at ``block_budget`` blocks, by a per-brick session and a single-pass session over the same
    store; warm frames, the two paths interleaved, medians of ``repeat`` (wall and process CPU time).
    Every ratio is the single pass's time over the per-brick path's for the same frame."""
    import tempfile

    from clipvol.app.session import RenderSession
    from clipvol.bricking.generators import ct_head
    from clipvol.bricking.pipeline import brick_volume
    from clipvol.bricking.summary import build_summary
    from clipvol.paging.open import open_store
    from clipvol.render import create_context
    from clipvol.scene.camera import Camera
    from clipvol.scene.params import RenderParams
    from clipvol.scene.transfer import TransferFunction
    from bench_lod import VIEWS

    tmp = tempfile.TemporaryDirectory(prefix="clipvol-bench-render-lod-")
    store = Path(tmp.name) / "head.zarr"
    brick_volume(ct_head((size,) * 3, seed=0), store, brick=brick, progress=False, summary=False)
    build_summary(store, progress=False)
    loader = open_store(store)
    pyr = loader.pyramid
    lo, hi = pyr.volume_box()
    c = (lo + hi) / 2.0
    diag = float(np.linalg.norm(hi - lo))
    tf = TransferFunction.preset("bone", value_range=pyr.value_range)
    budget = int(sum(pyr.num_bricks(L) for L in range(pyr.num_levels)) * pyr.brick_nbytes * 1.2) + (64 << 20)
    ctx = create_context()
    paths = ("bricks", "single-pass")
    sessions = {p: RenderSession(loader, ctx, memory_budget=budget, texture_budget=budget, tf=tf,
                                 params=RenderParams(policy="fixed", level=0, path=p)) for p in paths}
    cuts = {"full": dict(policy="fixed", level=0, block_budget=None),
            "image": dict(policy="image", level=None, visibility=True, block_budget=block_budget)}
    rows = []
    for view, (d, dist) in VIEWS.items():
        d = np.asarray(d, dtype=np.float64) / np.linalg.norm(d)
        cam = Camera.perspective(tuple(c - d * (dist or 0.6) * diag), tuple(c), up=(0, -1, 0), fov_y=40,
                                 size=(image, image))
        for cut, ch in cuts.items():
            imgs = {}
            for p, sess in sessions.items():
                sess.update(**ch)
                sess.render(cam, tuple(c), wait=True, timeout=600)
            wall = {p: [] for p in paths}
            cpu = {p: [] for p in paths}
            for _ in range(repeat):  # interleaved
                for p, sess in sessions.items():
                    w0, c0 = time.perf_counter(), time.process_time()
                    imgs[p] = sess.render(cam, tuple(c))
                    wall[p].append(time.perf_counter() - w0)
                    cpu[p].append(time.process_time() - c0)
            a = sessions["single-pass"].action
            key = lambda act: sorted((it.level, tuple(it.index), it.lo, it.hi) for it in act.last_selection.items)  # noqa: E731
            row = dict(view=view, cut=cut, image=image, repeat=repeat,
                       same_cut=int(key(a) == key(sessions["bricks"].action)),
                       items=len(a.last_selection.items), single_pass_nodes=a.page_table_nodes,
                       drawn_by=a.path_drawn, bricks_boxes=sessions["bricks"].action.boxes_drawn,
                       bricks_s=statistics.median(wall["bricks"]), single_pass_s=statistics.median(wall["single-pass"]),
                       single_over_bricks=statistics.median(wall["single-pass"]) / statistics.median(wall["bricks"]),
                       single_over_bricks_cpu=statistics.median(cpu["single-pass"]) / statistics.median(cpu["bricks"]),
                       maxdiff=int(np.abs(imgs["bricks"].astype(int) - imgs["single-pass"].astype(int)).max()))
            rows.append(row)
            log(f"{view} {cut}: {row['items']} items -> {row['bricks_boxes']} boxes / {row['single_pass_nodes']} nodes; "
                f"bricks {row['bricks_s'] * 1e3:.0f} ms, single pass {row['single_pass_s'] * 1e3:.0f} ms: "
                f"{row['single_over_bricks']:.2f}x wall, {row['single_over_bricks_cpu']:.2f}x CPU (max |diff| {row['maxdiff']}, "
                f"same cut {bool(row['same_cut'])})")
    for sess in sessions.values():
        sess.close()
    ctx.release()
    tmp.cleanup()
    out_dir.mkdir(parents=True, exist_ok=True)
    with open(out_dir / "bench_render_lod.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        for r in rows:
            w.writerow({k: (f"{v:.4g}" if isinstance(v, float) else v) for k, v in r.items()})
    return rows


def vs_paths(n: int, image: int, repeat: int, step: float, out_dir: Path, log=print) -> list[dict]:
    """Which draw path is faster for how many boxes: the same full-resolution cut of the fractal
    ``n``³ drawn unmerged as 1, 2, 4, 8 and 64 boxes (the volume or part of it cut into bricks of
    ``n``, ``n/2`` and ``n/4``), per brick and in one pass, each against :class:`RawCaster` on the
    same voxels, interleaved, medians of ``repeat``. The row that sets ``AUTO_SINGLE_PASS_BOXES``."""
    from clipvol.loaders.numpy_array import NumpyLoader
    from clipvol.paging.cliptexture import ClipTexture
    from clipvol.render import create_context
    from clipvol.render.action import ClipRenderAction

    ctx = create_context()
    vol, loader, cam, tf, budget, clip = fractal_scene(n, image, log)
    clip.close()
    h, q = n // 2, n // 4
    cases = [((n, n, n), n), ((n, h, h), h), ((n, n, h), h), ((n, n, n), h), ((n, n, n), q)]
    rows = []
    for shape, brick in cases:
        part = np.ascontiguousarray(vol[:shape[0], :shape[1], :shape[2]])
        ld = NumpyLoader(part, brick=brick, value_range=loader.pyramid.value_range)
        clip = ClipTexture(ld, budget, threads=2)
        common = dict(policy="fixed", level=0, step=step, texture_budget=budget, merge_boxes=False)
        actions = {p: ClipRenderAction(ctx, clip, path=p, **common) for p in ("bricks", "single-pass")}
        raw = RawCaster(ctx, part, loader.pyramid.value_range)
        try:
            mw, mc = interleaved_medians(raw, actions, cam, tf, step, repeat)
            boxes = actions["bricks"].boxes_drawn
            row = dict(size=n, image=image, shape="x".join(map(str, shape[::-1])), brick=brick, boxes=boxes,
                       raw_s=round(mw["raw"], 4), **ratio_columns(mw, mc, actions),
                       single_over_bricks=round(mw["single-pass"] / mw["bricks"], 3),
                       single_over_bricks_cpu=round(mc["single-pass"] / mc["bricks"], 3))
            rows.append(row)
            log(f"{boxes} boxes ({row['shape']}, bricks of {brick}): {raw_ratio_line(mw, mc, actions)}; "
                f"single pass / per brick {row['single_over_bricks']:.2f} (CPU {row['single_over_bricks_cpu']:.2f})")
        finally:
            for a in actions.values():
                a.close()
            raw.release()
            clip.close()
    ctx.release()
    out_dir.mkdir(parents=True, exist_ok=True)
    write_rows(out_dir / "bench_render_paths.csv", rows)
    return rows


def vs_stop(n: int, image: int, repeat: int, step: float, out_dir: Path, log=print) -> list[dict]:
    """What stopping rays at ``OPAQUE`` (1 - 0.5/255) instead of 0.9995 gives, per data set: the
    full-resolution frame of the fractal ``n``³ (the raw-caster view) and of the CT-like head ``n``³
    (the image-LOD benchmark's face, side and overview views), drawn by two actions that differ
    only in the stop, interleaved, medians of ``repeat``; the time ratio and the largest 8-bit
    difference between the two images. The stop is the module constant ``OPAQUE`` of
    ``clipvol.render.action``: the per-brick path reads it when an action first uses its program,
    the single pass every frame, so it is set here before each action's every frame (its own
    programs, one per action) and restored after; a switch for this benchmark only."""
    import clipvol.render.action as action_mod
    import clipvol.render.paths.setup as setup_mod  # where the draw paths read OPAQUE
    from clipvol.bricking.generators import ct_head
    from clipvol.loaders.numpy_array import NumpyLoader
    from clipvol.paging.cliptexture import ClipTexture
    from clipvol.render import create_context
    from clipvol.scene.camera import Camera
    from clipvol.scene.transfer import TransferFunction
    from bench_lod import VIEWS

    stops = {"0.9995": RAW_OPAQUE, "1-0.5/255": setup_mod.OPAQUE}
    kept = setup_mod.OPAQUE
    ctx = create_context()
    rows = []
    try:
        vol, loader, fcam, ftf, budget, clip = fractal_scene(n, image, log)
        head = NumpyLoader(ct_head((n,) * 3, seed=0), brick=32)
        hclip = ClipTexture(head, budget, threads=2)
        hp = head.pyramid
        lo, hi = hp.volume_box()
        c, diag = (lo + hi) / 2.0, float(np.linalg.norm(hi - lo))
        scenes = [("fractal", "raw-caster view", clip, fcam, ftf)]
        for name, (d, zoom) in VIEWS.items():
            d = np.asarray(d, dtype=np.float64) / np.linalg.norm(d)
            cam = Camera.perspective(tuple(c + d * diag * (zoom or 1.0)), tuple(c), up=(0, -1, 0), fov_y=35,
                                     size=(image, image))
            scenes.append(("ct head", name, hclip, cam, TransferFunction.preset("bone", value_range=hp.value_range)))
        for data, view, cl, cam, tf in scenes:
            acts = {k: action_mod.ClipRenderAction(ctx, cl, policy="fixed", level=0, step=step, texture_budget=budget)
                    for k in stops}
            imgs, wall = {}, {k: [] for k in stops}
            for k, a in acts.items():
                setup_mod.OPAQUE = stops[k]
                imgs[k] = a.render(cam, tf, wait=True, timeout=600)
            for _ in range(repeat):
                for k, a in acts.items():
                    setup_mod.OPAQUE = stops[k]
                    t = time.perf_counter()
                    imgs[k] = a.render(cam, tf)
                    wall[k].append(time.perf_counter() - t)
            med = {k: statistics.median(v) for k, v in wall.items()}
            diff = np.abs(imgs["0.9995"].astype(int) - imgs["1-0.5/255"].astype(int)).max(axis=2)
            row = dict(data=data, view=view, size=n, image=image, repeat=repeat, stop_0_9995_s=round(med["0.9995"], 4),
                       stop_new_s=round(med["1-0.5/255"], 4), new_over_old=round(med["1-0.5/255"] / med["0.9995"], 3),
                       maxdiff=int(diff.max()), pixels_differing=round(float((diff > 0).mean()), 4),
                       path=acts["1-0.5/255"].path_drawn)
            rows.append(row)
            log(f"{data}, {view}: {row['stop_0_9995_s']:.3f} s at 0.9995, {row['stop_new_s']:.3f} s at 1 - 0.5/255 "
                f"({row['new_over_old']:.2f}x); max |diff| {row['maxdiff']}, {100 * row['pixels_differing']:.1f} % of pixels")
            for a in acts.values():
                a.close()
        clip.close()
        hclip.close()
    finally:
        setup_mod.OPAQUE = kept
        ctx.release()
    write_rows(out_dir / "bench_render_stop.csv", rows)
    return rows


def quantised_fractal(n: int, dtype: str, data_dir: Path, log=print) -> np.ndarray:
    """``procedural:fractal?size=n`` quantised to ``dtype`` (uint8 / uint16) over the generator's value
    range, generated in slabs (never the float32 volume whole) and cached as ``.npy`` under
    ``data_dir``; returned in memory."""
    from clipvol.loaders.procedural import ProceduralLoader

    path = data_dir / f"fractal-{n}-{dtype}.npy"
    if path.is_file():
        return np.load(path)
    gen = ProceduralLoader(f"procedural:fractal?size={n}", brick=64)
    lo, hi = gen.pyramid.value_range
    top = float(np.iinfo(np.dtype(dtype)).max)
    vol = np.empty((n, n, n), dtype=dtype)
    t = time.perf_counter()
    for z in range(0, n, 32):
        slab = gen.generator.region(0, (z, 0, 0), (min(n, z + 32), n, n))
        vol[z:z + len(slab)] = np.clip(np.rint((slab - lo) * (top / (hi - lo))), 0, top)
    log(f"{n}^3 {dtype}: generated in {time.perf_counter() - t:.0f} s")
    data_dir.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".part.npy")
    np.save(tmp, vol)
    tmp.replace(path)  # never a half-written cache file under the final name
    return vol


def vs_raw_large(n: int, dtype: str, image: int, repeat: int, step: float, out_dir: Path, virtual: int = 4096,
                 budget: int = 1536 << 20, log=print) -> dict:
    """An ``n``^3 integer volume (1 GiB at 1024^3 uint8) against :class:`RawCaster`, and a virtual
    ``virtual``^3 multiresolution frame beside them.

    Same view geometry as :func:`vs_raw` (the volume fills the ``image``^2 view), same step and
    table; interleaved rounds, medians. Measured: the full-resolution frame (per brick and single
    pass), clipvol's own shader on one ``n``^3 texture (the draw without the bricks) and the
    multiresolution frame (``lod_threshold=1``) of the ``n``^3 volume, each divided by the raw
    caster's frame of the same volume (one ``n``^3 texture) at both stops (:func:`raw_stops`); and
    the multiresolution frame of
    ``procedural:fractal?size=virtual`` (float32 bricks generated on demand, 64 GiB at 4096^3 if it
    were whole) divided by the same raw caster's ``n``^3 frame - what a view of a volume 64x larger
    costs against what a plain caster pays for the largest texture it can hold here.
    """
    from clipvol.loaders.numpy_array import NumpyLoader, finite_range
    from clipvol.loaders.procedural import ProceduralLoader
    from clipvol.paging.cliptexture import ClipTexture
    from clipvol.render import create_context
    from clipvol.render.action import ClipRenderAction
    from clipvol.render.paths.setup import premultiplied_to_uint8
    from clipvol.scene.camera import Camera
    from clipvol.scene.transfer import TransferFunction

    def view(pyr):
        lo, hi = pyr.volume_box()
        centre = (lo + hi) / 2.0
        d = np.array([0.55, 0.45, 0.7])
        d /= np.linalg.norm(d)
        return Camera.perspective(tuple(centre - d * 1.05 * float(np.linalg.norm(hi - lo))), tuple(centre),
                                  up=(0, -1, 0), fov_y=35, size=(image, image))

    vol = quantised_fractal(n, dtype, DATA, log)
    vr = finite_range(vol)
    loader = NumpyLoader(vol, brick=64, value_range=vr)
    pyr = loader.pyramid
    cam = view(pyr)
    tf = TransferFunction.preset("bone", value_range=pyr.value_range)
    ctx = create_context()
    t0 = time.perf_counter()
    clip = ClipTexture(loader, budget, threads=2)
    actions = {"bricks": ClipRenderAction(ctx, clip, policy="fixed", level=0, path="bricks", step=step,
                                          texture_budget=budget),
               "single-pass": ClipRenderAction(ctx, clip, policy="fixed", level=0, path="single-pass", step=step,
                                               texture_budget=budget),
               "multiresolution": ClipRenderAction(ctx, clip, lod_threshold=1.0, step=step, texture_budget=budget)}
    # clipvol's shader on one n^3 texture (the whole level 0 as one brick): the draw without the bricks
    clip1 = ClipTexture(NumpyLoader(vol, brick=n, value_range=vr), vol.nbytes + (64 << 20), threads=1)
    actions["own shader, one texture"] = ClipRenderAction(ctx, clip1, policy="fixed", level=0, path="bricks", step=step,
                                                          texture_budget=vol.nbytes + (64 << 20))
    imgs = {k: a.render(cam, tf, wait=True, timeout=3600) for k, a in actions.items()}
    log(f"{n}^3 {dtype}: loaded and uploaded in {time.perf_counter() - t0:.0f} s")
    raw = RawCaster(ctx, vol, pyr.value_range)
    raw.render(cam, tf, step)
    vloader = ProceduralLoader(f"procedural:fractal?size={virtual}", brick=64)
    vcam = view(vloader.pyramid)
    vtf = TransferFunction.preset("bone", value_range=vloader.pyramid.value_range)
    vclip = ClipTexture(vloader, budget, threads=2)
    vact = ClipRenderAction(ctx, vclip, lod_threshold=1.0, step=step, texture_budget=budget)
    t0 = time.perf_counter()
    vact.render(vcam, vtf, wait=True, timeout=3600)
    log(f"virtual {virtual}^3: converged={vact.last_frame_stats.converged} in {time.perf_counter() - t0:.0f} s, "
        f"{vact.last_frame_stats.bricks_drawn} bricks per level")
    names = [*actions, f"virtual {virtual}^3 multiresolution"]
    times = {k: [] for k in [*names, *raw_stops()]}
    cpu = {k: [] for k in times}
    parts = {k: [] for k in names}  # select / upload / draw / readback seconds of each frame
    for _ in range(repeat):  # interleaved rounds
        raw_img = time_raw(raw, cam, tf, step, times, cpu)
        imgs["raw"] = premultiplied_to_uint8(raw_img.astype(np.float64))  # for the image check, not timed
        for name, a, cm, f in [(k, a, cam, tf) for k, a in actions.items()] + [(names[-1], vact, vcam, vtf)]:
            c = time.process_time()
            imgs[name] = a.render(cm, f, wait=False)
            cpu[name].append(time.process_time() - c)
            times[name].append(a.last_frame_stats.times["total"])
            parts[name].append(a.last_frame_stats.times)
    med = {k: statistics.median(v) for k, v in times.items()}
    mcpu = {k: statistics.median(v) for k, v in cpu.items()}
    diff = int(np.abs(imgs["bricks"].astype(int) - imgs["raw"].astype(int)).max())
    diff_sp = int(np.abs(imgs["single-pass"].astype(int) - imgs["raw"].astype(int)).max())
    row = dict(size=n, dtype=dtype, image=image, repeat=repeat, raw_s=med["raw"], raw_cpu_s=mcpu["raw"],
               raw_same_stop_s=med["raw_same_stop"],
               **{f"{k}_s": med[k] for k in names},
               **stop_ratios(med, mcpu, names),
               **{f"{k}_{p}_s": statistics.median(t[p] for t in parts[k]) for k in names
                  for p in ("select", "draw", "readback")},
               maxdiff_bricks_vs_raw=diff, maxdiff_single_pass_vs_raw=diff_sp, boxes_full=actions["bricks"].boxes_drawn,
               single_pass_nodes=actions["single-pass"].page_table_nodes,
               single_pass_drawn_by=actions["single-pass"].path_drawn,
               multires_levels=str(actions["multiresolution"].last_frame_stats.bricks_drawn),
               multires_drawn_by=actions["multiresolution"].path_drawn,
               virtual_levels=str(vact.last_frame_stats.bricks_drawn),
               virtual_drawn_by=vact.path_drawn,
               virtual_boxes=vact.boxes_drawn if vact.path_drawn == "bricks" else vact.page_table_nodes,
               virtual_converged=int(vact.last_frame_stats.converged))
    log(f"{n}^3 {dtype} at {image}^2 (median of {repeat}): " + raw_ratio_line(med, mcpu, names)
        + f"; full-resolution image vs raw: max |diff| {diff}")
    for a in (*actions.values(), vact):
        a.close()
    raw.release()
    clip.close()
    clip1.close()
    vclip.close()
    ctx.release()
    out_dir.mkdir(parents=True, exist_ok=True)
    with open(out_dir / "bench_render_large.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(row))
        w.writeheader()
        w.writerow({k: (f"{v:.4g}" if isinstance(v, float) else v) for k, v in row.items()})
    return row


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--source", default=None, help="store or procedural URL (default: the 2 GiB bench store)")
    ap.add_argument("--quick", action="store_true", help="small smoke run (procedural 96x192x192, bricks of 32)")
    ap.add_argument("--size", type=int, default=256, help="image edge in pixels (default 256)")
    ap.add_argument("--repeat", type=int, default=3, help="warm frames per configuration and round (median)")
    ap.add_argument("--step", type=float, default=0.5)
    ap.add_argument("--out-dir", type=Path, default=RESULTS)
    ap.add_argument("--vs-raw", default=None, metavar="SIZES",
                    help="only the comparison with the raw one-texture caster, on procedural fractal volumes of "
                         "these edges (e.g. 256,512); writes tools/bench/results/bench_render_raw.csv")
    ap.add_argument("--fly-only", type=int, default=None, metavar="N",
                    help="only the fly-path frame times on procedural:fractal?size=N (virtual: bricks generated "
                         "on demand, e.g. 4096); writes tools/bench/results/bench_render_fly.csv")
    ap.add_argument("--fly-frames", type=int, default=48, help="--vs-raw: frames of the fly path (frame-time stability)")
    ap.add_argument("--vs-raw-large", type=int, default=None, metavar="N",
                    help="only N^3 (e.g. 1024) quantised to --dtype against the raw caster, and a virtual "
                         "--virtual^3 multiresolution frame beside it; writes tools/bench/results/bench_render_large.csv")
    ap.add_argument("--vs-lod", action="store_true",
                    help="only the two draw paths (per brick, single pass) on the image-LOD benchmark's head, views "
                         "and cuts (full resolution and the image policy), interleaved; writes tools/bench/results/bench_render_lod.csv")
    ap.add_argument("--vs-paths", type=int, default=None, metavar="N",
                    help="only the two draw paths on the same cut of procedural:fractal?size=N drawn as 1, 2, 4, 8 "
                         "and 64 unmerged boxes, against the raw caster; writes tools/bench/results/bench_render_paths.csv")
    ap.add_argument("--vs-stop", type=int, default=None, metavar="N",
                    help="only the early-termination stop, 0.9995 against 1 - 0.5/255, on the fractal N^3 and the "
                         "CT-like head N^3; writes tools/bench/results/bench_render_stop.csv")
    ap.add_argument("--lod-size", type=int, default=256, help="--vs-lod: head volume edge (default 256)")
    ap.add_argument("--lod-brick", type=int, default=16, help="--vs-lod: brick edge (default 16, as bench_lod)")
    ap.add_argument("--block-budget", type=int, default=96, help="--vs-lod: the image policy's block budget")
    ap.add_argument("--dtype", choices=("uint8", "uint16"), default="uint8", help="--vs-raw-large: the volume's type")
    ap.add_argument("--virtual", type=int, default=4096, help="--vs-raw-large: edge of the virtual volume")
    args = ap.parse_args(argv)
    if args.vs_lod:
        vs_lod(args.lod_size, args.lod_brick, args.size, max(args.repeat, 5), args.out_dir, args.block_budget,
               log=lambda *a: print(*a, file=sys.stderr, flush=True))
        return 0
    if args.vs_stop:
        vs_stop(args.vs_stop, args.size, max(args.repeat, 5), args.step, args.out_dir,
                log=lambda *a: print(*a, file=sys.stderr, flush=True))
        return 0
    if args.vs_paths:
        vs_paths(args.vs_paths, args.size, max(args.repeat, 5), args.step, args.out_dir,
                 log=lambda *a: print(*a, file=sys.stderr, flush=True))
        return 0
    if args.vs_raw_large:
        vs_raw_large(args.vs_raw_large, args.dtype, args.size, max(args.repeat, 5), args.step, args.out_dir,
                     args.virtual, log=lambda *a: print(*a, file=sys.stderr, flush=True))
        return 0
    if args.fly_only:
        from clipvol.loaders.procedural import ProceduralLoader
        from clipvol.render import create_context
        from clipvol.scene.transfer import TransferFunction

        loader = ProceduralLoader(f"procedural:fractal?size={args.fly_only}", brick=64)
        budget = 512 << 20
        ctx = create_context()
        row = fly_stability(ctx, loader, TransferFunction.preset("bone", value_range=loader.pyramid.value_range),
                            args.size, args.step, budget, args.fly_frames, 8 * 64**3,
                            log=lambda *a: print(*a, file=sys.stderr, flush=True))
        args.out_dir.mkdir(parents=True, exist_ok=True)
        with open(args.out_dir / "bench_render_fly.csv", "w", newline="") as f:
            w = csv.DictWriter(f, fieldnames=["size", *row])
            w.writeheader()
            w.writerow({"size": args.fly_only, **{k: (f"{v:.4g}" if isinstance(v, float) else v) for k, v in row.items()}})
        return 0
    if args.vs_raw:
        sizes = [int(v) for v in args.vs_raw.split(",")]
        vs_raw(sizes, args.size, max(args.repeat, 5), args.step, args.out_dir, args.fly_frames,
               log=lambda *a: print(*a, file=sys.stderr, flush=True))
        return 0

    from PIL import Image

    from clipvol.paging.cliptexture import ClipTexture
    from clipvol.paging.open import open_store
    from clipvol.render import create_context
    from clipvol.render.action import ClipRenderAction
    from clipvol.scene.camera import Camera
    from clipvol.scene.metrics import percent_delta_e, psnr
    from clipvol.scene.transfer import TransferFunction

    if args.quick:
        source, kw = "procedural:fractal?size=96x192x192", {"brick": 32}
    elif args.source:
        source, kw = args.source, {}
    else:
        store = big_fractal_store()
        if store is None:
            return 2
        source, kw = str(store), {}
    loader = open_store(source, **kw)
    pyr = loader.pyramid
    lo, hi = pyr.volume_box()
    centre = (lo + hi) / 2.0
    diag = float(np.linalg.norm(hi - lo))
    direction = np.array([0.55, 0.45, 0.7])
    direction /= np.linalg.norm(direction)
    cam = Camera.perspective(tuple(centre - direction * 1.3 * diag), tuple(centre), up=(0, -1, 0), fov_y=35,
                             size=(args.size, args.size))
    tf = TransferFunction.preset("bone", value_range=pyr.value_range)
    brick_bytes = pyr.brick_nbytes
    all_bytes = sum(pyr.num_bricks(L) for L in range(pyr.num_levels)) * brick_bytes
    ctx = create_context()
    rows: list[tuple] = []
    log = lambda *a: print(*a, file=sys.stderr, flush=True)  # noqa: E731
    log(f"source {source}: level 0 {pyr.shape}, {pyr.num_bricks(0)} bricks of {pyr.brick_shape}, "
        f"{pyr.num_bricks(0) * brick_bytes / 2**30:.2f} GiB; image {args.size}^2, step {args.step}")

    # -- set-up (cold): full resolution as bricks, one texture, multiresolution -----------------
    from contextlib import ExitStack

    stack = ExitStack()
    budget = int(all_bytes * 1.1) + (64 << 20)
    t0 = time.perf_counter()
    clip = stack.enter_context(ClipTexture(loader, budget, center=centre))
    full = ClipRenderAction(ctx, clip, texture_budget=budget, policy="fixed", level=0, step=args.step)
    stack.callback(full.close)
    full.render(cam, tf, wait=True, timeout=1800)
    st = full.last_frame_stats
    cold_full = time.perf_counter() - t0
    n_frustum = len(full.last_selection.wanted)
    first_mbps = st.bytes_uploaded / max(st.times["upload"], 1e-9) / 1e6
    up_bytes = st.bytes_uploaded
    log(f"full resolution: {n_frustum} level-0 bricks in the frustum, cold frame {cold_full:.1f} s; "
        f"first sub-loads {up_bytes / 1e6:.0f} MB at {first_mbps:.0f} MB/s")
    sub_mbps, raw_mbps = _subload_vs_raw(full, clip)
    big_mbps = _raw_write_mbps(ctx, min(up_bytes, 512 << 20), pyr.brick_shape)
    log(f"warm sub-loads through the cache {sub_mbps:.0f} MB/s; raw texture.write of the same bricks "
        f"{raw_mbps:.0f} MB/s; one big texture.write {big_mbps:.0f} MB/s")

    whole = WholeVolume(loader)
    vol_bytes = int(np.prod(pyr.shape)) * pyr.dtype.itemsize
    clip1 = stack.enter_context(ClipTexture(whole, vol_bytes + (16 << 20), threads=1))
    one = ClipRenderAction(ctx, clip1, texture_budget=vol_bytes + (16 << 20), policy="fixed", level=0, step=args.step)
    stack.callback(one.close)
    one.render(cam, tf, wait=True, timeout=1800)
    raw = RawCaster(ctx, whole.read_brick(0, (0, 0, 0)), pyr.value_range)  # the reference outside clipvol
    stack.callback(raw.release)
    raw.render(cam, tf, args.step)

    t0 = time.perf_counter()
    clip2 = stack.enter_context(ClipTexture(loader, "512MB", center=centre))
    multi = ClipRenderAction(ctx, clip2, texture_budget="512MB", lod_threshold=1.0, step=args.step)
    stack.callback(multi.close)
    multi.render(cam, tf, wait=True, timeout=1800)
    cold_multi = time.perf_counter() - t0
    loaded_at_convergence = clip2.stats.bytes_loaded
    wanted = multi.last_selection.wanted
    st_m = multi.last_frame_stats

    # the overview: the same direction from twice as far (coarser levels suffice)
    far_cam = Camera.perspective(tuple(centre - direction * 2.6 * diag), tuple(centre), up=(0, -1, 0), fov_y=35,
                                 size=(args.size, args.size))
    multi.render(far_cam, tf, wait=True, timeout=1800)
    full.render(far_cam, tf, wait=True, timeout=1800)
    far_levels = None
    far = {"full": [], "multi": []}
    far_images = {}
    for _ in range(args.repeat):
        for name, action in (("full", full), ("multi", multi)):
            far_images[name] = action.render(far_cam, tf, wait=False)
            far[name].append(action.last_frame_stats.times["total"])
            if name == "multi":
                far_levels = action.last_frame_stats.bricks_drawn
    tf_full, tf_multi = statistics.median(far["full"]), statistics.median(far["multi"])
    pct_far = percent_delta_e(far_images["multi"], far_images["full"], 6.0, premultiplied=False)
    log(f"overview (2.6 diagonals): full {tf_full:.3f} s, multiresolution {tf_multi:.3f} s {far_levels}, "
        f"{pct_far:.2f} % pixels dE>=6")

    # -- warm frames: two rounds of blocks, so that the load of a shared machine hits all alike --
    times: dict[str, list] = {"full": [], "one": [], "multi": [], "raw": []}
    draws: dict[str, list] = {"full": [], "one": [], "multi": []}
    images = {}
    for _ in range(2):  # two rounds of blocks: a warm-up frame, then args.repeat timed frames each
        for name, action in (("full", full), ("one", one), ("multi", multi)):
            action.render(cam, tf, wait=False)
            for _ in range(args.repeat):
                images[name] = action.render(cam, tf, wait=False)
                times[name].append(action.last_frame_stats.times["total"])
                draws[name].append(action.last_frame_stats.times["draw"])
        for _ in range(args.repeat):
            t = time.perf_counter()
            raw.render(cam, tf, args.step)
            times["raw"].append(time.perf_counter() - t)
    t_full, t_one, t_multi, t_raw = (statistics.median(times[k]) for k in ("full", "one", "multi", "raw"))
    d_full, d_one, d_multi = (statistics.median(draws[k]) for k in ("full", "one", "multi"))
    img_full, img_one, img_multi = images["full"], images["one"], images["multi"]
    log("multiresolution warm frame stages: " + ", ".join(f"{k} {v:.3f}" for k, v in multi.last_frame_stats.times.items()))
    stack.close()
    same = int(np.abs(img_one.astype(int) - img_full.astype(int)).max())
    log(f"warm frames (median of {2 * args.repeat}): bricks {t_full:.3f} s, one texture {t_one:.3f} s, "
        f"multiresolution {t_multi:.3f} s; max |bricks - one texture| = {same}")
    view_bytes = len(wanted) * brick_bytes
    full_bytes = n_frustum * brick_bytes
    pct = percent_delta_e(img_multi, img_full, 6.0, premultiplied=False)
    ps = psnr(img_multi, img_full, premultiplied=False)
    log(f"multiresolution: bricks drawn {st_m.bricks_drawn}, converged {st_m.converged}, cold {cold_multi:.1f} s, "
        f"warm frame {t_multi:.3f} s; {pct:.2f} % pixels dE>=6, PSNR {ps:.1f} dB; view needs "
        f"{view_bytes / 1e6:.0f} MB vs {full_bytes / 1e6:.0f} MB (clip-texture loaded {loaded_at_convergence / 1e6:.0f} MB)")

    rows = [
        ("multires_frame_s", t_multi, "full_res_frame_s", t_full, t_full / t_multi, ">= 5x faster", t_full / t_multi >= 5),
        ("pct_pixels_dE6", pct, "-", "", "", "<= 5 %", pct <= 5.0),
        ("overview_multires_frame_s", tf_multi, "overview_full_res_frame_s", tf_full, tf_full / tf_multi,
         ">= 5x faster", tf_full / tf_multi >= 5),
        ("overview_pct_pixels_dE6", pct_far, "-", "", "", "<= 5 %", pct_far <= 5.0),
        ("psnr_db", ps, "-", "", "", "reported", ""),
        ("view_bytes", view_bytes, "full_res_frustum_bytes", full_bytes, full_bytes / max(view_bytes, 1), ">= 8x fewer",
         full_bytes / max(view_bytes, 1) >= 8),
        ("cliptexture_bytes_loaded", loaded_at_convergence, "full_res_frustum_bytes", full_bytes,
         full_bytes / max(loaded_at_convergence, 1), "reported", ""),
        ("subload_MBps", sub_mbps, "raw_write_MBps", raw_mbps, sub_mbps / raw_mbps, ">= 0.8", sub_mbps / raw_mbps >= 0.8),
        ("subload_MBps", sub_mbps, "one_big_write_MBps", big_mbps, sub_mbps / big_mbps, "reported", ""),
        ("full_res_frame_s", t_full, "raw_one_texture_caster_frame_s", t_raw, t_full / t_raw, "<= 1.1x",
         t_full / t_raw <= 1.1),
        ("own_shader_one_texture_frame_s", t_one, "raw_one_texture_caster_frame_s", t_raw, t_one / t_raw, "<= 1.05x",
         t_one / t_raw <= 1.05),
        ("bricks_frame_s", t_full, "one_texture_frame_s", t_one, t_full / t_one, "<= 1.5x", t_full / t_one <= 1.5),
        ("bricks_draw_s", d_full, "one_texture_draw_s", d_one, d_full / d_one, "reported", ""),
        ("max_abs_diff_bricks_vs_one_texture", same, "-", "", "", "reported", ""),
        ("full_res_cold_s", cold_full, "multires_cold_s", cold_multi, cold_full / cold_multi, "reported", ""),
    ]
    args.out_dir.mkdir(parents=True, exist_ok=True)
    with open(args.out_dir / "bench_render.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["metric", "value", "reference", "reference_value", "ratio", "target", "met"])
        for r in rows:
            w.writerow([r[0], f"{r[1]:.6g}" if isinstance(r[1], float) else r[1], r[2],
                        f"{r[3]:.6g}" if isinstance(r[3], float) else r[3],
                        f"{r[4]:.3f}" if isinstance(r[4], float) else r[4], r[5], r[6]])
    Image.fromarray(img_full, "RGBA").save(args.out_dir / "bench_render_full.png")
    Image.fromarray(img_multi, "RGBA").save(args.out_dir / "bench_render_multires.png")
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, ax = plt.subplots(1, 3, figsize=(12, 3.6))
        ax[0].bar(["multires", "full res\n(bricks)", "full res\n(one texture)"], [t_multi, t_full, t_one],
                  color=["tab:green", "tab:blue", "tab:gray"])
        ax[0].set_ylabel("warm frame time (s)")
        ax[0].set_title(f"frame time, {args.size}² (llvmpipe)")
        ax[1].bar(["view wants\n(multires)", "clip-texture\nloaded", "level-0 bricks\nin frustum"],
                  [view_bytes / 1e6, loaded_at_convergence / 1e6, full_bytes / 1e6], color=["tab:green", "tab:olive", "tab:blue"])
        ax[1].set_ylabel("MB")
        ax[1].set_title("bytes for the view")
        ax[2].bar(["cache\nsub-loads", "raw writes,\nsame bricks", "one big\nwrite"], [sub_mbps, raw_mbps, big_mbps],
                  color=["tab:green", "tab:gray", "tab:olive"])
        ax[2].set_ylabel("MB/s")
        ax[2].set_title("texture upload")
        fig.suptitle(f"multires: {pct:.2f} % pixels ΔE≥6, PSNR {ps:.1f} dB")
        fig.tight_layout()
        fig.savefig(args.out_dir / "bench_render.png", dpi=110)
    except ImportError:  # pragma: no cover
        log("matplotlib missing: no plot")
    for r in rows:
        print(",".join(str(x) for x in r))
    return 0


if __name__ == "__main__":
    sys.exit(main())
