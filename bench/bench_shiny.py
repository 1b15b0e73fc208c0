"""Benchmark: photometric stereo on shiny objects (issue "shiny skin"): mean angular error
(degrees) of plain least squares (no exclusion), the default least squares (shadow rule),
the robust solver, and both with the cross-band specular separation, on a sphere and a
wrinkled skin patch with a rough dielectric coat (Beckmann m = 0.1 / 0.2 / 0.4, surface
reflection 1x and 10x the skin default; 0 = no coat), under 4, 12 and 50 lights, rendered by the
simulator (tests/helpers/shiny.py); green band and the white (mean) band. Also the time of the
robust solver against least squares on 12 images of 1000 x 1000.
Results: bench/results/shiny.json.
"""

import sys
import time
from pathlib import Path

import numpy as np
from _results import write_result  # bench/_results.py (scripts run from bench/)

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the repository, for tests.helpers
from tests.helpers.shiny import light_set, render, skin_patch, sphere  # noqa: E402

from skintopo.normals import angular_error_degrees, photometric_stereo, separate_specular  # noqa: E402

CASES = [(0, 0.35), (1, 0.35), (10, 0.1), (10, 0.2), (10, 0.4)]


def errors(images, separation, band, lights, truth, mask):
    runs = {
        "plain": photometric_stereo(images[band], lights, shadow_fraction=0.0, specular_lobe=False),
        "default": photometric_stereo(images[band], lights),
        "robust": photometric_stereo(images[band], lights, solver="robust"),
        "cross-band default": photometric_stereo(images[band], lights, highlights=separation.highlights(images[band], band=band)),
        "cross-band robust": photometric_stereo(images[band], lights, solver="robust", highlights=separation.highlights(images[band], band=band)),
    }
    return {name: round(float(np.nanmean(angular_error_degrees(r.normals, truth)[mask])), 3) for name, r in runs.items()}


def main():
    table = []
    for name, (height, normals, mask) in (("sphere", sphere()), ("skin patch", skin_patch())):
        for count in (4, 12, 50):
            lights = light_set(count)
            for strength, roughness in CASES:
                images = render(height, normals, lights, specular_strength=strength, roughness=roughness)
                images["white"] = (images["red"] + images["green"] + images["blue"]) / 3
                separation = separate_specular(images["red"], images["green"], images["blue"])
                for band in ("green", "white"):
                    row = {"object": name, "lights": count, "specular_scale": strength, "roughness": roughness, "band": band}
                    row.update(errors(images, separation, band, lights, normals, mask))
                    table.append(row)
                    print(" ".join(f"{v}" for v in row.values()), flush=True)
    lights = light_set(12)  # speed on a realistic scene: a shiny sphere, 12 lights, 1000 x 1000
    height, normals, _ = sphere(size_px=1000, pixel_um=2.0)
    images = render(height, normals, lights, specular_strength=1.0)["green"]
    seconds = {}
    for solver in ("least-squares", "robust"):
        best = np.inf
        for _ in range(3):
            start = time.perf_counter()
            photometric_stereo(images, lights, solver=solver)
            best = min(best, time.perf_counter() - start)
        seconds[solver] = round(best, 3)
    write_result("shiny", {"benchmark": "mean angular error (deg) on simulated shiny objects; robust vs least-squares time",
                           "table": table, "seconds_12_images_1000x1000": seconds,
                           "robust_over_least_squares": round(seconds["robust"] / seconds["least-squares"], 2)})


if __name__ == "__main__":
    main()
