"""The seven one-line bugs of issue 25 that once passed every test, planted again one at a time.

``python bench/mutation_blind_spots.py``: for each, a copy of ``src/`` and ``tests/`` gets the
bug and the fast tests of the module run against it; the line printed names the first test
that fails (KILLED) or says SURVIVED. The working tree is never touched.
"""

import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent

# (bug, file, original text, planted text, the module's tests)
BLIND_SPOTS = [
    ("normals: the residual divided by all lights, not the lights used", "src/skintopo/normals.py",
     "residual = np.sqrt(np.add.reduce(error, axis=0) / count)", "residual = np.sqrt(np.add.reduce(error, axis=0) / m)",
     "tests/normals"),
    ("filters: the FFT Gaussian's row and column sigmas swapped", "src/skintopo/filters.py",
     "((sigmas[0] * fy) ** 2 + (sigmas[1] * fx) ** 2)", "((sigmas[1] * fy) ** 2 + (sigmas[0] * fx) ** 2)", "tests/filters"),
    ("correction: the feathered weight halved at the border", "src/skintopo/correction.py",
     "gaussian_filter(wrinkle_mask.astype(float), sigma) * 2)", "gaussian_filter(wrinkle_mask.astype(float), sigma) * 1)",
     "tests/correction"),
    ("wrinkles: orientation off by 90 degrees", "src/skintopo/wrinkles.py",
     "return axial_mean_deg(self.frame.direction_deg()[self._line[0]])",
     "return (axial_mean_deg(self.frame.direction_deg()[self._line[0]]) + 90) % 180", "tests/wrinkles"),
    ("acquisition: the sRGB decoding exponent inverted", "src/skintopo/acquisition/radiometry.py",
     "((values + 0.055) / 1.055) ** 2.4", "((values + 0.055) / 1.055) ** (1 / 2.4)", "tests/acquisition"),
    ("formats: a mesh mirrored in y", "src/skintopo/formats.py",
     "np.column_stack([c.ravel() * dx, -r.ravel() * dy,", "np.column_stack([c.ravel() * dx, r.ravel() * dy,", "tests/formats"),
    ("batch: the fingerprint ignores file contents", "src/skintopo/batch.py",
     "digest.update(block)", "pass", "tests/batch"),
]


def main():
    survived = 0
    for number, (bug, file, original, planted, tests) in enumerate(BLIND_SPOTS, start=1):
        with tempfile.TemporaryDirectory() as folder:
            copy = Path(folder)
            for part in ("src", "tests"):
                shutil.copytree(ROOT / part, copy / part, ignore=shutil.ignore_patterns("__pycache__"))
            shutil.copy(ROOT / "pyproject.toml", copy)
            source = copy / file
            text = source.read_text()
            if text.count(original) != 1:
                raise SystemExit(f"{file}: the line of blind spot {number} has changed; update this script")
            source.write_text(text.replace(original, planted))
            environment = {**os.environ, "PYTHONPATH": f"{copy / 'src'}{os.pathsep}{copy}"}
            run = subprocess.run([sys.executable, "-m", "pytest", "-q", "-x", "-m", "not slow", "-p", "no:cacheprovider", tests],
                                 cwd=copy, env=environment, capture_output=True, text=True)
        failed = next((line for line in run.stdout.splitlines() if line.startswith("FAILED")), None)
        survived += run.returncode == 0
        verdict = "SURVIVED" if run.returncode == 0 else f"KILLED by {failed.split()[1]}" if failed else f"KILLED (pytest exit {run.returncode})"
        print(f"{number}. {bug}: {verdict}", flush=True)
    sys.exit(1 if survived else 0)


if __name__ == "__main__":
    main()
