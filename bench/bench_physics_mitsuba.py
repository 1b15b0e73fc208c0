"""Benchmark: the physically based height on renders of a second, independent renderer, with
least squares and with the robust solver inside its iteration, side by side in one run.

Mitsuba 3 (``scalar_rgb`` path tracer, 8 bounces, tests/helpers/mitsuba_render.py) renders
forehead-moderate and forehead-high height fields (128 x 128 at 20 um, seed 4, 4 lights at 45
degrees, 32 samples per pixel, albedo 0.60 / 0.41 / 0.33) in four cases: diffuse; diffuse +
subsurface scattering (an exponential kernel exp(-r / d) per band, d = 120 / 70 / 40 um,
w = 0.5 / 0.35 / 0.25: a family the simulator does not use); a rough dielectric coat (Beckmann
alpha 0.2); coat alpha 0.3 + scattering. RMS height error (um) of red, the best band (red,
green, blue, white), the paper's correction and physics with each solver; and physics with
kernels from a calibration capture of each case's skin (``skintopo calibrate skin``'s
:func:`~skintopo.calibration.diffusion_profile_from_edge`): a black mask's straight edge
(reflectance 0.03) on a flat patch of the same material, 128 x 256 at 20 um, rendered by
Mitsuba under all four lights at once, the case's scattering applied to the light the skin
emits beside the mask (none enters under it).

Run from bench/: ``python bench_physics_mitsuba.py``. Results: bench/results/physics-mitsuba.json.
"""

import sys
import time
from pathlib import Path

import numpy as np
from _results import write_result  # bench/_results.py (scripts run from bench/)

from skintopo.calibration import diffusion_profile_from_edge
from skintopo.correction import spectral_correction
from skintopo.evaluation import evaluate_height
from skintopo.height import integrate_normals
from skintopo.normals import photometric_stereo
from skintopo.physics import physics_height
from skintopo.synth import make_surface, preset_spec
from skintopo.synth.render import default_lights

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the repository, for tests.helpers
from tests.helpers import mitsuba_render  # noqa: E402  (the second renderer lives with the tests)

BANDS = ("red", "green", "blue")
ALBEDO = (0.6, 0.41, 0.33)
SCATTERING = [(0.5, 120.0), (0.35, 70.0), (0.25, 40.0)]  # (weight, length um) per band
CASES = {"diffuse": (None, False), "diffuse + scattering": (None, True), "coat alpha 0.2": (0.2, False),
         "coat alpha 0.3 + scattering": (0.3, True)}


def edge_calibrated_kernels(lights, coat, scattering):
    """Diffusion profiles per band measured on a rendered skin-edge capture of the case's
    material (module notes; tests/helpers/mitsuba_render.py)."""
    images = mitsuba_render.render_skin_edge(lights, ALBEDO, coat_roughness=coat, scattering=SCATTERING if scattering else None)
    return {band: diffusion_profile_from_edge(images[c], 20.0, name=band)[0] for c, band in enumerate(BANDS)}


def rms(height, surface):
    try:
        return round(evaluate_height(height, surface.height)["rms_height_error_um"], 3)
    except Exception as error:  # an unregistrable result is a result too
        return f"failed: {error}"


def main():
    lights = default_lights()
    rows = []
    calibrated = {name: edge_calibrated_kernels(lights, coat, scattering) for name, (coat, scattering) in CASES.items()}
    for preset in ("forehead-moderate", "forehead-high"):
        surface = make_surface(preset_spec(preset, size_px=128), seed=4)
        for name, (coat, scattering) in CASES.items():
            start = time.perf_counter()
            rgb = mitsuba_render.render(surface.height.z, 20.0, lights, ALBEDO, coat_roughness=coat, spp=32, seed=1)
            if scattering:
                rgb = np.stack([mitsuba_render.exponential_scattering(rgb[c], 20.0, w, d) for c, (w, d) in enumerate(SCATTERING)])
            seconds_render = time.perf_counter() - start
            images = {band: rgb[c] for c, band in enumerate(BANDS)} | {"white": rgb.mean(0)}
            row = {"preset": preset, "case": name, "seconds_render": round(seconds_render, 1)}
            normals = {}
            for band, stack in images.items():
                stereo = photometric_stereo(stack, lights)
                normals[band] = stereo.normals
                row[band] = rms(integrate_normals(stereo.normals, 20.0, mask=stereo.valid), surface)
            row["best_band"] = min(row[b] for b in images if isinstance(row[b], float))
            row["paper"] = rms(spectral_correction({b: normals[b] for b in BANDS}, 20.0).height, surface)
            for solver in ("least-squares", "robust"):
                result = physics_height({b: images[b] for b in BANDS}, lights, 20.0, solver=solver)
                row[f"physics {solver}"] = rms(result.height, surface)
                row[f"physics {solver} plausible"] = result.plausible
            result = physics_height({b: images[b] for b in BANDS}, lights, 20.0, kernels=calibrated[name])
            row["physics edge-calibrated"] = rms(result.height, surface)
            row["physics edge-calibrated plausible"] = result.plausible
            rows.append(row)
            print(row, file=sys.stderr, flush=True)
    summary = {}
    for key in ("physics least-squares", "physics robust", "physics edge-calibrated"):
        values = [r[key] if isinstance(r[key], float) else float("inf") for r in rows]
        summary[key] = {"below_best_band": f"{sum(v < r['best_band'] for v, r in zip(values, rows))}/{len(rows)}",
                        "mean_change_vs_red_percent": round(float(np.mean([100 * (v / r["red"] - 1) for v, r in zip(values, rows)])), 1)}
    kernels = {name: {band: {"weights": [round(w, 4) for w in kernel.weights], "sigmas_um": [round(w, 1) for w in kernel.sigmas_um],
                             "transfer_at_8_cycles_per_mm": round(float(kernel.transfer(0.008)), 4)} for band, kernel in bands.items()}
               for name, bands in calibrated.items()}
    write_result("physics-mitsuba", {"summary": summary, "cases": rows, "edge_calibrated_kernels": kernels})


if __name__ == "__main__":
    main()
