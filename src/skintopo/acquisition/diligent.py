"""The DiLiGenT folder layout (Shi et al. 2016/2019)."""

from __future__ import annotations

import numpy as np

from skintopo.errors import AcquisitionError
from skintopo.acquisition.capture import BANDS, CHANNEL_INDEX, DEFAULT_WAVELENGTH_NM, Acquisition, BandImages, check_bands_requested, positive_number
from skintopo.acquisition.images import ImageCache, read_mask
from skintopo.lights import check_light_directions
from skintopo.acquisition.radiometry import full_scale_of, normalise


def _read_table(path, columns, problems):
    try:
        table = np.loadtxt(path, ndmin=2)
    except (OSError, ValueError) as exc:
        problems.append(f"{path}: not a table of numbers ({exc})")
        return None
    if table.shape[1] != columns:
        problems.append(f"{path}: expected {columns} numbers per line, got {table.shape[1]}")
        return None
    return table


def load_diligent(folder, pixel_um, bands, saturation, bytes_per_pixel=None):
    problems = []
    names = (folder / "filenames.txt").read_text(encoding="utf-8").split()
    lights = _read_table(folder / "light_directions.txt", 3, problems)
    intensities = None
    if (folder / "light_intensities.txt").is_file():
        intensities = _read_table(folder / "light_intensities.txt", 3, problems)
    for table, file in ((lights, "light_directions.txt"), (intensities, "light_intensities.txt")):
        if table is not None and len(table) != len(names):
            problems.append(f"{folder / file}: {len(table)} lines for {len(names)} images in filenames.txt")
    if intensities is not None and not np.all(intensities > 0):
        problems.append(f"{folder / 'light_intensities.txt'}: intensities must be positive")
    if lights is not None and len(lights) == len(names):
        problems += [f"{folder / 'light_directions.txt'}: {p}" for p in check_light_directions(lights, [f"line {i + 1} ({n})" for i, n in enumerate(names)])]
    if pixel_um is not None and not positive_number(pixel_um):
        problems.append(f"pixel size must be a positive number of micrometres, got {pixel_um!r}")
    if problems:
        raise AcquisitionError(folder, problems)
    wanted = check_bands_requested(folder, bands, set(BANDS))

    # held at once: the raw RGB 16-bit files (1.5 float32 images each) and a float32 image per band and file
    images = (1.5 + len(wanted)) * len(names)
    cache = ImageCache(problems, None if bytes_per_pixel is None else (folder, images, bytes_per_pixel))
    raw = [cache.get(folder / n) for n in names]
    if not problems and raw[0].ndim != 3:
        problems.append(f"{folder / names[0]}: DiLiGenT images are RGB; this one has a single channel")
    if problems:
        raise AcquisitionError(folder, problems)
    shape, dtype = cache.reference[1], cache.reference[2]
    mask = read_mask(folder / "mask.png", shape, problems) if (folder / "mask.png").is_file() else np.ones(shape, bool)
    if problems:
        raise AcquisitionError(folder, problems)

    scale = full_scale_of(dtype, None)
    per_light = intensities if intensities is not None else np.ones((len(names), 3))
    channels = {}
    for band in wanted:
        needed = ("red", "green", "blue") if band == "white" else (band,)
        for colour in needed:
            if colour not in channels:
                c = CHANNEL_INDEX[colour]
                channels[colour] = np.stack(
                    [normalise(image[..., c], scale, saturation, 1.0) / np.float32(per_light[i, c]) for i, image in enumerate(raw)]
                )
    lights = lights / np.linalg.norm(lights, axis=1, keepdims=True)
    files = tuple(str(folder / n) for n in names)
    by_band = {}
    for band in wanted:
        if band == "white":
            images = (channels["red"] + channels["green"] + channels["blue"]) / np.float32(3)
        else:
            images = channels[band]
        by_band[band] = BandImages(band, images, lights, files, DEFAULT_WAVELENGTH_NM[band])
    assumed = pixel_um is None
    return Acquisition(folder, "diligent", by_band, 1.0 if assumed else float(pixel_um), assumed, mask)
