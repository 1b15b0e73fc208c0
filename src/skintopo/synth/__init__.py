"""Skin acquisition simulator with exact ground truth (``skintopo synth``).

:mod:`skintopo.synth.surfaces` builds height maps of skin (microrelief, wrinkles, form) with
exact slopes; :mod:`skintopo.synth.render` renders them per band with shadows,
interreflection, specular reflection, translucency and sensor noise. This module holds the
presets and writes an acquisition folder in the same format as a real capture, with
``ground_truth/`` beside the images.

Presets (the paper's three forehead wrinkle states, Table 3, and a plain microrelief):

=====================  =========================================================
``flat-microrelief``   microrelief furrows and roughness, no wrinkles, no form
``forehead-low``       2 wrinkles, 60 / 50 um deep, 0.4 mm wide (V)
``forehead-moderate``  3 wrinkles, 120 / 100 / 90 um deep, 0.7 mm wide (V, U, V)
``forehead-high``      4 wrinkles, 220 / 180 / 200 / 160 um deep, 1.0 mm wide (U, V, U, V)
=====================  =========================================================

Forehead wrinkles run nearly horizontally (orientation within 6 degrees, gentle curvature),
evenly spaced over the field height, 75% of the field width long, on a cylinder of 80 mm
radius. Widths are physical; if the field is too small to hold the wrinkles side by side,
each is narrowed to 80% of the spacing, and the ground truth records the width used.
"""

from __future__ import annotations

import json
import time
from dataclasses import asdict, replace
from pathlib import Path

import numpy as np

from skintopo.acquisition import write_acquisition
from skintopo.defaults import DEFAULT_SKIN_OPTICS
from skintopo.errors import SkinTopoError
from skintopo.outputs import staged_output_folder, write_label_image
from skintopo.optics import PROFILES, SkinOptics, optics_profile
from skintopo.synth.render import Effects, RenderSettings, default_lights, render_bands, sensor, skin_generator, with_interreflection_radius
from skintopo.synth.surfaces import SkinSurface, SurfaceSpec, Wrinkle, geometric_measures, make_surface

__all__ = [
    "PRESETS",
    "PROFILES",
    "SkinOptics",
    "optics_profile",
    "Effects",
    "RenderSettings",
    "SkinSurface",
    "SurfaceSpec",
    "Wrinkle",
    "geometric_measures",
    "make_surface",
    "preset_spec",
    "simulate_acquisition",
    "write_synthetic_acquisition",
    "another_visit",
    "simulate_to_folder",
    "write_calibration_target",
]

_FOREHEAD = {  # (depth um, shape) per wrinkle, width um
    "forehead-low": ([(60.0, "V"), (50.0, "V")], 400.0),
    "forehead-moderate": ([(120.0, "V"), (100.0, "U"), (90.0, "V")], 700.0),
    "forehead-high": ([(220.0, "U"), (180.0, "V"), (200.0, "U"), (160.0, "V")], 1000.0),
}
PRESETS = ("flat-microrelief", *_FOREHEAD)


def preset_spec(name, *, size_px=256, pixel_um=20.0) -> SurfaceSpec:
    """The :class:`SurfaceSpec` of a named preset at a field size and pixel size."""
    if name not in PRESETS:
        raise SkinTopoError(f"unknown preset {name!r}; choose from {list(PRESETS)}")
    if not (isinstance(pixel_um, (int, float)) and pixel_um > 0):
        raise SkinTopoError(f"pixel size must be positive, got {pixel_um!r} um")
    shape = (size_px, size_px) if np.isscalar(size_px) else tuple(size_px)
    if name == "flat-microrelief":
        return SurfaceSpec(size_px=shape, pixel_um=float(pixel_um), form_radius_mm=None)
    wrinkles, width = _FOREHEAD[name]
    height_um, width_field_um = shape[0] * pixel_um, shape[1] * pixel_um
    spacing = height_um / (len(wrinkles) + 1)
    width = min(width, 0.8 * spacing)
    built = []
    for i, (depth, shape_name) in enumerate(wrinkles):
        y = height_um / 2 - spacing * (i + 1)
        built.append(
            Wrinkle(
                depth_um=depth,
                width_um=width,
                length_um=0.75 * width_field_um,
                orientation_deg=(-4.0, 3.0, -2.0, 6.0)[i],
                centre_um=((-0.05 + 0.04 * i) * width_field_um, y),
                curvature_per_mm=(0.04, -0.03, 0.05, -0.02)[i],
                shape=shape_name,
            )
        )
    return SurfaceSpec(size_px=shape, pixel_um=float(pixel_um), wrinkles=tuple(built))


def simulate_acquisition(surface: SkinSurface, settings: RenderSettings | None = None, seed=0, progress=iter, skin_seed=None):
    """Render every band and pass it through the sensor (``progress`` wraps the bands' loop).

    ``seed`` is the capture's (sensor noise); ``skin_seed`` (default: ``seed``) the skin's
    albedo variation: a repeat capture of the same skin keeps the skin's seed.

    Returns
    -------
    bands : dict of str to (images, lights)
        red, green, blue and white (the three LEDs at once: the mean of the three renders),
        images as fractions of full scale, ready for :func:`~skintopo.acquisition.write_acquisition`.
    info : dict
        Render diagnostics and timings; ``exposure_gain`` per band (written as the lights'
        relative intensity, so bands are radiometrically comparable once loaded).
    """
    settings = settings or RenderSettings()
    if settings.skin not in ("light", "dark"):
        raise SkinTopoError(f"unknown skin type {settings.skin!r}; choose light or dark")
    if settings.noise < 0:
        raise SkinTopoError(f"noise level must be >= 0, got {settings.noise}")
    settings = with_interreflection_radius(settings, surface.spec.wrinkles)
    rng = np.random.default_rng(seed)
    start = time.perf_counter()
    linear, info = render_bands(surface.height, surface.normals, settings, rng, progress, shift_um=surface.spec.shift_um,
                                skin_rng=skin_generator(seed, skin_seed))
    if settings.white_reference is not None:  # a flat Lambertian target: I = r l_z under each light
        reference = white_reference_box(surface.height.shape, settings.white_reference)
        rows, columns = reference.slices
        for band in ("red", "green", "blue"):
            linear[band][:, rows, columns] = (reference.reflectance[band] * np.maximum(np.asarray(settings.lights)[:, 2], 0))[:, None, None]
        info["white_reference"] = reference
    linear["white"] = (linear["red"] + linear["green"] + linear["blue"]) / 3
    info["seconds_render"] = time.perf_counter() - start
    lights = np.asarray(settings.lights, dtype=float)
    bands = {}
    info["exposure_gain"] = {}
    for band, images in linear.items():
        signal, gain = sensor(images, noise=settings.noise, saturate=settings.saturate, rng=rng)
        bands[band] = (signal, lights)
        info["exposure_gain"][band] = gain
    return bands, info


def white_reference_box(shape, reflectance):
    """The simulator's white reference: a flat target of ``reflectance`` covering the top-left
    tenth of each side of the field (:class:`~skintopo.acquisition.WhiteReference`)."""
    from skintopo.acquisition import WhiteReference

    return WhiteReference((0, 0, max(shape[0] // 10, 4), max(shape[1] // 10, 4)), dict.fromkeys(("red", "green", "blue"), float(reflectance)))


def write_synthetic_acquisition(out, surface: SkinSurface, bands, *, settings: RenderSettings, seed, info=None, overwrite=False,
                                capture_seed=None, manifest=True, device=None):
    """Write an acquisition folder plus ``ground_truth/`` (height.x3p, normals.npy,
    wrinkles.png with wrinkle ids, surface.json), all or nothing. ``seed`` made the surface,
    ``capture_seed`` (default: the same) the sensor noise. ``manifest=False`` leaves out
    ``acquisition.json``: the images as a camera writes them, for ``skintopo init``. With a
    ``device`` (:mod:`skintopo.synth.nearfield`), ``device.json`` is written and the images
    name their LEDs; ``surface`` is then the truth on the camera's grid."""
    reference = (info or {}).get("white_reference")
    mask = np.ones(surface.height.shape, bool)
    if reference is not None:  # the target is not skin
        mask[reference.slices] = False
    with staged_output_folder(out, overwrite=overwrite) as staging:
        write_acquisition(
            staging, bands, surface.spec.pixel_um, mask=mask, description="skintopo synthetic skin acquisition",
            intensities=(info or {}).get("exposure_gain"), device=device, white_reference=reference,
        )
        truth = staging / "ground_truth"
        truth.mkdir()
        surface.height.save(truth / "height.x3p")
        np.save(truth / "normals.npy", surface.normals.astype(np.float32))
        write_label_image(truth / "wrinkles.png", surface.wrinkle_labels)
        if surface.pore_labels is not None and surface.spec.pores:
            write_label_image(truth / "pores.png", surface.pore_labels)
        for name, values in (info or {}).get("chromophores", {}).items():  # melanin.npy, haemoglobin.npy, baseline.npy
            np.save(truth / f"{name}.npy", np.asarray(values, dtype=np.float32))
        description = {
            "units": {"lengths": "um", "curvature": "1/mm", "angles": "degrees"},
            "seed": seed,
            "capture_seed": seed if capture_seed is None else capture_seed,
            "surface": surface.describe(),
            "render": {
                "skin": settings.skin,
                "optics": settings.optics.describe(),
                "lights": np.asarray(settings.lights).tolist() if device is None else "the device's LEDs (device.json)",
                "effects": asdict(settings.effects),
                "interreflection_radius_um": settings.interreflection_radius_um,
                "n_azimuth": settings.n_azimuth,
                "specular_strength": settings.specular_strength,
                "noise": settings.noise,
                "saturate": settings.saturate,
                "pigmentation": None if settings.pigmentation is None else asdict(settings.pigmentation),
                "white_reference": settings.white_reference,
            },
            "wrinkle_measures": [geometric_measures(w) for w in surface.spec.wrinkles],
            "wrinkles_png": "0 = no wrinkle, i = wrinkle i (1-based, order of surface.wrinkles), half-depth region",
            "chromophores": ("melanin.npy, haemoglobin.npy, baseline.npy: optical densities at 523 nm (skintopo.chromophores)"
                             if "chromophores" in (info or {}) else None),
            "pores_png": "0 = no pore, i = pore i (1-based, order of surface.pores), the opening",
            "diagnostics": {key: value for key, value in (info or {}).items() if key not in ("chromophores", "white_reference")},
        }
        (truth / "surface.json").write_text(json.dumps(description, indent=2, default=float) + "\n", encoding="utf-8")
        if not manifest:
            (staging / "acquisition.json").unlink()
    return Path(out)


def another_visit(spec: SurfaceSpec, *, depth_factors=None, shift_um=(0.0, 0.0)) -> SurfaceSpec:
    """The same skin at another visit: wrinkle i (1-based, in the order of ``spec.wrinkles``)
    made ``depth_factors[i]`` times as deep (a treatment), and the field displaced by
    ``shift_um`` (x right, y up, micrometres)."""
    factors = dict(depth_factors or {})
    unknown = sorted(i for i in factors if not 1 <= i <= len(spec.wrinkles))
    if unknown:
        raise SkinTopoError(f"the skin has wrinkles 1..{len(spec.wrinkles)}, not {unknown}")
    wrinkles = tuple(replace(w, depth_um=w.depth_um * factors.get(i, 1.0)) for i, w in enumerate(spec.wrinkles, start=1))
    return replace(spec, wrinkles=wrinkles, shift_um=tuple(shift_um))


def simulate_to_folder(out, spec: SurfaceSpec, settings: RenderSettings, *, seed=0, capture_seed=None, device=None, manifest=True,
                       overwrite=False, progress=iter) -> SkinSurface:
    """Simulate the skin of ``spec`` (surface ``seed``) captured with ``settings`` (sensor
    noise ``capture_seed``, default ``seed``: another value is a repeat capture of the same
    skin) and write it as an acquisition folder with its ground truth
    (:func:`write_synthetic_acquisition`). With a ``device`` (:class:`skintopo.device.Device`)
    the skin is rendered through its near-field LEDs and perspective camera
    (:mod:`skintopo.synth.nearfield`). Returns the true surface (on the camera's grid)."""
    capture_seed = seed if capture_seed is None else capture_seed
    if device is None:
        surface = make_surface(spec, seed=seed)
        bands, info = simulate_acquisition(surface, settings, seed=capture_seed, progress=progress, skin_seed=seed)
    else:
        from skintopo.synth.nearfield import camera_grid_surface, device_surface, simulate_device_acquisition

        rendered = device_surface(spec, device, seed=seed)
        images, info = simulate_device_acquisition(rendered, device, settings, seed=capture_seed, skin_seed=seed)
        surface = camera_grid_surface(rendered, device)
        bands = {band: (stack, device.central_directions()) for band, stack in images.items()}
    write_synthetic_acquisition(out, surface, bands, settings=settings, seed=seed, info=info, overwrite=overwrite,
                                capture_seed=capture_seed, manifest=manifest, device=device)
    return surface


def write_calibration_target(out, target, *, device=None, size_px=256, pixel_um=20.0, optics=None, skin="light", seed=0,
                             overwrite=False) -> str:
    """Write rehearsal images of a calibration ``target`` (``chrome-sphere``, ``matte-sphere``)
    under the default lights, ``size_px`` square (:func:`skintopo.synth.targets.write_sphere_target`);
    with a ``device``: a chrome sphere at two places and a flat target through its near-field
    LEDs (:func:`skintopo.synth.nearfield.write_device_targets`); ``skin-edge``: a black mask's
    edge on skin of the ``optics`` profile, ``size_px`` x 2 ``size_px`` at ``pixel_um``
    (:func:`skintopo.synth.targets.write_skin_edge_target`). Returns what was written, in
    words."""
    if target == "skin-edge":
        from skintopo.synth.targets import write_skin_edge_target

        optics = optics_profile(DEFAULT_SKIN_OPTICS if optics is None else optics)
        write_skin_edge_target(out, optics, skin, default_lights(), shape=(size_px, 2 * size_px), pixel_um=pixel_um, seed=seed,
                               overwrite=overwrite)
        return (f"a black mask's edge on {skin} skin ({optics.name} optics), edge_red/green/blue.png at {pixel_um:g} um; "
                "the true diffusion profiles in ground_truth.json")
    if device is not None:
        from skintopo.synth.nearfield import write_device_targets

        write_device_targets(out, device, seed=seed, overwrite=overwrite)
        return ("a chrome sphere at two places (place_1/, place_2/) and a flat target (flat/) through the device, design.json "
                "to calibrate, the true device in ground_truth.json")
    from skintopo.synth.targets import write_sphere_target

    lights = default_lights()
    write_sphere_target(out, target, lights, shape=(size_px, size_px), seed=seed, overwrite=overwrite)
    return f"{target} under {len(lights)} lights (sphere_1.png, ...; the true lights in ground_truth.json)"


def default_settings(**changes):
    """RenderSettings with the default lights (4 at 45 degrees slant, 90 degrees apart)."""
    return replace(RenderSettings(lights=default_lights()), **changes)
