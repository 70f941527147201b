"""The front door is light: building the parser for ``clipvol --help`` (and for a command whose flags
need no registry of the library) imports no numpy, and imports no command module but the one named.

Reference: ``sys.modules`` of a fresh interpreter (a subprocess), not a timing.
"""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

PROBE = """
import json, sys
from clipvol.tools import cli
cli.build_parser(cli._command_of(sys.argv[1:]))
print(json.dumps(sorted(m for m in sys.modules if m == "numpy" or m.startswith("clipvol.tools.cmd_"))))
"""


def _modules(*argv: str) -> list[str]:
    out = subprocess.run([sys.executable, "-c", PROBE, *argv], capture_output=True, text=True, timeout=120, check=True)
    return json.loads(out.stdout)


@pytest.mark.parametrize("argv", [(), ("--help",), ("brick", "--help"), ("brick-points", "--help"), ("repair", "--help"),
                                  ("summarize", "--help"), ("demo", "--help")], ids=lambda a: " ".join(a) or "none")
def test_building_the_parser_imports_no_numpy_and_only_the_named_command(argv):
    mods = _modules(*argv)
    assert "numpy" not in mods, mods
    named = [f"clipvol.tools.cmd_{argv[0].replace('-', '_')}"] if argv and not argv[0].startswith("-") else []
    assert mods == named, mods


def test_help_still_lists_every_command(capsys):
    from clipvol.tools import cli

    with pytest.raises(SystemExit):
        cli.main(["--help"])
    out = capsys.readouterr().out
    assert all(name in out for name in cli.COMMANDS)
