"""The ``skintopo`` command line: a thin layer over the Python API (:mod:`skintopo.pipeline`,
:mod:`skintopo.results`), one small module per command, shared options in
:mod:`skintopo.cli.options`.

Errors caused by the input (:class:`~skintopo.errors.SkinTopoError`) are printed as one
clear message, exit status 2, without a traceback; Ctrl-C gives exit status 130.
"""

from __future__ import annotations

import argparse
import sys

from skintopo import __version__
from skintopo.errors import SkinTopoError

COMMANDS = ("init", "reconstruct", "correct", "evaluate", "demo", "measure", "wrinkles", "compare", "batch", "calibrate", "paper_tables", "synth")


def build_parser():
    """The argument parser of every command (each module's ``add_parser``)."""
    import importlib

    parser = argparse.ArgumentParser(prog="skintopo", description="3D skin topography by multispectral photometric stereo.")
    parser.add_argument("--version", action="version", version=f"skintopo {__version__}")
    commands = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name in COMMANDS:
        importlib.import_module(f"skintopo.cli.{name}").add_parser(commands)
    return parser


def main(argv=None):
    """Run one command; returns its exit status."""
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return args.handler(args)
    except SkinTopoError as exc:
        print(f"skintopo {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"skintopo {args.command}: interrupted; no output written", file=sys.stderr)
        return 130
