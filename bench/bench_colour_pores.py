"""Benchmark: melanin and haemoglobin maps, and pores (issue 26), against the simulator's truth.

Colour: forehead-low/-moderate/-high x light/dark skin x seeds 1-2 (384 px at 20 um), albedo
made from melanin and haemoglobin maps (skintopo.synth.render.Pigmentation), reconstructed by
least-squares photometric stereo per band, inverted by skintopo.chromophores (default 30 um
smoothing). Two renders per field: the topography effects (shading, cast shadows,
interreflection, translucency) and all effects (the same plus skin's surface reflection).
Per field and chromophore: correlation with the true map, the worst relative error of the
mean over the field and its four quadrants, and the wrinkle leak (inside minus outside the
wrinkles, estimate minus truth, in units of the truth's standard deviation).

Pores: 20 fields at 10 um pixels (512 px; the four presets in turn, microrelief plates of
0.7 mm) with 6 pores each (openings 0.05-0.5 mm, 30-150 um deep) placed on the plateaus,
measured on the true height (the geometry); and the same presets without pores at 20 and
10 um (false pores). Then 4 of the pore fields rendered and measured as `measure` does
(the paper's correction height), to show what photometric stereo leaves of a pore's depth.

Run from bench/: ``python bench_colour_pores.py``. Results: bench/results/colour_pores.json.
"""

import time
from dataclasses import replace

import numpy as np
from _results import write_result  # bench/_results.py (scripts run from bench/)

from skintopo.chromophores import RGB, chromophore_maps
from skintopo.normals import photometric_stereo
from skintopo.pores import measure_pores
from skintopo.synth import RenderSettings, make_surface, preset_spec, simulate_acquisition
from skintopo.synth.render import Effects, Pigmentation
from skintopo.synth.surfaces import place_pores

PRESETS = ("forehead-low", "forehead-moderate", "forehead-high", "flat-microrelief")


def colour_field(preset, skin, seed, effects):
    surface = make_surface(preset_spec(preset, size_px=384), seed=seed)
    bands, info = simulate_acquisition(surface, RenderSettings(skin=skin, pigmentation=Pigmentation(seed=seed), effects=effects), seed=seed)
    albedo = {b: photometric_stereo(bands[b][0] / info["exposure_gain"][b], bands[b][1]).albedo for b in RGB}
    maps = chromophore_maps(albedo, pixel_um=20.0)
    wrinkles = surface.wrinkle_labels > 0
    windows = [(slice(None), slice(None))] + [(slice(r, r + 192), slice(c, c + 192)) for r in (0, 192) for c in (0, 192)]
    scores = {}
    for name in ("melanin", "haemoglobin"):
        found, truth = getattr(maps, name), info["chromophores"][name]
        valid = np.isfinite(found)
        leak = (np.nanmean(found[wrinkles]) - np.nanmean(found[~wrinkles])) - (truth[wrinkles].mean() - truth[~wrinkles].mean())
        scores[name] = {"correlation": float(np.corrcoef(found[valid], truth[valid])[0, 1]),
                        "field_mean_error": float(np.nanmean(found) / truth.mean() - 1),
                        "worst_region_mean_error": float(max(abs(np.nanmean(found[w]) / truth[w].mean() - 1) for w in windows)),
                        "wrinkle_leak_sd": float(leak / truth.std())}
    return scores


def pore_field(seed, pixel=10.0, size=512, count=6):
    spec = replace(preset_spec(PRESETS[seed % 4], size_px=size, pixel_um=pixel), plate_um=700.0)
    spec = place_pores(spec, seed, count, radius_um=(25.0, 250.0), depth_um=(30.0, 150.0))
    return spec, make_surface(spec, seed=seed)


def matched(measures, surface, spec):
    """(per true pore: (opening um, depth um, area error, depth error) or None when missed
    or split), false pores (found where there is none)."""
    found, false = {}, 0
    for pore in measures.pores:
        ids = surface.pore_labels[measures.labels == pore.id]
        ids = ids[ids > 0]
        if ids.size == 0:
            false += 1
            continue
        found.setdefault(int(np.bincount(ids).argmax()), []).append(pore)
    rows = []
    for index, truth in enumerate(spec.pores, start=1):
        hits = found.get(index, [])
        area = np.pi * truth.radius_um**2 * 1e-6
        rows.append((2 * truth.radius_um, truth.depth_um, hits[0].area_mm2 / area - 1, hits[0].depth_um / truth.depth_um - 1)
                    if len(hits) == 1 else (2 * truth.radius_um, truth.depth_um, None, None))
    return rows, false


def main():
    result = {"colour": {}, "pores": {}}
    started = time.perf_counter()
    for label, effects in (("topography", Effects(specular=False)), ("all effects", Effects())):
        fields = {f"{preset} {skin} {seed}": colour_field(preset, skin, seed, effects)
                  for preset in PRESETS[:3] for skin in ("light", "dark") for seed in (1, 2)}
        summary = {}
        for name in ("melanin", "haemoglobin"):
            for skin in ("light", "dark"):
                chosen = [v[name] for k, v in fields.items() if f" {skin} " in k]
                summary[f"{name} {skin}"] = {"min_correlation": min(c["correlation"] for c in chosen),
                                             "worst_region_mean_error": max(c["worst_region_mean_error"] for c in chosen),
                                             "mean_field_error": float(np.mean([c["field_mean_error"] for c in chosen])),
                                             "largest_wrinkle_leak_sd": max(abs(c["wrinkle_leak_sd"]) for c in chosen)}
        result["colour"][label] = {"summary": summary, "fields": fields}
    result["colour"]["seconds"] = time.perf_counter() - started

    started = time.perf_counter()
    rows, false, counts_exact = [], 0, 0
    for seed in range(1, 21):
        spec, surface = pore_field(seed)
        field_rows, field_false = matched(measure_pores(surface.height), surface, spec)
        rows += field_rows
        false += field_false
        counts_exact += all(r[2] is not None for r in field_rows) and field_false == 0
    area = np.array([r[2] for r in rows if r[2] is not None])
    depth = np.array([r[3] for r in rows if r[3] is not None])
    no_pores = {f"{preset} {pixel:g} um seed {seed}": len(measure_pores(make_surface(preset_spec(preset, size_px=size, pixel_um=pixel), seed=seed).height).pores)
                for preset in PRESETS for pixel, size in ((20.0, 384), (10.0, 512)) for seed in (5, 6, 7)}
    result["pores"]["geometry"] = {
        "fields": 20, "pores": len(rows), "found": int(area.size), "false": false, "fields_with_exact_count": int(counts_exact),
        "area_error_mean": float(area.mean()), "area_error_worst": float(area[np.argmax(np.abs(area))]),
        "area_within_10_percent": int((np.abs(area) <= 0.10).sum()), "depth_error_mean": float(depth.mean()),
        "depth_error_worst": float(depth[np.argmax(np.abs(depth))]), "depth_within_10_percent": int((np.abs(depth) <= 0.10).sum()),
        "outside_10_percent": [{"opening_um": r[0], "depth_um": r[1], "area_error": r[2], "depth_error": r[3]}
                               for r in rows if r[2] is not None and (abs(r[2]) > 0.1 or abs(r[3]) > 0.1)],
        "false_pores_in_fields_without_pores": no_pores, "seconds": time.perf_counter() - started,
    }
    measured = []
    for seed in range(1, 5):  # rendered and measured: what photometric stereo leaves of the pores
        from skintopo.correction import spectral_correction

        spec, surface = pore_field(seed, size=384, count=4)
        bands, info = simulate_acquisition(surface, RenderSettings(), seed=seed)
        normals = {b: photometric_stereo(bands[b][0], bands[b][1]).normals for b in RGB}
        height = spectral_correction(normals, spec.pixel_um).height
        field_rows, field_false = matched(measure_pores(height), surface, spec)
        measured.append({"found": sum(r[2] is not None for r in field_rows), "pores": len(field_rows), "false": field_false,
                         "depth_ratio": [None if r[3] is None else 1 + r[3] for r in field_rows],
                         "true_depth_um": [r[1] for r in field_rows], "opening_um": [r[0] for r in field_rows]})
    result["pores"]["measured_by_photometric_stereo"] = measured
    write_result("colour_pores", result)


if __name__ == "__main__":
    main()
