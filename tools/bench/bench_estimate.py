"""The image policy's visible-error estimate against the measured error, per view and cut.

For each view of :func:`bench_mission.views` (``iso`` and ``face``: overviews; ``close``: a part of
the volume filling the image) and of ``clipvol report``'s own path (``turn0``-``turn2``: the
report's three default views, :func:`report_views`, framing the voxels the transfer function shows)
and image size, the image policy draws its cut at block budgets 8-128
and at the error budgets ``max_error`` 20, 10, 5 and 2 % (``--classify``, default ``distribution``; step 0.5),
one warm frame each; the row holds the policy's own prediction (:attr:`ImageBased.estimated_error`,
the predicted % of pixels with CIELUV Delta E >= 6) and the measured % against the **converged
picture** (:mod:`clipvol.app.converged`: level 0 at step 0.25, 2x2 rays per pixel), their ratio, the
cut's bricks and levels, and the edge share of the view's visibility estimate
(:func:`clipvol.scene.visible_edges.edge_share`, the term that scales the estimate per view).
No timing: every figure is an image's error, so the load does not move it. ``--time-cut N`` adds
what the estimate costs per frame: for each view, the image policy's cut (the greedy refinement
with its running estimate, :func:`clipvol.scene.selection.select`, no GL) made ``N`` times from the
same visibility estimate with the edge term (the ``distribution`` errors) and with the
classification bias in its place (the ``mean`` errors: the estimate before the edge term), the
medians in ms and their ratio.

``python tools/bench/bench_estimate.py --store mni32.zarr --images 256,512``; rows to
``tools/bench/results/bench_estimate.csv``.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
if str(HERE) not in sys.path:
    sys.path.insert(0, str(HERE))

import bench_mission  # noqa: E402
import common  # noqa: E402


def settings() -> dict:
    out = {f"image b={b}": dict(policy="image", block_budget=b) for b in (8, 16, 32, 64, 128)}
    out.update({f"max-error={e:g}%": dict(policy="image", max_error=e / 100.0) for e in (20, 10, 5, 2)})
    return out


def report_views(loader, tf, image: int, n: int = 3) -> dict:
    """``clipvol report``'s views (``turn0`` ...): its default path (the orbit, a turntable raised
    25 degrees for a patient-frame store) with ``n`` views framing the voxels ``tf`` shows, as
    :func:`clipvol.app.report_measure.measure` makes them."""
    from clipvol.scene.framing import visible_points
    from clipvol.scene.paths import make_path
    from clipvol.scene.views import patient_path

    name, kw = patient_path("orbit", getattr(loader, "frame", None))
    pts = visible_points(loader, tf)
    if pts is not None:
        kw["fit"] = pts
    return {f"turn{i}": cam for i, (cam, _) in enumerate(make_path(name, loader.pyramid, n, size=(image, image), **kw))}


def far_views(pyr, image: int) -> dict:
    """Two views from farther away (2.0 and 2.2 volume diagonals, iso and side), where a level-0
    voxel covers about half a pixel at 256²: outside the views the estimate was fitted on; only run
    when named (``--views far_iso,far_side``)."""
    from clipvol.scene.camera import Camera

    lo, hi = pyr.volume_box()
    c = (lo + hi) / 2.0
    diag = float(np.linalg.norm(hi - lo))
    out = {}
    for name, d, dist in (("far_iso", np.array([0.55, 0.45, 0.7]), 2.0), ("far_side", np.array([1.0, 0.1, 0.2]), 2.2)):
        d = d / np.linalg.norm(d)
        out[name] = Camera.perspective(tuple(c - d * dist * diag), tuple(c), up=(0, -1, 0), fov_y=35, size=(image, image))
    return out


def run(store: Path, images, view_names=None, classify: str = "distribution", log=print) -> list[dict]:
    from clipvol.app.converged import ConvergedPictures
    from clipvol.scene.metrics import percent_delta_e
    from clipvol.scene.params import RenderParams
    from clipvol.scene.visible_edges import edge_share

    scene = common.WarmScene(store)
    pyr, tf = scene.pyramid, scene.tf
    actions = {k: scene.action(step=0.5, classify=classify, **kw) for k, kw in settings().items()}
    ref = scene.action(policy="fixed", level=0)

    def draw(c, params):
        ref.set_params(params)
        return ref.render(c, tf, wait=True, timeout=600)

    conv = ConvergedPictures(draw, RenderParams(step=0.5), supersample=2, step=0.25)
    rows = []
    try:
        for image in images:
            cams = {**bench_mission.views(pyr, image), **report_views(scene.loader, tf, image)}
            if view_names and any(v.startswith("far") for v in view_names):
                cams.update(far_views(pyr, image))
            for view, cam in cams.items():
                if view_names and view not in view_names:
                    continue
                truth = conv.get(cam, key=(image, view))
                full = float(percent_delta_e(draw(cam, RenderParams(step=0.5, policy="fixed", level=0)), truth,
                                             threshold=6.0, premultiplied=False))
                for k, a in actions.items():
                    img = a.render(cam, tf, wait=True, timeout=600)
                    pol = a.last_policy
                    pct = float(percent_delta_e(img, truth, threshold=6.0, premultiplied=False))
                    est = 100.0 * pol.estimated_error
                    levels = sorted({lv for lv, _ in pol.node_data})
                    vis = pol.visibility
                    edges = edge_share(np.asarray(vis.alpha[-1])) if vis is not None else float("nan")
                    row = dict(date=time.strftime("%Y-%m-%d"), store=store.name, image=image, view=view, setting=k,
                               classify=classify,
                               bricks=len(pol.node_data), levels="/".join(map(str, levels)),
                               edge_share=round(edges, 4), full_pct_de6=round(full, 3),
                               predicted_pct_de6=round(est, 3), pct_de6=round(pct, 3),
                               predicted_over_measured=round(est / pct, 3) if pct > 0 else "")
                    rows.append(row)
                    log(f"{image}^2 {view:5} {k:14}: {row['bricks']:3d} bricks (levels {row['levels']}), edge share "
                        f"{edges:.3f}: predicted {est:6.2f} %, measured {pct:6.2f} % "
                        f"(ratio {row['predicted_over_measured']}); full resolution {full:.2f} %")
    finally:
        scene.close()
    return rows


def time_cut(store: Path, images, view_names=None, repeat: int = 20, log=print) -> list[dict]:
    """Median ms of the image policy's cut per view, with the edge term and with the bias in its place
    (same visibility estimate, ``max_error`` 5 % and block budget 64), interleaved."""
    from clipvol.scene.lod_error import lod_errors
    from clipvol.scene.params import RenderParams
    from clipvol.scene.selection import select
    from clipvol.scene.selection.policies.image_based import ImageBased

    scene = common.WarmScene(store)
    pyr, tf = scene.pyramid, scene.tf
    act = scene.action(step=0.5, policy="image", block_budget=64)
    rows = []
    try:
        for image in images:
            cams = {**bench_mission.views(pyr, image), **report_views(scene.loader, tf, image)}
            for view, cam in cams.items():
                if view_names and view not in view_names:
                    continue
                act.render(cam, tf, wait=True, timeout=600)
                vis, tables = act.last_policy.visibility, act.image_lod.tables
                errs = {c: lod_errors(tables, tf, c) for c in ("distribution", "mean")}
                for setting, kw in (("max-error=5%", dict(max_error=0.05)), ("image b=64", dict(block_budget=64))):
                    times = {c: [] for c in errs}
                    for _ in range(repeat):
                        for c, e in errs.items():
                            params = RenderParams(policy="image", classify=c, **kw)
                            t0 = time.perf_counter()
                            select(pyr, cam, params, policy=ImageBased(params, errors=e, visibility=vis))
                            times[c].append(1000.0 * (time.perf_counter() - t0))
                    med = {c: float(np.median(v)) for c, v in times.items()}
                    row = dict(date=time.strftime("%Y-%m-%d"), store=store.name, image=image, view=view, setting=setting,
                               cut_ms_edges=round(med["distribution"], 2), cut_ms_bias=round(med["mean"], 2),
                               ratio=round(med["distribution"] / med["mean"], 3), repeat=repeat)
                    rows.append(row)
                    log(f"{image}^2 {view:5} {setting:13}: cut {row['cut_ms_edges']:.1f} ms with the edge term, "
                        f"{row['cut_ms_bias']:.1f} ms with the bias ({row['ratio']:.2f}x)")
    finally:
        scene.close()
    return rows


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--store", type=Path, required=True, help="a clipvol store with summary tables")
    ap.add_argument("--images", default="256", help="image edges, comma separated (default 256)")
    ap.add_argument("--views", default=None, help="views, comma separated (default iso,face,close,turn0,turn1,turn2; far_iso and far_side "
                         "when named)")
    ap.add_argument("--classify", default="distribution", choices=("distribution", "mean"),
                    help="how coarse voxels are classified (default distribution)")
    ap.add_argument("--out", type=Path, default=common.RESULTS / "bench_estimate.csv")
    ap.add_argument("--time-cut", type=int, default=0, metavar="N",
                    help="also time the image policy's cut N times per view, with the edge term and with the bias "
                         "(rows to OUT with _cut before the suffix)")
    a = ap.parse_args(argv)
    if a.time_cut:
        rows = time_cut(a.store, [int(v) for v in a.images.split(",")], None if a.views is None else a.views.split(","),
                        a.time_cut)
        common.save_rows(a.out.with_name(a.out.stem + "_cut" + a.out.suffix), rows)
    rows = run(a.store, [int(v) for v in a.images.split(",")], None if a.views is None else a.views.split(","), a.classify)
    return common.save_rows(a.out, rows)


if __name__ == "__main__":
    sys.exit(main())
