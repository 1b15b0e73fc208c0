"""Benchmark: a 20-megapixel acquisition end to end (issue 21).

`skintopo synth --size 4472 --no-interreflection` (4472 x 4472 = 20.0 megapixels, 16 images;
about 8 minutes and 10 GiB, not part of the target), then `reconstruct`, `correct` and
`measure` with their default options, each as a new process, as a user runs them: wall time
and peak memory (the process's own maximum resident set, getrusage). Target: every peak at
most 8 GiB. ``python bench_scale.py [--size N]`` (a smaller field for a quick look). Results:
bench/results/scale.json (scale-N.json for another size).

``--camera``: the issue's camera frame instead, 5472 x 3648 (20.0 megapixels) with 12 images
(red, green and blue; no white): a 5472 x 5472 field is synthesised (about 14 GiB, not part of
the target) and its top 3648 rows and colour bands written as the acquisition.
Results: bench/results/scale-5472x3648.json.
"""

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from _results import write_result  # bench/_results.py (scripts run from bench/)

from skintopo.formats import read_png, write_png

CAMERA = (5472, 3648)  # columns, rows: a 20-megapixel dermatology camera's frame

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


def camera_frame(synthesised, acquisition):
    """The top ``CAMERA[1]`` rows of a square ``synthesised`` acquisition, colour bands only."""
    manifest = json.loads((synthesised / "acquisition.json").read_text())
    manifest["images"] = [image for image in manifest["images"] if image["band"] != "white"]
    acquisition.mkdir()
    for name in [image["file"] for image in manifest["images"]] + [manifest["mask"]]:
        write_png(acquisition / name, read_png(synthesised / name)[:CAMERA[1]])
    (acquisition / "acquisition.json").write_text(json.dumps(manifest, indent=2))


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--size", type=int, default=4472, help="field size in pixels (square; default 4472, 20 megapixels)")
    parser.add_argument("--camera", action="store_true", help=f"a {CAMERA[0]} x {CAMERA[1]} frame with 12 images instead")
    arguments = parser.parse_args()
    size = CAMERA[0] if arguments.camera else arguments.size
    with tempfile.TemporaryDirectory() as folder:
        folder = Path(folder)
        acquisition = folder / "acq"
        synth = run("synth", "-o", acquisition, "--size", size, "--no-interreflection", "-q")
        if arguments.camera:
            camera_frame(acquisition, folder / "frame")
            acquisition, rows, images, name = folder / "frame", CAMERA[1], 12, "scale-{}x{}".format(*CAMERA)
        else:
            rows, images, name = size, 16, "scale" if size == 4472 else f"scale-{size}"
        result = {"benchmark": f"{size} x {rows} acquisition ({size * rows / 1e6:.1f} megapixels, {images} images, forehead-moderate, "
                               "no interreflection), each command a new process with its default options",
                  "target_peak_gib": 8, "synth": synth}
        for command in ("reconstruct", "correct", "measure"):
            result[command] = run(command, acquisition, "-o", folder / command, "-q")
        summary = json.loads((folder / "measure" / "summary.json").read_text())
        result["measure"]["wrinkles"] = summary["wrinkle_totals"]["count"]
    write_result(name, result)


if __name__ == "__main__":
    main()
