"""Where an orbit frame's time goes outside the kept cut's update, stage by stage, for several
volumes drawn alternately in one process: the rendering thread's CPU time (``time.thread_time``)
and the wall time of each stage of :class:`~clipvol.render.action.ClipRenderAction`'s frame path
(the frame loop, the merge, the page table, its texture writes, the uniforms, the draw call, the
read-back, the frame's statistics), per frame, along the orbit of ``bench_frame_cost.py --flat``
(the same warm-up, then ``--frames`` frames of 1 degree each, the volumes' frames alternating).

The stages are timed by wrapping the methods and functions that exist in the code it runs (it runs
on an older tree too, where some are missing). A stage called inside another counts in both
(``ClipRenderAction.render`` is the whole frame); the last lines are stages less the stages timed
inside them, ``rest`` the frame less the frame loop and the merge: what the draw path, the page
table, the GL calls and the statistics cost. Medians and means over the frames, per volume; then
per stage the median (and mean) over frames of each pair's difference from the first volume's
frame drawn beside it, and the frame's per-pair ratio to the first's with its quartiles (as
``bench_frame_cost.py --flat`` gives it).

    python tools/bench/profile_frame_rest.py --store mni16.zarr --head 512 --frames 24
"""

from __future__ import annotations

import importlib
import statistics
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
if str(HERE) not in sys.path:
    sys.path.insert(0, str(HERE))

import bench_frame_cost  # noqa: E402  (beside this script)
import common  # noqa: E402

#: ``(module, owner, name)`` timed where they exist (owner None: a module-level function, replaced
#: in that module's namespace: the caller's import of it)
STAGES = [
    ("clipvol.render.action", "ClipRenderAction", "render"),
    ("clipvol.render.action", "ClipRenderAction", "_selection_camera"),
    ("clipvol.render.action", "ClipRenderAction", "_transparent"),
    ("clipvol.render.frame_loop", "FrameLoop", "run"),
    ("clipvol.render.frame_loop", "FrameLoop", "replay"),
    ("clipvol.render.frame_loop", "FrameLoop", "update"),
    ("clipvol.scene.selection.kept_cut", "KeptCut", "update"),
    ("clipvol.render.action", "ClipRenderAction", "_draw"),
    ("clipvol.render.action", "ClipRenderAction", "_merged"),
    ("clipvol.scene.selection.merge", "KeptMerge", "merge"),
    ("clipvol.scene.selection.merge", "KeptMerge", "answers_hold"),
    ("clipvol.render.action", "ClipRenderAction", "_samples"),
    ("clipvol.render.action", "ClipRenderAction", "_skips"),
    ("clipvol.render.action", "ClipRenderAction", "defines"),
    ("clipvol.render.action", "ClipRenderAction", "_frame_context"),
    ("clipvol.render.paths.single_pass", "SinglePassPath", "draw"),
    ("clipvol.render.paths.single_pass", None, "update_page_table"),
    ("clipvol.render.paths.single_pass", "SinglePassPath", "_upload"),
    ("clipvol.render.paths.single_pass", "SinglePassPath", "_table_uniforms"),
    ("clipvol.render.paths.single_pass", "SinglePassPath", "_max_regions"),
    ("clipvol.render.paths.single_pass", "SinglePassPath", "_scissor"),
    ("clipvol.render.paths.setup", "DrawSetup", "begin"),
    ("clipvol.render.paths.setup", "DrawSetup", "program"),
    ("clipvol.render.paths.setup", "DrawSetup", "frame_uniforms"),
    ("clipvol.render.paths.setup", "DrawSetup", "tf_texture"),
    ("clipvol.render.paths.setup", "DrawSetup", "bind_occupancy"),
    ("clipvol.render.paths.setup", "DrawSetup", "read_back"),
    ("clipvol.render.gpu_cache", "GpuBrickCache", "occupancy_texture"),
    ("clipvol.render.gpu_cache", "GpuBrickCache", "empty_fraction"),
    ("clipvol.render.action", None, "frame_stats"),
    ("clipvol.render.frame_stats", None, "failed_bricks"),
    ("moderngl", "VertexArray", "render"),
    ("moderngl", "Context", "finish"),
    ("moderngl", "Texture", "write"),
    ("moderngl", "Uniform", "write"),
]


def _wrap(acc: dict) -> None:
    """Wrap every stage of :data:`STAGES` to add ``(cpu, wall)`` seconds to ``acc[label]``."""
    for mod, owner_name, name in STAGES:
        try:
            module = importlib.import_module(mod)
            owner = module if owner_name is None else getattr(module, owner_name)
        except (ImportError, AttributeError):
            continue
        f = getattr(owner, name, None)
        if f is None:
            continue
        label = f"{owner_name or mod.rsplit('.', 1)[-1]}.{name}"

        def timed(*a, _f=f, _label=label, **k):
            c, t = time.thread_time(), time.perf_counter()
            try:
                return _f(*a, **k)
            finally:
                was = acc.get(_label, (0.0, 0.0, 0))
                acc[_label] = (was[0] + time.thread_time() - c, was[1] + time.perf_counter() - t, was[2] + 1)

        setattr(owner, name, timed)


def _stats(frames: list[dict], key: str) -> tuple[float, float, float, float]:
    """Median and mean CPU ms, median wall ms, mean calls of stage ``key`` over ``frames``."""
    cpu = [d.get(key, (0.0, 0.0, 0))[0] for d in frames]
    wall = [d.get(key, (0.0, 0.0, 0))[1] for d in frames]
    calls = [d.get(key, (0.0, 0.0, 0))[2] for d in frames]
    return (1e3 * statistics.median(cpu), 1e3 * statistics.mean(cpu), 1e3 * statistics.median(wall),
            statistics.mean(calls))


def main(argv: list[str] | None = None) -> int:
    ap = common.orbit_parser(__doc__, frames=24)
    a = ap.parse_args(argv)
    from clipvol.render import create_context

    entries = common.orbit_stores(a)
    acc: dict = {}
    _wrap(acc)
    ctx = create_context()
    scenes, acts, seqs = [], [], []
    try:
        for store, _ in entries:
            scene = common.WarmScene(store, ctx=ctx)
            scenes.append(scene)
            act = scene.action(policy="projected-size", lod_threshold=a.lod, step=bench_frame_cost.STEP)
            cams = bench_frame_cost.cameras(scene.pyramid, a.image, "orbit", a.frames)
            for cam in (*cams, cams[0]):  # the benchmark's warm-up
                act.render(cam, scene.tf, wait=True, timeout=900)
            acts.append(act)
            seqs.append(cams)
        frames: list[list] = [[] for _ in entries]
        for k in range(a.frames):
            for i in (range(len(entries)) if k % 2 == 0 else reversed(range(len(entries)))):
                acc.clear()
                acts[i].render(seqs[i][k], scenes[i].tf)
                frames[i].append(dict(acc))
    finally:
        for scene in reversed(scenes):
            scene.close()
        ctx.release()
    print(f"{a.frames} orbit frames each, alternating, {a.image}^2, load {bench_frame_cost._load()}")
    keys = sorted({k for fr in frames for d in fr for k in d})
    print(f"  {'stage':38} " + " | ".join(f"{name[:26]:>26}" for _, name in entries))
    print(f"  {'(CPU median / mean ms, wall median ms, calls)':38}")
    for key in keys:
        cells = []
        for fr in frames:
            med, mean, wall, calls = _stats(fr, key)
            cells.append(f"{med:6.3f} {mean:6.3f} {wall:6.3f} {calls:4.1f}")
        print(f"  {key:38} " + " | ".join(f"{c:>26}" for c in cells))
    derived = {  # a stage less the stages timed inside it
        "rest (render - FrameLoop.run - _merged)": ("ClipRenderAction.render", "FrameLoop.run",
                                                    "ClipRenderAction._merged"),
        "_merged less merge, answers_hold": ("ClipRenderAction._merged", "KeptMerge.merge", "KeptMerge.answers_hold"),
        "FrameLoop.run less KeptCut.update": ("FrameLoop.run", "KeptCut.update"),
        "SinglePassPath.draw less read_back": ("SinglePassPath.draw", "DrawSetup.read_back"),
    }
    for label, (whole, *inner) in derived.items():
        cells = []
        for fr in frames:
            for d in fr:
                w = d.get(whole, (0.0, 0.0, 0))
                parts = [d.get(k, (0.0, 0.0, 0)) for k in inner]
                d[label] = (w[0] - sum(p[0] for p in parts), w[1] - sum(p[1] for p in parts), 1)
            med, mean, wall, _ = _stats(fr, label)
            cells.append(f"{med:6.3f} {mean:6.3f} {wall:6.3f}     ")
        print(f"  {label:38} " + " | ".join(f"{c:>26}" for c in cells))
    # what grows: per stage, the median over frames of each pair's difference from the first
    # volume's frame drawn beside it (a drift in the load weighs on both alike)
    print(f"  {'stage: CPU ms more than the first (median of pairs)':52} "
          + " | ".join(f"{name[:16]:>16}" for _, name in entries[1:]))
    for key in [*keys, *derived]:
        cells = []
        for fr in frames[1:]:
            diff = [d.get(key, (0.0, 0.0, 0))[0] - d0.get(key, (0.0, 0.0, 0))[0] for d, d0 in zip(fr, frames[0])]
            cells.append(f"{1e3 * statistics.median(diff):+7.3f} ({1e3 * statistics.mean(diff):+7.3f})")
        print(f"  {key:52} " + " | ".join(f"{c:>16}" for c in cells))
    base = [d.get("ClipRenderAction.render", (1.0, 0.0, 0))[0] for d in frames[0]]
    for (_, name), fr in zip(entries, frames):
        mine = [d.get("ClipRenderAction.render", (0.0, 0.0, 0))[0] for d in fr]
        ratios = [m / b for m, b in zip(mine, base)]
        q = [float(v) for v in np.percentile(ratios, [25, 50, 75])]
        print(f"  {name}: frame {1e3 * statistics.median(mine):.2f} ms CPU, per pair {q[1]:.2f}x the first's "
              f"(quartiles {q[0]:.2f}-{q[2]:.2f})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
