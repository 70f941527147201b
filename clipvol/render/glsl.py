"""Load the GLSL sources shipped in ``clipvol/render/shaders/`` and compile them as *variants*.

Why variants instead of branches
--------------------------------
A ray caster's inner loop runs once per sample: every test there that is constant for the whole
frame (the compositing mode, whether the data can hold NaN, a lighting model) is paid millions of
times per frame. So such choices are compile-time ``#define``\\ s, and one program is compiled per
combination actually used (lazily, cached per context). The fast path of plain finite data then
carries no NaN test at all, and MIP carries no transfer-function lookup.

The mechanism (how to add a feature)
------------------------------------
* A shader file may contain ``#include "name.glsl"`` lines (resolved from this package's
  ``shaders/`` folder, recursively, each file once): shared code such as the sampling functions
  lives in one file used by both volume paths.
* :func:`shader_source` inserts one ``#define NAME value`` line per entry of ``defines`` right after
  the ``#version`` line. The shader guards its feature code with ``#ifdef NAME`` / ``#if NAME``.
* :class:`ProgramCache` compiles ``(vertex, fragment, defines)`` once and hands back the same
  program for the same key. A render action builds its ``defines`` from what it knows per frame
  (mode, data properties, parameters) - see ``ClipRenderAction._defines`` - so a new feature is
  one more entry there and one more ``#ifdef`` block in the shader.

Defines used by the volume shaders today: ``MODE_MIP`` (maximum intensity projection; none of
the ``MODE_*``: composite; ``MODE_MINIP``, ``MODE_AVERAGE``, ``MODE_ISO`` likewise, each the ``define``
of a mode in :mod:`clipvol.render.modes`; ``MODE_GLSL``: a registered mode's own GLSL, inserted at the
line ``#include MODE_GLSL``), ``HAS_NAN`` (the data may hold NaN/Inf: NaN-aware trilinear filtering over the finite
neighbours, non-finite samples skipped; absent: one hardware trilinear fetch, no test), ``SHADING``
(composite only: Blinn-Phong gradient lighting from central differences, ``volume_common.glsl``),
``EMPTY_SKIP`` (composite without overlays: leap over cells the transfer function makes
transparent, :mod:`clipvol.scene.occupancy`; ``SKIP_BLOCK`` samples per cell lookup, default 8; the
single pass compiles 2, see :data:`clipvol.render.paths.single_pass.SINGLE_PASS_SKIP_BLOCK`).
"""

from __future__ import annotations

import re
from functools import lru_cache
from importlib import resources
from typing import Mapping

from ..errors import ParameterError

__all__ = ["load_shader", "shader_source", "ProgramCache", "register_source", "unregister_source"]

_INCLUDE = re.compile(r'^\s*#include\s+"([^"]+)"\s*$', re.MULTILINE)
#: the line a shader puts where a draw mode's own GLSL goes (the source named by the MODE_GLSL define)
_MODE_INCLUDE = re.compile(r'^\s*#include\s+MODE_GLSL\s*$', re.MULTILINE)
#: GLSL sources held in memory by name (a registered draw mode's own code, clipvol.render.modes)
_SOURCES: dict[str, str] = {}


def register_source(name: str, text: str) -> None:
    """Hold ``text`` as the GLSL that ``#include MODE_GLSL`` inserts where ``MODE_GLSL`` is ``name``."""
    _SOURCES[name] = text


def unregister_source(name: str) -> None:
    """Forget the source ``name`` (:func:`register_source`)."""
    _SOURCES.pop(name, None)


@lru_cache(maxsize=None)
def _read(filename: str) -> str:
    return resources.files(__package__).joinpath("shaders", filename).read_text(encoding="utf-8")


@lru_cache(maxsize=None)
def load_shader(name: str) -> str:
    """Source text of ``shaders/<name>.glsl`` (e.g. ``"brick.frag"``), ``#include`` lines resolved."""
    seen: set[str] = set()

    def expand(filename: str) -> str:
        if filename in seen:
            return ""  # each file once (include guard)
        seen.add(filename)
        return _INCLUDE.sub(lambda m: expand(m.group(1)), _read(filename))

    return expand(f"{name}.glsl")


def shader_source(name: str, defines: Mapping[str, object] | None = None) -> str:
    """:func:`load_shader` with ``#define NAME value`` lines after ``#version`` (``True``: defined as 1;
    ``False``/``None``: left out), and the line ``#include MODE_GLSL`` replaced by the registered
    source the ``MODE_GLSL`` define names (:func:`register_source`; without it, by nothing)."""
    src = load_shader(name)
    if _MODE_INCLUDE.search(src):
        mode = (defines or {}).get("MODE_GLSL")
        if mode and mode not in _SOURCES:
            raise ParameterError(f"MODE_GLSL: expected a registered GLSL source, got {mode!r} (a draw mode "
                                 f"unregistered since?)")
        src = _MODE_INCLUDE.sub(lambda _m: _SOURCES[mode] if mode else "", src)
    lines = [f"#define {k} {1 if v is True else v}" for k, v in sorted((defines or {}).items())
             if v is not None and v is not False]
    if not lines:
        return src
    head, sep, rest = src.partition("\n")
    if not head.startswith("#version"):
        return "\n".join(lines) + "\n" + src
    return head + sep + "\n".join(lines) + "\n" + rest


class ProgramCache:
    """Programs of one context, one per ``(vertex, fragment, defines)``, compiled on first use."""

    def __init__(self, ctx) -> None:
        self.ctx = ctx
        self._programs: dict = {}

    def get(self, vertex: str, fragment: str, defines: Mapping[str, object] | None = None):
        key = (vertex, fragment, tuple(sorted((defines or {}).items())))
        prog = self._programs.get(key)
        if prog is None:
            prog = self.ctx.program(vertex_shader=shader_source(vertex, defines),
                                    fragment_shader=shader_source(fragment, defines))
            self._programs[key] = prog
        return prog

    def __len__(self) -> int:
        return len(self._programs)

    def release(self) -> None:
        for prog in self._programs.values():
            prog.release()
        self._programs.clear()
