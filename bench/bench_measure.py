"""Benchmark: `skintopo measure`, measured side by side in one run (issue 21).

1. A 1000 x 1000 acquisition of 16 images (4 lights x red/green/blue/white; simulated first,
   not timed, interreflection off to keep the set-up short), report included, default height
   method: the `measure` command called in this process (imports already made), and the
   whole process (`python -m skintopo.cli measure`). Target: under 3 s.
2. A 1024 x 1024 height map (forehead-moderate, 20 um pixels, x3p): the whole process of
   `skintopo measure` against surfalize's ``Surface.roughness_parameters()`` on the same
   surface (the call alone, after a warm-up, in this process; surfalize is GPL, used only here
   and in the tests), five runs of each taken in turn. Target: ratio at most 1.0.
3. Before and after: what the machine's second core gives at the moment (``two_core_speedup``),
   since skintopo's measure uses two threads and surfalize's call one.

Best of 3 runs each (5 for the height map), medians beside. The package's bytecode is compiled first (``compileall``),
as after a first run on a normal install: with PYTHONDONTWRITEBYTECODE set (as on some build
machines) every new process would otherwise compile skintopo's sources again (about 0.1 s).
Results: bench/results/measure.json.
"""

import compileall
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
import scipy.fft
from _results import write_result  # bench/_results.py (scripts run from bench/)

import skintopo
from skintopo.cli import main
from skintopo.formats import write_height
from skintopo.synth import Effects, default_settings, make_surface, preset_spec, simulate_acquisition, write_synthetic_acquisition

RUNS = 3


def timings(*calls, runs=RUNS):
    """(best, median) in seconds of each of ``calls``, ``runs`` calls of each taken in turn
    (so that the machine's drift falls on all alike); one call: its (best, median)."""
    times = [[] for _ in calls]
    for _ in range(runs):
        for call, kept in zip(calls, times):
            start = time.perf_counter()
            call()
            kept.append(time.perf_counter() - start)
    results = [(round(min(t), 2), round(float(np.median(t)), 2)) for t in times]
    return results[0] if len(calls) == 1 else results


def two_core_speedup():
    """How much the machine's second core gives at the moment: the work of two threads (each 5
    FFTs of 2048^2, single-threaded) over the time of one doing half of it, ideally 2. skintopo's
    measure runs on two threads and surfalize's call on one, so the ratio depends on it (on the
    slow evening of 2026-12-06 each of two threads ran up to 1.6x slower than one alone)."""
    image = np.random.default_rng(0).random((2048, 2048))

    def work():
        for _ in range(5):
            scipy.fft.rfft2(image, workers=1)

    work()  # warm-up
    start = time.perf_counter()
    work()
    one = time.perf_counter() - start
    threads = [threading.Thread(target=work) for _ in range(2)]
    start = time.perf_counter()
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    two = time.perf_counter() - start
    return {"one_thread_seconds": round(one, 3), "two_threads_twice_the_work_seconds": round(two, 3), "speedup": round(2 * one / two, 2)}


def measure_process(source, out):
    """``skintopo measure`` as a new Python process, as a user runs it."""
    subprocess.run([sys.executable, "-m", "skintopo.cli", "measure", str(source), "-o", str(out), "-q", "--overwrite"], check=True)


def main_bench():
    compileall.compile_dir(Path(skintopo.__file__).parent, quiet=1)
    before = two_core_speedup()
    with tempfile.TemporaryDirectory() as folder:
        folder = Path(folder)
        surface = make_surface(preset_spec("forehead-moderate", size_px=1000), seed=0)
        settings = default_settings(effects=Effects(interreflection=False))
        bands, info = simulate_acquisition(surface, settings, seed=0)
        write_synthetic_acquisition(folder / "acq", surface, bands, settings=settings, seed=0, info=info)
        in_process = timings(lambda: main(["measure", str(folder / "acq"), "-o", str(folder / "out"), "-q", "--overwrite"]))
        process = timings(lambda: measure_process(folder / "acq", folder / "out"))
        report_bytes = (folder / "out" / "report.html").stat().st_size

        z = make_surface(preset_spec("forehead-moderate", size_px=1024), seed=0).height.z
        write_height(folder / "h.x3p", z, (20.0, 20.0))
        from surfalize import Surface

        Surface(z.copy(), 20.0, 20.0).roughness_parameters()  # warm-up
        # interleaved, so that the machine's drift (20-30% within minutes on the shared 2-core
        # machine) falls on both alike
        height_process, surfalize = timings(lambda: measure_process(folder / "h.x3p", folder / "out_h"),
                                            lambda: Surface(z.copy(), 20.0, 20.0).roughness_parameters(), runs=2 * RUNS - 1)
    result = {
        "acquisition": {"benchmark": "skintopo measure, 1000x1000 acquisition, 16 images (4 lights x red/green/blue/white), report included",
                        "seconds_in_process": in_process[0], "median_seconds_in_process": in_process[1],
                        "seconds_whole_process": process[0], "median_seconds_whole_process": process[1],
                        "target_seconds": 3, "report_bytes": report_bytes},
        "height_map": {"benchmark": "1024x1024 height map (forehead-moderate, 20 um): whole process of skintopo measure (report included) "
                                    "vs surfalize's roughness_parameters() call on the same surface",
                       "skintopo_measure_process_seconds": height_process[0], "skintopo_median_seconds": height_process[1],
                       "surfalize_roughness_parameters_seconds": surfalize[0], "surfalize_median_seconds": surfalize[1],
                       "ratio": round(height_process[0] / surfalize[0], 2), "ratio_of_medians": round(height_process[1] / surfalize[1], 2),
                       "target_ratio": 1.0, "statistic": f"best of {2 * RUNS - 1} runs taken in turn with surfalize's, medians beside"},
        "statistic": f"best of {RUNS} runs, medians beside",
        "two_core_speedup": {"before": before, "after": two_core_speedup()},
    }
    write_result("measure", result)


if __name__ == "__main__":
    main_bench()
