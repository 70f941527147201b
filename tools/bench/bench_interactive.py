"""Interactive benchmark: frames per second while dragging the view, and time to the refined frame.

What a user of ``clipvol view`` on a machine without a GPU feels, measured offscreen (EGL, Mesa
llvmpipe) at the viewer's default 960x640 with the viewer's own parts - a
:class:`~clipvol.app.session.RenderSession` and an :class:`~clipvol.app.adaptive.AdaptiveQuality`
at its default 100 ms target - on two stores:

* ``demo``: the demo's 192^3 fractal ball (32^3 bricks), its ``demo`` transfer function;
* ``512``: a 512^3 float32 fractal (64^3 bricks, 537 MB of level 0), the automatic transfer function.

For each: the view converges at full quality; then a **drag** orbits the camera by 6 pixels a
frame for ``--frames`` frames, rendering as the viewer does (``wait=False``: whatever is resident),
with the adaptive controller; then the camera **stops** and the time to the **refined** frame is
measured (full quality, converged: every brick it wants loaded and drawn at its own level).

The adaptive drag runs twice per setting, alternating ``before`` (the viewer's controller until
2026-11-29: 100 ms target, the user's projected-size cut while moving, only the step longer, any
step factor the cost asks for) and ``after`` (today's
defaults: a 1/15 s target, the step factor on a few rungs, and moving frames draw one whole
level, a cut replayed from frame to frame: :func:`clipvol.app.adaptive.frame_params`);
each drag's **preview error** is the percent of pixels with CIELUV Delta E >= 6 between its last
frame, scaled up bilinearly to 960x640 as the viewer's texture does, and the converged full-quality
frame at the same camera.

Ratios, each against a reference measured in the same run:

* drag fps with adaptation against the **same drag at full quality** (the viewer without
  adaptive quality: every frame at 960x640 and the base step);
* the ``after`` drag's frame at its median size and step against the **one-texture caster** at the
  same size and step (the two measured alternately): what the paging and bricking code costs on
  a preview frame;
* the full-quality frame against a **one-texture, one-pass ray caster** of level 0 (the whole
  volume in a single 3D texture, one draw, same view and step: the paging and bricking code out
  of the path), the two measured alternately - so the numbers can be compared with
  ``bench_render``'s.

``python tools/bench/bench_interactive.py`` (builds the two stores under ``bench-data/`` if
missing; ``--quick`` for a small smoke run). Writes ``tools/bench/results/bench_interactive.csv`` and
``tools/bench/results/bench_interactive.png``.
"""

from __future__ import annotations

import argparse
import csv
import statistics
import sys
import time
from pathlib import Path

import numpy as np

from common import DATA, RESULTS, WholeVolume  # noqa: E402  (tools/bench/common.py)
SIZE = (960, 640)


def _store(name: str, quick: bool) -> Path:
    from clipvol.bricking.pipeline import brick_volume

    data = DATA
    data.mkdir(exist_ok=True)
    if name == "demo":
        n = 64 if quick else 192
        path = data / f"demo-{n}-b32.zarr"
        if not (path / "zarr.json").exists():
            from clipvol.tools.cmd_demo import demo_volume

            brick_volume(demo_volume(n), path, brick=32, progress=False)
        return path
    n = 128 if quick else 512
    path = data / f"fractal-{n}-b64.zarr"
    if not (path / "zarr.json").exists():
        brick_volume(f"procedural:fractal?size={n}", path, brick=64, progress=True)
    return path


def _tf(name: str, loader):
    from clipvol.scene.auto_tf import auto_transfer_function
    from clipvol.scene.transfer import TransferFunction

    return TransferFunction.preset("demo") if name == "demo" else auto_transfer_function(loader)


def _converge(sess, cam, coi, timeout=300.0) -> float:
    t = time.perf_counter()
    sess.render(cam, coi, wait=True, timeout=timeout)
    return time.perf_counter() - t


def _apply(sess, q, base_step: float, cam=None, whole_level: bool = True) -> None:
    """The viewer's parameters for a frame at quality ``q`` seen by ``cam``
    (:func:`clipvol.app.adaptive.frame_params`, the user's own: the default projected-size policy at
    a threshold of 1 pixel); ``whole_level=False``: the viewer until 2026-11-29, whose moving frames
    changed only the step."""
    from clipvol.app.adaptive import FULL, frame_params
    from clipvol.render.paths.setup import max_step

    user = dict(step=base_step, lod_threshold=1.0, policy="projected-size", level=None)
    previous = sess.params.level if sess.params.policy == "fixed" else None  # the preview's level so far
    want = frame_params(q if whole_level else FULL, sess.pyramid, cam, max_step=max_step(sess.pyramid),
                        previous=previous, **user)
    if not whole_level:
        want["step"] = min(base_step * q.step_factor, max_step(sess.pyramid))
    changes = {k: v for k, v in want.items() if getattr(sess.params, k) != v}
    if changes:
        sess.update(**changes)


def _drag(sess, controls, coi_fn, frames: int, aq, base_step: float, whole_level: bool = True) -> list[dict]:
    """Orbit by 6 px per frame; returns one row per frame (the last one holds its image)."""
    from clipvol.app.adaptive import FULL

    rows = []
    now = 0.0
    for i in range(frames):
        controls.orbit(6.0, 0.0)
        q = aq.next(True, now) if aq is not None else FULL
        cam = controls.camera(q.size(SIZE))
        _apply(sess, q, base_step, cam, whole_level)
        t0 = time.perf_counter()
        img = sess.render(cam, coi_fn(), wait=False)
        ft = time.perf_counter() - t0
        if aq is not None:
            aq.done(q, ft)
        now += ft
        rows.append({"frame": i, "frame_s": ft, "scale": q.scale, "step_factor": q.step_factor,
                     "level": sess.params.level, "replayed": bool(sess.frame_stats.replayed),
                     "pixels": cam.size[0] * cam.size[1]})
    rows[-1]["_image"] = img
    return rows


def _upscale(img: np.ndarray, size) -> np.ndarray:
    """Bilinear scaling of an RGBA frame to ``size`` (w, h), pixel centres aligned as a GL texture's
    LINEAR filter draws a small frame over the window."""
    h, w = img.shape[:2]
    W, H = size
    x = np.clip((np.arange(W) + 0.5) * w / W - 0.5, 0, w - 1)
    y = np.clip((np.arange(H) + 0.5) * h / H - 0.5, 0, h - 1)
    x0, y0 = np.floor(x).astype(int), np.floor(y).astype(int)
    x1, y1 = np.minimum(x0 + 1, w - 1), np.minimum(y0 + 1, h - 1)
    fx, fy = (x - x0)[None, :, None], (y - y0)[:, None, None]
    a = img.astype(np.float64)
    top = a[y0][:, x0] * (1 - fx) + a[y0][:, x1] * fx
    bot = a[y1][:, x0] * (1 - fx) + a[y1][:, x1] * fx
    return np.rint(top * (1 - fy) + bot * fy).astype(np.uint8)


def _adaptive_drag(sess, controls, coi, frames: int, aq, base_step: float, full_frame_s: float,
                   whole_level: bool) -> dict:
    """From the converged home view, one drag with controller ``aq``; fps, median quality, and the
    preview error of its last frame against the converged full-quality frame at its camera."""
    from clipvol.app.adaptive import FULL
    from clipvol.scene.metrics import percent_delta_e

    controls.reset()
    _apply(sess, FULL, base_step)
    _converge(sess, controls.camera(SIZE), coi())
    aq.done(aq.next(False, 0.0), full_frame_s)  # the viewer's first full frame seeds it
    rows = _drag(sess, controls, coi, frames, aq, base_step, whole_level)
    steady = rows[len(rows) // 3:]
    last = rows[-1].pop("_image")
    _apply(sess, FULL, base_step)
    ref = sess.render(controls.camera(SIZE), coi(), wait=True, timeout=600)
    return {"fps": len(steady) / sum(r["frame_s"] for r in steady),
            "frame_ms_median": 1e3 * statistics.median(r["frame_s"] for r in steady),
            "scale_median": statistics.median(r["scale"] for r in steady),
            "step_factor_median": statistics.median(r["step_factor"] for r in steady),
            "level_median": statistics.median(-1 if r["level"] is None else r["level"] for r in steady),
            "replayed_share": statistics.mean(r["replayed"] for r in steady),
            "preview_pct_de6": percent_delta_e(_upscale(last, SIZE), ref), "_rows": rows}


def _alternate(ctx, loader, sess, cam, coi, tf, step: float, repeat: int) -> tuple[float, float]:
    """Median seconds of the session's warm frame at its current parameters and of a one-pass frame
    of the whole of level 0 as one brick in one 3D texture at ``cam`` and ``step``, measured
    alternately (a busy machine's speed drifts)."""
    from clipvol.paging.cliptexture import ClipTexture
    from clipvol.render.action import ClipRenderAction
    from clipvol.scene.params import RenderParams

    whole = WholeVolume(loader)
    nbytes = int(np.prod(whole.pyramid.shape)) * whole.pyramid.dtype.itemsize
    params = RenderParams(policy="fixed", level=0, step=step, texture_budget=nbytes * 2 + (64 << 20))
    ours, one = [], []
    with ClipTexture(whole, nbytes + (64 << 20), threads=1) as clip, ClipRenderAction(ctx, clip, params) as action:
        action.render(cam, tf, wait=True, timeout=600)
        sess.render(cam, coi, wait=True, timeout=600)
        for _ in range(repeat):
            t0 = time.perf_counter()
            sess.render(cam, coi, wait=False)
            ours.append(time.perf_counter() - t0)
            t0 = time.perf_counter()
            action.render(cam, tf, wait=False)
            one.append(time.perf_counter() - t0)
    return statistics.median(ours), statistics.median(one)


def bench(name: str, quick: bool, frames: int, ctx, log) -> dict:
    from clipvol.app.adaptive import FULL, AdaptiveQuality
    from clipvol.app.session import RenderSession
    from clipvol.scene.params import RenderParams
    from clipvol.paging.open import open_store
    from clipvol.viewer.controls import OrbitControls

    loader = open_store(_store(name, quick))
    tf = _tf(name, loader)
    base_step = 0.5
    out: dict = {"store": name, "shape": "x".join(map(str, loader.pyramid.shape))}
    with RenderSession(loader, ctx, memory_budget="1GB", params=RenderParams(step=base_step, texture_budget="1GB"),
                       tf=tf) as sess:
        controls = OrbitControls.for_pyramid(loader.pyramid, size=SIZE)
        coi = lambda: controls.center_of_interest  # noqa: E731
        home = controls.camera(SIZE)
        out["first_converged_s"] = _converge(sess, home, coi())
        # full-quality frame, warm
        ts = []
        for _ in range(3):
            t0 = time.perf_counter()
            sess.render(home, coi(), wait=False)
            ts.append(time.perf_counter() - t0)
        out["full_frame_s"] = statistics.median(ts)
        log(f"{name}: full-quality warm frame {out['full_frame_s'] * 1e3:.0f} ms")
        # the drag at full quality (the reference), then with adaptation, from the same start:
        # the controller before (100 ms, the user's LOD threshold while moving) and after, alternately
        full_rows = _drag(sess, controls, coi, max(4, frames // 4), None, base_step)
        full_rows[-1].pop("_image")
        settings = {"before": (lambda: AdaptiveQuality(0.1, step_rungs=None), False),
                    "after": (AdaptiveQuality, True)}
        runs: dict = {k: [] for k in settings}
        for _ in range(2):
            for key, (make, whole) in settings.items():
                runs[key].append(_adaptive_drag(sess, controls, coi, frames, make(), base_step, out["full_frame_s"],
                                                whole))
        for key, rs in runs.items():
            for m in ("fps", "frame_ms_median", "scale_median", "step_factor_median", "level_median",
                      "replayed_share", "preview_pct_de6"):
                out[f"{key}_{m}"] = statistics.mean(r[m] for r in rs)
            log(f"{name}: drag {key}: {out[key + '_fps']:.1f} fps (median scale {out[key + '_scale_median']:.2f}, "
                f"step x{out[key + '_step_factor_median']:.2f}, level {out[key + '_level_median']:g} "
                f"(-1: projected size), {100 * out[key + '_replayed_share']:.0f} % of frames replayed), preview "
                f"{out[key + '_preview_pct_de6']:.1f} % pixels dE>=6 against the converged frame")
        rows = runs["after"][-1]["_rows"]
        out["drag_fps"] = out["after_fps"]
        out["full_drag_fps"] = len(full_rows) / sum(r["frame_s"] for r in full_rows)
        out["fps_ratio"] = out["drag_fps"] / out["full_drag_fps"]
        log(f"{name}: drag {out['drag_fps']:.1f} fps adaptive vs {out['full_drag_fps']:.2f} fps at full quality")
        # the after drag's preview frame against the one-texture caster at the same size and step
        q = AdaptiveQuality().quality_for(out["after_scale_median"] ** 2 / out["after_step_factor_median"])
        pcam = controls.camera(q.size(SIZE))
        _apply(sess, q, base_step, pcam)
        sess.render(pcam, coi(), wait=True, timeout=600)
        ours_p, one_p = _alternate(ctx, loader, sess, pcam, coi(), tf, base_step * q.step_factor, 5)
        out["preview_size"] = "x".join(map(str, q.size(SIZE)))
        out["preview_ms"], out["preview_one_pass_ms"] = 1e3 * ours_p, 1e3 * one_p
        out["preview_vs_one_pass"] = ours_p / one_p
        log(f"{name}: preview frame {out['preview_size']} step x{q.step_factor:.2f}: {1e3 * ours_p:.0f} ms, "
            f"the one-texture caster at that size and step {1e3 * one_p:.0f} ms ({out['preview_vs_one_pass']:.2f}x)")
        # stop: the refined frame
        _apply(sess, FULL, base_step)
        cam = controls.camera(SIZE)
        t0 = time.perf_counter()
        sess.render(cam, coi(), wait=False)
        out["first_full_after_stop_s"] = time.perf_counter() - t0
        out["refined_s"] = out["first_full_after_stop_s"] + _converge(sess, cam, coi())
        log(f"{name}: first full frame after the stop {out['first_full_after_stop_s'] * 1e3:.0f} ms, "
            f"refined (converged) after {out['refined_s'] * 1e3:.0f} ms")
        out["_rows"] = rows
        out["_full_rows"] = full_rows
        ours, one = _alternate(ctx, loader, sess, home, coi(), tf, base_step, 3)
    out["full_frame_alt_s"], out["one_pass_s"] = ours, one
    out["full_vs_one_pass"] = ours / one
    log(f"{name}: one-texture one-pass caster {one * 1e3:.0f} ms, our full-quality frame {ours * 1e3:.0f} ms "
        f"measured alternately ({out['full_vs_one_pass']:.2f}x)")
    return out


def _plot(results, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(results), figsize=(5 * len(results), 3.4), squeeze=False)
    for ax, r in zip(axes[0], results):
        ax.plot([x["frame"] for x in r["_rows"]], [1e3 * x["frame_s"] for x in r["_rows"]], "o-", ms=3,
                label="adaptive (target 1/15 s, one whole level while moving)")
        ax.plot([x["frame"] for x in r["_full_rows"]], [1e3 * x["frame_s"] for x in r["_full_rows"]], "s-", ms=3,
                label="full quality (reference)")
        ax.axhline(1e3 / 15, color="grey", lw=0.8, ls="--")
        ax.set_yscale("log")
        ax.set_xlabel("frame of the drag")
        ax.set_ylabel("frame time, ms")
        ax.set_title(f"{r['store']} ({r['shape']}), 960x640, llvmpipe")
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--quick", action="store_true", help="small stores, few frames (a smoke run)")
    p.add_argument("--frames", type=int, default=None, help="drag frames (default 40; 8 with --quick)")
    p.add_argument("--stores", default="demo,512", help="which stores: demo, 512 (comma-separated)")
    p.add_argument("--out", default=str(RESULTS), help="folder for the CSV and PNG")
    args = p.parse_args(argv)
    from clipvol.render import create_context

    frames = args.frames or (8 if args.quick else 40)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    ctx = create_context()
    results = []
    try:
        for name in [s.strip() for s in args.stores.split(",") if s.strip()]:
            results.append(bench(name, args.quick, frames, ctx, lambda s: print(s, flush=True)))
    finally:
        ctx.release()
    cols = [k for k in results[0] if not k.startswith("_")]
    with open(out / "bench_interactive.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=cols)
        w.writeheader()
        for r in results:
            w.writerow({k: (f"{v:.4g}" if isinstance(v, float) else v) for k, v in r.items() if k in cols})
    _plot(results, out / "bench_interactive.png")
    print(f"wrote {out / 'bench_interactive.csv'} and {out / 'bench_interactive.png'}")
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
