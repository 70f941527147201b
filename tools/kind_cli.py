"""The data-kind hand-over of the commands: which kind's code runs ``clipvol info|check|render|slice|view|report``.

Each command asks :func:`kind_command` for the hook of the source's data kind
(:func:`clipvol.app.kinds.kind_of`) and returns what it returns: the volume's hooks
(``clipvol.tools.volume_cli``) and the point kind's (``clipvol.tools.point_cli``) are found the same
way, so a new kind is its module and one registry line, with no command to edit. A kind that names
its hooks as a module has that module imported here, by the CLI, so the library's kinds never
import the CLI.
"""

from __future__ import annotations

import importlib

from clipvol.app.kinds import kind_of
from clipvol.errors import ParameterError

__all__ = ["kind_command"]


def kind_command(source, command: str):
    """The hook that runs ``clipvol {command}`` on ``source``.

    Raises
    ------
    ParameterError
        The source's kind has no hook for this command (one line naming the source, kind and command).
    """
    kind = kind_of(source)
    cli = importlib.import_module(kind.cli) if isinstance(kind.cli, str) else kind.cli
    hook = getattr(cli, command, None)
    if hook is None:
        raise ParameterError(f"{source}: a {kind.name} store; `clipvol {command}` does not take this kind")
    return hook
