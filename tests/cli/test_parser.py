"""The command line's parser: every option has a help text, the parser needs no numerical library, and the help names every format."""

import argparse
import subprocess
import sys

from skintopo.cli import build_parser


def _subparsers(parser, prefix=()):
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield (*prefix, name), sub
                yield from _subparsers(sub, (*prefix, name))


def test_every_option_of_every_command_has_a_help_text():
    missing = []
    for name, parser in _subparsers(build_parser()):
        parser.format_help()  # every help text must also format (no stray % signs)
        for action in parser._actions:
            if not isinstance(action, argparse._SubParsersAction) and not (action.help and action.help.strip()):
                missing.append(f"{' '.join(name)} {'/'.join(action.option_strings) or action.dest}")
    assert not missing, missing


def test_the_command_line_parser_needs_no_numerical_library():
    """``skintopo --help`` builds every command's parser from plain defaults (skintopo.defaults):
    no NumPy, SciPy, scikit-image or matplotlib is imported until a command runs (it starts in
    about 0.07 s instead of 1 s)."""
    code = ("import sys, skintopo.cli; skintopo.cli.build_parser(); "
            "print(sorted({m.split('.')[0] for m in sys.modules} & {'numpy', 'scipy', 'skimage', 'matplotlib'}))")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert done.stdout.strip() == "[]", done.stdout


def test_help_texts_name_every_readable_height_map_format():
    """Every command that reads a height map says which files it reads: all of them
    (formats.READABLE; a user reported .sdf/.gwy/.tif working but missing from the help)."""
    from skintopo.formats import READABLE

    parsers = {" ".join(name): parser for name, parser in _subparsers(build_parser())}
    for command, argument in (("measure", "input"), ("evaluate", "result"), ("evaluate", "reference"), ("compare", "baseline"),
                              ("wrinkles", "input")):
        text = next(a.help for a in parsers[command]._actions if a.dest == argument)
        assert all(suffix in text for suffix in READABLE), (command, argument, text)
