"""Benchmark: visit registration (registration.register_height_maps) on 512 x 512 pairs with a known
rotation and sub-pixel shift: time and recovered parameters (the test suite checks the
accuracy on 256 x 256). Results: bench/results/registration.json.
"""

import sys
import time
from pathlib import Path

from _results import write_result  # bench/_results.py (scripts run from bench/)

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the repository, for tests.helpers
from tests.helpers.transforms import transformed_view  # noqa: E402

from skintopo.registration import register_height_maps  # noqa: E402
from skintopo.heightmap import HeightMap  # noqa: E402
from skintopo.synth import make_surface, preset_spec  # noqa: E402

CASES = [(3.7, (1.3, -2.6)), (-5.0, (0.4, 0.7)), (0.8, (-3.25, 2.1))]


def main():
    big = make_surface(preset_spec("forehead-moderate", size_px=704), seed=3).height.z
    baseline = HeightMap(transformed_view(big, 512, 96, 0.0, (0, 0)), 20.0)
    rows = []
    for angle, shift in CASES:
        follow_up = HeightMap(transformed_view(big, 512, 96, angle, shift), 20.0)
        start = time.perf_counter()
        _, registration = register_height_maps(baseline, follow_up)
        seconds = time.perf_counter() - start
        rows.append({"true_rotation_deg": angle, "true_shift_px": list(shift), "rotation_deg": round(registration.rotation_deg, 6),
                     "shift_px": [round(v, 6) for v in registration.shift_px], "seconds": round(seconds, 2)})
        print(rows[-1], flush=True)
    write_result("registration", {"benchmark": "register_visits on 512 x 512 forehead pairs", "cases": rows,
                                  "seconds_mean": round(sum(r["seconds"] for r in rows) / len(rows), 2)})


if __name__ == "__main__":
    main()
