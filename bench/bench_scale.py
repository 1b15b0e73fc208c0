"""Benchmark: a 20-megapixel acquisition end to end (issue 21).

`skintopo synth --size 4472 --no-interreflection` (4472 x 4472 = 20.0 megapixels, 16 images;
about 8 minutes and 10 GiB, not part of the target), then `reconstruct`, `correct` and
`measure` with their default options, each as a new process, as a user runs them: wall time
and peak memory (the process's own maximum resident set, getrusage). Target: every peak at
most 8 GiB. ``python bench_scale.py [--size N]`` (a smaller field for a quick look). Results:
bench/results/scale.json (scale-N.json for another size).
"""

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from _results import write_result  # bench/_results.py (scripts run from bench/)

# the command, then its own peak resident memory (Linux: kilobytes) on the last line of stderr
RUN = ("import resource, sys\nfrom skintopo.cli import main\ncode = main(sys.argv[1:])\n"
       "print(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss, file=sys.stderr)\nsys.exit(code)")


def run(*args):
    start = time.perf_counter()
    done = subprocess.run([sys.executable, "-c", RUN, *map(str, args)], capture_output=True, text=True)
    seconds = time.perf_counter() - start
    if done.returncode != 0:
        raise SystemExit(f"skintopo {' '.join(map(str, args))} failed:\n{done.stderr}")
    return {"seconds": round(seconds, 1), "peak_gib": round(int(done.stderr.strip().splitlines()[-1]) / 2**20, 2)}


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--size", type=int, default=4472, help="field size in pixels (square; default 4472, 20 megapixels)")
    size = parser.parse_args().size
    with tempfile.TemporaryDirectory() as folder:
        folder = Path(folder)
        acquisition = folder / "acq"
        result = {"benchmark": f"{size} x {size} acquisition ({size * size / 1e6:.1f} megapixels, 16 images, forehead-moderate, "
                               "no interreflection), each command a new process with its default options",
                  "target_peak_gib": 8, "synth": run("synth", "-o", acquisition, "--size", size, "--no-interreflection", "-q")}
        for command in ("reconstruct", "correct", "measure"):
            result[command] = run(command, acquisition, "-o", folder / command, "-q")
        summary = json.loads((folder / "measure" / "summary.json").read_text())
        result["measure"]["wrinkles"] = summary["wrinkle_totals"]["count"]
    write_result("scale" if size == 4472 else f"scale-{size}", result)


if __name__ == "__main__":
    main()
