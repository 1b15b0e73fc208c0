"""Package structure: data flows one way; the library imports and runs without the command line."""

import subprocess
import sys

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
