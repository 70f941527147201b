"""Where a refined frame's time goes: the host, each pass's set-up (clear, mask), its rays, the read-back.

``python tools/bench/bench_refine_breakdown.py --store mni32.zarr`` (default: the CT-like head of
``bench_mission.py``). Per view of ``bench_mission.views`` and image size, the full-resolution frame,
the raw one-texture caster and the chosen refined settings (``--settings``, names of
``bench_mission.settings()``; level-1 settings with ``classify="distribution"``), warm, in
``--repeat`` interleaved rounds (forward order on even rounds, reverse on odd). Each setting is
drawn twice per round:

* **free** - as any frame (``perf_counter`` around ``render``): the frame's time and the speed-up
  over the full-resolution frame of the same round;
* **split** - with ``ctx.finish()`` before and after each pass's phases, timed on the host:

  - ``setup``: :meth:`DrawSetup.begin` - bind and clear the pass's target and, in a masked pass,
    the mask (``shaders/refine_mask.frag.glsl``);
  - ``rays``: the draw path's uniforms and proxy boxes - the rays cast;
  - ``read``: :meth:`DrawSetup.read_back` - a coarse pass's nothing, the image pass's resolve and
    read-back;

  and ``host``: the split frame's time less its phases (selection, merge, Python). A finish stops
  Mesa llvmpipe from overlapping one pass's rasterisation with the next pass's set-up, so the split
  frame is slower than the free one; its phases say which part of a frame is which share.

``--floor`` adds each refined setting at tolerance 1 (every finer pixel a blend of the coarse pass:
what the passes cost without their rays). The rays each pass casts (its pixels, or those its mask
leaves) are counted on one more, untimed frame.
Rows go to ``tools/bench/results/bench_refine_breakdown.csv``.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
if str(HERE) not in sys.path:
    sys.path.insert(0, str(HERE))

import bench_mission  # noqa: E402
import common  # noqa: E402

DEFAULT_SETTINGS = "step=2 refine=0.16,L1 step=1 refine=0.08"


class PhaseClock:
    """Host time of each draw-path pass's set-up, rays and read-back, the GL finished at each end
    (patched into :class:`~clipvol.render.paths.setup.DrawSetup` while ``on``; :meth:`close`
    restores it)."""

    def __init__(self, ctx) -> None:
        from clipvol.render.paths.setup import DrawSetup

        self.ctx, self.cls = ctx, DrawSetup
        self.orig = (DrawSetup.begin, DrawSetup.read_back)
        self.on = False
        self.count_rays = False
        self.records: list = []  # (pass, phase, seconds)
        self.rays: list = []  # (pass, rays) while count_rays
        self._t = 0.0
        clock = self
        begin, read_back = self.orig

        def split_begin(setup, frame, clear):
            if clock.on:
                clock.ctx.finish()
                t = time.perf_counter()
            out = begin(setup, frame, clear)
            if clock.on:
                clock.ctx.finish()
                clock._t = time.perf_counter()
                clock.records.append((frame.refine_level, "setup", clock._t - t))
            if clock.count_rays:
                clock.rays.append((frame.refine_level, clock._live(setup, frame, out[0])))
            return out

        def split_read_back(setup, frame, *args, **kw):
            if clock.on:
                clock.ctx.finish()
                t = time.perf_counter()
                clock.records.append((frame.refine_level, "rays", t - clock._t))
            out = read_back(setup, frame, *args, **kw)
            if clock.on:
                clock.ctx.finish()
                clock.records.append((frame.refine_level, "read", time.perf_counter() - t))
            return out

        DrawSetup.begin, DrawSetup.read_back = split_begin, split_read_back

    @staticmethod
    def _live(setup, frame, fbo) -> int:
        """Rays the pass casts: its pixels (a coarse pass) or the pixels its mask left (depth 1)."""
        w, h = (int(v) for v in frame.camera.size)
        if not frame.repeats_pass:
            return w * h
        ox, oy = setup.origin
        d = np.frombuffer(fbo.read(viewport=(ox, oy, w, h), components=1, attachment=-1, dtype="f4"), dtype=np.float32)
        return int(np.count_nonzero(d != 0.0))

    def take(self) -> dict:
        """``{(pass, phase): ms}`` of the frame drawn since the last call."""
        out: dict = {}
        for k, phase, sec in self.records:
            key = ("image" if not k else f"1/{2 ** k}", phase)
            out[key] = out.get(key, 0.0) + 1e3 * sec
        self.records = []
        return out

    def close(self) -> None:
        self.cls.begin, self.cls.read_back = self.orig


def run(store: Path, volume, label: str, images, repeat: int, names, view_names, floor: bool = False,
        log=print) -> list[dict]:
    from clipvol.render.paths.setup import OPAQUE

    scene = common.WarmScene(store)
    pyr, tf = scene.pyramid, scene.tf
    raw = scene.raw_caster(volume)
    known = bench_mission.settings()
    conf = {"full": dict(policy="fixed", level=0)}  # name -> params
    for n in names:
        kw = dict(known[n])
        if kw.get("level", 0) >= 1:
            kw["classify"] = "distribution"
        conf[n] = kw
        if floor and kw.get("refine_tolerance", 0) > 0:
            conf[n + " floor"] = dict(kw, refine_tolerance=1.0)
    actions = {k: scene.action(**{"step": 0.5, **kw}) for k, kw in conf.items()}
    clock = PhaseClock(scene.ctx)

    rows = []
    try:
        for image in images:
            for view, cam in bench_mission.views(pyr, image).items():
                if view_names and view not in view_names:
                    continue
                shows = {}
                for k in actions:
                    actions[k].render(cam, tf, wait=True, timeout=600)
                    clock.count_rays, clock.rays = True, []
                    img = actions[k].render(cam, tf)
                    clock.count_rays = False
                    shows[k] = (float(np.mean(img[..., 3] > 0)), dict(clock.rays))
                fc = actions["full"]._selection_camera(cam)
                raw.render(fc, tf, 0.5, OPAQUE)
                order = ["raw", *actions]
                times = {k: [] for k in order}
                split = {k: [] for k in actions}
                for r in range(repeat):
                    for k in (order if r % 2 == 0 else order[::-1]):
                        t = time.perf_counter()
                        if k == "raw":
                            raw.render(fc, tf, 0.5, OPAQUE)
                            times[k].append(time.perf_counter() - t)
                            continue
                        actions[k].render(cam, tf)
                        times[k].append(time.perf_counter() - t)
                        clock.on = True
                        t = time.perf_counter()
                        actions[k].render(cam, tf)
                        total = 1e3 * (time.perf_counter() - t)
                        clock.on = False
                        ph = clock.take()
                        ph[("frame", "host")] = max(0.0, total - sum(ph.values()))
                        ph[("frame", "split")] = total
                        split[k].append(ph)
                for k in actions:
                    ph = {key: statistics.median(p.get(key, 0.0) for p in split[k]) for key in split[k][0]}
                    free = 1e3 * statistics.median(times[k])
                    speed = statistics.median(f / s for f, s in zip(times["full"], times[k]))
                    shown, rays = shows[k]
                    row = {"date": time.strftime("%Y-%m-%d"), "volume": label, "image": image, "view": view,
                           "setting": k, "rounds": repeat, "ms": round(free, 2), "speedup": round(speed, 3),
                           "over_raw": round(statistics.median(times[k]) / statistics.median(times["raw"]), 3),
                           "raw_ms": round(1e3 * statistics.median(times["raw"]), 2),
                           "pixels_shown": round(shown, 4), "boxes": actions[k].boxes_drawn,
                           "path": actions[k].path_drawn}
                    for (pas, phase), ms in ph.items():
                        row[f"{pas} {phase} ms"] = round(ms, 2)
                    for pas, n in sorted(rays.items(), key=lambda kv: -(kv[0] or 0)):
                        row[f"{'image' if not pas else f'1/{2 ** pas}'} rays"] = n
                    rows.append(row)
                    parts = " | ".join(f"{p} {q}: {ms:.1f}" for (p, q), ms in ph.items() if p != "frame")
                    rs = ", ".join(f"{'image' if not p else f'1/{2 ** p}'} {n}" for p, n in
                                   sorted(rays.items(), key=lambda kv: -(kv[0] or 0)))
                    log(f"{image}^2 {view:5} {k:>32}: {free:6.1f} ms ({speed:4.2f}x full, {row['over_raw']:.2f}x raw); "
                        f"split {ph[('frame', 'split')]:.1f} = host {ph[('frame', 'host')]:.1f} | {parts}; "
                        f"rays {rs}; shown {shown:.2f}")
    finally:
        clock.close()
        scene.close()
    return rows


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--store", type=Path, default=None, help="a clipvol store (default: the CT-like head)")
    ap.add_argument("--images", default="256", help="image edges, comma separated (default 256)")
    ap.add_argument("--views", default="iso,face", help="views, comma separated (default iso,face)")
    ap.add_argument("--settings", default=DEFAULT_SETTINGS,
                    help=f"refined settings of bench_mission.py, comma separated (default {DEFAULT_SETTINGS!r}; "
                         "level-1 settings are drawn with classify='distribution')")
    ap.add_argument("--repeat", type=int, default=5, help="interleaved rounds (default 5)")
    ap.add_argument("--floor", action="store_true", help="each refined setting again at tolerance 1 (no rays refined)")
    ap.add_argument("--out", type=Path, default=common.RESULTS / "bench_refine_breakdown.csv")
    a = ap.parse_args(argv)
    names = [s for s in a.settings.split(",") if s]
    unknown = set(names) - set(bench_mission.settings())
    if unknown:
        ap.error(f"--settings: unknown {sorted(unknown)}; known: {', '.join(bench_mission.settings())}")
    store, volume, label = common.store_or_ct(a.store)
    rows = run(store, volume, label, [int(v) for v in a.images.split(",")], a.repeat, names, a.views.split(","),
               floor=a.floor)
    keys = list(dict.fromkeys(k for r in rows for k in r))  # a pass's columns only where it drew: blank elsewhere
    return common.save_rows(a.out, [{k: r.get(k, "") for k in keys} for r in rows])


if __name__ == "__main__":
    sys.exit(main())
