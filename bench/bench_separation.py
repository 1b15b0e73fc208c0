"""Benchmark (issues 15, 16, 22): how well the dichromatic separation
(``normals.separate_specular``, used by ``--highlights cross-band``) finds the specular light
of simulated skin, and why.

Each case renders one field twice with the same seed, with and without surface (specular)
reflection (forehead-moderate, 256 x 256 at 20 um, the 4 default lights, all other effects
on): the truth of the specular part is the difference, averaged over the bands. Per skin-optics
profile x light / dark skin x translucency on / off, seeds 1-2:

- ``removed_over_true``: mean specular part the separation finds / the true one (1 = right,
  above 1 it takes diffuse light for specular light); ``specular_rms_over_true_mean``: RMS of
  its error / the true mean;
- ``diffuse_colour_spread``: on the render without specular light, the whiteness of each
  observation's colour, k = v_par / |v_perp| (the quantity the separation assumes is one per
  pixel), max - min over a pixel's lit observations (above 10% of its brightest, as the
  separation), median over the pixels, relative to the median k;
- RMS height error (um, least squares, the default integrator) of each band: the images as
  rendered, the true diffuse images (what a perfect separation gives), the separated diffuse
  images; a height that cannot be registered to the truth counts as infinite (medians, and
  the number of such band heights per kind).

Usage (from bench/): python bench_separation.py [SEEDS]. Results: bench/results/separation.json.
"""

import sys

import numpy as np
from _results import write_result  # bench/_results.py (scripts run from bench/)

from skintopo.evaluation import evaluate_height
from skintopo.height import integrate_normals
from skintopo.normals import photometric_stereo, separate_specular
from skintopo.synth import PROFILES, make_surface, optics_profile, preset_spec, simulate_acquisition
from skintopo.synth.render import Effects, RenderSettings, default_lights

RGB = ("red", "green", "blue")
LIT_FRACTION = 0.1  # as separate_specular's default


def rms_height_error(images, lights, surface):
    stereo = photometric_stereo(images, lights)
    try:
        return round(evaluate_height(integrate_normals(stereo.normals, 20.0, mask=stereo.valid), surface.height)["rms_height_error_um"], 3)
    except Exception:  # a reconstruction that cannot even be registered is a result too
        return float("inf")


def render(surface, optics, skin, seed, specular, translucency):
    settings = RenderSettings(skin=skin, lights=default_lights(), optics=optics_profile(optics),
                              effects=Effects(specular=specular, translucency=translucency))
    bands, info = simulate_acquisition(surface, settings, seed=seed)
    return {b: bands[b][0] / info["exposure_gain"][b] for b in RGB}, bands["red"][1]


def colour_spread(images):
    """Median over pixels of (max - min) of k = v_par / |v_perp| over the lit observations,
    relative to the median k."""
    v = np.stack([images[b] for b in RGB], axis=-1).astype(np.float64)
    parallel = v.sum(axis=-1) / np.sqrt(3)
    perpendicular = np.sqrt(np.maximum((v * v).sum(axis=-1) - parallel**2, 0))
    with np.errstate(invalid="ignore", divide="ignore"):
        lit = perpendicular > LIT_FRACTION * perpendicular.max(axis=0)
        k = np.where(lit, parallel / perpendicular, np.nan)
    spread = np.nanmax(k, axis=0) - np.nanmin(k, axis=0)
    return round(float(np.nanmedian(spread) / np.nanmedian(k)), 4)


def case(optics, skin, seed, translucency):
    surface = make_surface(preset_spec("forehead-moderate", size_px=256), seed=seed)
    rendered, lights = render(surface, optics, skin, seed, True, translucency)
    diffuse, _ = render(surface, optics, skin, seed, False, translucency)
    true = np.mean([rendered[b] - diffuse[b] for b in RGB], axis=0)
    separation = separate_specular(*(rendered[b] for b in RGB))
    return {
        "optics": optics, "skin": skin, "seed": seed, "translucency": translucency,
        "removed_over_true": round(float(separation.specular.mean() / true.mean()), 3),
        "specular_rms_over_true_mean": round(float(np.sqrt(np.mean((separation.specular - true) ** 2)) / true.mean()), 3),
        "diffuse_colour_spread": colour_spread(diffuse),
        "rms_um": {kind: {b: rms_height_error(images[b], lights, surface) for b in RGB}
                   for kind, images in (("as rendered", rendered), ("true diffuse", diffuse), ("separated", separation.diffuse))},
    }


def main(seeds):
    cases = []
    for optics in PROFILES:
        for skin in ("light", "dark"):
            for translucency in (True, False):
                for seed in range(1, seeds + 1):
                    cases.append(case(optics, skin, seed, translucency))
                    print(cases[-1], flush=True, file=sys.stderr)
    summary = {}
    for optics in PROFILES:
        for translucency in (True, False):
            chosen = [c for c in cases if c["optics"] == optics and c["translucency"] == translucency]
            summary[f"{optics}, translucency {'on' if translucency else 'off'}"] = {
                "removed_over_true": round(float(np.median([c["removed_over_true"] for c in chosen])), 3),
                "specular_rms_over_true_mean": round(float(np.median([c["specular_rms_over_true_mean"] for c in chosen])), 3),
                "diffuse_colour_spread": round(float(np.median([c["diffuse_colour_spread"] for c in chosen])), 4),
                "median_rms_um": {kind: {b: round(float(np.median([c["rms_um"][kind][b] for c in chosen])), 3) for b in RGB}
                                  for kind in ("as rendered", "true diffuse", "separated")},
                "unregistrable": {kind: sum(not np.isfinite(c["rms_um"][kind][b]) for c in chosen for b in RGB)
                                  for kind in ("as rendered", "true diffuse", "separated")},
            }
    write_result("separation", {"benchmark": "dichromatic separation against the true specular part, forehead-moderate 256 px, "
                                             f"seeds 1-{seeds}, light and dark skin (medians over the cases)",
                                "summary": summary, "cases": cases})


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 2)
