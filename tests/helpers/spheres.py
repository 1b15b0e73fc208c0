"""Rendered calibration spheres (skintopo.synth.targets) written as 16-bit images, and their true lights."""

import numpy as np

from skintopo.formats import write_png
from skintopo.synth.targets import sphere_images

SHAPE = (240, 300)


def true_lights():
    slant = np.radians([30, 40, 45, 55, 35, 60])
    tilt = np.radians([10, 95, 185, 275, 140, 320])
    return np.stack([np.sin(slant) * np.cos(tilt), np.sin(slant) * np.sin(tilt), np.cos(slant)], axis=1)


def sixteen_bit(images):
    return [np.round(image * 65535).astype(np.uint16) for image in images]


def render_chrome(lights, seed=0):
    """Mirror sphere (skintopo.synth.targets: an LED about 2 degrees wide reflected where the
    mirror direction of the view meets it, a dim room, noise, a saturated highlight), 16-bit."""
    return sixteen_bit(sphere_images("chrome-sphere", lights, shape=SHAPE, seed=seed)[0])


def write(folder, images):
    folder.mkdir(exist_ok=True)
    paths = []
    for i, image in enumerate(images):
        paths.append(folder / f"sphere_{i}.png")
        write_png(paths[-1], image)
    return paths


def angle_degrees(a, b):
    return np.degrees(np.arccos(np.clip(np.sum(np.asarray(a) * np.asarray(b), axis=-1), -1, 1)))
