"""clipvol: look interactively at volumes far larger than memory.

A preprocessing step (``clipvol brick``) bricks a volume into a multiresolution zarr store; at
view time a :class:`ClipTexture` keeps per-level toroidal brick windows around a centre of
interest in main memory, filled by loader threads, and a :class:`ClipRenderAction` picks each
region's level with a selection policy (:class:`RenderParams`), uploads bricks under a texture
budget and ray-casts them in visibility order with moderngl.

The package is built in stages, each importing only the ones below it: ``bricking`` -> ``paging``
-> ``scene`` -> ``render`` -> ``app`` -> ``viewer`` (see ``docs/architecture.md``).

Public names are imported lazily so ``import clipvol`` stays cheap (no zarr, no GL).
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

__version__ = "0.1.0"

_LAZY = {
    # contracts and geometry
    "Loader": "clipvol.paging.loader",
    "HasBrickRanges": "clipvol.paging.loader",
    "BrickKey": "clipvol.paging.loader",
    "Pyramid": "clipvol.bricking.pyramid",
    "LevelInfo": "clipvol.bricking.pyramid",
    "parse_bytes": "clipvol.units",
    # paging
    "ClipTexture": "clipvol.paging.cliptexture",
    "BrickState": "clipvol.paging.cliptexture",
    "open_store": "clipvol.paging.open",
    # data access (numpy / dask, through the verified loader)
    "open": "clipvol.app.volume_access",
    "Volume": "clipvol.app.volume_access",
    # rendering (pure numpy parts)
    "Camera": "clipvol.scene.camera",
    "TransferFunction": "clipvol.scene.transfer",
    "Shape": "clipvol.scene.geometry",
    "RenderParams": "clipvol.scene.params",
    # rendering (GL)
    "create_context": "clipvol.render.context",
    "ClipRenderAction": "clipvol.render.action",
    # preprocessing
    "brick_volume": "clipvol.bricking.pipeline",
    "BuildOptions": "clipvol.bricking.build_options",
    # notebooks (anywidget, an optional extra)
    "show": "clipvol.app.kinds",  # the notebook view of the source's data kind
}

__all__ = sorted(_LAZY) + ["__version__"]


def __getattr__(name: str) -> Any:
    mod = _LAZY.get(name)
    if mod is None:
        raise AttributeError(f"module 'clipvol' has no attribute {name!r}")
    value = getattr(importlib.import_module(mod), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return __all__


if TYPE_CHECKING:  # pragma: no cover
    from .bricking.pipeline import brick_volume
    from .bricking.pyramid import LevelInfo, Pyramid
    from .paging.cliptexture import BrickState, ClipTexture
    from .paging.loader import BrickKey, HasBrickRanges, Loader
    from .app.volume_access import Volume, open
    from .paging.open import open_store
    from .render.action import ClipRenderAction
    from .render.context import create_context
    from .scene.camera import Camera
    from .scene.geometry import Shape
    from .scene.params import RenderParams
    from .scene.transfer import TransferFunction
    from .units import parse_bytes
