"""Benchmark (issue 17): wrinkle measures against the geometry on random fields, detection, and
the speed of the wrinkle measures on a 1000 x 1000 map.

Fields: ``synth.random_wrinkle_spec`` (two wrinkles, V/U/G, 0.15-1.2 mm wide, 20-300 um deep,
2.5-5 mm long, straight or arcs of 5-50 mm radius; 384 x 384 pixels of 20 um), seeds 0..N-1:
microrelief (furrows 20-60 um and roughness) on even seeds, off on odd ones; every fifth seed a
crossing pair. Truth: ``synth.geometric_measures`` (the wrinkle alone, never filtered).

Reported: per measure, the share of found wrinkles within the issue's tolerance (5% max/mean
depth and length, 10% width and volume) and the median |error|; detection of every wrinkle at
least 30 um deep and 1.5 mm long at half depth; false wrinkles (a measured wrinkle whose
centre line lies on no simulated wrinkle's half-depth region). Usage: python bench_wrinkles.py [N]
Results: bench/results/wrinkles.json.
"""

import sys
import time

import numpy as np
from _results import write_result  # bench/_results.py (scripts run from bench/)

from skintopo.evaluation import match_wrinkle
from skintopo.segmentation import segment_wrinkles
from skintopo.synth import make_surface, preset_spec
from skintopo.synth.surfaces import geometric_measures, random_wrinkle_spec
from skintopo.wrinkles import measure_wrinkles

TOLERANCES = {"max_depth_um": 0.05, "mean_depth_um": 0.05, "mean_width_mm": 0.10, "length_mm": 0.05, "volume_mm3": 0.10}


def field(seed):
    rng = np.random.default_rng(seed)
    microrelief, crossing = seed % 2 == 0, seed % 5 == 4
    surface = make_surface(random_wrinkle_spec(rng, microrelief=microrelief, crossing=crossing), seed=seed)
    measures = measure_wrinkles(surface.height, segment_wrinkles(surface.height))
    rows = []
    for index, wrinkle in enumerate(surface.spec.wrinkles):
        truth = geometric_measures(wrinkle)
        measured = match_wrinkle(measures, surface.wrinkle_labels == index + 1)
        rows.append({
            "seed": seed, "microrelief": microrelief, "crossing": crossing, "shape": wrinkle.shape,
            "depth_um": wrinkle.depth_um, "width_um": wrinkle.width_um, "length_mm": truth["length_mm"],
            "radius_mm": abs(1 / wrinkle.curvature_per_mm) if wrinkle.curvature_per_mm else None,
            "found": measured is not None,
            "errors": None if measured is None else {k: getattr(measured, k) / truth[k] - 1 for k in TOLERANCES},
        })
    false = sum(not (surface.wrinkle_labels[measures.lines & (measures.labels == w.id)] > 0).any() for w in measures.wrinkles)
    return rows, false


def summary(rows, false_counts, fields):
    found = [r for r in rows if r["found"]]
    out = {"fields": fields, "wrinkles": len(rows), "found": len(found)}
    for name, tolerance in TOLERANCES.items():
        errors = np.array([r["errors"][name] for r in found])
        out[name] = {"within_tolerance": float(np.mean(np.abs(errors) <= tolerance)) if errors.size else None,
                     "median_abs_error": float(np.median(np.abs(errors))) if errors.size else None,
                     "worst_abs_error": float(np.max(np.abs(errors))) if errors.size else None}
    out["all_measures_within"] = float(np.mean([all(abs(r["errors"][k]) <= t for k, t in TOLERANCES.items()) for r in found]))
    detectable = [r for r in rows if r["depth_um"] >= 30 and r["length_mm"] >= 1.5]
    out["detectable_found"] = float(np.mean([r["found"] for r in detectable])) if detectable else None
    by_field = {}
    for r in detectable:
        by_field.setdefault(r["seed"], []).append(r["found"])
    out["fields_with_every_detectable_found"] = float(np.mean([all(v) for v in by_field.values()])) if by_field else None
    out["fields_without_false_wrinkle"] = float(np.mean([f == 0 for f in false_counts]))
    return out


def speed():
    surface = make_surface(preset_spec("forehead-moderate", size_px=1000), seed=1)
    segmentation = segment_wrinkles(surface.height)
    times = []
    for _ in range(3):
        start = time.perf_counter()
        measure_wrinkles(surface.height, segmentation)
        times.append(time.perf_counter() - start)
    return {"map": "forehead-moderate, 1000 x 1000 at 20 um, 3 wrinkles", "wrinkle_measures_s_best_of_3": min(times)}


def main(n):
    per_field = [field(seed) for seed in range(n)]
    rows = [r for field_rows, _ in per_field for r in field_rows]
    groups = {"all": lambda r: True, "smooth skin, no crossing": lambda r: not r["microrelief"] and not r["crossing"],
              "microrelief, no crossing": lambda r: r["microrelief"] and not r["crossing"], "crossing pairs": lambda r: r["crossing"]}
    result = {"benchmark": f"wrinkle measures against the geometry, {n} random fields (issue 17)", "tolerances": TOLERANCES}
    for name, keep in groups.items():
        seeds = sorted({r["seed"] for r in rows if keep(r)})
        result[name] = summary([r for r in rows if keep(r)], [per_field[s][1] for s in seeds], len(seeds))
    result["speed"] = speed()
    result["rows"] = rows
    write_result("wrinkles", result)


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 120)
