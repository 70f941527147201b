"""The registry of selection policies by name: a leaf module that both sides of the choice import.

:class:`~clipvol.scene.params.RenderParams` validates ``policy`` against :data:`POLICIES`, and the
policy classes (:mod:`clipvol.scene.selection.policies`) register themselves here. Why a leaf: the
traversal that runs a policy takes a ``RenderParams``, so ``params`` must not import the policies
(that would be a package cycle, scene <-> scene.selection, hidden in a function).

When it is full: ``clipvol/scene/__init__.py`` imports the policies package, and ``params`` can
only be imported through that package, so every built-in policy is registered before the first
``RenderParams`` is validated. A policy added later (a plug-in, a test) calls :func:`register`.
"""

from __future__ import annotations

__all__ = ["POLICIES", "register", "policy_names"]

#: name -> policy class (a :class:`~clipvol.scene.selection.policies.base.SelectionPolicy`)
POLICIES: dict[str, type] = {}


def register(cls: type) -> type:
    """Add ``cls`` under its ``name`` (a class attribute); returns ``cls``, so it works as a decorator."""
    name = getattr(cls, "name", "")
    if not isinstance(name, str) or not name:
        raise ValueError(f"policy {cls.__name__}: expected a non-empty class attribute 'name', got {name!r}")
    POLICIES[name] = cls
    return cls


def policy_names() -> tuple[str, ...]:
    """The registered policy names, sorted (for error messages and command-line choices)."""
    return tuple(sorted(POLICIES))
