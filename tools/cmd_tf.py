"""Save a transfer function to a JSON file, or load one and say what it does.

``clipvol tf save SOURCE FILE.json [--tf ... --window C,W --opacity ...]`` writes the transfer
function those flags give for that data (by default the automatic one, from the store's
histograms) - a starting point to edit by hand or in the viewer, and to pass back with
``--tf FILE.json`` to ``render``, ``view`` and ``report``. ``clipvol tf load FILE.json`` checks a
file (also one written by hand, in data values: see the guide's "Transfer functions") and prints
its window and where it becomes visible. The file format is documented in ``docs/guide.md``.
"""

from __future__ import annotations

import argparse


def add_arguments(p: argparse.ArgumentParser) -> None:
    from clipvol.tools.tf_args import add_tf_arguments

    sub = p.add_subparsers(dest="tf_command", metavar="ACTION", parser_class=type(p))
    s = sub.add_parser("save", help="write the transfer function the flags give for SOURCE to FILE.json",
                       description="Write the transfer function the flags give for SOURCE to FILE.json.")
    s.add_argument("source", help="a clipvol store / OME-Zarr directory, procedural:NAME?size=N, or a .npy file")
    s.add_argument("file", metavar="FILE.json", help="output JSON file")
    from clipvol.tools.common_args import add_common_arguments

    add_common_arguments(s, ("brick",))
    add_tf_arguments(s.add_argument_group("transfer function"))
    ld = sub.add_parser("load", help="read FILE.json, check it and describe it",
                        description="Read a transfer-function JSON file, check it and describe it.")
    ld.add_argument("file", metavar="FILE.json", help="a file written by 'clipvol tf save', the viewer's S key or by hand")


def describe(tf) -> list[str]:
    """A few lines saying what ``tf`` does (window, where opacity starts, its peak)."""
    import numpy as np

    tab = tf.table
    n = len(tab)
    lines = [f"name        {tf.name or 'custom'}",
             "window      " + ("the data's value range" if tf.value_range is None else
                              f"{tf.value_range[0]:g} .. {tf.value_range[1]:g}"),
             f"entries     {n}"]
    vis = np.flatnonzero(tab[:, 3] > 0)
    if vis.size == 0:
        lines.append("opacity     0 everywhere (nothing will show)")
    else:
        def at(i):
            t = (i + 0.5) / n
            if tf.value_range is None:
                return f"{100 * t:.1f} % of the range"
            lo, hi = tf.value_range
            return f"{lo + t * (hi - lo):g}"

        lines.append(f"opacity     > 0 from {at(vis[0])}; peak {tab[:, 3].max():.3f} at {at(int(np.argmax(tab[:, 3])))}")
    return lines


def run(args) -> int:
    from clipvol.errors import ParameterError
    from clipvol.scene.transfer import TransferFunction

    if args.tf_command is None:
        raise ParameterError("expected an action: save or load")
    if args.tf_command == "load":
        tf = TransferFunction.load(args.file)
        for line in describe(tf):
            print(line)
        return 0
    from clipvol.app.session import open_loader
    from clipvol.app.outputs import check_output_file
    from clipvol.tools.tf_args import transfer_function_from_args

    check_output_file(args.file, ".json", "FILE.json")
    loader = open_loader(args.source, **({} if args.brick is None else {"brick": args.brick}))
    tf = transfer_function_from_args(args, loader)
    tf.save(args.file)
    for line in describe(tf):
        print(line)
    print(f"wrote {args.file}; use it with --tf {args.file}")
    return 0
