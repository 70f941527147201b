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

``--levels`` measures what the estimate's growth per level stands on, per view: each level drawn
alone (``policy="fixed"``, the same classification), its measured % against the converged picture
and that % as a share of the shown pixels per unit of the view's edge share, beside the estimate's
``q`` (:func:`clipvol.scene.visible_edges.edge_difference`) at that edge share, and per level what
the summary tables say of the data (:func:`level_tables`: the share of level 0's visible opacity the
level's own voxels lose, the classification bias, the share of fine voxels whose colour the coarse
value changes by Delta E >= 6). ``--nodes`` holds the estimate against the measurement node by node:
for each cut, each node's predicted ``q`` (:meth:`ImageBased.node_estimates`), its edge share and
shown share in the opacity map (:meth:`OcclusionLayers.footprint`) and the measured share of the
shown pixels in its screen rectangle that differ (rectangles overlap: a node's share also counts
what lies in front of or behind it).

``python tools/bench/bench_estimate.py --store mni32.zarr --images 256,512``; rows to
``tools/bench/results/bench_estimate.csv`` (``--levels``: ``_levels`` before the suffix, ``--nodes``:
``_nodes``). The CT-like head of ``tests/render/test_error_budget.py``: ``--store ct-head-96``
(built once under ``bench-data/``: :func:`ct_head_store`) ``--images 96 --views iso,face``.
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


#: the name ``--store`` takes for the CT-like head of ``tests/render/test_error_budget.py``
CT_HEAD = "ct-head-96"


def ct_head_store(data_dir: Path = common.DATA) -> Path:
    """The test's head: :func:`~clipvol.bricking.generators.ct_head` 96³, seed 3, 8³ bricks (8-bit),
    built once under ``bench-data/``."""
    from clipvol.bricking.generators import ct_head
    from clipvol.bricking.pipeline import brick_volume

    path = data_dir / "ct-head-96-seed3-b8.zarr"
    if not common.store_is_built(path):
        data_dir.mkdir(parents=True, exist_ok=True)
        brick_volume(ct_head((96, 96, 96), seed=3), path, brick=8, progress=False, overwrite=True)
    return path


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


def _scene_and_truth(store: Path):
    """The warm scene, its level-0 action and the converged pictures of ``store``."""
    scene = common.WarmScene(store)
    draw = scene.converged_drawer()
    return scene, draw, scene.converged_pictures(draw)


def _cams(scene, image: int, view_names) -> dict:
    cams = {**bench_mission.views(scene.pyramid, image), **report_views(scene.loader, scene.tf, image)}
    return {k: c for k, c in cams.items() if not view_names or k in view_names}


def run(store: Path, images, view_names=None, classify: str = "distribution", log=print) -> list[dict]:
    from clipvol.scene.metrics import percent_delta_e
    from clipvol.scene.params import RenderParams
    from clipvol.scene.visible_edges import edge_share

    scene, draw, conv = _scene_and_truth(store)
    pyr, tf = scene.pyramid, scene.tf
    actions = {k: scene.action(step=0.5, classify=classify, **kw) for k, kw in settings().items()}
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


def level_tables(tables, tf) -> list[dict]:
    """Per level ``L >= 1``, from the summary tables under ``tf`` (no voxel read): ``opacity_lost``,
    ``1 - A_L / A_0`` with ``A_L`` the summed opacity of level ``L``'s own voxels and ``A_0`` that of
    the level-0 voxels beneath them per level-``L`` voxel; ``bias``, the classification bias
    (:func:`clipvol.scene.lod_error.classification_bias`, mean mode) averaged with the bricks' opacity
    as weights; ``pairs_de6``, the share of the level-``L-1`` voxels that show something whose
    colour differs from their level-``L`` voxel's by Delta E >= 6 (the correspondence tables)."""
    from clipvol.bricking.summary import SUMMARY_BINS
    from clipvol.scene.lod_error import colour_table, lod_errors

    pyr = tables.pyramid
    centres = tables.quantiser.centres()
    alpha = tf.lookup(centres, pyr.value_range)[:, 3].astype(np.float64)
    F = colour_table(tf, centres, pyr.value_range)
    err = lod_errors(tables, tf)
    H = [tables.histogram[L].reshape(-1, SUMMARY_BINS).astype(np.float64) for L in range(pyr.num_levels)]
    count = [h.sum(axis=1) for h in H]
    own = [(h @ alpha) / np.maximum(n, 1.0) for h, n in zip(H, count)]
    below = own[0]  # per brick: the mean opacity of the level-0 voxels beneath it
    out = []
    for L in range(1, pyr.num_levels):
        child = np.stack(np.unravel_index(np.arange(pyr.num_bricks(L - 1)), pyr.grid(L - 1)), axis=1)
        parent = np.ravel_multi_index(tuple((child // 2).T), pyr.grid(L))
        n = pyr.num_bricks(L)
        w = count[L - 1]
        below = np.bincount(parent, weights=w * below, minlength=n) / np.maximum(np.bincount(parent, weights=w, minlength=n), 1.0)
        fine, coarse = float(np.sum(count[L] * below)), float(np.sum(count[L] * own[L]))
        off = tables.pairs_offsets[L - 1]
        code = tables.pairs_code[L - 1].astype(np.int64)
        k, c = code // SUMMARY_BINS, code % SUMMARY_BINS
        pw = tables.pairs_count[L - 1].astype(np.float64)
        shows = (alpha[c] > 0) | (alpha[k] > 0)
        de6 = np.linalg.norm(F[k] - F[c], axis=1) >= 6.0
        op = err.opacity[L].reshape(-1)
        b = np.asarray(err.bias[L]).reshape(-1)
        out.append(dict(level=L, opacity_lost=round(max(0.0, 1.0 - coarse / fine) if fine > 0 else 0.0, 4),
                        bias=round(float(np.sum(op * b) / max(np.sum(op), 1e-300)), 3),
                        pairs_de6=round(float(np.sum(pw[shows & de6]) / max(np.sum(pw[shows]), 1e-300)), 4),
                        bricks=int(len(off) - 1)))
    return out


def levels(store: Path, images, view_names=None, classify: str = "distribution", log=print) -> list[dict]:
    """Per view and level: the level drawn alone against the converged picture, per unit of the
    view's edge share, beside the estimate's ``q`` there and :func:`level_tables` (see the module
    docstring)."""
    from clipvol.render.image_lod import ImageLod  # noqa: F401 - the tables as the policy opens them
    from clipvol.render.visibility import CpuVisibilityEstimator
    from clipvol.scene.metrics import delta_e_luv
    from clipvol.scene.params import RenderParams
    from clipvol.scene.visible_edges import EDGE_ALPHA, edge_difference, edge_share

    scene, draw, conv = _scene_and_truth(store)
    pyr, tf = scene.pyramid, scene.tf
    probe = scene.action(step=0.5, policy="image", block_budget=8, classify=classify)
    rows = []
    try:
        tables = None
        for image in images:
            for view, cam in _cams(scene, image, view_names).items():
                truth = conv.get(cam, key=(image, view))
                shown = truth[..., 3] > EDGE_ALPHA * 255.0
                if tables is None:
                    probe.render(cam, tf, wait=True, timeout=600)
                    tables = level_tables(probe.image_lod.tables, tf)
                e = edge_share(np.asarray(CpuVisibilityEstimator(scene.loader).estimate(cam, tf).alpha[-1]))
                for L in range(pyr.num_levels):
                    img = draw(cam, RenderParams(policy="fixed", level=L, step=0.5, classify=classify))
                    d = delta_e_luv(img, truth, premultiplied=False) >= 6.0
                    share = float(d[shown].mean()) if shown.any() else 0.0
                    tab = tables[L - 1] if L else dict(opacity_lost=0.0, bias=0.0, pairs_de6=0.0)
                    row = dict(date=time.strftime("%Y-%m-%d"), store=store.name, image=image, view=view, level=L,
                               classify=classify, edge_share=round(e, 4), shown=round(float(shown.mean()), 4),
                               pct_de6=round(100.0 * float(d.mean()), 3), shown_share_de6=round(share, 4),
                               per_edge=round(share / e, 3) if e > 0 else "",
                               q=round(float(edge_difference(L, e)), 4), opacity_lost=tab["opacity_lost"],
                               bias=tab["bias"], pairs_de6=tab["pairs_de6"])
                    rows.append(row)
                    log(f"{image}^2 {view:5} level {L}: {row['pct_de6']:6.2f} % ({share:.3f} of the shown pixels, "
                        f"{row['per_edge']} per edge share {e:.3f}; estimate's q {row['q']:.3f}); tables: opacity lost "
                        f"{tab['opacity_lost']:.4f}, bias {tab['bias']:.2f}, pairs >= 6 {tab['pairs_de6']:.4f}")
    finally:
        scene.close()
    return rows


def nodes(store: Path, images, view_names=None, classify: str = "distribution", log=print) -> list[dict]:
    """Per cut of :func:`settings` and node: the predicted ``q`` against the measured share of the
    shown pixels in the node's screen rectangle that differ (see the module docstring)."""
    from clipvol.scene.metrics import delta_e_luv
    from clipvol.scene.selection.octree import Octree
    from clipvol.scene.visibility import screen_rects
    from clipvol.scene.visible_edges import EDGE_ALPHA

    scene, draw, conv = _scene_and_truth(store)
    pyr, tf = scene.pyramid, scene.tf
    tree = Octree(pyr)
    actions = {k: scene.action(step=0.5, classify=classify, **kw) for k, kw in settings().items()}
    rows = []
    try:
        for image in images:
            for view, cam in _cams(scene, image, view_names).items():
                truth = conv.get(cam, key=(image, view))
                shown = truth[..., 3] > EDGE_ALPHA * 255.0
                for k, a in actions.items():
                    img = a.render(cam, tf, wait=True, timeout=600)
                    pol = a.last_policy
                    d = (delta_e_luv(img, truth, premultiplied=False) >= 6.0) & shown
                    est = pol.node_estimates()
                    H, W = d.shape
                    for (L, b), (w, q) in sorted(est.items()):
                        lo, hi = tree.boxes(L, np.array([b]))
                        r = screen_rects(cam, lo, hi)[0][0]
                        x0, y0 = int(np.clip(np.floor(r[0]), 0, W - 1)), int(np.clip(np.floor(r[1]), 0, H - 1))
                        x1, y1 = int(np.clip(np.ceil(r[2]), x0 + 1, W)), int(np.clip(np.ceil(r[3]), y0 + 1, H))
                        n = int(shown[y0:y1, x0:x1].sum())
                        fs, fe = pol.visibility.footprint(lo, hi, cam)
                        rows.append(dict(date=time.strftime("%Y-%m-%d"), store=store.name, image=image, view=view, setting=k,
                                         level=L, brick="/".join(map(str, b)), weight=round(w, 2),
                                         map_shown=round(float(fs[0]), 4), map_edges=round(float(fe[0]), 4),
                                         predicted=round(q, 4), shown_pixels=n,
                                         measured=round(float(d[y0:y1, x0:x1].sum()) / n, 4) if n else ""))
                    log(f"{image}^2 {view:5} {k:14}: {len(est)} nodes")
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
    ap.add_argument("--store", type=Path, required=True, help=f"a clipvol store with summary tables, or {CT_HEAD} (the "
                    "CT-like head of tests/render/test_error_budget.py, built once under bench-data/)")
    ap.add_argument("--images", default="256", help="image edges, comma separated (default 256)")
    ap.add_argument("--views", default=None, help="views, comma separated (default iso,face,close,turn0,turn1,turn2; far_iso and far_side "
                         "when named)")
    ap.add_argument("--classify", default="distribution", choices=("distribution", "mean"),
                    help="how coarse voxels are classified (default distribution)")
    ap.add_argument("--out", type=Path, default=common.RESULTS / "bench_estimate.csv")
    ap.add_argument("--time-cut", type=int, default=0, metavar="N",
                    help="also time the image policy's cut N times per view, with the edge term and with the bias "
                         "(rows to OUT with _cut before the suffix)")
    ap.add_argument("--levels", action="store_true", help="each level drawn alone, per view, against the edge share "
                    "and the summary tables (rows to OUT with _levels before the suffix), instead of the cuts")
    ap.add_argument("--nodes", action="store_true", help="the estimate against the measurement node by node (rows "
                    "to OUT with _nodes before the suffix), instead of the cuts")
    a = ap.parse_args(argv)
    if str(a.store) == CT_HEAD:
        a.store = ct_head_store()
    images = [int(v) for v in a.images.split(",")]
    views = None if a.views is None else a.views.split(",")
    if a.levels or a.nodes:
        for flag, fn, tag in ((a.levels, levels, "_levels"), (a.nodes, nodes, "_nodes")):
            if flag:
                common.save_rows(a.out.with_name(a.out.stem + tag + a.out.suffix), fn(a.store, images, views, a.classify))
        return 0
    if a.time_cut:
        common.save_rows(a.out.with_name(a.out.stem + "_cut" + a.out.suffix), time_cut(a.store, images, views, a.time_cut))
    return common.save_rows(a.out, run(a.store, images, views, a.classify))


if __name__ == "__main__":
    sys.exit(main())
