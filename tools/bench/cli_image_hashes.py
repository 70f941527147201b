"""The sha256 of every output of a set of ``clipvol render`` / ``slice`` / ``view --offscreen``
command lines on small stores, to show a refactoring keeps every image bit-identical.

Usage::

    python tools/bench/cli_image_hashes.py record HASHES.json   # on the code before the change
    python tools/bench/cli_image_hashes.py check HASHES.json    # on the code after it: exit 1 on a difference

To record on an older commit without switching branches, unpack it (``git archive COMMIT | tar -x
-C OLD``), link ``OLD/clipvol/tools`` to ``../tools`` and ``OLD/clipvol/loaders`` to ``../loaders``
(the layout the installed package has), and run the script with ``PYTHONPATH=OLD``.

``tools/bench/results/cli_image_hashes.json`` holds the hashes recorded on 2026-11-29 (Mesa
llvmpipe, offscreen EGL) on the commit before render and slice went through the sessions; images
from another GL driver differ, so on another machine record afresh on the older commit.

The stores are built afresh in a temporary folder from seeded numpy data (a NIfTI head with a
patient frame and a label image, an OME-Zarr image with a channel axis, one with a time axis, a
co-registered overlay, a point cloud), so the hashes depend on the code only. The command lines
cover the draw modes (composite, MIP, iso-surface), an overlay, labels shown and hidden, channels,
a channel and a time point, a crop box, a clip plane, the image policy, a frame refused for its
texture budget (exit 3) and the same frame written with ``--allow-partial``, sort-last on Dask
workers, a point store, slices in the three planes and an oblique one, a point of interest, the
float values (``--npy``) and the statistics JSON (``--stats``; its timings and load counters left
out of the hash, :data:`STATS_KEYS`),
and a short offscreen path (PNG frames; its per-frame CSV hashed without the time columns). Each
command line's exit status is recorded beside its hashes.
"""

from __future__ import annotations

import hashlib
import json
import sys
import tempfile
from pathlib import Path

import numpy as np


def _make_stores(d: Path) -> dict:
    """Small seeded inputs in ``d``; returns their paths by name."""
    import nibabel as nib
    import zarr
    from scipy.ndimage import gaussian_filter

    from clipvol.tools.cli import main

    n = 40
    z, y, x = np.meshgrid(*(np.arange(n, dtype=np.float64),) * 3, indexing="ij")
    r = np.sqrt((x - 19.5) ** 2 + (y - 21.0) ** 2 + (z - 18.5) ** 2)
    rng = np.random.default_rng(43)
    head = np.where(r < 17, np.where(r > 13, 100.0, 30.0 + 20 * gaussian_filter(rng.random((n, n, n)), 2)), 0.0)
    lab = np.zeros((n, n, n), np.uint8)
    lab[14:26, 14:26, 14:26] = 1
    lab[14:26, 14:26, 26:30] = 2
    aff = np.diag([2.0, 2.0, 2.0, 1.0])
    aff[:3, 3] = (-40.0, -42.0, -38.0)
    nib.save(nib.Nifti1Image(head.astype(np.float32).transpose(2, 1, 0), aff), str(d / "head.nii.gz"))
    np.save(d / "lab.npy", lab)
    assert main(["brick", str(d / "head.nii.gz"), str(d / "head.zarr"), "--brick", "16", "--quiet",
                 "--labels", f"{d / 'lab.npy'}:organs"]) == 0
    zmap = gaussian_filter(rng.standard_normal((n, n, n)), 3) * 20
    nib.save(nib.Nifti1Image(zmap.astype(np.float32).transpose(2, 1, 0), aff), str(d / "zmap.nii.gz"))
    assert main(["brick", str(d / "zmap.nii.gz"), str(d / "zmap.zarr"), "--brick", "16", "--quiet"]) == 0

    shape = (20, 24, 22)
    chans = np.stack([gaussian_filter(rng.random(shape), 2.0) for _ in range(3)]).astype(np.float32)
    chans = (chans - chans.min(axis=(1, 2, 3), keepdims=True)) / np.ptp(chans, axis=(1, 2, 3), keepdims=True)
    g = zarr.open_group(str(d / "cells.zarr"), mode="w")
    g.create_array("0", shape=chans.shape, chunks=(1, 16, 16, 16), dtype="float32")[...] = chans
    axes = [{"name": "c", "type": "channel"}] + [{"name": a, "type": "space", "unit": "micrometer"} for a in "zyx"]
    g.attrs.update({"ome": {"version": "0.5", "multiscales": [{"axes": axes, "datasets": [
        {"path": "0", "coordinateTransformations": [{"type": "scale", "scale": [1, 1.2, 1.0, 0.9]}]}]}],
        "omero": {"channels": [{"window": {"min": 0.2, "max": 1.0}} for _ in range(3)]}}})

    ts = rng.random((2, 16, 16, 16), dtype=np.float32)
    ts[1] *= 0.25
    g = zarr.open_group(str(d / "ts.zarr"), mode="w")
    g.create_array("0", shape=ts.shape, chunks=(1, 8, 8, 8), dtype="float32")[...] = ts
    axes = [{"name": "t", "type": "time"}] + [{"name": a, "type": "space"} for a in "zyx"]
    g.attrs.update({"ome": {"version": "0.5", "multiscales": [{"axes": axes, "datasets": [
        {"path": "0", "coordinateTransformations": [{"type": "scale", "scale": [1, 1, 1, 1]}]}]}],
        "omero": {"channels": [{"window": {"min": 0.0, "max": 1.0}}]}}})

    pts = rng.random((3000, 4))
    pts[:, 3] = np.linalg.norm(pts[:, :3] - 0.5, axis=1)
    np.save(d / "p.npy", pts)
    assert main(["brick-points", str(d / "p.npy"), str(d / "points.zarr"), "--max-points", "32", "--quiet"]) == 0
    return {k: str(d / v) for k, v in dict(head="head.zarr", zmap="zmap.zarr", cells="cells.zarr", ts="ts.zarr",
                                            points="points.zarr").items()}


def command_lines(s: dict) -> list[tuple[str, list[str], list[str]]]:
    """``(name, argv, outputs)``: ``{out}`` in argv is the run's output folder."""
    o = "{out}"
    small = ["--size", "64x56"]
    R = [("render-composite", ["render", s["head"], "--out", f"{o}/a.png"] + small, ["a.png"]),
         ("render-mip", ["render", s["head"], "--out", f"{o}/a.png", "--mode", "mip", "--view", "left"] + small, ["a.png"]),
         ("render-iso", ["render", s["head"], "--out", f"{o}/a.png", "--mode", "iso", "--iso-value", "60",
                         "--shading"] + small, ["a.png"]),
         ("render-ortho-fixed", ["render", s["head"], "--out", f"{o}/a.png", "--ortho", "--view", "front",
                                 "--policy", "fixed", "--level", "1", "--no-labels"] + small, ["a.png"]),
         ("render-overlay", ["render", s["head"], "--out", f"{o}/a.png", "--tf", "grey", "--overlay",
                             f"{s['zmap']}:diverging@-5,5"] + small, ["a.png"]),
         ("render-label-overlay", ["render", s["head"], "--out", f"{o}/a.png", "--label-overlay", "organs",
                                   "--label-colors", "1=#ff0000", "--view", "front", "--ortho"] + small, ["a.png"]),
         ("render-hide-labels", ["render", s["head"], "--out", f"{o}/a.png", "--hide-labels", "organs:1"] + small,
          ["a.png"]),
         ("render-channels", ["render", s["cells"], "--out", f"{o}/a.png", "--channels",
                              "0:green,1:magenta,2:#ffaa00"] + small, ["a.png"]),
         ("render-channel-c", ["render", s["cells"], "--out", f"{o}/a.png", "--c", "2", "--mode", "mip"] + small,
          ["a.png"]),
         ("render-time-t", ["render", s["ts"], "--out", f"{o}/a.png", "--t", "1", "--mode", "mip", "--tf", "grey",
                            "--policy", "fixed"] + small, ["a.png"]),
         ("render-crop", ["render", s["head"], "--out", f"{o}/a.png", "--crop", "-30,-30,-30,10,20,30"] + small,
          ["a.png"]),
         ("render-clip-plane", ["render", s["head"], "--out", f"{o}/a.png", "--clip-plane", "0,0,0,1,0,0.5",
                                "--view", "right"] + small, ["a.png"]),
         ("render-eye-target", ["render", s["head"], "--out", f"{o}/a.png", "--eye", "100,80,60", "--target", "0,0,0",
                                "--up", "0,0,1", "--fov", "30"] + small, ["a.png"]),
         ("render-image-policy", ["render", s["head"], "--out", f"{o}/a.png", "--policy", "image", "--block-budget",
                                  "4"] + small, ["a.png"]),
         ("render-over-texture-budget", ["render", s["head"], "--out", f"{o}/a.png", "--policy", "fixed", "--level",
                                         "0", "--texture-budget", "40KB"] + small, ["a.png"]),
         ("render-allow-partial", ["render", s["head"], "--out", f"{o}/a.png", "--policy", "fixed", "--level", "0",
                                   "--texture-budget", "40KB", "--allow-partial"] + small, ["a.png"]),
         ("render-bad-out", ["render", s["head"], "--out", f"{o}/a.jpg"] + small, ["a.jpg"]),
         ("render-sort-last", ["render", s["head"], "--out", f"{o}/a.png", "--workers", "2"] + small, ["a.png"]),
         ("render-points", ["render", s["points"], "--out", f"{o}/a.png", "--tolerance", "0.05"] + small, ["a.png"]),
         ("render-points-mip", ["render", s["points"], "--out", f"{o}/a.png", "--mode", "mip", "--view", "top"] + small,
          ["a.png"])]
    S = [("slice-axial", ["slice", s["head"], "--axis", "axial", "--out", f"{o}/a.png", "--npy", f"{o}/a.npy",
                          "--stats", f"{o}/a.json"], ["a.png", "a.npy", "a.json"]),
         ("slice-coronal", ["slice", s["head"], "--axis", "coronal", "--index", "12", "--out", f"{o}/a.png"],
          ["a.png"]),
         ("slice-sagittal", ["slice", s["head"], "--axis", "sagittal", "--neurological", "--out", f"{o}/a.png",
                             "--tf", "magma"], ["a.png"]),
         ("slice-plane-z", ["slice", s["head"], "--plane", "z=20", "--out", f"{o}/a.png", "--window", "50,80",
                            "--no-labels"], ["a.png"]),
         ("slice-oblique", ["slice", s["head"], "--origin", "0,0,0", "--normal", "1,1,2", "--out", f"{o}/a.png",
                            "--npy", f"{o}/a.npy", "--size", "48x40"], ["a.png", "a.npy"]),
         ("slice-poi", ["slice", s["head"], "--poi", "5,-3,4", "--level", "0", "--out", f"{o}/a.png", "--stats",
                        f"{o}/a.json"], ["a.png", "a.json"]),
         ("slice-crop", ["slice", s["head"], "--axis", "axial", "--crop", "-30,-30,-30,10,20,30", "--npy",
                         f"{o}/a.npy"], ["a.npy"]),
         ("slice-over-texture-budget", ["slice", s["head"], "--axis", "axial", "--level", "0", "--texture-budget",
                                        "40KB", "--out", f"{o}/a.png"], ["a.png"]),
         ("slice-channel", ["slice", s["cells"], "--plane", "x=10", "--out", f"{o}/a.png"], ["a.png"]),
         ("slice-points", ["slice", s["points"], "--out", f"{o}/a.png"], ["a.png"]),
         ("slice-no-output", ["slice", s["head"]], [])]
    V = [("view-offscreen", ["view", s["head"], "--offscreen", "--frames", "3", "--size", "48x40", "--converged",
                             "--out", f"{o}/frames"], ["frames/frame_0000.png", "frames/frame_0002.png",
                                                       "frames/frames.csv"])]
    return R + S + V


#: the fields of ``slice --stats`` hashed: what the slice drew and where. Left out are the times and
#: the load and upload counters, which depend on whether a prefetched neighbour's read ended before
#: the frame's upload (9 or 10 bricks uploaded in repeated runs of the same code).
STATS_KEYS = ("size", "plane", "poi", "level", "edges", "tiles", "tiles_per_level", "blended", "bricks_needed",
              "bytes_needed", "converged", "failed_bricks", "balance_splits")


def _digest(path: Path) -> str | None:
    """sha256 of the file (None if absent); of a stats JSON the fields that do not race the loader
    threads (:data:`STATS_KEYS`), of a frames CSV the columns that are no timings."""
    if not path.exists():
        return None
    data = path.read_bytes()
    if path.suffix == ".json":
        doc = json.loads(data)
        data = json.dumps({k: doc.get(k) for k in STATS_KEYS}, sort_keys=True).encode()
    elif path.suffix == ".csv":
        lines = data.decode().splitlines()
        head = lines[0].split(",")
        keep = [i for i, h in enumerate(head) if not (h.endswith("_s") or h.endswith("_ms") or "time" in h)]
        data = "\n".join(",".join(row.split(",")[i] for i in keep) for row in lines).encode()
    return hashlib.sha256(data).hexdigest()


def run_all() -> dict:
    from clipvol.tools.cli import main

    out: dict = {}
    with tempfile.TemporaryDirectory(prefix="clipvol-hashes-") as tmp:
        stores = _make_stores(Path(tmp))
        for k, (name, argv, outputs) in enumerate(command_lines(stores)):
            od = Path(tmp) / f"run{k:02d}"
            od.mkdir()
            rc = main([a.replace("{out}", str(od)) for a in argv])
            out[name] = {"rc": rc, **{f: _digest(od / f) for f in outputs}}
            print(f"{name:28s} rc {rc}", file=sys.stderr, flush=True)
    return out


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if len(argv) != 2 or argv[0] not in ("record", "check"):
        print(__doc__, file=sys.stderr)
        return 2
    got = run_all()
    if argv[0] == "record":
        Path(argv[1]).write_text(json.dumps(got, indent=1, sort_keys=True) + "\n")
        print(f"recorded {len(got)} command lines in {argv[1]}")
        return 0
    want = json.loads(Path(argv[1]).read_text())
    bad = [k for k in sorted(set(want) | set(got)) if want.get(k) != got.get(k)]
    for k in bad:
        print(f"DIFFERS {k}: before {want.get(k)} after {got.get(k)}")
    print(f"{len(got) - len(bad)} of {len(got)} command lines identical (exit status and every output's sha256)")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
