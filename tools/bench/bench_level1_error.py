"""Where level 1's error comes from (issue 41): its representation, or its resolution?

Target: a coarse level within 2 percentage points of level 0's own error (% of pixels with CIELUV
Delta E >= 6 against the converged picture). ``bench_mission``'s views miss it at level 1 by 1.7-4.2
points. This benchmark splits that error, per view (``bench_mission.views``: ``iso``, ``face``,
``close``) and image size, by drawing the same level several ways against the same converged picture
(:mod:`clipvol.app.converged`: level 0 at step 0.25, ``--supersample`` rays per pixel):

* ``L0``: clipvol's full-resolution frame (level 0, step 0.5): level 0's own error;
* ``L0 step=S``: level 0 at the level's sample spacing (``S = 0.5 * 2**L`` level-0 voxels): the
  coarser step alone;
* ``L0 classified (plain)``: the level-0 voxels classified by the transfer function in numpy, drawn
  as a premultiplied RGBA volume by a plain caster (:class:`common.LevelCaster`) at that step:
  classification before interpolation, full resolution;
* ``LL mean`` / ``LL dist``: clipvol's fixed level ``L`` at step 0.5 of its voxels, its mean
  classified (``classify="mean"``) and its distribution classified (``"distribution"``, the default);
* ``LL mean (plain)``: the plain caster on the stored level's means with the table: clipvol's mean
  path drawn outside clipvol; its difference from ``LL mean`` (``plain_vs_clipvol_pct``) says how
  far the plain caster's geometry and lattice are from clipvol's (the decomposition holds if small);
* ``LL ideal (plain)``: **a perfect distribution per coarse voxel**: the level-0 voxels classified
  (RGBA, premultiplied), averaged over each ``2**L`` block (edge-replicated like the mean filter) -
  the exact expected classification of the distribution beneath each coarse voxel - and drawn by the
  plain caster (interpolated trilinearly between coarse voxels, which is the distribution itself
  interpolated: the expectation over a trilinear mix of eight distributions is the mix of their
  expectations; then the opacity corrected for the step). Any per-voxel distribution (histogram
  bins, sparse values and weights) tends to it as it grows more faithful;
* ``LL normal (plain)``: the stored mean and spread classified per coarse voxel under clipvol's normal
  model (:func:`clipvol.scene.consistent.distribution_tables`), then interpolated like the ideal: the
  model's share (normal against the true distribution) apart from the interpolation's (clipvol
  interpolates mean and spread, then classifies);
* ``LL dist (plain)``: the plain caster on the stored mean and spread, classified by clipvol's table
  after interpolation: clipvol's distribution path drawn outside clipvol (``plain_vs_clipvol_pct``);
* ``LL dist cubic (plain)``: the same mean and spread resampled onto level 0's grid by a cubic
  B-spline (:func:`cubic_to_level0`) and classified the same way: does a reconstruction sharper than
  trilinear place level L's edges nearer the converged picture's? ``LL dist smooth cubic (plain)``:
  the approximating cubic B-spline instead (no prefilter: a GPU's cheap tricubic filter on raw data);
* ``LL dist spread*k`` (``--spread-scales``): clipvol's distribution path with every spread read
  ``k`` times wider: is the normal model's width at its best?

Where the error lies: ``pct_de6_off_edges`` counts only the wrong pixels off the converged picture's
**edges** - pixels whose colour differs by Delta E >= 6 from a pixel within half a coarse voxel's
footprint on screen (:func:`sub_resolution`; ``edge_pixels_pct`` of the image). An error there is a
wrong colour where the picture is flat over a coarse voxel (the representation's); an error on an
edge is an edge's position or a structure's width, which a per-voxel distribution (it has no
position inside the voxel) cannot place.

Usage::

    python tools/bench/bench_level1_error.py --store /tmp/r8d/mni32.zarr --images 256,512

Rows go to ``tools/bench/results/bench_level1_error.csv`` (``--out``). Errors only, no timing.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
if str(HERE) not in sys.path:
    sys.path.insert(0, str(HERE))

import common  # noqa: E402
from bench_mission import views  # noqa: E402


def classify(values: np.ndarray, tf, value_range) -> np.ndarray:
    """``(..., 4)`` float64 premultiplied RGBA of ``values`` (raw units): the table read the way
    ``GL_LINEAR`` reads it (entry centres at ``(j + 0.5) / n``, clamped), opacity per level-0 voxel."""
    table = np.asarray(tf.table, dtype=np.float64)
    n = len(table)
    lo, hi = tf.window(value_range)
    t = (np.asarray(values, dtype=np.float64) - lo) / (hi - lo)
    x = np.clip(t * n - 0.5, 0.0, n - 1.0)
    rgba = np.stack([np.interp(x, np.arange(n), table[:, c]) for c in range(4)], axis=-1)
    rgba[..., :3] *= rgba[..., 3:4]
    return rgba


def block_mean(rgba: np.ndarray, f: int) -> np.ndarray:
    """Mean of each ``f``-cube of ``rgba`` ``(z, y, x, c)``, odd extents edge-replicated (the last
    block holds the voxels that exist, as if repeated: the pyramid's mean filter, level by level)."""
    out = rgba
    while f > 1:
        pad = [(0, s % 2) for s in out.shape[:3]] + [(0, 0)]
        p = np.pad(out, pad, mode="edge")
        z, y, x = (s // 2 for s in p.shape[:3])
        out = p.reshape(z, 2, y, 2, x, 2, -1).mean(axis=(1, 3, 5))
        f //= 2
    return out


def normal_classified(mean: np.ndarray, spread: np.ndarray, tf, value_range) -> np.ndarray:
    """``(..., 4)`` premultiplied ``(E[a c], E[a])`` of ``N(mean, spread)`` per coarse voxel, read from
    clipvol's pre-integrated table (ratio 1) at each voxel's own mean and spread."""
    from clipvol.scene.consistent import SPREAD_ROWS, _bilinear, distribution_tables

    tab = distribution_tables(np.asarray(tf.table, dtype=np.float64), [1.0])[0]  # (rows, N, 4) straight
    prem = np.concatenate([tab[..., :3] * tab[..., 3:4], tab[..., 3:4]], axis=-1)
    return _bilinear(prem, tf, mean, spread, value_range, SPREAD_ROWS)


def cubic_to_level0(pair: np.ndarray, pyramid, level: int, interpolating: bool = True) -> np.ndarray:
    """``(z, y, x, 2)`` (mean, spread) of ``level`` resampled onto level 0's grid by a cubic B-spline
    (``scipy.ndimage.zoom``, grid-aligned: level-0 voxel ``i`` at ``(i + 1/2) / 2**L - 1/2`` of the
    level, ends clamped), the spread kept >= 0, drawn at level 0 with the same table.
    ``interpolating``: the spline through the voxels' values (its coefficients prefiltered: a
    reconstruction sharper than trilinear); else the approximating spline of the raw values (what a
    GPU's 8-fetch tricubic filter gives without prefiltered coefficients: smoother)."""
    from scipy import ndimage

    f = 2 ** level
    shape = pyramid.levels[0].shape
    out = np.empty((*shape, 2), dtype=np.float32)
    for c in range(2):
        up = ndimage.zoom(pair[..., c].astype(np.float64), f, order=3, mode="nearest", grid_mode=True,
                          prefilter=interpolating)
        out[..., c] = up[: shape[0], : shape[1], : shape[2]]
    out[..., 1] = np.maximum(out[..., 1], 0.0)
    return out


def straight_u8(prem: np.ndarray) -> np.ndarray:
    """A premultiplied float RGBA image as clipvol's frames are: straight uint8 RGBA."""
    a = np.clip(prem[..., 3:4], 0.0, 1.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        rgb = np.where(a > 0, prem[..., :3] / np.where(a > 0, a, 1.0), 0.0)
    return np.rint(np.clip(np.concatenate([rgb, a], axis=-1), 0.0, 1.0) * 255.0).astype(np.uint8)


def footprint_px(cam, pyramid, level: int) -> float:
    """Pixels across one voxel of ``level`` at the view's aim point (perspective: its distance)."""
    dist = float(np.linalg.norm(np.subtract(cam.aim, cam.eye)))
    pixel = 2.0 * dist * np.tan(np.radians(float(cam.fov_y)) / 2.0) / float(cam.size[1])
    return 2 ** level * float(min(pyramid.spacing)) / pixel


def sub_resolution(truth: np.ndarray, radius: int) -> np.ndarray:
    """``(h, w)`` bool: pixels of the converged picture (straight uint8) whose colour differs by
    Delta E >= 6 from some pixel within ``radius`` pixels (a square): where the picture changes
    within the footprint of a coarse voxel on screen - an edge's position or a structure's width
    that the coarse grid cannot place finer."""
    from clipvol.scene.metrics import delta_e_luv

    h, w = truth.shape[:2]
    p = np.pad(truth, ((radius, radius), (radius, radius), (0, 0)), mode="edge")
    worst = np.zeros((h, w))
    for dy in range(-radius, radius + 1):
        for dx in range(-radius, radius + 1):
            if dy or dx:
                shifted = p[radius + dy: radius + dy + h, radius + dx: radius + dx + w]
                worst = np.maximum(worst, delta_e_luv(truth, shifted, premultiplied=False))
    return worst >= 6.0


def check_classified_path(scene, volume: np.ndarray, log=print) -> float:
    """The plain caster's classified-RGBA path against its value path under a linear table (opacity
    and premultiplied colour linear in the value, so classifying before and after interpolation
    agree): the largest difference of premultiplied RGBA over a 128^2 iso view, which must stay
    below 0.01 (measured 0.002: the table's entries). Checks the RGBA path's colour and opacity
    correction, the part of the caster that clipvol's frames cannot check."""
    from clipvol.render.paths.setup import OPAQUE
    from clipvol.scene.transfer import TransferFunction

    pyr = scene.pyramid
    tf = TransferFunction.from_points([(0.0, (0.9, 0.8, 0.6, 0.0)), (1.0, (0.9, 0.8, 0.6, 0.08))],
                                      value_range=pyr.value_range)
    by_value = common.LevelCaster(scene.ctx, volume.astype(np.float32), pyr, 0)
    by_rgba = common.LevelCaster(scene.ctx, classify(volume, tf, pyr.value_range).astype(np.float32), pyr, 0)
    try:
        cam = views(pyr, 128)["iso"]
        diff = float(np.abs(by_value.render(cam, tf, 1.0, OPAQUE) - by_rgba.render(cam, tf, 1.0, OPAQUE)).max())
    finally:
        by_value.release()
        by_rgba.release()
    log(f"check: classified RGBA against values under a linear table: largest difference {diff:.4f}")
    if diff > 0.01:
        raise RuntimeError(f"the plain caster's classified path is off its value path by {diff:.4f} (expected < 0.01)")
    return diff


def run(store: Path, images, levels, supersample: int = 2, spread_scales=(), log=print) -> list[dict]:
    import zarr

    from clipvol.app.converged import ConvergedPictures
    from clipvol.bricking.spread import SPREAD_GROUP
    from clipvol.render.paths import setup
    from clipvol.render.paths.setup import OPAQUE
    from clipvol.scene import consistent
    from clipvol.scene.metrics import delta_e_luv, percent_delta_e
    from clipvol.scene.params import RenderParams

    from clipvol.scene.consistent import distribution_tables

    step = 0.5
    scene = common.WarmScene(store)
    pyr, tf, ctx = scene.pyramid, scene.tf, scene.ctx
    vr = pyr.value_range
    sp0 = float(min(pyr.spacing))
    vol0 = common.WholeVolume(scene.loader).read_brick(0, (0, 0, 0))
    fine = classify(vol0, tf, vr).astype(np.float32)
    casters: dict[str, tuple[common.LevelCaster, float]] = {}
    acts = {"L0": scene.action(policy="fixed", level=0, step=step)}
    for L in levels:
        delta = step * 2 ** L * sp0  # level L at step 0.5 of its voxels, in world units
        S = f"{step * 2 ** L:g}"
        acts[f"L0 step={S}"] = scene.action(policy="fixed", level=0, step=step * 2 ** L)
        for c in ("mean", "distribution"):
            acts[f"L{L} {'dist' if c == 'distribution' else c}"] = scene.action(policy="fixed", level=L, step=step,
                                                                                 classify=c)
        for k in spread_scales:
            acts[f"L{L} dist spread*{k:g}"] = scene.action(policy="fixed", level=L, step=step, classify="distribution")
        mean = np.asarray(zarr.open_array(str(store / str(L)), mode="r")[...], dtype=np.float32)
        spread = np.asarray(zarr.open_array(str(store / SPREAD_GROUP / str(L)), mode="r")[...], dtype=np.float64)
        casters[f"L0 classified step={S} (plain)"] = (common.LevelCaster(ctx, fine, pyr, 0), delta)
        casters[f"L{L} mean (plain)"] = (common.LevelCaster(ctx, mean, pyr, L), delta)
        casters[f"L{L} ideal (plain)"] = (common.LevelCaster(ctx, block_mean(fine, 2 ** L), pyr, L), delta)
        casters[f"L{L} normal (plain)"] = (common.LevelCaster(ctx, normal_classified(mean, spread, tf, vr), pyr, L),
                                           delta)
        table = distribution_tables(np.asarray(tf.table, dtype=np.float64), [delta / sp0])[0]
        pair = np.stack([mean, spread], axis=-1)
        casters[f"L{L} dist (plain)"] = (common.LevelCaster(ctx, pair, pyr, L, table), delta)
        casters[f"L{L} dist cubic (plain)"] = (common.LevelCaster(ctx, cubic_to_level0(pair, pyr, L), pyr, 0, table),
                                               delta)
        casters[f"L{L} dist smooth cubic (plain)"] = (
            common.LevelCaster(ctx, cubic_to_level0(pair, pyr, L, interpolating=False), pyr, 0, table), delta)
    draw = scene.converged_drawer(timeout=900)

    conv = ConvergedPictures(draw, RenderParams(step=step), supersample=supersample)
    log(f"errors against the converged picture: {conv.describe()}")
    rows = []
    try:
        for image in images:
            for view, cam in views(pyr, image).items():
                t0 = time.perf_counter()
                truth = conv.get(cam, key=(image, view))
                imgs = {}
                for k, a in acts.items():
                    scale = float(k.split("spread*")[1]) if "spread*" in k else 1.0
                    setup.SPREAD_MAX = consistent.SPREAD_MAX / scale  # the spread read k times wider
                    try:
                        imgs[k] = a.render(cam, tf, wait=True, timeout=900)
                    finally:
                        setup.SPREAD_MAX = consistent.SPREAD_MAX
                    if not a.last_frame_stats.converged:
                        raise RuntimeError(f"{k}: the frame did not converge ({image}^2 {view})")
                for k, (c, delta) in casters.items():
                    imgs[k] = straight_u8(c.render(cam, tf, delta, OPAQUE))

                def pct(a, b=truth):
                    return round(float(percent_delta_e(a, b, threshold=6.0, premultiplied=False)), 3)

                radius = max(1, int(round(footprint_px(cam, pyr, max(levels)) / 2.0)))
                edges = sub_resolution(truth, radius)

                l0 = pct(imgs["L0"])
                load = os.getloadavg()[0]
                for k, img in imgs.items():
                    row = dict(date=time.strftime("%Y-%m-%d"), store=store.name, image=image, view=view,
                               setting=k, pct_de6=pct(img), l0_pct_de6=l0, over_l0_points=round(pct(img) - l0, 3),
                               plain_vs_clipvol_pct="", supersample=supersample, load=round(load, 2),
                               edge_radius_px=radius, edge_pixels_pct=round(100.0 * float(edges.mean()), 3))
                    bad = delta_e_luv(img, truth, premultiplied=False) >= 6.0
                    row["pct_de6_off_edges"] = round(100.0 * float((bad & ~edges).mean()), 3)
                    if k.endswith((" mean (plain)", " dist (plain)")):
                        row["plain_vs_clipvol_pct"] = pct(img, imgs[k.replace(" (plain)", "")])
                    rows.append(row)
                    plain = row["plain_vs_clipvol_pct"]
                    log(f"{image}^2 {view:5} {k:>28}: {row['pct_de6']:6.2f} % dE>=6 ({row['over_l0_points']:+6.2f} "
                        f"points over level 0; {row['pct_de6_off_edges']:5.2f} % off edges)"
                        + (f"; plain vs clipvol {plain:.2f} %" if plain != "" else ""))
                log(f"{image}^2 {view}: {time.perf_counter() - t0:.0f} s, load {load:.2f}; edges (Delta E >= 6 within "
                    f"{radius} px, a level-{max(levels)} voxel ~{footprint_px(cam, pyr, max(levels)):.1f} px): "
                    f"{100.0 * float(edges.mean()):.1f} % of pixels")
        check_classified_path(scene, vol0, log)  # after clipvol's frames: its casters' framebuffer is released
    finally:
        for c, _ in casters.values():
            c.release()
        scene.close()
    return rows


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--store", type=Path, required=True, help="a clipvol store built with its spread arrays")
    ap.add_argument("--images", default="256,512", help="image edges, comma separated (default 256,512)")
    ap.add_argument("--levels", default="1", help="coarse levels to split, comma separated (default 1)")
    ap.add_argument("--supersample", type=int, default=2,
                    help="rays per pixel along each axis of the converged picture (default 2)")
    ap.add_argument("--spread-scales", default="",
                    help="also draw each level classified with its spread scaled by these factors (a probe of the "
                         "normal model's width: the renderer's spread-to-row scale divided by each), comma separated")
    ap.add_argument("--out", type=Path, default=common.RESULTS / "bench_level1_error.csv")
    a = ap.parse_args(argv)
    rows = run(a.store, [int(v) for v in a.images.split(",")], [int(v) for v in a.levels.split(",")], a.supersample,
               [float(v) for v in a.spread_scales.split(",") if v])
    return common.save_rows(a.out, rows)


if __name__ == "__main__":
    sys.exit(main())
