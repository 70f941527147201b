"""Where a kept projected-size cut's frame goes, stage by stage: the rendering thread's CPU time in
each of :class:`~clipvol.scene.selection.kept_cut.KeptCut`'s steps and the kept merge's, per frame,
along the camera sequence of ``bench_frame_cost.py`` (the same warm-up, then ``--frames`` frames).

The stages are timed by wrapping the methods that exist in the code it runs (it runs on an older
tree too, where some are missing), with ``time.thread_time`` (llvmpipe rasterises on its own
threads). A stage called inside another counts in both. Medians and means over the frames, and the
band (the nodes re-tested) per frame.

``--replay N`` then replays the cameras the frames handed ``KeptCut.update`` through N fresh kept
cuts built as the frame loop built its own, without drawing (the warm-up's cameras replayed too, untimed,
and the first frame after them left out): the update's stages alone, away from llvmpipe's threads, over N times as many
frames (steadier figures on a loaded machine). It runs on an older tree too (the kept cut's own
methods are all it calls).

    python tools/bench/profile_kept_cut.py --store mni16.zarr --camera orbit --frames 12 --replay 5
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
if str(HERE) not in sys.path:
    sys.path.insert(0, str(HERE))

import bench_frame_cost  # noqa: E402  (beside this script)
import common  # noqa: E402

#: ``(module, class, method)`` timed where they exist
STAGES = [("clipvol.scene.selection.kept_cut", "KeptCut", m)
          for m in ("update", "_test", "_propagate", "_spread", "_settle", "_selection", "_grow")] + \
         [("clipvol.scene.selection.band", "MotionBand", m) for m in ("advance", "set")] + \
         [("clipvol.scene.selection.merge", "KeptMerge", m) for m in ("merge", "answers_hold")]


def _wrap(acc: dict) -> None:
    import importlib

    for mod, cls, name in STAGES:
        try:
            owner = getattr(importlib.import_module(mod), cls)
        except (ImportError, AttributeError):
            continue
        f = getattr(owner, name, None)
        if f is None:
            continue

        def timed(*a, _f=f, _label=f"{cls}.{name}", **k):
            t = time.thread_time()
            try:
                return _f(*a, **k)
            finally:
                acc[_label] = acc.get(_label, 0.0) + time.thread_time() - t

        setattr(owner, name, timed)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--store", type=Path, required=True, help="a clipvol store")
    ap.add_argument("--camera", default="orbit", choices=("static", "orbit", "fly"))
    ap.add_argument("--frames", type=int, default=12)
    ap.add_argument("--image", type=int, default=32)
    ap.add_argument("--lod", type=float, default=0.1)
    ap.add_argument("--replay", type=int, default=0, help="replays of the update alone (see above)")
    a = ap.parse_args(argv)
    acc: dict = {}
    _wrap(acc)
    from clipvol.scene.selection import kept_cut

    made, seen = [], []
    init, update = kept_cut.KeptCut.__init__, kept_cut.KeptCut.update

    def recorded_init(self, *args, **kw):  # (how the frame loop builds its kept cut)
        made.append((args, kw))
        init(self, *args, **kw)

    def recorded_update(self, camera, *args, **kw):  # (the cameras it hands the update)
        seen.append((camera, args, kw))
        return update(self, camera, *args, **kw)

    kept_cut.KeptCut.__init__, kept_cut.KeptCut.update = recorded_init, recorded_update
    scene = common.WarmScene(a.store)
    try:
        act = scene.action(policy="projected-size", lod_threshold=a.lod, step=bench_frame_cost.STEP)
        cams = bench_frame_cost.cameras(scene.pyramid, a.image, a.camera, a.frames)
        for cam in (*cams, cams[0]):  # the benchmark's warm-up
            act.render(cam, scene.tf, wait=True, timeout=900)
        frames, bands = [], []
        start = len(seen)  # (the warm-up's cameras before: replayed untimed)
        for cam in cams:
            acc.clear()
            t = time.thread_time()
            act.render(cam, scene.tf)
            frames.append((time.thread_time() - t, dict(acc)))
            cut = act.frame_loop._cut
            if cut:
                bands.append(cut[1].retested)
        replayed, rbands = [], []
        if a.replay and made and seen:
            kept_cut.KeptCut.update = update
            for _ in range(a.replay):
                kc = kept_cut.KeptCut(*made[-1][0], **made[-1][1])
                for k, (cam, args, kw) in enumerate(seen):
                    acc.clear()
                    t = time.thread_time()
                    kc.update(cam, *args, **kw)
                    if k > start:
                        replayed.append((time.thread_time() - t, dict(acc)))
                        rbands.append(kc.retested)
    finally:
        scene.close()
    print(f"{a.store.name} {a.camera}, {len(frames)} frames, load {bench_frame_cost._load()}")
    print(f"  frame (main-thread CPU)  median {1e3 * statistics.median(t for t, _ in frames):.2f} ms")
    for k in sorted({k for _, d in frames for k in d}):
        v = [d.get(k, 0.0) for _, d in frames]
        print(f"  {k:24} median {1e3 * statistics.median(v):.3f} ms, mean {1e3 * statistics.mean(v):.3f} ms")
    if bands:
        print(f"  band (nodes re-tested)   median {statistics.median(bands)}")
    if replayed:
        print(f"  replayed: {a.replay} x {len(replayed) // a.replay} updates, load {bench_frame_cost._load()}")
        for k in sorted({k for _, d in replayed for k in d}):
            v = [d.get(k, 0.0) for _, d in replayed]
            print(f"  {k:24} median {1e3 * statistics.median(v):.3f} ms, mean {1e3 * statistics.mean(v):.3f} ms")
        print(f"  band (nodes re-tested)   median {statistics.median(rbands)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
