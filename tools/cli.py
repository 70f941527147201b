"""``clipvol``: one console script, one sub-command per job.

Each sub-command lives in its own module ``clipvol.tools.cmd_<name>`` with two functions,
``add_arguments(parser)`` and ``run(args) -> int``. Modules import heavy dependencies (zarr,
moderngl, glfw) inside ``run`` so that ``clipvol --help`` starts fast, and :func:`main` imports only
the module of the command its arguments name (``clipvol --help`` none: the listing needs only
:data:`COMMANDS`). No parser imports numpy or zarr: the
choices and shown defaults of the drawing commands come from :mod:`clipvol.choices`, and a flag
several commands share is declared once (:mod:`clipvol.tools.common_args`, ``render_args``,
``tf_args``); ``tests/cli/test_front_door_imports.py`` checks every command's parser in a fresh
interpreter.

Errors a user can cause (:class:`clipvol.errors.ClipvolError`) print one line naming the file or
parameter and exit with status 2, no traceback; so does an ``OSError`` of the machine's state (disk
full, read-only file system, permission denied: :data:`clipvol.errors.OPERATIONAL_ERRNOS`) that no
step reported itself. A frame that could not draw some bricks of the view exits with status 3
(:data:`EXIT_PARTIAL`; ``--allow-partial`` draws it anyway, marked). Ctrl-C exits with 130 after the
command has cleaned up (threads joined, partial outputs left resumable, never marked complete).
"""

from __future__ import annotations

import argparse
import importlib
import re
import signal
import sys
import threading

from clipvol.errors import OPERATIONAL_ERRNOS, ClipvolError, FrameIncompleteError, describe_os_error

#: exit status of a frame some of whose bricks failed and were not replaced (clipvol.app.partial)
EXIT_PARTIAL = FrameIncompleteError.exit_code

#: sub-command -> one-line help; the module is clipvol.tools.cmd_<name>
COMMANDS = {
    "brick": "brick a volume into a multiresolution zarr store (OME-Zarr)",
    "brick-points": "build a point octree store from scattered points (npy, csv, parquet, ply, meshes)",
    "info": "describe a store or any OME-Zarr: levels, shapes, bricks, bytes, compression, value range, NaN/Inf",
    "check": "validate a store: checksums, statistics and filter of sampled (or --all) bricks",
    "repair": "rebuild a store's bad bricks and their ancestors from its input",
    "summarize": "build the summary tables of image-based level of detail for an existing store",
    "render": "render one image of a store or procedural volume",
    "slice": "draw a cutting plane (axial, coronal, sagittal, oblique), fine near a point of interest",
    "export": "take a region out of a store at one level: .npy, .tif, .nii(.gz) or .zarr, with its geometry",
    "view": "interactive roaming / multiresolution viewer (or --offscreen frames)",
    "serve": "serve an interactive view to web browsers (token-protected, 127.0.0.1 by default)",
    "report": "image error against run time for a sweep of quality settings",
    "demo": "brick the built-in dataset, fly around it, and write the report",
    "tf": "save a transfer function to JSON (tf save), or check and describe one (tf load)",
}


#: a value, not an option: a number or a comma/colon list of numbers that starts with a minus
#: (``--tf-range -5,5``, ``--origin -2,5,46``, ``--tf-points -200:0,0,0,0;300:1,1,1,1``); argparse alone
#: takes only a single plain negative number for a value and reads the rest as an unknown option
NEGATIVE_VALUE = re.compile(r"^-(\d|\.\d)[\d.eE+\-,:;]*$")


class _Parser(argparse.ArgumentParser):
    """The CLI's parser: one-line usage errors, and values that start with a minus taken as values."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self._negative_number_matcher = NEGATIVE_VALUE

    def parse_known_args(self, args=None, namespace=None):
        """argparse's parse, then each shared flag left out takes the command's own value
        (:func:`clipvol.tools.common_args.fill_unset`; the flag's help names it)."""
        ns, rest = super().parse_known_args(args, namespace)
        if getattr(ns, "command", None):  # the top-level parser, once the command's flags are in
            from clipvol.tools.common_args import fill_unset

            fill_unset(ns)
        return ns, rest

    def error(self, message: str):  # argparse's usage errors: one line, exit 2
        self.exit(2, f"clipvol {self.prog.split()[-1] if ' ' in self.prog else ''}: error: {message}\n".replace("  ", " "))


def build_parser(only: str | None = None) -> argparse.ArgumentParser:
    """The ``clipvol`` parser with every command of :data:`COMMANDS`.

    ``only`` names the one command whose module is imported and whose arguments are added (the
    others are listed with their one-line help, enough for ``clipvol --help``); ``""`` adds none and
    None adds all. :func:`main` passes the command its ``argv`` names, so ``clipvol --help`` imports
    no command module and ``clipvol CMD --help`` only CMD's."""
    parser = _Parser(prog="clipvol", description="Out-of-core multiresolution volume rendering with 3D clip-textures.")
    from clipvol import __version__

    parser.add_argument("--version", action="version", version=f"clipvol {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    for name, help_text in COMMANDS.items():
        if only is not None and name != only:
            sub.add_parser(name, help=help_text, description=help_text)
            continue
        mod = importlib.import_module(f"clipvol.tools.cmd_{name.replace('-', '_')}")
        p = sub.add_parser(name, help=help_text, description=(mod.__doc__ or help_text).strip().splitlines()[0])
        mod.add_arguments(p)
        p.set_defaults(_run=mod.run)
    return parser


def _caused_by_interrupt(e: BaseException) -> bool:
    """Whether a KeyboardInterrupt lies in ``e``'s chain of causes: a Ctrl-C that landed inside a C
    extension (numpy's sort, a codec) may be re-raised by it as a ``TypeError`` or ``SystemError``
    whose context is the interrupt; the user still pressed Ctrl-C and expects exit 130."""
    seen = set()
    while e is not None and id(e) not in seen:
        if isinstance(e, KeyboardInterrupt):
            return True
        seen.add(id(e))
        e = e.__cause__ or e.__context__
    return False


def _command_of(argv: list[str]) -> str:
    """The command ``argv`` names (its first word that is not an option), or ``""``."""
    for word in argv:
        if not word.startswith("-"):
            return word if word in COMMANDS else ""
    return ""


def main(argv: list[str] | None = None) -> int:
    parser = build_parser(_command_of(sys.argv[1:] if argv is None else list(argv)))
    args = parser.parse_args(argv)
    if not getattr(args, "_run", None):
        parser.print_help(sys.stderr)
        return 2
    import warnings

    show = warnings.showwarning

    def one_line_notes(message, category, filename, lineno, file=None, line=None):
        """clipvol's own notes (an unverified store) as one line, without Python's source echo."""
        if category.__module__.startswith("clipvol."):
            print(f"clipvol {args.command}: note: {message}", file=sys.stderr)
        else:
            show(message, category, filename, lineno, file, line)

    warnings.showwarning = one_line_notes
    from clipvol import interrupts

    interrupts.clear()

    def on_sigint(signum, frame):
        interrupts.note()  # some C code (numpy's structured compare) drops the interrupt it caught
        raise KeyboardInterrupt

    previous = None
    if threading.current_thread() is threading.main_thread():
        previous = signal.signal(signal.SIGINT, on_sigint)
    try:
        from clipvol.tools.common_args import check_common_values

        check_common_values(args)  # --threads, --timeout, --memory-budget, --brick: one check, every command
        rc = int(args._run(args) or 0)
        if interrupts.pending():  # the interrupt was swallowed on its way (C code, a thread): the work did not finish
            print(f"clipvol {args.command}: interrupted", file=sys.stderr)
            return 130
        return rc
    except ClipvolError as e:
        if interrupts.pending():  # the interrupt stopped a step that then reported its own failure
            print(f"clipvol {args.command}: interrupted", file=sys.stderr)
            return 130
        print(f"clipvol {args.command}: error: {e}", file=sys.stderr)
        return int(getattr(e, "exit_code", 2))
    except KeyboardInterrupt:
        print(f"clipvol {args.command}: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:  # `clipvol info | head`
        return 0
    except OSError as e:
        if interrupts.pending() or _caused_by_interrupt(e):
            print(f"clipvol {args.command}: interrupted", file=sys.stderr)
            return 130
        if e.errno not in OPERATIONAL_ERRNOS:
            raise
        print(f"clipvol {args.command}: error: {describe_os_error(e)}", file=sys.stderr)
        return 2
    except Exception as e:
        if interrupts.pending() or _caused_by_interrupt(e):  # Ctrl-C inside a C extension can surface as another error
            print(f"clipvol {args.command}: interrupted", file=sys.stderr)
            return 130
        raise
    finally:
        warnings.showwarning = show
        interrupts.clear()
        if previous is not None:
            signal.signal(signal.SIGINT, previous)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
