"""Benchmark (issue 17): change detection on simulated visits of unchanged and treated skin.

Each trial is a new skin (forehead-moderate, 3 wrinkles, 256 x 256 at 20 um, surface seed =
trial) captured five times, each with new sensor noise and a new random shift of up to 40 um
(registration and resampling): the baseline, two repeat captures, a follow-up of the
unchanged skin and a follow-up where one wrinkle (chosen in turn) is 20% shallower. Heights
from the white band (least squares, DCT integration). The detection limits come from the
two repeats (``compare.detection_limits``, 99% confidence; also from the first repeat alone).

Reported: per parameter, the share of trials in which the unchanged follow-up is flagged
(issue 17: at most 5% for every parameter); the share in which the treated wrinkle's max and
mean depth are flagged (at least 95%); untouched wrinkles flagged in the treated follow-up.
Usage: python bench_change_detection.py [TRIALS]. Results: bench/results/change_detection.json
(50 trials, the issue's count), change_detection-TRIALS.json otherwise.
"""

import dataclasses
import sys

import numpy as np
from _results import write_result  # bench/_results.py (scripts run from bench/)

from skintopo.compare import compare_visits, detection_limits
from skintopo.height import integrate_normals
from skintopo.normals import photometric_stereo
from skintopo.results import comparison_rows
from skintopo.synth import default_settings, make_surface, preset_spec, simulate_acquisition


def capture(spec, surface_seed, noise_seed, rng):
    shifted = dataclasses.replace(spec, shift_um=tuple(rng.uniform(-40.0, 40.0, 2)))
    bands, _ = simulate_acquisition(make_surface(shifted, seed=surface_seed), default_settings(), seed=noise_seed, skin_seed=surface_seed)
    stereo = photometric_stereo(*bands["white"])
    return integrate_normals(stereo.normals, spec.pixel_um, mask=stereo.valid)


def flags(comparison, limits):
    return {row["parameter"]: bool(row["detectable"]) for row in comparison_rows(comparison, limits.limits) if row["detectable"] is not None}


def trial(index):
    rng = np.random.default_rng(10_000 + index)
    spec = preset_spec("forehead-moderate", size_px=256)
    treated_index = index % len(spec.wrinkles)
    wrinkles = list(spec.wrinkles)
    wrinkles[treated_index] = dataclasses.replace(wrinkles[treated_index], depth_um=0.8 * wrinkles[treated_index].depth_um)
    baseline, repeat_a, repeat_b, unchanged = (capture(spec, index, 100 * index + k, rng) for k in range(4))
    treated = capture(dataclasses.replace(spec, wrinkles=tuple(wrinkles)), index, 100 * index + 4, rng)
    repeats = [compare_visits(baseline, r) for r in (repeat_a, repeat_b)]
    limits_two, limits_one = detection_limits(repeats), detection_limits(repeats[:1])
    unchanged_comparison, treated_comparison = compare_visits(baseline, unchanged), compare_visits(baseline, treated)
    # the treated wrinkle's id in the baseline: the one whose centroid is nearest the spec's wrinkle
    rows, _ = spec.size_px
    truth_row = (rows - 1) / 2 - spec.wrinkles[treated_index].centre_um[1] / spec.pixel_um
    treated_id = min(treated_comparison.baseline_wrinkles.wrinkles, key=lambda w: abs(w.centroid_y_mm * 1000 / spec.pixel_um - truth_row)).id
    return {
        "unchanged_two_repeats": flags(unchanged_comparison, limits_two),
        "unchanged_one_repeat": flags(unchanged_comparison, limits_one),
        "treated_two_repeats": flags(treated_comparison, limits_two),
        "treated_one_repeat": flags(treated_comparison, limits_one),
        "treated_id": treated_id,
        "treated_change_percent": treated_comparison.wrinkles[treated_id].get("max_depth_um", {}).get("change_percent"),
        "wrinkles_found": len(treated_comparison.baseline_wrinkles.wrinkles),
    }


def rates(trials, key):
    names = sorted({name for t in trials for name in t[key]})
    return {name: float(np.mean([t[key].get(name, False) for t in trials])) for name in names}


def main(n):
    trials = [trial(i) for i in range(n)]
    result = {"benchmark": f"change detection, {n} trials of simulated visits (issue 17)", "confidence": 0.99}
    for repeats in ("two_repeats", "one_repeat"):
        false_rates = rates(trials, f"unchanged_{repeats}")
        treated = [t for t in trials if t[f"treated_{repeats}"]]
        hit = {name: float(np.mean([t[f"treated_{repeats}"].get(f"wrinkle{t['treated_id']}.{name}", False) for t in treated]))
               for name in ("max_depth_um", "mean_depth_um", "volume_mm3")}
        untouched = [flag for t in treated for parameter, flag in t[f"treated_{repeats}"].items()
                     if parameter.startswith("wrinkle") and not parameter.startswith(("wrinkles.", f"wrinkle{t['treated_id']}."))]
        result[repeats] = {
            "unchanged_flag_rate_worst": max(false_rates.values()),
            "unchanged_flag_rate_worst_parameter": max(false_rates, key=false_rates.get),
            "parameters_flagged_in_more_than_5_percent": sorted(k for k, v in false_rates.items() if v > 0.05),
            "unchanged_flag_rates": false_rates,
            "treated_wrinkle_flag_rate": hit,
            "untouched_wrinkle_measures_flagged_in_treated": float(np.mean(untouched)) if untouched else None,
        }
    result["treated_max_depth_change_percent"] = [t["treated_change_percent"] for t in trials]
    write_result("change_detection" if n == 50 else f"change_detection-{n}", result)


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 50)
