"""The guide's before/after figure: three differently distributed volumes, first render, no flags.

Top row: a plain default transfer function (viridis with opacity rising linearly over the whole
value range). Bottom row: what ``clipvol render`` does with no flags (the automatic
transfer function, :mod:`clipvol.scene.auto_tf`). Volumes (96^3, made here): a CT-like head (air
-1000 HU around soft tissue, a skull shell), a fluorescence stack (bright cells on a dark, noisy
background) and a signed statistical map (a positive and a negative blob on 0, NaN outside a
sphere). Writes ``docs/images/first_look.png``.

``python tools/bench/figure_first_look.py``
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import numpy as np

from common import REPO  # noqa: E402  (tools/bench/common.py)


def volumes(n: int = 96, seed: int = 0) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    c = (np.arange(n) + 0.5) / n * 2 - 1
    z, y, x = np.meshgrid(c, c, c, indexing="ij")
    r = np.sqrt(x * x + y * y + z * z)
    ct = np.full(r.shape, -1000.0)
    ct[r < 0.8] = 40.0
    ct[(r > 0.68) & (r < 0.78) & (z < 0.5)] = 1200.0
    ct[(np.abs(x) < 0.08) & (r < 0.6)] = 300.0
    ct += rng.normal(0, 20, r.shape)
    fl = 100.0 + rng.normal(0, 5, r.shape)
    for cz, cy, cx in rng.uniform(-0.7, 0.7, (14, 3)):
        fl += 2000.0 * np.exp(-((x - cx) ** 2 + (y - cy) ** 2 + (z - cz) ** 2) / 0.006)
    sm = 6 * np.exp(-((x - 0.3) ** 2 + y * y + z * z) / 0.03) - 5 * np.exp(-((x + 0.3) ** 2 + y * y + z * z) / 0.03)
    sm = sm + rng.normal(0, 0.2, r.shape)
    sm[r > 0.9] = np.nan
    return {"CT-like (int16, air -1000)": ct.astype(np.int16),
            "fluorescence (uint16, dark background)": np.clip(fl, 0, 65535).astype(np.uint16),
            "signed map (float32, 0 and NaN around)": sm.astype(np.float32)}


def main(argv=None) -> int:
    from PIL import Image, ImageDraw

    from clipvol.app.session import RenderSession
    from clipvol.bricking.pipeline import brick_volume
    from clipvol.loaders.zarr_store import ZarrLoader
    from clipvol.render import create_context
    from clipvol.scene.auto_tf import auto_transfer_function
    from clipvol.scene.transfer import TransferFunction
    from clipvol.viewer.controls import OrbitControls

    table = TransferFunction.preset("viridis").table.astype(np.float64)
    table[:, 3] = (np.arange(len(table)) + 0.5) / len(table)  # the old opacity: t over the whole range
    old = TransferFunction(table, name="before")
    size = (240, 240)
    tiles = []
    ctx = create_context()
    try:
        with tempfile.TemporaryDirectory() as tmp:
            for i, (label, vol) in enumerate(volumes().items()):
                path = Path(tmp) / f"v{i}.zarr"
                brick_volume(vol, path, brick=32, progress=False)
                loader = ZarrLoader(path)
                cam = OrbitControls.for_pyramid(loader.pyramid, size=size).camera(size)
                row = []
                for tf in (old, auto_transfer_function(loader)):
                    with RenderSession(loader, ctx, tf=tf) as s:
                        img = s.render(cam, cam.target, wait=True, timeout=120)
                    bg = Image.new("RGBA", size, (30, 30, 30, 255))
                    bg.alpha_composite(Image.fromarray(img, "RGBA"))
                    d = ImageDraw.Draw(bg)
                    d.text((6, 4), label if tf is old else (tf.name or ""), fill=(255, 255, 255, 255))
                    row.append(bg)
                tiles.append(row)
    finally:
        ctx.release()
    out = Image.new("RGBA", (size[0] * len(tiles), size[1] * 2))
    for i, (before, after) in enumerate(tiles):
        out.paste(before, (i * size[0], 0))
        out.paste(after, (i * size[0], size[1]))
    path = REPO / "docs" / "images" / "first_look.png"
    out.convert("RGB").save(path)
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
