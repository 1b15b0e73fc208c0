"""Benchmark: simulate a forehead acquisition with every effect on (shadows, converged
interreflection, specular, translucency, noise): 12 band images plus the white band.
Targets (issue 3): 512 x 512 under 30 s, 1024 x 1024 under 2 minutes on 2 cores.
Results: bench/results/synth.json.
"""

import time

from _results import write_result  # bench/_results.py (scripts run from bench/)

from skintopo.synth import default_settings, make_surface, preset_spec, simulate_acquisition


def main():
    rows = []
    for size in (512, 1024):
        start = time.perf_counter()
        surface = make_surface(preset_spec("forehead-moderate", size_px=size), seed=0)
        surface_s = time.perf_counter() - start
        bands, info = simulate_acquisition(surface, default_settings(), seed=0)
        total = time.perf_counter() - start
        rows.append({
            "size_px": size,
            "seconds_surface": round(surface_s, 2),
            "seconds_render": round(info["seconds_render"], 2),
            "seconds_total": round(total, 2),
            "target_seconds": 30 if size == 512 else 120,
            "interreflection_nonzeros": info["interreflection_nonzeros"],
            "max_radiosity_iterations": max(info["iterations"].values()),
        })
        print(rows[-1])
    result = {"benchmark": "simulate_acquisition, forehead-moderate, all effects, 20 um pixels", "runs": rows}
    write_result("synth", result)


if __name__ == "__main__":
    main()
