"""Shiny test objects for photometric stereo: a sphere and a wrinkled skin patch with a
rough dielectric coat (Torrance-Sparrow, Beckmann roughness m, Fresnel), rendered by the
simulator under 4, 12 or 50 distant lights, with exact normals. Images are divided by each
band's exposure gain, so the bands are radiometrically comparable, as a calibrated device
delivers them."""

import numpy as np

from skintopo.heightmap import HeightMap
from skintopo.synth import make_surface, preset_spec
from skintopo.synth.render import Effects, RenderSettings, default_lights, render_bands, sensor


def light_set(count):
    """4: the paper's ring at 45 degrees; 12: rings at 25, 45 and 60 degrees; 50 and more:
    a Fibonacci spiral over the cap of slants up to 60 degrees (DiLiGenT-like)."""
    if count == 4:
        return default_lights(45.0, 4)
    if count == 12:
        return np.concatenate([default_lights(slant, 4) @ _rotation_z(offset) for slant, offset in ((25, 0), (45, 30), (60, 60))])
    index = np.arange(count) + 0.5
    cos_slant = 1 - (1 - np.cos(np.radians(60))) * index / count
    azimuth = np.pi * (1 + 5**0.5) * index
    sin_slant = np.sqrt(1 - cos_slant**2)
    return np.stack([sin_slant * np.cos(azimuth), sin_slant * np.sin(azimuth), cos_slant], axis=1)


def _rotation_z(degrees):
    a = np.radians(degrees)
    return np.array([[np.cos(a), np.sin(a), 0], [-np.sin(a), np.cos(a), 0], [0, 0, 1]])


def sphere(size_px=96, pixel_um=10.0):
    """A sphere of radius 0.45 field widths on a flat ground: height (um), exact normals, and
    the evaluation mask (inside 0.95 of the radius, where the height field is well sampled)."""
    radius = 0.45 * size_px * pixel_um
    centre = (size_px - 1) / 2 * pixel_um
    y, x = np.mgrid[0:size_px, 0:size_px] * pixel_um
    dx, dy = x - centre, centre - y  # y up
    inside = dx**2 + dy**2 < radius**2
    z = np.where(inside, np.sqrt(np.maximum(radius**2 - dx**2 - dy**2, 0.0)), 0.0)
    normals = np.where(inside[..., None], np.stack([dx, dy, z], axis=-1) / radius, np.array([0.0, 0.0, 1.0]))
    return HeightMap(z, pixel_um), normals, dx**2 + dy**2 < (0.95 * radius) ** 2


def skin_patch(size_px=96, seed=1):
    """The simulator's moderate forehead (20 um pixels, wrinkles and microrelief)."""
    surface = make_surface(preset_spec("forehead-moderate", size_px=size_px), seed=seed)
    return surface.height, surface.normals, np.ones(surface.height.shape, bool)


def render(height, normals, lights, *, specular_strength=1.0, roughness=0.35, seed=0, noise=1.0):
    """{band: intensity-corrected images (m, rows, columns)} for red, green and blue."""
    settings = RenderSettings(lights=lights, effects=Effects(interreflection=False, translucency=False, specular=specular_strength > 0),
                              specular_strength=specular_strength, specular_roughness=roughness, noise=noise)
    rng = np.random.default_rng(seed)
    linear, _ = render_bands(height, normals, settings, rng)
    corrected = {}
    for band, images in linear.items():
        signal, gain = sensor(images, noise=noise, saturate=False, rng=rng)
        corrected[band] = (signal / gain).astype(np.float32)
    return corrected
