"""The skintopo manifest (``acquisition.json``, format version 1): validation reporting every problem at once, and writing."""

from __future__ import annotations

import json
import math
import os
from pathlib import Path

import numpy as np

from skintopo.defaults import DEFAULT_SATURATION
from skintopo.errors import AcquisitionError, SkinTopoError, header_problems
from skintopo.formats import fsync_path, write_png
from skintopo.acquisition.capture import (
    BANDS,
    CHANNEL_INDEX,
    CHANNELS,
    DEFAULT_WAVELENGTH_NM,
    FORMAT_NAME,
    FORMAT_VERSION,
    MANIFEST_NAME,
    Acquisition,
    BandImages,
    WhiteReference,
    check_bands_requested,
    positive_number,
)
from skintopo.acquisition.images import ImageCache, read_mask
from skintopo.device import DEVICE_NAME, DeviceError, read_device, write_device
from skintopo.lights import check_light_directions
from skintopo.acquisition.radiometry import full_scale_of, normalise


_IMAGE_KEYS = {"file", "band", "light", "led", "intensity", "wavelength_nm", "channel", "flat"}


_MANIFEST_KEYS = {"format", "version", "pixel_size_um", "mask", "gamma", "full_scale", "images", "description", "dark", "crosstalk",
                  "device", "white_reference"}
_WHITE_REFERENCE_KEYS = {"box_px", "reflectance"}
SATURATED_REFERENCE_LIMIT = 0.01  # more than this fraction of a white reference box's observations saturated: refused


def _white_reference(entry, name, problems):
    """The manifest's ``white_reference`` as a :class:`WhiteReference` (None, with the
    problems appended, when it is malformed): ``{"box_px": [row_start, column_start,
    row_stop, column_stop], "reflectance": r or {"red": r, "green": r, "blue": r}}``."""
    label = f"{name}: field 'white_reference'"
    if not isinstance(entry, dict):
        problems.append(f"{label} must be an object with 'box_px' and 'reflectance'")
        return None
    unknown = sorted(set(entry) - _WHITE_REFERENCE_KEYS)
    missing = sorted(_WHITE_REFERENCE_KEYS - set(entry))
    if unknown or missing:
        problems.append(f"{label}: " + "; ".join(filter(None, [unknown and f"unknown keys {unknown}", missing and f"missing {missing}"])))
        return None
    box = entry["box_px"]
    if not (isinstance(box, list) and len(box) == 4 and all(isinstance(v, int) and not isinstance(v, bool) and v >= 0 for v in box)
            and box[2] > box[0] and box[3] > box[1]):
        problems.append(f"{label}: 'box_px' must be [row_start, column_start, row_stop, column_stop], non-negative integers with "
                        f"stop > start, got {box!r}")
        return None
    value = entry["reflectance"]
    reflectance = dict.fromkeys(("red", "green", "blue"), value) if not isinstance(value, dict) else value
    bad = {band: r for band, r in reflectance.items() if not (positive_number(r) and r <= 1)}
    if set(reflectance) != {"red", "green", "blue"} or bad:
        problems.append(f"{label}: 'reflectance' must be a number in (0, 1] or one per band (red, green, blue), got {value!r}")
        return None
    return WhiteReference(tuple(box), {band: float(r) for band, r in reflectance.items()})


def _white_reference_problems(reference, by_band, shape, name):
    """The box must lie inside the images, hold no more than 1% saturated observations in
    any image and be lit."""
    top, left, bottom, right = reference.box_px
    if bottom > shape[0] or right > shape[1]:
        return [f"{name}: the white reference box {list(reference.box_px)} reaches outside the {shape[0]} x {shape[1]} images"]
    problems = []
    rows, columns = reference.slices
    for band in ("red", "green", "blue"):
        if band not in by_band:
            continue
        for file, image in zip(by_band[band].files, by_band[band].images):
            saturated = float(np.isnan(image[rows, columns]).mean())
            if saturated > SATURATED_REFERENCE_LIMIT:
                problems.append(f"{Path(file).name}: {100 * saturated:.1f}% of the white reference box is saturated: lower the "
                                "exposure (the reference must be captured unsaturated under every light)")
    return problems


def load_manifest(manifest_path, pixel_um, bands, saturation, bytes_per_pixel=None):
    folder = manifest_path.parent
    try:
        manifest = json.loads(manifest_path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise AcquisitionError(manifest_path, [f"not valid JSON ({exc})"]) from None
    name = manifest_path.name
    if not isinstance(manifest, dict):
        raise AcquisitionError(manifest_path, ["the manifest must be a JSON object"])
    problems = header_problems(manifest, _MANIFEST_KEYS, FORMAT_NAME, FORMAT_VERSION, prefix=f"{name}: ")
    declared_pixel = manifest.get("pixel_size_um")
    if not positive_number(declared_pixel):
        problems.append(f"{name}: field 'pixel_size_um' must be a positive number of micrometres, got {declared_pixel!r}")
    elif pixel_um is not None and not math.isclose(pixel_um, declared_pixel, rel_tol=1e-9):
        problems.append(f"{name}: pixel_size_um is {declared_pixel} but {pixel_um} was given")
    gamma = manifest.get("gamma", 1.0)
    if not (gamma == "srgb" or positive_number(gamma)):
        problems.append(f"{name}: field 'gamma' must be a positive number or \"srgb\", got {gamma!r}")
    full_scale = manifest.get("full_scale")
    if full_scale is not None and not positive_number(full_scale):
        problems.append(f"{name}: field 'full_scale' must be a positive number, got {full_scale!r}")
    crosstalk = manifest.get("crosstalk")
    unmix = None
    if crosstalk is not None:
        try:
            matrix = np.array(crosstalk, dtype=float)
            unmix = np.linalg.inv(matrix) if matrix.shape == (3, 3) and np.all(np.isfinite(matrix)) else None
        except (ValueError, TypeError, np.linalg.LinAlgError):
            unmix = None
        if unmix is None:
            problems.append(f"{name}: field 'crosstalk' must be an invertible 3 x 3 matrix (camera channel rows, LED band columns)")
    device = None
    device_file = manifest.get("device")
    if device_file is not None:
        if not (isinstance(device_file, str) and device_file):
            problems.append(f"{name}: field 'device' must name a device file (device.json)")
        else:
            try:
                device = read_device(folder / device_file)
            except DeviceError as error:
                problems += [f"{device_file}: {problem}" for problem in error.problems]
    if device is not None and positive_number(declared_pixel) and abs(declared_pixel / device.pixel_um - 1) > 1e-3:
        problems.append(f"{name}: pixel_size_um is {declared_pixel} but the device's pixel footprint at its working distance is "
                        f"{device.pixel_um:.6g} um")
    white_reference = None
    if manifest.get("white_reference") is not None:
        white_reference = _white_reference(manifest["white_reference"], name, problems)
        if device is not None and white_reference is not None:
            problems.append(f"{name}: a white reference box is not supported with a device (near-field LEDs light it unevenly)")
    dark_file = manifest.get("dark")
    if dark_file is not None and not (isinstance(dark_file, str) and dark_file):
        problems.append(f"{name}: field 'dark' must name an image file")
    entries = manifest.get("images")
    if not isinstance(entries, list) or not entries:
        problems.append(f"{name}: field 'images' must be a non-empty list")
        entries = []

    parsed = []  # (band, file path, light, intensity, wavelength, channel, label)
    for index, entry in enumerate(entries):
        label = f"{name}: images[{index}]"
        if not isinstance(entry, dict):
            problems.append(f"{label} must be an object")
            continue
        file = entry.get("file")
        if isinstance(file, str) and file:
            label = f"{name}: images[{index}] ({file})"
        else:
            problems.append(f"{label}: field 'file' must name an image file")
        for key in sorted(set(entry) - _IMAGE_KEYS):
            problems.append(f"{label}: unknown field {key!r}")
        if not isinstance(file, str) or not file:
            continue
        band = entry.get("band")
        if band not in BANDS:
            problems.append(f"{label}: field 'band' must be one of {list(BANDS)}, got {band!r}")
        light = entry.get("light")
        led = entry.get("led")
        if device_file is not None:
            # With a device the LED is named, and the light vector depends on the point lit.
            if "light" in entry:
                problems.append(f"{label}: with a 'device', name the image's LED ('led'), not a light direction ('light')")
            if "flat" in entry:
                problems.append(f"{label}: with a 'device', a per-light 'flat' is not used: the device models the LEDs' fall-off")
            if device is not None:
                names = [d.name for d in device.leds]
                if led not in names:
                    problems.append(f"{label}: field 'led' must name one of the device's LEDs {names}, got {led!r}")
                else:
                    light = device.central_directions()[names.index(led)].tolist()
        elif led is not None:
            problems.append(f"{label}: field 'led' needs a 'device' file in the manifest")
        elif not (isinstance(light, list) and len(light) == 3 and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in light)):
            problems.append(f"{label}: field 'light' must be a list of 3 numbers (unit vector x, y, z)")
            light = None
        intensity = entry.get("intensity", 1.0)
        if not positive_number(intensity):
            problems.append(f"{label}: field 'intensity' must be a positive number, got {intensity!r}")
        wavelength = entry.get("wavelength_nm", DEFAULT_WAVELENGTH_NM.get(band))
        if wavelength is not None and not positive_number(wavelength):
            problems.append(f"{label}: field 'wavelength_nm' must be a positive number, got {wavelength!r}")
        channel = entry.get("channel")
        if channel is not None and channel not in CHANNELS:
            problems.append(f"{label}: field 'channel' must be one of {list(CHANNELS)}, got {channel!r}")
        flat = entry.get("flat")
        if flat is not None and not (isinstance(flat, str) and flat):
            problems.append(f"{label}: field 'flat' must name an image file")
        elif flat is not None and "intensity" in entry:
            problems.append(f"{label}: give either 'flat' (the intensity is then measured) or 'intensity', not both")
        flat_file = folder / flat if isinstance(flat, str) and flat else None  # a bad 'flat' is reported above
        parsed.append((band, folder / file, light, intensity, wavelength, channel, label, flat_file, led))

    if problems:  # structure is wrong: do not read images yet, report what we have
        raise AcquisitionError(manifest_path, problems)

    present = {p[0] for p in parsed}
    wanted = check_bands_requested(manifest_path, bands, present)
    for band in sorted(present):
        members = [p for p in parsed if p[0] == band]
        for problem in check_light_directions([p[2] for p in members], [p[6] for p in members]):
            problems.append(problem if problem.startswith(name) else f"{name}: band {band}: {problem}")
        leds = [p[8] for p in members if p[8] is not None]
        if len(set(leds)) != len(leds):
            problems.append(f"{name}: band {band}: each LED may have one image per band, got {sorted(leds)}")

    images = sum(1 for entry in parsed if entry[0] in wanted)
    cache = ImageCache(problems, None if bytes_per_pixel is None else (manifest_path, images, bytes_per_pixel))
    dark_path = folder / dark_file if isinstance(dark_file, str) and dark_file else None
    cache.prefetch([path for path in [dark_path] + [path for band in wanted for p in parsed if p[0] == band for path in (p[1], p[7])]
                    if path is not None])  # in the order they are read below
    dark = cache.get(dark_path) if dark_path is not None else None

    def linear(image, channel, band):
        """Dark-subtracted, linear, unmixed, one channel; NaN where saturated."""
        scale = full_scale_of(image.dtype, full_scale)
        # Normalise before picking the channel, so that a saturated channel makes the mean NaN too.
        values = normalise(image, scale, saturation, gamma)
        if dark is not None:
            values = values - np.nan_to_num(normalise(dark, scale, 2.0, gamma))
        if values.ndim == 3:
            if unmix is not None:
                values = values @ unmix.T.astype(np.float32)
            channel = channel or ("mean" if band == "white" else band)
            values = values.mean(axis=2) if channel == "mean" else values[..., CHANNEL_INDEX[channel]]
        return values

    by_band = {}
    for band in wanted:
        members = [p for p in parsed if p[0] == band]
        images = []
        for _, file, light, intensity, wavelength, channel, label, flat_file, _ in members:
            image = cache.get(file)
            if image is None:
                continue
            if image.ndim == 2 and channel not in (None, "mean"):
                problems.append(f"{label}: field 'channel' is {channel!r} but the image has a single channel")
                continue
            values = linear(image, channel, band)
            if flat_file is not None:
                flat = cache.get(flat_file)
                if flat is None:
                    continue
                # A flat diffuse target facing the camera gives rho_ref e_i(x) l_z: dividing by it
                # and multiplying by l_z removes the light's intensity and its spatial fall-off.
                flat_values = linear(flat, channel, band)
                with np.errstate(invalid="ignore", divide="ignore"):
                    values = np.where(flat_values > 0, values / flat_values, np.nan) * np.float32(light[2] / np.linalg.norm(light))
                images.append(values.astype(np.float32))
            else:
                images.append(values / np.float32(intensity))
        if len(images) == len(members):
            lights = np.array([p[2] for p in members], dtype=np.float64)
            with np.errstate(invalid="ignore", divide="ignore"):  # bad lights are already reported
                lights /= np.linalg.norm(lights, axis=1, keepdims=True)
            leds = tuple(p[8] for p in members) if device is not None else None
            by_band[band] = BandImages(band, np.stack(images), lights, tuple(str(p[1]) for p in members), members[0][4], leds)

    shape = cache.reference[1] if cache.reference else None
    mask = None
    if manifest.get("mask") is not None:
        if not isinstance(manifest["mask"], str):
            problems.append(f"{name}: field 'mask' must name an image file")
        else:
            mask = read_mask(folder / manifest["mask"], shape, problems)
    if problems:
        raise AcquisitionError(manifest_path, problems)
    if device is not None and shape is not None and tuple(shape) != tuple(device.camera.size_px):
        problems.append(f"{name}: the images are {shape[0]} x {shape[1]} pixels but the device's camera has "
                        f"{device.camera.size_px[0]} x {device.camera.size_px[1]}")
    if problems:
        raise AcquisitionError(manifest_path, problems)
    if white_reference is not None:
        problems += _white_reference_problems(white_reference, by_band, shape, name)
    if problems:
        raise AcquisitionError(manifest_path, problems)
    if mask is None:
        mask = np.ones(shape, dtype=bool)
    return Acquisition(folder, "manifest", by_band, float(declared_pixel), False, mask, device, white_reference)


def write_acquisition(folder, bands, pixel_um, *, mask=None, description=None, intensities=None, device=None, white_reference=None):
    """Write images to an acquisition folder in the manifest format (16-bit PNG, linear).

    Parameters
    ----------
    folder : str or Path
        Created; must not exist or be empty.
    bands : dict of str to (images, lights)
        For each band, linear intensities ``(m, rows, columns)`` as fractions of full scale
        (values are clipped to [0, 1] and quantised to 16 bits) and unit light directions
        ``(m, 3)``.
    pixel_um : float
        Pixel size in micrometres.
    mask : array_like of bool, optional
        Written as ``mask.png`` (255 inside).
    description : str, optional
        Free text stored in the manifest.
    intensities : dict of str to float, optional
        Relative light intensity per band (the gain between radiance and recorded values),
        written to every image entry of the band.
    device : skintopo.device.Device, optional
        Written as ``device.json``; the images of each band are then one per LED, in the
        device's order, and entries name their LED instead of a light direction.
    white_reference : WhiteReference, optional
        Written as the manifest field ``white_reference``.

    Returns
    -------
    Path
        The manifest path.
    """
    folder = Path(folder)
    if folder.exists() and any(folder.iterdir()):
        raise SkinTopoError(f"{folder}: folder is not empty; will not write an acquisition into it")
    folder.mkdir(parents=True, exist_ok=True)
    entries = []
    for band, (images, lights) in bands.items():
        if band not in BANDS:
            raise SkinTopoError(f"unknown band {band!r}; choose from {list(BANDS)}")
        for index, (image, light) in enumerate(zip(np.asarray(images), np.asarray(lights, dtype=float))):
            name = f"{band}_{index:02d}.png"
            counts = np.round(np.clip(np.nan_to_num(image), 0.0, 1.0) * 65535).astype(np.uint16)
            write_png(folder / name, counts)
            if device is None:
                entry = {"file": name, "band": band, "light": [round(float(v), 9) for v in light]}
            else:
                entry = {"file": name, "band": band, "led": device.leds[index].name}
            if intensities and band in intensities:
                entry["intensity"] = float(intensities[band])
            if DEFAULT_WAVELENGTH_NM[band] is not None:
                entry["wavelength_nm"] = DEFAULT_WAVELENGTH_NM[band]
            entries.append(entry)
    manifest = {"format": FORMAT_NAME, "version": FORMAT_VERSION, "pixel_size_um": float(pixel_um)}
    if device is not None:
        write_device(folder / DEVICE_NAME, device)
        manifest["device"] = DEVICE_NAME
    if description:
        manifest["description"] = description
    if mask is not None:
        write_png(folder / "mask.png", np.where(np.asarray(mask, dtype=bool), 255, 0).astype(np.uint8))
        manifest["mask"] = "mask.png"
    if white_reference is not None:
        manifest["white_reference"] = {"box_px": list(white_reference.box_px), "reflectance": dict(white_reference.reflectance)}
    manifest["images"] = entries
    path = folder / MANIFEST_NAME
    path.write_text(json.dumps(manifest, indent=2) + "\n", encoding="utf-8")
    return path


IMAGE_SUFFIXES = (".png", ".tif", ".tiff")


def manifest_for_folder(folder, lights, pixel_um, *, pattern="{band}_{index}", mask=None):
    """A manifest (dict) for a folder of images named after ``pattern`` and a list of lights.

    ``pattern`` names the files without their suffix: ``{band}`` stands for red, green, blue
    or white and ``{index}`` for the light's number (any integers: sorted, the k-th file of a
    band is taken under the k-th light). ``lights`` is the ``lights`` list that ``skintopo
    calibrate lights`` writes: ``{"light": [x, y, z], "intensity": ...}`` per light, in light
    order (``intensity`` optional). Every problem is reported at once (AcquisitionError).
    """
    import re

    folder = Path(folder)
    problems = []
    if "{band}" not in pattern or "{index}" not in pattern:
        raise AcquisitionError(folder, [f"the file name pattern {pattern!r} must contain {{band}} and {{index}}"])
    regex = re.compile("^" + re.escape(pattern).replace(r"\{band\}", "(?P<band>" + "|".join(BANDS) + ")")
                       .replace(r"\{index\}", r"(?P<index>\d+)") + "$")
    found = {}
    for path in sorted(folder.iterdir()) if folder.is_dir() else []:
        match = regex.match(path.stem) if path.suffix.lower() in IMAGE_SUFFIXES else None
        if match:
            found.setdefault(match["band"], []).append((int(match["index"]), path.name))
    if not folder.is_dir():
        raise AcquisitionError(folder, ["no such folder"])
    if not found:
        raise AcquisitionError(folder, [f"no image named like {pattern!r} (.png, .tif): e.g. red_1.png, for band red under light 1"])
    entries = []
    for band in (b for b in BANDS if b in found):
        files = sorted(found[band])
        if len(files) != len(lights):
            problems.append(f"band {band}: {len(files)} image(s) ({', '.join(name for _, name in files)}) for {len(lights)} light(s)")
            continue
        for (_, name), light in zip(files, lights):
            entry = {"file": name, "band": band, "light": [float(v) for v in light["light"]]}
            if "intensity" in light:
                entry["intensity"] = float(light["intensity"])
            entries.append(entry)
    if problems:
        raise AcquisitionError(folder, problems)
    manifest = {"format": FORMAT_NAME, "version": FORMAT_VERSION, "pixel_size_um": float(pixel_um)}
    if mask is not None:
        manifest["mask"] = Path(mask).name
    manifest["images"] = entries
    return manifest


def write_manifest(folder, manifest, *, overwrite=False):
    """Write ``folder/acquisition.json`` after checking it loads as :func:`load_acquisition`
    would load it (every problem reported, nothing written when one is found). An existing
    manifest is replaced only with ``overwrite``; the images are never touched."""
    folder = Path(folder)
    target = folder / MANIFEST_NAME
    if target.exists() and not overwrite:
        raise SkinTopoError(f"{target}: exists; use --overwrite to replace it")
    trial = folder / f".{MANIFEST_NAME}.checking.json"
    trial.write_text(json.dumps(manifest, indent=2) + "\n", encoding="utf-8")
    try:
        acquisition = load_manifest(trial, None, None, DEFAULT_SATURATION)
        fsync_path(trial)
        os.replace(trial, target)
        fsync_path(folder)
    finally:
        trial.unlink(missing_ok=True)
    return acquisition
