"""The data-kind hand-over of the commands: which kind's code runs ``clipvol info|check|render|view|report``.

Each command asks :func:`kind_command` for the hook of the source's data kind
(:func:`clipvol.app.kinds.kind_of`) before its own volume path. None means a volume, the default
kind, whose path is the command's own code; any other kind's hook runs instead and its exit status
is the command's. A kind that names its hooks as a module (``"clipvol.tools.point_cli"``) has that
module imported here, by the CLI, so the library's kinds never import the CLI.
"""

from __future__ import annotations

import importlib

from clipvol.app.kinds import DEFAULT_KIND, kind_of
from clipvol.errors import ParameterError

__all__ = ["kind_command"]


def kind_command(source, command: str):
    """The hook that runs ``clipvol {command}`` on ``source``, or None for a volume.

    Raises
    ------
    ParameterError
        The source's kind has no hook for this command (one line naming the source, kind and command).
    """
    kind = kind_of(source)
    if kind.name == DEFAULT_KIND:
        return None
    cli = importlib.import_module(kind.cli) if isinstance(kind.cli, str) else kind.cli
    hook = getattr(cli, command, None)
    if hook is None:
        raise ParameterError(f"{source}: a {kind.name} store; `clipvol {command}` does not take this kind")
    return hook
