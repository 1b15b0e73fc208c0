"""Benchmark: the real device (issue 22). A paper-like device (skintopo.device.paper_device: 4
LEDs on a 60 mm ring 80 mm above the skin, 1000 x 1000 camera, 65 x 65 mm at 150 mm) looks
at a forehead with wrinkles on a sphere of 80 mm radius. Three reconstructions of the red
band, scored against the raw geometry:

- ideal: the same surface rendered under distant lights (the directions from the field centre
  to the LEDs) by an orthographic camera, reconstructed by distant-light photometric stereo;
- near-field: the device's images through :func:`skintopo.nearfield.near_field_photometric_stereo`;
- distant solver: the device's images through distant-light photometric stereo (what skintopo
  did before), to show how much it bends.

Scores: RMS height error after removing its mean ("raw"), and after removing its best-fitting
quadratic ("after form": the error left in the wrinkle band, what form removal would not take
away; the truth itself is not processed); the forehead radius from a least-squares sphere
(:func:`skintopo.filters.sphere_fit`) of the reconstruction.
Speed: 12 images (3 bands x 4 LEDs) of 1000 x 1000 through the near-field solver against the
distant-light one (normals + integration per band).

Run from bench/: ``python bench_nearfield.py [--size N] [--effects lambertian|skin] [--highlights cross-band]``;
``--mitsuba`` runs the comparison on Mitsuba 3 renders instead (nearfield-mitsuba-SIZE.json);
``--per-effect`` scores ideal and near-field with each of the skin's effects alone (and the
highlights with the cross-band separation, the same with the profile's true specular colour
given, the colour calibrated from a simulated cross-polarised repeat capture
(:func:`skintopo.calibration.specular_colour_from_differences`), and removed exactly), to find
which one makes the near-field gap
(nearfield-SIZE-per-effect[-OPTICS].json).
``--physics`` scores the physics height through the device against the same skin under
ideal lights, with highlights also on the cross-band diffuse images, white or of the colour
calibrated from a cross-polarised repeat capture (nearfield-SIZE-physics[-OPTICS].json).
``--optics NAME`` renders with that skin-optics profile (default: the simulator's, default-v1).
Results: bench/results/nearfield.json (size 1000, lambertian) or nearfield-SIZE-EFFECTS[-cross-band][-OPTICS].json.
"""

import argparse
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import scipy.ndimage
from _results import write_result  # bench/_results.py (scripts run from bench/)

from skintopo.calibration import specular_colour_from_differences
from skintopo.defaults import DEFAULT_SKIN_OPTICS
from skintopo.device import paper_device
from skintopo.filters import polynomial_form, sphere_fit
from skintopo.height import integrate_normals
from skintopo.heightmap import HeightMap
from skintopo.nearfield import near_field_photometric_stereo
from skintopo.normals import photometric_stereo, separate_specular
from skintopo.physics import near_field_physics_height, physics_height
from skintopo.synth import PROFILES, Effects, RenderSettings, optics_profile, preset_spec, simulate_acquisition
from skintopo.synth.nearfield import device_surface, simulate_device_acquisition, camera_grid_surface
from skintopo.synth.render import fresnel_dielectric

RADIUS_MM = 80.0
RGB = ("red", "green", "blue")
EFFECTS = {"lambertian": Effects.none(), "skin": Effects(interreflection=False)}


def device_scene(size, seed=1):
    device = paper_device(size_px=size)
    spec = replace(preset_spec("forehead-moderate", size_px=size, pixel_um=device.pixel_um), form_shape="sphere", form_radius_mm=RADIUS_MM)
    return device, device_surface(spec, device, seed=seed)


def height_error(height: HeightMap, truth: HeightMap):
    """(error, valid, after form): the height error (NaN where either is missing), where it is
    valid, and the error minus its own least-squares quadratic (the truth is not processed)."""
    error = height.z - truth.z
    valid = np.isfinite(error) & height.mask
    error = np.where(valid, error, np.nan)
    return error, valid, error - polynomial_form(np.where(valid, error, 0.0), truth.spacing, order=2, mask=valid)


def scores(height: HeightMap, truth: HeightMap):
    error, valid, after_form = height_error(height, truth)
    radius_um, _ = sphere_fit(height)
    return {
        "rms_raw_um": float(np.sqrt(np.nanmean((error - np.nanmean(error)) ** 2))),
        "rms_after_form_um": float(np.sqrt(np.nanmean(after_form[valid] ** 2))),
        "mean_offset_um": float(np.nanmean(error)),
        "radius_mm": radius_um / 1000,
        "radius_error_percent": 100 * (radius_um / 1000 / RADIUS_MM - 1),
        "valid_fraction": float(valid.mean()),
    }


def split_after_form(height: HeightMap, truth: HeightMap, wavelength_um=2600.0):
    """The after-form error (:func:`scores`) split at ``wavelength_um``: (RMS of its Gaussian
    low-pass with sigma = wavelength / (2 pi), RMS of the rest), um: the forehead's form
    error against the wrinkle band."""
    _, valid, after_form = height_error(height, truth)
    residual = np.where(valid, after_form, 0.0)
    low = scipy.ndimage.gaussian_filter(residual, wavelength_um / (2 * np.pi) / truth.spacing[0])
    return float(np.sqrt(np.mean(low[valid] ** 2))), float(np.sqrt(np.mean((residual - low)[valid] ** 2)))


def red_without_specular(images, exposure_gain, specular_colour=None):
    """The red images minus the specular part that the cross-band separation finds in
    ``images`` (band -> stack of images, in each band's exposure units), the surface
    reflection taken as white or of ``specular_colour``."""
    separation = separate_specular(*(images[b] / exposure_gain[b] for b in RGB), specular_colour=specular_colour)
    return images["red"] - separation.band_specular("red") * exposure_gain["red"]


def fresnel_colour(optics):
    """The profile's surface reflection colour: the Fresnel reflectance at normal incidence of
    its refractive index in red, green and blue (what the renders use; an oracle)."""
    return [float(fresnel_dielectric(1.0, optics.fresnel_index[b])) for b in RGB]


def calibrated_colours(surface, device, crop, settings, near_images, ideal_images):
    """The surface reflection's colour measured as ``skintopo calibrate highlight`` does, from
    a cross-polarised repeat capture (the same skin rendered without surface reflection, other
    sensor noise) beside each capture (band -> images in exposure-divided units): (near-field,
    ideal)."""
    crossed = replace(settings, effects=replace(settings.effects, specular=False))
    near, near_info = simulate_device_acquisition(surface, device, crossed, seed=2, skin_seed=1)
    ideal, ideal_info = simulate_acquisition(crop, replace(crossed, lights=device.central_directions()), seed=2, skin_seed=1)
    return (specular_colour_from_differences(near_images, {b: near[b] / near_info["exposure_gain"][b] for b in RGB})[0],
            specular_colour_from_differences(ideal_images, {b: ideal[b][0] / ideal_info["exposure_gain"][b] for b in RGB})[0])


def per_effect(size, optics_name=None):
    """Ideal and near-field red heights with one effect of the skin profile at a time."""
    optics = optics_profile(optics_name or DEFAULT_SKIN_OPTICS)
    device, surface = device_scene(size)
    crop = camera_grid_surface(surface, device)
    truth, lights = crop.height, device.central_directions()
    alone = {"cast shadows": Effects(interreflection=False, specular=False, translucency=False, albedo_variation=False),
             "translucency": Effects(shadows=False, interreflection=False, specular=False, albedo_variation=False),
             "albedo variation": Effects(shadows=False, interreflection=False, specular=False, translucency=False),
             "highlights": Effects(shadows=False, interreflection=False, translucency=False, albedo_variation=False)}
    cases = [(name, effects, "none") for name, effects in alone.items()]
    cases += [("highlights", alone["highlights"], "cross-band"), ("highlights", alone["highlights"], "cross-band, colour given"),
              ("skin (all but interreflection)", EFFECTS["skin"], "cross-band"),
              ("skin (all but interreflection)", EFFECTS["skin"], "cross-band, colour given"),
              ("skin (all but interreflection)", EFFECTS["skin"], "cross-band, colour calibrated"),
              ("skin (all but interreflection)", EFFECTS["skin"], "removed exactly")]
    rows = []
    for name, effects, highlights in cases:
        settings = RenderSettings(effects=effects, noise=1.0, optics=optics)
        bands, info = simulate_device_acquisition(surface, device, settings, seed=1)
        ideal_bands, ideal_info = simulate_acquisition(crop, replace(settings, lights=lights), seed=1)
        red, ideal_red = bands["red"], ideal_bands["red"][0]
        if highlights == "removed exactly":  # what a perfect separation would leave: the same renders without specular light
            diffuse = replace(settings, effects=replace(effects, specular=False))
            red, diffuse_info = simulate_device_acquisition(surface, device, diffuse, seed=1)
            red = red["red"] * info["exposure_gain"]["red"] / diffuse_info["exposure_gain"]["red"]
            ideal_red, diffuse_info = simulate_acquisition(crop, replace(diffuse, lights=lights), seed=1)
            ideal_red = ideal_red["red"][0] * ideal_info["exposure_gain"]["red"] / diffuse_info["exposure_gain"]["red"]
        colours = [None, None]
        if highlights.endswith("colour given"):
            colours = [fresnel_colour(optics)] * 2
        elif highlights.endswith("colour calibrated"):
            colours = calibrated_colours(surface, device, crop, settings, {b: bands[b] / info["exposure_gain"][b] for b in RGB},
                                         {b: ideal_bands[b][0] / ideal_info["exposure_gain"][b] for b in RGB})
        if highlights.startswith("cross-band"):
            red = red_without_specular(bands, info["exposure_gain"], colours[0])
            ideal_red = red_without_specular({b: ideal_bands[b][0] for b in RGB}, ideal_info["exposure_gain"], colours[1])
        ideal = distant_reconstruction(ideal_red, lights, truth.spacing)
        near = near_field_photometric_stereo(red, device, "red")
        row = {"effect": name, "highlights": highlights, "photometric_scale_of_working_distance": near.scales[-1]}
        if highlights.endswith("colour calibrated"):
            row["calibrated_colour"] = {"near_field": list(colours[0]), "ideal": list(colours[1])}
        for key, height in (("ideal", ideal), ("near_field", near.height)):
            row[key] = scores(height, truth)
            row[key]["after_form_longer_than_2.6mm_um"], row[key]["after_form_shorter_um"] = split_after_form(height, truth)
        rows.append(row)
        print(name, highlights, round(row["ideal"]["rms_after_form_um"], 2), round(row["near_field"]["rms_after_form_um"], 2), flush=True)
    name = f"nearfield-{size}-per-effect" + ("" if optics_name is None else f"-{optics_name}")
    write_result(name, {"device": device.describe(), "optics": optics.name, "specular_colour": fresnel_colour(optics), "size_px": size,
                        "band": "red", "rows": rows})


def distant_reconstruction(images, lights, spacing):
    stereo = photometric_stereo(images, lights)
    return integrate_normals(stereo.normals, spacing)


def mitsuba_check(size, spp=16):
    """The same comparison on Mitsuba 3 renders (tests/helpers/mitsuba_render.py): the device with
    isotropic LEDs (Mitsuba's point emitters, mu = 0), perspective sensor, and the ideal
    orthographic / distant-light render; direct light, smooth mesh normals. Ours alongside."""
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the repository, for tests.helpers
    from tests.helpers import mitsuba_render

    device, surface = device_scene(size)
    device = replace(device, leds=tuple(replace(led, mu=0.0) for led in device.leds))
    crop = camera_grid_surface(surface, device)
    lights, albedo = device.central_directions(), (0.6, 0.45, 0.35)
    result = {"size_px": size, "spp": spp, "renderers": {}}
    start = time.perf_counter()
    mitsuba_near = mitsuba_render.render_device(surface.height.z, device.pixel_um, device, albedo, spp=spp, seed=1)[0]
    mitsuba_ideal = mitsuba_render.render(crop.height.z, device.pixel_um, lights, albedo, spp=spp, max_depth=2, seed=1, face_normals=False)[0]
    result["seconds_mitsuba"] = time.perf_counter() - start
    settings = RenderSettings(effects=Effects.none(), noise=1.0)
    ours_near = simulate_device_acquisition(surface, device, settings, seed=1)[0]["red"]
    ours_ideal = simulate_acquisition(crop, replace(settings, lights=lights), seed=1)[0]["red"][0]
    for name, near_images, ideal_images in (("mitsuba", mitsuba_near, mitsuba_ideal), ("skintopo", ours_near, ours_ideal)):
        near = scores(near_field_photometric_stereo(near_images, device, "red").height, crop.height)
        ideal = scores(distant_reconstruction(ideal_images, lights, crop.height.spacing), crop.height)
        result["renderers"][name] = {"near_field": near, "ideal": ideal,
                                     "near_over_ideal_after_form": near["rms_after_form_um"] / ideal["rms_after_form_um"]}
    write_result(f"nearfield-mitsuba-{size}", result)


def physics_check(size, optics_name=None):
    """The physics height (skintopo.physics) through the device against the same skin under
    ideal distant lights and an orthographic camera, with plain red and blue beside it, for
    three sets of the skin's effects; with highlights, physics both with its own highlight
    lobe and on the cross-band diffuse images (its lobe off, as ``--highlights cross-band``
    gives it). Images divided by the recorded exposure, as an acquisition's intensities do."""
    optics = optics_profile(optics_name or DEFAULT_SKIN_OPTICS)
    device, surface = device_scene(size)
    crop = camera_grid_surface(surface, device)
    truth, lights = crop.height, device.central_directions()
    cases = {"translucency": Effects(shadows=False, interreflection=False, specular=False, albedo_variation=False),
             "skin without highlights": Effects(specular=False), "skin": Effects()}
    rows = []
    for name, effects in cases.items():
        settings = RenderSettings(effects=effects, noise=1.0, optics=optics)
        bands, info = simulate_device_acquisition(surface, device, settings, seed=1)
        ideal, ideal_info = simulate_acquisition(crop, replace(settings, lights=lights), seed=1)
        bands = {b: bands[b] / info["exposure_gain"][b] for b in RGB}
        ideal = {b: ideal[b][0] / ideal_info["exposure_gain"][b] for b in RGB}
        variants = [("none", bands, ideal)]
        if effects.specular:
            for highlights, colours in (("cross-band", (None, None)),
                                        ("cross-band, colour calibrated", calibrated_colours(surface, device, crop, settings, bands, ideal))):
                separated = []
                for images, colour in zip((bands, ideal), colours):
                    separation = separate_specular(*(images[b] for b in RGB), specular_colour=colour)  # once per capture, not per band
                    separated.append({b: images[b] - separation.band_specular(b) for b in RGB})
                variants.append((highlights, *separated))
        for highlights, near_images, ideal_images in variants:
            row = {"effects": name, "highlights": highlights, "ideal": {}, "near_field": {}}
            start = None
            for band in ("red", "blue"):
                row["ideal"][band] = scores(distant_reconstruction(ideal_images[band], lights, truth.spacing), truth)
                start = near_field_photometric_stereo(near_images[band], device, band, start=start)
                row["near_field"][band] = scores(start.height, truth)
            lobe = highlights == "none"  # on the cross-band diffuse images physics' own lobe is off
            begun = time.perf_counter()
            found = physics_height(ideal_images, lights, truth.spacing, highlights=lobe)
            row["ideal"]["physics"] = scores(found.height, truth) | {"seconds": time.perf_counter() - begun, "changes": found.changes}
            begun = time.perf_counter()
            found = near_field_physics_height(near_images, device, highlights=lobe)
            row["near_field"]["physics"] = scores(found.height, truth) | {"seconds": time.perf_counter() - begun, "changes": found.changes,
                                                                           "kernels": {b: k.as_dict() for b, k in found.kernels.items()}}
            rows.append(row)
            print(name, highlights, {side: {k: round(v["rms_after_form_um"], 2) for k, v in row[side].items()} for side in ("ideal", "near_field")},
                  flush=True)
    name = f"nearfield-{size}-physics" + ("" if optics_name is None else f"-{optics_name}")
    write_result(name, {"device": device.describe(), "optics": optics.name, "size_px": size, "rows": rows})


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--size", type=int, default=1000, help="camera pixels across (the field stays 65 mm)")
    parser.add_argument("--effects", choices=sorted(EFFECTS), default="lambertian",
                        help="lambertian: diffuse only; skin: + translucency, highlights, cast shadows (no interreflection)")
    parser.add_argument("--highlights", choices=["none", "cross-band"], default="none",
                        help="cross-band: every reconstruction solves the dichromatic diffuse images (images minus their specular part)")
    parser.add_argument("--optics", choices=PROFILES, default=None,
                        help="the skin-optics profile of the renders (default: the simulator's, default-v1)")
    parser.add_argument("--mitsuba", action="store_true", help="the comparison on Mitsuba 3 renders instead (mitsuba-SIZE.json)")
    parser.add_argument("--per-effect", action="store_true", help="each skin effect alone (nearfield-SIZE-per-effect.json)")
    parser.add_argument("--physics", action="store_true", help="the physics height through the device (nearfield-SIZE-physics.json)")
    args = parser.parse_args()
    if args.mitsuba:
        return mitsuba_check(args.size)
    if args.per_effect:
        return per_effect(args.size, args.optics)
    if args.physics:
        return physics_check(args.size, args.optics)
    device, surface = device_scene(args.size)
    settings = RenderSettings(effects=EFFECTS[args.effects], noise=1.0)
    if args.optics is not None:
        settings = replace(settings, optics=optics_profile(args.optics))
    start = time.perf_counter()
    bands, info = simulate_device_acquisition(surface, device, settings, seed=1)
    seconds_render = time.perf_counter() - start
    crop = camera_grid_surface(surface, device)
    truth = crop.height
    lights = device.central_directions()
    ideal_bands, ideal_info = simulate_acquisition(crop, replace(settings, lights=lights), seed=1)

    result = {"device": device.describe(), "effects": args.effects, "optics": settings.optics.name, "size_px": args.size, "pixel_um": device.pixel_um,
              "forehead_radius_mm": RADIUS_MM, "seconds_render": seconds_render, "band": "red"}
    red, ideal_red = bands["red"], ideal_bands["red"][0]
    if args.highlights == "cross-band":
        red = red_without_specular(bands, info["exposure_gain"])
        ideal_red = red_without_specular({b: ideal_bands[b][0] for b in RGB}, ideal_info["exposure_gain"])
    result["highlights"] = args.highlights
    result["ideal"] = scores(distant_reconstruction(ideal_red, lights, truth.spacing), truth)
    near = near_field_photometric_stereo(red, device, "red")
    result["near_field"] = scores(near.height, truth)
    result["near_field"]["iterations"] = near.options["iterations"]
    result["near_field"]["changes_um"] = near.changes_um
    result["near_field"]["binned"] = near.options.get("binned")
    result["distant_solver"] = scores(distant_reconstruction(red, lights, truth.spacing), truth)
    result["difference_after_form_um"] = result["near_field"]["rms_after_form_um"] - result["ideal"]["rms_after_form_um"]

    # speed: 12 images, three bands; the distant-light time on the ideal scene's images (where
    # it is the right method; on the device's images it meets more shadowed pixels and
    # switches to the slower masked integrator). Best of 5, the two interleaved (this
    # machine's speed varies by 30-50% between runs).
    def distant_bands():
        for band in RGB:
            distant_reconstruction(ideal_bands[band][0], lights, truth.spacing)

    def near_bands():  # as the pipeline does: the other bands start from the first one's depth
        first = near_field_photometric_stereo(bands["red"], device, "red")
        for band in ("green", "blue"):
            near_field_photometric_stereo(bands[band], device, band, start=first)

    seconds = {"distant": [], "near_field": []}
    for _ in range(5):
        for name, run in (("distant", distant_bands), ("near_field", near_bands)):
            start = time.perf_counter()
            run()
            seconds[name].append(time.perf_counter() - start)
    start = time.perf_counter()
    for band in RGB:
        near_field_photometric_stereo(bands[band], device, band)
    seconds_independent = time.perf_counter() - start
    result["speed"] = {"images": 12, "seconds_distant": min(seconds["distant"]), "seconds_near_field": min(seconds["near_field"]),
                       "ratio": min(seconds["near_field"]) / min(seconds["distant"]),
                       "ratio_of_medians": float(np.median(seconds["near_field"]) / np.median(seconds["distant"])), "runs": seconds,
                       "seconds_near_field_bands_independent": seconds_independent}
    name = "nearfield" if (args.size, args.effects) == (1000, "lambertian") else f"nearfield-{args.size}-{args.effects}"
    name += "" if args.highlights == "none" else "-cross-band"
    name += "" if args.optics is None else f"-{args.optics}"
    write_result(name, result)


if __name__ == "__main__":
    main()
