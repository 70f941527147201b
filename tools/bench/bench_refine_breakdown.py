"""Where a refined frame's time goes: the host, each pass's set-up (clear, mask), its rays, the read-back.

``python tools/bench/bench_refine_breakdown.py --store mni32.zarr`` (default: the CT-like head of
``bench_mission.py``). Per view of ``bench_mission.views`` and image size, the full-resolution frame,
the raw one-texture caster and the chosen refined settings (``--settings``, names of
``bench_mission.settings()``), warm, in ``--repeat`` interleaved rounds. Each frame is timed on the
host (``perf_counter`` around ``render``) and, inside it, with GL time queries (``GL_TIME_ELAPSED``,
one at a time, never nested) around each pass's three phases:

* ``setup`` - :meth:`DrawSetup.begin`: bind and clear the pass's target and, in a masked pass, the
  mask (``shaders/refine_mask.frag.glsl``) and, compacted, the list of live pixels;
* ``rays`` - the draw path's uniforms and proxy boxes: the rays cast;
* ``read`` - :meth:`DrawSetup.read_back`: a coarse pass's nothing (or the compacted pass's scatter),
  the image pass's finish, resolve and read-back.

``host`` is the frame's time less the sum of the queried phases (selection, merge, uniforms, Python).
A second, untimed frame per setting counts the rays each pass casts (the pixels its mask leaves, read
from the depth buffer) and the image's pixels that show something. On Mesa llvmpipe a query measures
the rasteriser's work between its begin and end (the GL calls in it are executed when the query ends
at the latest), so the phases add up to the frame's GL time; on a GPU they are GPU times.

Rows go to ``tools/bench/results/bench_refine_breakdown.csv``: per setting, view and round medians
of each phase in ms, the rays per pass, and the speed-up over the full-resolution frame (median of
the paired ratios).
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
    """GL time queries around each draw-path pass's set-up, rays and read-back (patched into
    :class:`~clipvol.render.paths.setup.DrawSetup` while it lives; :meth:`close` restores it)."""

    def __init__(self, ctx) -> None:
        from clipvol.render.paths.setup import DrawSetup

        self.ctx, self.cls = ctx, DrawSetup
        self.orig = (DrawSetup.begin, DrawSetup.read_back)
        self.records: list = []  # (pass, phase, query)
        self.count_rays = False
        self.rays: list = []  # (pass, rays) while count_rays
        clock = self
        begin, read_back = self.orig

        def timed_begin(setup, frame, clear):
            k = frame.refine_level
            q = clock.ctx.query(time=True)
            with q:
                out = begin(setup, frame, clear)
            clock.records.append((k, "setup", q))
            if clock.count_rays:
                clock.rays.append((k, clock._live(setup, frame, out[0])))
            clock._open = clock.ctx.query(time=True)
            clock._open.__enter__()
            return out

        def timed_read_back(setup, frame, *args, **kw):
            q = clock._open
            q.__exit__(None, None, None)
            clock.records.append((frame.refine_level, "rays", q))
            q = clock.ctx.query(time=True)
            with q:
                out = read_back(setup, frame, *args, **kw)
            clock.records.append((frame.refine_level, "read", q))
            return out

        DrawSetup.begin, DrawSetup.read_back = timed_begin, timed_read_back

    @staticmethod
    def _live(setup, frame, fbo) -> int:
        """Rays the pass casts: its pixels (a coarse pass), the pixels its mask left (depth 1), or
        the compact list's length."""
        if getattr(setup, "compacted", False):
            return int(setup.refine.compaction.count)
        w, h = (int(v) for v in frame.camera.size)
        if not frame.repeats_pass:
            return w * h
        ox, oy = setup.origin
        d = np.frombuffer(fbo.read(viewport=(ox, oy, w, h), components=1, attachment=-1, dtype="f4"), dtype=np.float32)
        return int(np.count_nonzero(d != 0.0))

    def take(self) -> dict:
        """``{(pass, phase): ms}`` of the frame drawn since the last call."""
        out: dict = {}
        for k, phase, q in self.records:
            key = ("image" if not k else f"1/{2 ** k}", phase)
            out[key] = out.get(key, 0.0) + q.elapsed / 1e6
        self.records = []
        return out

    def close(self) -> None:
        self.cls.begin, self.cls.read_back = self.orig


def run(store: Path, volume, label: str, images, repeat: int, names, view_names, log=print) -> list[dict]:
    from clipvol.render.paths.setup import OPAQUE

    scene = common.WarmScene(store)
    pyr, tf = scene.pyramid, scene.tf
    raw = scene.raw_caster(volume)
    known = bench_mission.settings()
    conf = {"full": dict(policy="fixed", level=0)}
    for n in names:
        kw = dict(known[n])
        if kw.get("level", 0) >= 1:
            kw["classify"] = "distribution"
        conf[n] = kw
    actions = {k: scene.action(**{"step": 0.5, **kw}) for k, kw in conf.items()}
    clock = PhaseClock(scene.ctx)
    rows = []
    try:
        for image in images:
            for view, cam in bench_mission.views(pyr, image).items():
                if view_names and view not in view_names:
                    continue
                shows = {}
                for k, a in actions.items():
                    a.render(cam, tf, wait=True, timeout=600)
                    clock.count_rays, clock.rays = True, []
                    img = a.render(cam, tf)
                    clock.count_rays = False
                    shows[k] = (float(np.mean(img[..., 3] > 0)), dict(clock.rays))
                    clock.take()
                fc = actions["full"]._selection_camera(cam)
                raw.render(fc, tf, 0.5, OPAQUE)
                names_all = ["raw", *actions]
                times = {k: [] for k in names_all}
                phases = {k: [] for k in actions}
                for r in range(repeat):
                    for k in (names_all if r % 2 == 0 else names_all[::-1]):
                        t = time.perf_counter()
                        if k == "raw":
                            raw.render(fc, tf, 0.5, OPAQUE)
                            times[k].append(time.perf_counter() - t)
                            continue
                        actions[k].render(cam, tf)
                        times[k].append(time.perf_counter() - t)
                        phases[k].append(clock.take())
                for k in actions:
                    ph = {key: statistics.median(p.get(key, 0.0) for p in phases[k]) for key in phases[k][0]}
                    total = 1e3 * statistics.median(times[k])
                    gl = statistics.median(sum(p.values()) for p in phases[k])
                    speed = statistics.median(f / s for f, s in zip(times["full"], times[k]))
                    shown, rays = shows[k]
                    row = {"date": time.strftime("%Y-%m-%d"), "volume": label, "image": image, "view": view,
                           "setting": k, "rounds": repeat, "ms": round(total, 2),
                           "host_ms": round(max(0.0, total - gl), 2), "gl_ms": round(gl, 2),
                           "speedup": round(speed, 3), "over_raw": round(statistics.median(times[k]) /
                                                                          statistics.median(times["raw"]), 3),
                           "raw_ms": round(1e3 * statistics.median(times["raw"]), 2),
                           "pixels_shown": round(shown, 4), "boxes": actions[k].boxes_drawn,
                           "path": actions[k].path_drawn}
                    for (pas, phase), ms in sorted(ph.items()):
                        row[f"{pas} {phase} ms"] = round(ms, 2)
                    for pas, n in sorted(rays.items(), key=lambda kv: -(kv[0] or 0)):
                        row[f"{'image' if not pas else f'1/{2 ** pas}'} rays"] = n
                    rows.append(row)
                    parts = " | ".join(f"{p} {ph_}: {ms:.1f}" for (p, ph_), ms in sorted(ph.items(), reverse=True))
                    rs = ", ".join(f"{'image' if not p else f'1/{2 ** p}'} {n}" for p, n in
                                   sorted(rays.items(), key=lambda kv: -(kv[0] or 0)))
                    log(f"{image}^2 {view:5} {k:>22}: {total:6.1f} ms ({speed:4.2f}x full, {row['over_raw']:.2f}x raw), "
                        f"host {row['host_ms']:.1f}, GL {gl:.1f} = {parts}; rays {rs}; shown {shown:.2f}")
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
    ap.add_argument("--out", type=Path, default=common.RESULTS / "bench_refine_breakdown.csv")
    a = ap.parse_args(argv)
    names = [s for s in a.settings.split(",") if s]
    unknown = set(names) - set(bench_mission.settings())
    if unknown:
        ap.error(f"--settings: unknown {sorted(unknown)}; known: {', '.join(bench_mission.settings())}")
    if a.store is not None:
        from clipvol.paging.open import open_store

        loader = open_store(a.store)
        volume = common.WholeVolume(loader).read_brick(0, (0, 0, 0))
        store, label = a.store, f"{a.store.name}, {loader.pyramid.brick_shape[0]}^3 bricks"
    else:
        store, volume = common.ct_store("256x256x256", 32), common.ct_volume((256, 256, 256))
        label = "ct_head 256x256x256 uint16 (12 bit), 32^3 bricks"
    rows = run(store, volume, label, [int(v) for v in a.images.split(",")], a.repeat, names, a.views.split(","))
    keys = list(dict.fromkeys(k for r in rows for k in r))  # a pass's columns only where it drew: blank elsewhere
    return common.save_rows(a.out, [{k: r.get(k, "") for k in keys} for r in rows])


if __name__ == "__main__":
    sys.exit(main())
