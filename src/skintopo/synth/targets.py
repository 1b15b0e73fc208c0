"""Calibration targets seen by the simulated device: a chrome (mirror) sphere and a matte
white sphere under each light, to rehearse ``skintopo calibrate lights`` and ``skintopo init``.

Orthographic camera looking down -z, image rows running downward (y up), directional lights.
The sphere (centre and radius in pixels) gives each pixel its normal
n = ((x - cx) / r, -(y - cy) / r, sqrt(1 - ...)).

Chrome: a mirror reflects the light where the mirror direction of the view, 2 (n . v) n - v,
meets it; the LED is a small disc (angular radius 2 degrees, a Gaussian spot), over a dim
reflected room (6% of full scale), with sensor noise; the highlight saturates, as it does
on a real mirror sphere.

Matte: a Lambertian white sphere, I = e rho max(0, n . l), rho = 0.7, with the light's
relative intensity e.

Skin edge (for ``skintopo calibrate skin``): skin with its microrelief (preset
``flat-microrelief``) under all lights at once, through crossed polarisers (no surface
reflection), with an opaque black mask (reflectance 0.03) laid over the left 30% of the
field, its edge tilted by 2 degrees; a pixel the edge crosses is lit and seen in proportion
to its uncovered area. The skin's radiance is the profile's scattering T[rho E] of the
irradiance E that reaches the uncovered skin (light re-emerging under the mask is absorbed).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from skintopo.errors import SkinTopoError
from skintopo.formats import write_png
from skintopo.outputs import staged_output_folder

SPHERE_TARGETS = ("chrome-sphere", "matte-sphere")
LED_ANGULAR_RADIUS_DEG = 2.0
MASK_REFLECTANCE = 0.03  # black tape
EDGE_TILT_DEG = 2.0
ROOM_LEVEL = 0.06
MATTE_ALBEDO = 0.7


def sphere_normals_of(shape, centre_xy, radius):
    """Unit normals (rows, columns, 3) of a sphere seen from above; NaN outside it.

    Written here rather than taken from :func:`skintopo.calibration.sphere_normals` on
    purpose: these targets test that code, so they must not share its geometry."""
    rows, columns = np.indices(shape, dtype=float)
    x, y = (columns - centre_xy[0]) / radius, -(rows - centre_xy[1]) / radius
    z2 = 1 - x**2 - y**2
    inside = z2 > 0
    return np.where(inside[..., None], np.dstack([x, y, np.sqrt(np.where(inside, z2, 0.0))]), np.nan)


def sphere_images(kind, lights, *, shape=(240, 320), intensities=None, noise=0.003, seed=0):
    """One image per light of the target ``kind`` (fractions of full scale, clipped to [0, 1]).

    Returns the images and the sphere as (centre x, centre y, radius) in pixels.
    """
    if kind not in SPHERE_TARGETS:
        raise SkinTopoError(f"unknown sphere target {kind!r}; choose from {list(SPHERE_TARGETS)}")
    lights = np.asarray(lights, dtype=float)
    intensities = np.ones(len(lights)) if intensities is None else np.asarray(intensities, dtype=float)
    sphere = (shape[1] / 2 + 0.37, shape[0] / 2 - 0.21, 0.38 * min(shape))  # off the pixel grid on purpose
    normals = sphere_normals_of(shape, sphere[:2], sphere[2])
    inside = np.isfinite(normals[..., 2])
    n = np.nan_to_num(normals)
    rng = np.random.default_rng(seed)
    images = []
    for light, intensity in zip(lights, intensities):
        if kind == "chrome-sphere":
            mirror = 2 * n[..., 2:3] * n - np.array([0.0, 0.0, 1.0])
            angle = np.degrees(np.arccos(np.clip(mirror @ light, -1, 1)))
            image = ROOM_LEVEL + 3.0 * intensity * np.exp(-((angle / LED_ANGULAR_RADIUS_DEG) ** 2))
        else:
            image = MATTE_ALBEDO * intensity * np.maximum(n @ light, 0.0)
        image = np.where(inside, image, 0.0) + noise * rng.standard_normal(shape)
        images.append(np.clip(image, 0.0, 1.0))
    return images, sphere


def write_sphere_target(out, kind, lights, *, shape=(240, 320), intensities=None, seed=0, overwrite=False):
    """Write ``sphere_1.png``, ... (16-bit) and ``ground_truth.json`` (the true lights and
    sphere) into the new folder ``out``, all or nothing."""
    import json

    images, sphere = sphere_images(kind, lights, shape=shape, intensities=intensities, seed=seed)
    with staged_output_folder(out, overwrite=overwrite) as staging:
        for index, image in enumerate(images, start=1):
            write_png(staging / f"sphere_{index}.png", np.round(image * 65535).astype(np.uint16))
        truth = {"target": kind, "lights": np.asarray(lights).tolist(),
                 "intensities": None if intensities is None else np.asarray(intensities).tolist(),
                 "sphere_px": {"centre_x": sphere[0], "centre_y": sphere[1], "radius": sphere[2]},
                 "files": [f"sphere_{i}.png" for i in range(1, len(images) + 1)]}
        (staging / "ground_truth.json").write_text(json.dumps(truth, indent=2) + "\n", encoding="utf-8")
    return Path(out)


def skin_edge_images(optics, skin, lights, *, shape=(256, 512), pixel_um=20.0, noise=1.0, seed=0):
    """Images of the skin-edge target per band (fractions of full scale; module notes) and the
    edge's place (the column where it crosses the top of the field, its tilt in degrees)."""
    from skintopo.synth import make_surface, preset_spec
    from skintopo.synth.render import sensor

    surface = make_surface(preset_spec("flat-microrelief", size_px=shape, pixel_um=pixel_um), seed=seed)
    lights = np.asarray(lights, dtype=float)
    irradiance = np.maximum(np.einsum("rck,mk->rc", surface.normals, lights), 0.0) / len(lights)
    rows, columns = np.indices(shape, dtype=float)
    start = 0.3 * shape[1]
    edge = start + np.tan(np.radians(EDGE_TILT_DEG)) * (rows + 0.5)
    uncovered = np.clip(columns + 1.0 - edge, 0.0, 1.0)  # the share of each pixel right of the edge (small tilt)
    mask_radiance = MASK_REFLECTANCE * lights[:, 2].mean()
    rng = np.random.default_rng(seed)
    images = {}
    for band in ("red", "green", "blue"):
        transport = optics.scattering[band].operator(shape, pixel_um)
        emitted = optics.albedo[skin][band] * irradiance * uncovered
        skin_radiance = emitted if transport is None else transport(emitted)
        linear = uncovered * skin_radiance + (1 - uncovered) * mask_radiance
        images[band] = sensor(linear, noise=noise, saturate=False, rng=rng)[0]
    return images, {"edge_column_at_top": start, "tilt_deg": EDGE_TILT_DEG}


def write_skin_edge_target(out, optics, skin, lights, *, shape=(256, 512), pixel_um=20.0, seed=0, overwrite=False):
    """Write ``edge_red.png``, ``edge_green.png``, ``edge_blue.png`` (16-bit) and
    ``ground_truth.json`` (the optics profile's true diffusion profiles) into the new folder
    ``out``, all or nothing."""
    import json

    images, edge = skin_edge_images(optics, skin, lights, shape=shape, pixel_um=pixel_um, seed=seed)
    with staged_output_folder(out, overwrite=overwrite) as staging:
        for band, image in images.items():
            write_png(staging / f"edge_{band}.png", np.round(image * 65535).astype(np.uint16))
        truth = {"target": "skin-edge", "optics": optics.name, "skin": skin, "pixel_um": pixel_um, "edge": edge,
                 "scattering": {band: {"weights": list(p.weights), "sigmas_um": list(p.sigmas_um)} for band, p in optics.scattering.items()}}
        (staging / "ground_truth.json").write_text(json.dumps(truth, indent=2) + "\n", encoding="utf-8")
    return Path(out)
