"""Rendering through a device: point LEDs and a perspective camera (:mod:`skintopo.device`).

The skin is a height field h(x, y) on a regular grid in the skin plane, placed at
z = -D + h (D the working distance; h = 0 at the field centre's apex). Each band is rendered
on that grid with :func:`skintopo.synth.render.render_bands` (the same diffuse, translucency,
interreflection and specular models as under distant lights), with per-point LED light
vectors s(P) = Phi (cos theta)^mu (L - P) / |L - P|^3 and per-point view directions. Each
camera pixel's ray d (a, b, -1) is then intersected with the surface by the fixed point
d = D - h(d a, d b) (a contraction: the surface's slope times the ray's obliquity is far
below 1) and the rendered radiance is read there by cubic interpolation. Cast shadows are
marched along the direction from the field centre to each LED (an approximation).

The grid is wider than the image by ``margin`` so that a surface falling away from the camera
(a curved forehead) still fills the image. The ground truth of a device acquisition is the
central part of that grid (:func:`camera_grid_surface`), on the grid the near-field solver
returns (:func:`skintopo.nearfield.surface_grid`): spacing D pitch / f, centred on the
optical axis.
"""

from __future__ import annotations

import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import scipy.ndimage

from skintopo.device import Device
from skintopo.errors import SkinTopoError
from skintopo.heightmap import HeightMap
from skintopo.synth.render import NearLighting, RenderSettings, render_bands, sensor, skin_generator, with_interreflection_radius
from skintopo.synth.surfaces import SkinSurface, SurfaceSpec, make_surface

DEFAULT_MARGIN = 0.15  # the rendered grid is this fraction wider than the image on each side


def surface_points_mm(height: HeightMap, working_distance_mm):
    """Camera-frame points (rows, columns, 3) in mm of a height field centred on the optical
    axis at the working distance."""
    rows, columns = height.shape
    dy, dx = height.spacing
    x = (np.arange(columns) - (columns - 1) / 2) * dx / 1000
    y = ((rows - 1) / 2 - np.arange(rows)) * dy / 1000
    z = -working_distance_mm + np.asarray(height.z, dtype=float) / 1000
    return np.stack(np.broadcast_arrays(x[None, :], y[:, None], z), axis=-1)


def near_lighting(height: HeightMap, device: Device):
    """:class:`~skintopo.synth.render.NearLighting` of the device's LEDs over a height field."""
    points = surface_points_mm(height, device.working_distance_mm)
    # times D^2: an LED of intensity 1 gives irradiance 1 at the working distance on its axis, the
    # convention of the near-field solver (skintopo.nearfield.per_pixel_photometric_stereo), so that the
    # albedo it finds is the skin's reflectance (which the physics height's interreflection needs). It
    # was normalised to 1 at the field centre, 100 mm from the paper device's LEDs, and the albedo came
    # out 2.25x too low; the images after the sensor's auto-exposure are the same either way.
    vectors = np.stack([np.moveaxis(led.light_vectors(np.moveaxis(points, -1, 0)), 0, -1) for led in device.leds])
    vectors *= device.working_distance_mm**2
    view = -points / np.linalg.norm(points, axis=-1, keepdims=True)
    intensities = {band: np.array([led.intensity.get(band, 1.0) for led in device.leds]) for band in ("red", "green", "blue")}
    return NearLighting(vectors, intensities, view, device.central_directions())


def device_surface(spec: SurfaceSpec, device: Device, *, seed=0, margin=DEFAULT_MARGIN) -> SkinSurface:
    """A synthetic surface on the grid a device renders: the device's pixel footprint at the
    working distance, the image size plus ``margin`` on each side. The microrelief is
    resolved at that sampling: furrows at least 3 pixels wide and plates at least 20 pixels
    (the skin's 70 um furrows would alias on a 65 um pixel: a point-sampled render of them is
    noise no camera lens would pass)."""
    rows, columns = device.camera.size_px
    pad = int(np.ceil(margin * max(rows, columns)))
    pixel = device.pixel_um
    return make_surface(replace(spec, size_px=(rows + 2 * pad, columns + 2 * pad), pixel_um=pixel,
                                furrow_width_um=max(spec.furrow_width_um, 3 * pixel), plate_um=max(spec.plate_um, 20 * pixel)), seed=seed)


def camera_grid_surface(surface: SkinSurface, device: Device) -> SkinSurface:
    """The ground truth on the grid the near-field solver returns: the central image-size
    part of the rendered grid (same spacing, same centre), heights, slopes, normals and
    wrinkle labels alike."""
    rows, columns = device.camera.size_px
    top = (surface.height.shape[0] - rows) // 2
    left = (surface.height.shape[1] - columns) // 2
    window = (slice(top, top + rows), slice(left, left + columns))
    return SkinSurface(HeightMap(surface.height.z[window], surface.height.spacing), surface.p[window], surface.q[window],
                       surface.normals[window], surface.wrinkle_labels[window], surface.wrinkle_depth[window], surface.spec)


def camera_sample_points(height: HeightMap, device: Device, iterations=12):
    """Where each camera pixel's ray meets the surface: fractional (row, column) indices into
    the height field's grid, and the depth d (mm) along the optical axis."""
    a, b = device.camera.rays()
    rows, columns = height.shape
    dy, dx = height.spacing
    z = np.asarray(height.z, dtype=float)
    depth = np.full(a.shape, device.working_distance_mm)
    for _ in range(iterations):
        column = depth * a * 1000 / dx + (columns - 1) / 2
        row = (rows - 1) / 2 - depth * b * 1000 / dy
        h = scipy.ndimage.map_coordinates(z, [row, column], order=1, mode="nearest")
        depth = device.working_distance_mm - h / 1000
    if row.min() < 0 or column.min() < 0 or row.max() > rows - 1 or column.max() > columns - 1:
        raise SkinTopoError("the simulated skin does not cover the camera's view (the device sees beyond the rendered margin): "
                            "a wider margin or a device with a narrower field is needed")
    return row, column, depth


def simulate_device_acquisition(surface: SkinSurface, device: Device, settings: RenderSettings | None = None, seed=0, skin_seed=None):
    """Render a surface through a device (point LEDs, perspective camera) and the sensor
    (``seed``: the capture's noise; ``skin_seed``, default ``seed``: the skin's albedo
    variation, as :func:`skintopo.synth.simulate_acquisition`).

    Returns
    -------
    bands : dict of str to ndarray (m, rows, columns)
        red, green, blue and white images (fractions of full scale), one per LED in the
        device's order, of the camera's size.
    info : dict
        ``exposure_gain`` per band, render diagnostics, timings.
    """
    settings = settings or RenderSettings()
    settings = with_interreflection_radius(settings, surface.spec.wrinkles)
    rng = np.random.default_rng(seed)
    start = time.perf_counter()
    near = near_lighting(surface.height, device)
    linear, info = render_bands(surface.height, surface.normals, settings, rng, near=near, skin_rng=skin_generator(seed, skin_seed))
    row, column, _ = camera_sample_points(surface.height, device)
    projected = {band: np.stack([scipy.ndimage.map_coordinates(image, [row, column], order=3, mode="nearest") for image in images])
                 for band, images in linear.items()}
    projected = {band: np.maximum(images, 0.0) for band, images in projected.items()}
    projected["white"] = (projected["red"] + projected["green"] + projected["blue"]) / 3
    info["seconds_render"] = time.perf_counter() - start
    bands, info["exposure_gain"] = {}, {}
    for band, images in projected.items():
        bands[band], info["exposure_gain"][band] = sensor(images, noise=settings.noise, saturate=settings.saturate, rng=rng)
    return bands, info


CHROME_ROOM_LEVEL = 0.06  # the dim room a chrome sphere reflects (fraction of full scale)


def _unit_rays(device: Device):
    a, b = device.camera.rays()
    rays = np.stack([a, b, -np.ones_like(a)])
    return rays / np.linalg.norm(rays, axis=0)


def device_sphere_images(device: Device, centre_mm, radius_mm, *, led_radius_mm=2.0, noise=0.003, seed=0):
    """A chrome (mirror) sphere seen through the device, one image per LED.

    Each pixel's ray meets the sphere at P (normal N) and is reflected along
    m = r - 2 (r . N) N; the LED, a disc of ``led_radius_mm``, shows where m points at it
    (a Gaussian spot of the disc's angular radius seen from P) over a dim room; the highlight
    saturates. Rays that miss the sphere see a black background. Sensor noise, clipped to
    [0, 1]."""
    centre = np.asarray(centre_mm, dtype=float)
    rays = _unit_rays(device)
    along = np.tensordot(centre, rays, axes=1)
    discriminant = along**2 - (centre @ centre - radius_mm**2)
    hit = discriminant > 0
    distance = along - np.sqrt(np.where(hit, discriminant, 0.0))
    points = distance * rays
    normals = (points - centre[:, None, None]) / radius_mm
    mirrored = rays - 2 * np.sum(rays * normals, axis=0) * normals
    rng = np.random.default_rng(seed)
    images = []
    for led in device.leds:
        towards = np.asarray(led.position_mm, dtype=float)[:, None, None] - points
        length = np.linalg.norm(towards, axis=0)
        angle = np.arccos(np.clip(np.sum(mirrored * towards, axis=0) / length, -1, 1))
        spot = 3.0 * np.exp(-((angle / np.arctan(led_radius_mm / length)) ** 2))
        image = np.where(hit, CHROME_ROOM_LEVEL + spot, 0.0) + noise * rng.standard_normal(hit.shape)
        images.append(np.clip(image, 0.0, 1.0))
    return images


def device_flat_images(device: Device, depth_mm, *, albedo=0.7, noise=0.003, seed=0, band="red"):
    """A flat Lambertian target facing the camera at ``depth_mm``, one image per LED:
    I = albedo n . s(P), n = (0, 0, 1), scaled so that the brightest image peaks at 80% of
    full scale, with sensor noise."""
    a, b = device.camera.rays()
    points = depth_mm * np.stack([a, b, -np.ones_like(a)])
    shading = np.stack([np.maximum(led.light_vectors(points, band)[2], 0.0) for led in device.leds]) * albedo
    shading *= 0.8 / shading.max()
    rng = np.random.default_rng(seed)
    return list(np.clip(shading + noise * rng.standard_normal(shading.shape), 0.0, 1.0))


SPHERE_PLACES_MM = ((-18.0, 12.0, -148.0), (18.0, -12.0, -143.0))  # the chrome sphere's centres in the rehearsal (in the depth of field)
SPHERE_RADIUS_MM = 10.0


def write_device_targets(out, device: Device, *, seed=0, overwrite=False):
    """A calibration rehearsal for ``skintopo calibrate leds``: the chrome sphere (radius 10
    mm) at two places (``place_1/``, ``place_2/``) and a flat matte target at the working
    distance (``flat/``), one 16-bit image per LED each (``01_east.png``, ...: sorted in LED order), rendered through a device whose
    LEDs differ from ``device`` (the design, written as ``design.json``) by a few millimetres,
    with mu 1.3 and unequal intensities; the true device in ``ground_truth.json``."""
    from skintopo.device import write_device
    from skintopo.formats import write_png
    from skintopo.outputs import staged_output_folder

    rng = np.random.default_rng(seed)
    true_leds = tuple(replace(led, position_mm=tuple(float(c) for c in np.add(led.position_mm, rng.uniform(-3, 3, 3))), mu=1.3,
                              intensity={band: float(share) for band in ("red", "green", "blue")})
                      for led, share in zip(device.leds, rng.uniform(0.8, 1.0, len(device.leds))))
    truth = replace(device, leds=true_leds, description="the true device of this rehearsal")
    with staged_output_folder(out, overwrite=overwrite) as staging:
        for place, centre in enumerate(SPHERE_PLACES_MM, start=1):
            folder = staging / f"place_{place}"
            folder.mkdir()
            for i, (led, image) in enumerate(zip(device.leds, device_sphere_images(truth, centre, SPHERE_RADIUS_MM, seed=seed + place))):
                write_png(folder / f"{i + 1:02d}_{led.name}.png", np.round(image * 65535).astype(np.uint16))
        (staging / "flat").mkdir()
        for i, (led, image) in enumerate(zip(device.leds, device_flat_images(truth, truth.working_distance_mm, seed=seed))):
            write_png(staging / "flat" / f"{i + 1:02d}_{led.name}.png", np.round(image * 65535).astype(np.uint16))
        write_device(staging / "design.json", device)
        write_device(staging / "ground_truth.json", truth)
    return Path(out)
