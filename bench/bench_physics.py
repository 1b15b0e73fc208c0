"""Benchmark: the physically based height (``--method physics``) against every band and the
paper's correction, in the simulator: forehead-low / -moderate / -high x light / dark skin x
seeds 1-6, 256 x 256 at 20 um, all effects on. RMS height error (um) and mean |relative
error| of the wrinkles' max depth, per method; physics also with the skin-optics profile's
true diffusion profiles given as its kernels ("physics-given-kernels": what estimating the
kernels costs) and with kernels from a simulated calibration capture ("physics-edge-calibrated":
a black mask's edge on the same skin, ``skintopo calibrate skin``); an ablation (each component off) on seed 1;
and, with ``--speed``, the time of physics on a 1000 x 1000 acquisition (12 images; median of
3 runs in one process, each run's time recorded).
Results: bench/results/physics.json and physics_speed.json.

Run from bench/: ``python bench_physics.py [SEEDS] [--optics PROFILE]`` (default 6 seeds, the
default-v1 skin optics; another profile writes physics-PROFILE.json; ``--physics-solver robust``
adds -robust to the name), ``python bench_physics.py --speed``.
"""

import argparse
import sys
import time

import numpy as np
from _results import write_result  # bench/_results.py (scripts run from bench/)

from skintopo.calibration import diffusion_profile_from_edge
from skintopo.correction import spectral_correction
from skintopo.defaults import DEFAULT_SKIN_OPTICS, DEFAULT_SOLVER
from skintopo.evaluation import evaluate_height
from skintopo.height import integrate_normals
from skintopo.normals import photometric_stereo
from skintopo.physics import physics_height
from skintopo.synth import make_surface, optics_profile, preset_spec, simulate_acquisition
from skintopo.synth.render import RenderSettings, default_lights
from skintopo.synth.targets import skin_edge_images

BANDS = ("red", "green", "blue", "white")
ABLATIONS = {"physics": {}, "no-scattering": {"scattering": False}, "no-interreflection": {"interreflection": False},
             "no-highlights": {"highlights": False}}


def scores(height, surface):
    try:
        found = evaluate_height(height, surface.height, wrinkle_labels=surface.wrinkle_labels)
    except Exception as error:  # a failed reconstruction is a result too
        return {"rms_um": float("inf"), "depth_error": float("inf"), "depth_bias": float("nan"), "failed": str(error)}
    return {"rms_um": round(found["rms_height_error_um"], 3),
            "depth_error": round(float(np.mean(found["wrinkle_depth_error_relative"])), 4),
            "depth_bias": round(float(np.mean(np.array(found["wrinkle_max_depth_um"]) / found["wrinkle_max_depth_true_um"] - 1)), 4)}


def edge_calibrated_kernels(optics, skin, seed):
    """Kernels from a simulated calibration capture: a black mask's edge on another patch of the
    same skin (skintopo.synth.targets.skin_edge_images, 1024 x 512 at 20 um: a 20 mm edge), through
    skintopo.calibration.diffusion_profile_from_edge."""
    images, _ = skin_edge_images(optics_profile(optics), skin, default_lights(), shape=(1024, 512), pixel_um=20.0, seed=1000 + seed)
    return {band: diffusion_profile_from_edge(images[band], 20.0)[0] for band in ("red", "green", "blue")}


def case(preset, skin, seed, ablation, optics=DEFAULT_SKIN_OPTICS, solver=DEFAULT_SOLVER):
    surface = make_surface(preset_spec(preset, size_px=256), seed=seed)
    settings = RenderSettings(skin=skin, lights=default_lights(), optics=optics_profile(optics))
    bands, info = simulate_acquisition(surface, settings, seed=seed)
    images = {band: bands[band][0] / info["exposure_gain"][band] for band in BANDS}
    lights = bands["red"][1]
    row, normals = {}, {}
    for band in BANDS:
        stereo = photometric_stereo(images[band], lights)
        normals[band] = stereo.normals
        row[band] = scores(integrate_normals(stereo.normals, 20.0, mask=stereo.valid), surface)
    for method in ("paper", "feathered"):
        row[method] = scores(spectral_correction(normals, 20.0, method=method).height, surface)
    runs = list(ABLATIONS.items()) if ablation else [("physics", {})]
    runs.append(("physics-given-kernels", {"kernels": optics_profile(optics).scattering}))
    runs.append(("physics-edge-calibrated", {"kernels": edge_calibrated_kernels(optics, skin, seed)}))
    runs = [(name, switches | {"solver": solver}) for name, switches in runs]  # the profile's true diffusion profiles
    for name, switches in runs:
        start = time.perf_counter()
        result = physics_height(images, lights, 20.0, **switches)
        row[name] = scores(result.height, surface) | {"seconds": round(time.perf_counter() - start, 2),
                                                       "iterations": result.iterations, "converged": result.converged,
                                                       "plausible": result.plausible}
    return row


def main(seeds, optics, solver):
    cases = []
    for preset in ("forehead-low", "forehead-moderate", "forehead-high"):
        for skin in ("light", "dark"):
            for seed in range(1, seeds + 1):
                row = case(preset, skin, seed, ablation=seed == 1, optics=optics, solver=solver)
                cases.append({"preset": preset, "skin": skin, "seed": seed, "results": row})
                best_other = min(v["rms_um"] for k, v in row.items() if k in (*BANDS, "paper", "feathered"))
                print(preset, skin, seed, "physics", row["physics"]["rms_um"], "given kernels", row["physics-given-kernels"]["rms_um"],
                      "edge-calibrated", row["physics-edge-calibrated"]["rms_um"],
                      "best other", best_other, flush=True, file=sys.stderr)
    others = [*BANDS, "paper", "feathered"]
    summary = {m: {"mean_rms_um": round(float(np.mean([c["results"][m]["rms_um"] for c in cases])), 3),
                   "mean_depth_error": round(float(np.mean([c["results"][m]["depth_error"] for c in cases])), 4)}
               for m in (*others, "physics", "physics-given-kernels", "physics-edge-calibrated")}

    def best_cases(method, key):
        return f"{sum(all(c['results'][method][key] < c['results'][m][key] for m in others) for c in cases)}/{len(cases)}"

    flagged = sum(not c["results"]["physics"]["plausible"] for c in cases)
    name = "physics" + ("" if optics == DEFAULT_SKIN_OPTICS else f"-{optics}") + ("" if solver == DEFAULT_SOLVER else f"-{solver}")
    write_result(name, {
        "optics": optics, "physics_solver": solver, "summary": summary,
        "physics_best_rms_cases": best_cases("physics", "rms_um"), "physics_best_depth_cases": best_cases("physics", "depth_error"),
        "given_kernels_best_rms_cases": best_cases("physics-given-kernels", "rms_um"),
        "given_kernels_best_depth_cases": best_cases("physics-given-kernels", "depth_error"),
        "edge_calibrated_best_rms_cases": best_cases("physics-edge-calibrated", "rms_um"),
        "edge_calibrated_best_depth_cases": best_cases("physics-edge-calibrated", "depth_error"),
        "physics_flagged_implausible": f"{flagged}/{len(cases)}", "cases": cases})


def speed():
    surface = make_surface(preset_spec("forehead-moderate", size_px=1000), seed=1)
    bands, info = simulate_acquisition(surface, RenderSettings(lights=default_lights()), seed=1)
    images = {b: bands[b][0] / info["exposure_gain"][b] for b in ("red", "green", "blue")}
    seconds = []
    for _ in range(3):  # the first run pays the imports physics makes on first use (scipy.optimize)
        start = time.perf_counter()
        result = physics_height(images, bands["red"][1], 20.0)
        seconds.append(round(time.perf_counter() - start, 2))
    write_result("physics_speed", {"seconds_physics_1000x1000": float(np.median(seconds)), "seconds_runs": seconds,
                                   "target_seconds": 5.0, "iterations": result.iterations,
                                   "interreflection_grid_factor": result.components["interreflection_grid_factor"]})


if __name__ == "__main__":
    parser = argparse.ArgumentParser()
    parser.add_argument("seeds", nargs="?", type=int, default=6)
    parser.add_argument("--optics", default=DEFAULT_SKIN_OPTICS)
    parser.add_argument("--physics-solver", default=DEFAULT_SOLVER, help="photometric-stereo solver inside physics")
    parser.add_argument("--speed", action="store_true")
    arguments = parser.parse_args()
    speed() if arguments.speed else main(arguments.seeds, arguments.optics, arguments.physics_solver)
