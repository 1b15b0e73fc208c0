"""Package structure: data flows one way (the library never imports the command line), and
every command line option says what it does."""

import argparse
import subprocess
import sys

from skintopo.cli import build_parser

BLOCK_CLI = """
import importlib, importlib.abc, pkgutil, sys
class NoCli(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name == "skintopo.cli" or name.startswith("skintopo.cli."):
            raise ImportError("the command line is not available")
sys.meta_path.insert(0, NoCli())
import skintopo
names = [m.name for m in pkgutil.walk_packages(skintopo.__path__, "skintopo.") if not m.name.startswith("skintopo.cli")]
for name in names:
    importlib.import_module(name)
from skintopo.pipeline import measure_height
from skintopo.synth import make_surface, preset_spec
measurement = measure_height(make_surface(preset_spec("forehead-low", size_px=64), seed=1).height)
print(len(names), "modules", len(measurement.parameter_rows()), "parameters")
"""


def test_library_imports_and_runs_without_the_command_line():
    run = subprocess.run([sys.executable, "-c", BLOCK_CLI], capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr
    assert "modules" in run.stdout and int(run.stdout.split()[0]) >= 25


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
