"""Setting shader uniforms from float64 numpy values, shared by every render action.

Positions reach the GL as float32 only after they were made relative to the eye (or the plane's
origin) in float64, so the conversion lives in one place: :func:`vec3` turns any 3-sequence into
the tuple of Python floats moderngl writes, and :func:`uset` sets a uniform only where the
compiled shader variant kept it (a variant compiles unused uniforms away).
"""

from __future__ import annotations

__all__ = ["vec3", "uset"]


def vec3(v) -> tuple[float, float, float]:
    """``v`` (any 3-sequence, numpy or not) as a tuple of Python floats for a ``vec3`` uniform."""
    return tuple(float(x) for x in v)  # type: ignore[return-value]


def uset(prog, name: str, value) -> None:
    """Set a uniform if this shader variant has it (a variant compiles unused ones away)."""
    u = prog.get(name, None)
    if u is not None:
        u.value = value
