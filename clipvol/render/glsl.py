"""Load the GLSL sources shipped in ``clipvol/render/shaders/`` by name (package data)."""

from __future__ import annotations

from functools import lru_cache
from importlib import resources

__all__ = ["load_shader"]


@lru_cache(maxsize=None)
def load_shader(name: str) -> str:
    """Source text of ``shaders/<name>.glsl`` (e.g. ``"brick.frag"``)."""
    return resources.files(__package__).joinpath("shaders", f"{name}.glsl").read_text(encoding="utf-8")
