"""Benchmark: `skintopo measure` on a 1000 x 1000 acquisition of 12 images (+ white), report
included. Target (issue 8): under 10 s on 2 cores. The acquisition is simulated first (not
timed; interreflection off to keep the set-up short). Results: bench/results/measure.json.
"""

import tempfile
import time
from pathlib import Path

from _results import write_result  # bench/_results.py (scripts run from bench/)

from skintopo.cli import main
from skintopo.synth import Effects, default_settings, make_surface, preset_spec, simulate_acquisition, write_synthetic_acquisition


def main_bench():
    with tempfile.TemporaryDirectory() as folder:
        folder = Path(folder)
        surface = make_surface(preset_spec("forehead-moderate", size_px=1000), seed=0)
        settings = default_settings(effects=Effects(interreflection=False))
        bands, info = simulate_acquisition(surface, settings, seed=0)
        write_synthetic_acquisition(folder / "acq", surface, bands, settings=settings, seed=0, info=info)
        start = time.perf_counter()
        assert main(["measure", str(folder / "acq"), "-o", str(folder / "out"), "-q"]) == 0
        seconds = time.perf_counter() - start
        size = (folder / "out" / "report.html").stat().st_size
    result = {"benchmark": "skintopo measure, 1000x1000 acquisition, 16 images (4 lights x red/green/blue/white), report included",
              "seconds": round(seconds, 2), "target_seconds": 10, "report_bytes": size}
    write_result("measure", result)


if __name__ == "__main__":
    main_bench()
