"""Package structure: data flows one way; the library imports and runs without the command line."""

import subprocess
import sys

import numpy as np
import pytest

from skintopo.errors import SkinTopoError
from skintopo.height import integrate_slopes
from skintopo.normals import photometric_stereo
from skintopo.registration import Registration, apply_registration
from tests.helpers.analytic import four_lights

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


def test_contract_violations_are_plain_value_errors_and_bad_input_is_a_skintopo_error():
    """Arrays of the wrong shape from a caller are a bug (``ValueError``, not the user-facing
    ``SkinTopoError``); a bad value given by the user is a ``SkinTopoError``."""
    lights = four_lights()[:3]
    contract_violations = [
        lambda: integrate_slopes(np.zeros((4, 4)), np.zeros((4, 5)), 1.0),
        lambda: photometric_stereo(np.zeros((2, 4, 4)), lights),
        lambda: apply_registration(np.zeros((4, 4, 3)), Registration((0.0, 0.0), 0.0, 1.0, 0.0)),
    ]
    for call in contract_violations:
        with pytest.raises(ValueError) as raised:
            call()
        assert not isinstance(raised.value, SkinTopoError), raised.value
    with pytest.raises(SkinTopoError, match="unknown solver"):
        photometric_stereo(np.zeros((3, 4, 4)), lights, solver="magic")
