"""Benchmark: photometric stereo for 12 images of 1000 x 1000 (4 lights x red, green, blue)
plus one DCT-Poisson integration. Target (issue 2): under 0.5 s on 2 cores, peak memory
under 1 GiB. Reproducible: fixed seed; run `python bench/bench_reconstruct.py`.

Results are written to bench/results/reconstruct.json.
"""

import time
import tracemalloc

import numpy as np
from _results import write_result  # bench/_results.py (scripts run from bench/)

from skintopo.height import dct_poisson, normals_to_gradients
from skintopo.normals import photometric_stereo, render_lambertian

SIZE = 1000
REPEATS = 5


def make_bands():
    rng = np.random.default_rng(0)
    rows, columns = np.mgrid[:SIZE, :SIZE] * 20.0
    z = 40 * np.sin(rows / 300) * np.cos(columns / 170) + 2 * rng.standard_normal((SIZE, SIZE))
    gy, gx = np.gradient(z, 20.0)
    normals = np.dstack([-gx, gy, np.ones_like(z)])
    normals /= np.linalg.norm(normals, axis=2, keepdims=True)
    slant, tilt = np.radians(45), np.radians([0, 90, 180, 270])
    lights = np.stack([np.sin(slant) * np.cos(tilt), np.sin(slant) * np.sin(tilt), np.full(4, np.cos(slant))], 1)
    bands = {}
    for band, albedo in (("red", 0.6), ("green", 0.41), ("blue", 0.33)):
        images = render_lambertian(normals, albedo, lights).astype(np.float32)
        # 2% of observations cast-shadowed and 0.5% saturated, so the per-pixel exclusion path runs too
        images[rng.random(images.shape) < 0.02] *= 0.01
        images[rng.random(images.shape) < 0.005] = np.nan
        bands[band] = (images, lights)
    return bands


def run(bands, solver="least-squares"):
    start = time.perf_counter()
    results = {band: photometric_stereo(images, lights, solver=solver) for band, (images, lights) in bands.items()}
    middle = time.perf_counter()
    p, q = normals_to_gradients(results["red"].normals)
    dct_poisson(p, q, 20.0)
    end = time.perf_counter()
    return middle - start, end - middle


def main():
    bands = make_bands()
    run(bands)  # warm-up
    timings = [run(bands) for _ in range(REPEATS)]
    tracemalloc.start()
    run(bands)
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    robust_s = min(run(bands, "robust")[0] for _ in range(REPEATS))
    normals_s = min(t[0] for t in timings)
    integration_s = min(t[1] for t in timings)
    result = {
        "benchmark": "normals for 12 images of 1000x1000 (3 bands x 4 lights) + one DCT-Poisson integration",
        "seconds_normals_all_bands": round(normals_s, 4),
        "seconds_dct_integration": round(integration_s, 4),
        "seconds_total": round(normals_s + integration_s, 4),
        "target_seconds": 0.5,
        "seconds_robust_normals_all_bands": round(robust_s, 4),
        "robust_over_least_squares": round(robust_s / normals_s, 2),
        "target_robust_ratio": 5,
        "peak_memory_mib": round(peak / 2**20, 1),
        "peak_memory_note": "tracemalloc peak of NumPy allocations during the run, input images excluded",
        "target_peak_memory_mib": 1024,
        "repeats": REPEATS,
    }
    write_result("reconstruct", result)


if __name__ == "__main__":
    main()
