"""Benchmark: every areal, volume and functional parameter plus the four fractal estimators
on a 1024 x 1024 map in one call (skintopo.texture.measure_texture), against surfalize
computing its equivalent set (no fractal dimension: surfalize has none) in the same run:
its least-squares plane levelling (``Surface.level``, our ``level_order=1``) and then the
same parameters.
Target (issue 5): at least 10x faster than surfalize. surfalize is GPL: it is only imported
here and in the tests, never by the package. Results: bench/results/texture.json.
"""

import time

import numpy as np
from _results import write_result  # bench/_results.py (scripts run from bench/)

from skintopo.heightmap import HeightMap
from skintopo.texture import measure_texture

SURFALIZE_SET = ("Sa", "Sq", "Ssk", "Sku", "Sp", "Sv", "Sz", "Sdq", "Sdr", "Sal", "Str", "Std",
                 "Sk", "Spk", "Svk", "Smr1", "Smr2", "Sxp", "Vmp", "Vmc", "Vvc", "Vvv")


def surface(size=1024):
    rng = np.random.default_rng(0)
    k = np.hypot(np.fft.fftfreq(size)[:, None], np.fft.fftfreq(size)[None, :])
    k[0, 0] = np.inf
    z = np.real(np.fft.ifft2(k**-1.7 * (rng.standard_normal((size, size)) + 1j * rng.standard_normal((size, size)))))
    return z / z.std() * 10


def main():
    z = surface()
    height = HeightMap(z, 1.0)
    measure_texture(height)  # warm-up
    ours = []
    for _ in range(10):
        start = time.perf_counter()
        measure_texture(height)
        ours.append(time.perf_counter() - start)
    result = {"benchmark": "1024x1024: areal + volume + functional parameters and 4 fractal estimators in one call",
              "statistic": "best of 10 runs (skintopo) and of 3 runs (surfalize, about 1 s each), as timeit reports; medians beside",
              "skintopo_seconds": round(min(ours), 3), "skintopo_median_seconds": round(float(np.median(ours)), 3)}
    try:
        from surfalize import Surface
    except ImportError:
        result["surfalize_seconds"] = None
        result["note"] = "surfalize not installed (pip install surfalize) - no comparison"
    else:
        times = []
        for _ in range(3):
            raw = Surface(z.copy(), 1.0, 1.0)
            start = time.perf_counter()
            s = raw.level()
            for name in SURFALIZE_SET:
                getattr(s, name)()
            times.append(time.perf_counter() - start)
        result["surfalize_seconds"] = round(min(times), 3)
        result["surfalize_median_seconds"] = round(float(np.median(times)), 3)
        result["speedup"] = round(min(times) / min(ours), 1)
        result["speedup_of_medians"] = round(float(np.median(times) / np.median(ours)), 1)
        result["target_speedup"] = 10
    write_result("texture", result)


if __name__ == "__main__":
    main()
