"""Acquisitions: reading and validating one photometric-stereo capture.

Two folder layouts are read.

**skintopo manifest, format version 1** (``acquisition.json`` in the folder)::

    {
      "format": "skintopo-acquisition",
      "version": 1,
      "pixel_size_um": 20.0,
      "mask": "mask.png",                 # optional; non-zero = measured skin
      "gamma": 1.0,                       # optional; 1.0 = linear data (default), a number g
                                          # means linear = value ** g, "srgb" undoes sRGB
      "full_scale": 65535,                # optional; default from the bit depth (255, 65535)
      "images": [
        {"file": "red_0.png", "band": "red", "light": [0.707, 0.0, 0.707],
         "intensity": 1.0,                # optional relative light intensity, default 1
         "wavelength_nm": 625,            # optional; defaults 625/523/462 nm for red/green/blue
         "channel": "red"}                # camera channel: red, green, blue or mean; only for
                                          # RGB images, default = the band's colour (mean for white)
      ]
    }

Light directions are unit vectors in the camera frame: x right, y up, z toward the camera.
The same RGB file may be listed once per channel (white light, each channel a band).

**DiLiGenT layout** (Shi et al. 2016/2019): ``filenames.txt``, ``light_directions.txt``
(one unit vector per line, same frame), optional ``light_intensities.txt`` (RGB intensity
per light; each image is divided by its row) and ``mask.png``. The RGB images give bands
red, green, blue and a grey ``white`` band (the mean of the three intensity-corrected
channels). Such folders carry no pixel size: it is given by the caller (default 1 um, and
:attr:`Acquisition.pixel_um_assumed` says so).

Images are 8- or 16-bit PNG or TIFF (or float TIFF), or camera raw files (rawpy: linear,
no auto-brightness, no white balance), kept in linear units: nothing is guessed about gamma. 16-bit RGB PNGs are read with OpenCV, because Pillow (and readers built on it)
silently reduces them to 8 bits.

Every problem found while reading is collected and reported at once in an
:class:`~skintopo.errors.AcquisitionError` naming the file and the field.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from skintopo.errors import AcquisitionError, SkinTopoError
from skintopo.formats import read_png, write_png

MANIFEST_NAME = "acquisition.json"
FORMAT_NAME = "skintopo-acquisition"
FORMAT_VERSION = 1
BANDS = ("red", "green", "blue", "white")
DEFAULT_WAVELENGTH_NM = {"red": 625.0, "green": 523.0, "blue": 462.0, "white": None}
CHANNEL_INDEX = {"red": 0, "green": 1, "blue": 2}
CHANNELS = ("red", "green", "blue", "mean")
RAW_SUFFIXES = (".dng", ".nef", ".cr2", ".cr3", ".arw", ".raf", ".orf", ".rw2", ".pef", ".srw")
UNIT_TOLERANCE = 1e-3
DEFAULT_SATURATION = 0.995
_IMAGE_KEYS = {"file", "band", "light", "intensity", "wavelength_nm", "channel", "flat"}
_MANIFEST_KEYS = {"format", "version", "pixel_size_um", "mask", "gamma", "full_scale", "images", "description", "dark", "crosstalk"}


@dataclass(frozen=True, eq=False)
class BandImages:
    """The images of one spectral band.

    Attributes
    ----------
    band : str
        red, green, blue or white.
    images : ndarray, shape (m, rows, columns), float32
        Linear intensities as a fraction of the sensor's full scale, divided by each light's
        relative intensity. NaN marks a saturated observation, which must not be used.
    lights : ndarray, shape (m, 3)
        Unit light directions in the camera frame.
    files : tuple of str
        The image file of each row of ``images``.
    wavelength_nm : float or None
    """

    band: str
    images: np.ndarray
    lights: np.ndarray
    files: tuple
    wavelength_nm: float | None


@dataclass(frozen=True, eq=False)
class Acquisition:
    """One validated capture: images per band, the pixel size and the mask.

    Attributes
    ----------
    source : Path
        The folder read.
    layout : str
        ``"manifest"`` or ``"diligent"``.
    bands : dict of str to BandImages
    pixel_um : float
        Pixel size in micrometres.
    pixel_um_assumed : bool
        True when the folder carries no pixel size and a default was used.
    mask : ndarray of bool, shape (rows, columns)
        True where the skin (object) is measured.
    """

    source: Path
    layout: str
    bands: dict
    pixel_um: float
    pixel_um_assumed: bool
    mask: np.ndarray

    @property
    def shape(self):
        """Image shape (rows, columns)."""
        return self.mask.shape


def read_image(path):
    """Read a PNG or TIFF image with its native bit depth.

    Returns
    -------
    ndarray
        ``(rows, columns)`` or ``(rows, columns, 3)`` (RGB order; an alpha channel is dropped),
        in the file's own dtype (uint8, uint16 or float).

    Raises
    ------
    SkinTopoError
        Naming the file, when it is missing, of an unsupported type or unreadable.
    """
    path = Path(path)
    if not path.is_file():
        raise SkinTopoError(f"{path}: image file not found")
    suffix = path.suffix.lower()
    if suffix == ".png":
        image = read_png(path)
        if image.ndim == 3:
            image = image[..., :3] if image.shape[2] >= 3 else image[..., 0]  # alpha dropped
    elif suffix in (".tif", ".tiff"):
        import tifffile

        try:
            image = tifffile.imread(path)
        except Exception as exc:  # tifffile raises many types for damaged files
            raise SkinTopoError(f"{path}: not a readable TIFF image ({exc})") from None
        if image.ndim == 3 and image.shape[0] in (3, 4) and image.shape[2] not in (3, 4):
            image = np.moveaxis(image, 0, -1)  # planar RGB
        if image.ndim == 3:
            image = image[..., :3]
    elif suffix in RAW_SUFFIXES:
        image = _read_raw(path)
    else:
        raise SkinTopoError(f"{path}: unsupported image type {suffix!r} (use PNG, TIFF or a camera raw file)")
    if image.ndim not in (2, 3) or (image.ndim == 3 and image.shape[2] != 3):
        raise SkinTopoError(f"{path}: expected a grey or RGB image, got an array of shape {image.shape}")
    if not (np.issubdtype(image.dtype, np.unsignedinteger) or np.issubdtype(image.dtype, np.floating)):
        raise SkinTopoError(f"{path}: unsupported pixel type {image.dtype}")
    return np.ascontiguousarray(image)


def _read_raw(path):
    """Camera raw via rawpy (LibRaw): demosaiced, linear (gamma 1), no auto-brightness, no
    white balance, the camera's native colour channels, 16 bits."""
    import rawpy

    try:
        with rawpy.imread(str(path)) as raw:
            return raw.postprocess(
                gamma=(1, 1), no_auto_bright=True, output_bps=16, use_camera_wb=False, use_auto_wb=False,
                user_wb=[1.0, 1.0, 1.0, 1.0], output_color=rawpy.ColorSpace.raw,
            )
    except (rawpy.LibRawError, OSError, ValueError) as exc:
        raise SkinTopoError(f"{path}: not a readable camera raw file ({exc.__class__.__name__}: {exc})") from None


def check_light_directions(lights, names=None):
    """List what is wrong with a set of light directions (an empty list if nothing).

    Each direction must be a finite, non-zero unit vector (norm within 1e-3 of 1) pointing
    toward the camera side (z > 0), and the set must hold at least three directions that are
    not coplanar (smallest / largest singular value of the m x 3 matrix above 1e-3): otherwise
    the Lambertian system n = (S^T S)^-1 S^T I has no unique solution.

    Parameters
    ----------
    lights : array_like, shape (m, 3)
    names : sequence of str, optional
        A label for each light, used in the messages.
    """
    lights = np.asarray(lights, dtype=np.float64)
    if lights.ndim != 2 or lights.shape[1] != 3:
        return [f"light directions must be an m x 3 array, got shape {lights.shape}"]
    names = names or [f"light {i}" for i in range(len(lights))]
    problems = []
    norms = np.linalg.norm(lights, axis=1)
    for name, light, norm in zip(names, lights, norms):
        if not np.all(np.isfinite(light)):
            problems.append(f"{name}: light direction {light.tolist()} is not finite")
        elif norm == 0:
            problems.append(f"{name}: light direction is the zero vector")
        elif abs(norm - 1) > UNIT_TOLERANCE:
            problems.append(f"{name}: light direction {light.tolist()} is not a unit vector (norm {norm:.4f})")
        elif light[2] <= 0:
            problems.append(f"{name}: light direction {light.tolist()} points away from the camera (z <= 0)")
    if len(lights) < 3:
        problems.append(f"only {len(lights)} light(s); photometric stereo needs at least 3")
    elif not problems:
        singular = np.linalg.svd(lights, compute_uv=False)
        if singular[-1] / singular[0] < 1e-3:
            problems.append("the light directions are coplanar: the surface normal cannot be solved for")
    return problems


def load_acquisition(path, *, pixel_um=None, bands=None, saturation=DEFAULT_SATURATION):
    """Read and validate an acquisition folder.

    Parameters
    ----------
    path : str or Path
        A folder holding ``acquisition.json`` or a DiLiGenT layout, or the manifest file.
    pixel_um : float, optional
        Pixel size in micrometres for folders that carry none (DiLiGenT); default 1. For a
        manifest it must agree with ``pixel_size_um`` if given.
    bands : sequence of str, optional
        Bands to read (default: all present).
    saturation : float
        Observations at or above this fraction of the sensor's full scale are marked
        saturated (NaN) and left out of the fit.

    Returns
    -------
    Acquisition

    Raises
    ------
    AcquisitionError
        Listing every problem found, each naming the file and field.
    """
    path = Path(path)
    if path.is_file() and path.suffix.lower() == ".json":
        return _load_manifest(path, pixel_um, bands, saturation)
    if not path.is_dir():
        raise AcquisitionError(path, ["no such acquisition folder or manifest"])
    if (path / MANIFEST_NAME).is_file():
        return _load_manifest(path / MANIFEST_NAME, pixel_um, bands, saturation)
    if (path / "filenames.txt").is_file() and (path / "light_directions.txt").is_file():
        return _load_diligent(path, pixel_um, bands, saturation)
    raise AcquisitionError(
        path, [f"neither {MANIFEST_NAME} nor a DiLiGenT layout (filenames.txt, light_directions.txt) found"]
    )


def _check_bands_requested(source, bands, present):
    if bands is None:
        return [b for b in BANDS if b in present]
    unknown = [b for b in bands if b not in BANDS]
    if unknown:
        raise AcquisitionError(source, [f"unknown band(s) {unknown}; choose from {list(BANDS)}"])
    missing = [b for b in bands if b not in present]
    if missing:
        raise AcquisitionError(source, [f"band(s) {missing} not in this acquisition (it has {sorted(present)})"])
    return list(bands)


class _ImageCache:
    """Reads each file once, checking that all images share one shape and one pixel type."""

    def __init__(self, problems):
        self.problems = problems
        self.images = {}
        self.reference = None  # (file, shape, dtype)

    def get(self, path):
        if path in self.images:
            return self.images[path]
        try:
            image = read_image(path)
        except SkinTopoError as exc:
            self.problems.append(str(exc))
            image = None
        if image is not None:
            if self.reference is None:
                self.reference = (path.name, image.shape[:2], image.dtype)
            else:
                ref_name, ref_shape, ref_dtype = self.reference
                if image.shape[:2] != ref_shape:
                    self.problems.append(
                        f"{path}: image size {image.shape[1]}x{image.shape[0]} differs from "
                        f"{ref_name} ({ref_shape[1]}x{ref_shape[0]})"
                    )
                    image = None
                elif image.dtype != ref_dtype:
                    self.problems.append(
                        f"{path}: pixel type {image.dtype} differs from {ref_name} ({ref_dtype}); "
                        "all images of an acquisition must share one bit depth"
                    )
                    image = None
        self.images[path] = image
        return image


def _full_scale(dtype, declared):
    if declared is not None:
        return float(declared)
    if np.issubdtype(dtype, np.unsignedinteger):
        return float(np.iinfo(dtype).max)
    return None  # float images: taken as already normalised, no saturation test


def _linearise(values, gamma):
    """Undo the declared transfer function; ``gamma`` 1.0 (the default) leaves data linear."""
    if gamma == "srgb":
        return np.where(values <= 0.04045, values / 12.92, ((values + 0.055) / 1.055) ** 2.4).astype(np.float32)
    if gamma != 1.0:
        return np.power(values, np.float32(gamma))
    return values


def _normalise(image, full_scale, saturation, gamma):
    """Linear intensity as a fraction of full scale, NaN where saturated."""
    values = image.astype(np.float32)
    if full_scale is not None:
        saturated = values >= saturation * full_scale
        values /= np.float32(full_scale)
        values = _linearise(values, gamma)
        values[saturated] = np.nan
    return values


def _read_mask(path, shape, problems):
    try:
        mask = read_image(path)
    except SkinTopoError as exc:
        problems.append(str(exc))
        return None
    mask = mask.any(axis=2) if mask.ndim == 3 else mask > 0
    if shape is not None and mask.shape != shape:
        problems.append(f"{path}: mask size {mask.shape[1]}x{mask.shape[0]} differs from the images ({shape[1]}x{shape[0]})")
        return None
    return mask


def _positive_number(value):
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value) and value > 0


def _load_manifest(manifest_path, pixel_um, bands, saturation):
    folder = manifest_path.parent
    try:
        manifest = json.loads(manifest_path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise AcquisitionError(manifest_path, [f"not valid JSON ({exc})"]) from None
    problems = []
    name = manifest_path.name
    if not isinstance(manifest, dict):
        raise AcquisitionError(manifest_path, ["the manifest must be a JSON object"])
    for key in sorted(set(manifest) - _MANIFEST_KEYS):
        problems.append(f"{name}: unknown field {key!r}")
    if manifest.get("format") != FORMAT_NAME:
        problems.append(f"{name}: field 'format' must be {FORMAT_NAME!r}, got {manifest.get('format')!r}")
    if manifest.get("version") != FORMAT_VERSION:
        problems.append(f"{name}: field 'version' must be {FORMAT_VERSION} (this reader's format), got {manifest.get('version')!r}")
    declared_pixel = manifest.get("pixel_size_um")
    if not _positive_number(declared_pixel):
        problems.append(f"{name}: field 'pixel_size_um' must be a positive number of micrometres, got {declared_pixel!r}")
    elif pixel_um is not None and not math.isclose(pixel_um, declared_pixel, rel_tol=1e-9):
        problems.append(f"{name}: pixel_size_um is {declared_pixel} but {pixel_um} was given")
    gamma = manifest.get("gamma", 1.0)
    if not (gamma == "srgb" or _positive_number(gamma)):
        problems.append(f"{name}: field 'gamma' must be a positive number or \"srgb\", got {gamma!r}")
    full_scale = manifest.get("full_scale")
    if full_scale is not None and not _positive_number(full_scale):
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
        if not (isinstance(light, list) and len(light) == 3 and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in light)):
            problems.append(f"{label}: field 'light' must be a list of 3 numbers (unit vector x, y, z)")
            light = None
        intensity = entry.get("intensity", 1.0)
        if not _positive_number(intensity):
            problems.append(f"{label}: field 'intensity' must be a positive number, got {intensity!r}")
        wavelength = entry.get("wavelength_nm", DEFAULT_WAVELENGTH_NM.get(band))
        if wavelength is not None and not _positive_number(wavelength):
            problems.append(f"{label}: field 'wavelength_nm' must be a positive number, got {wavelength!r}")
        channel = entry.get("channel")
        if channel is not None and channel not in CHANNELS:
            problems.append(f"{label}: field 'channel' must be one of {list(CHANNELS)}, got {channel!r}")
        flat = entry.get("flat")
        if flat is not None and not (isinstance(flat, str) and flat):
            problems.append(f"{label}: field 'flat' must name an image file")
        elif flat is not None and "intensity" in entry:
            problems.append(f"{label}: give either 'flat' (the intensity is then measured) or 'intensity', not both")
        parsed.append((band, folder / file, light, intensity, wavelength, channel, label, None if flat is None else folder / flat))

    if problems:  # structure is wrong: do not read images yet, report what we have
        raise AcquisitionError(manifest_path, problems)

    present = {p[0] for p in parsed}
    wanted = _check_bands_requested(manifest_path, bands, present)
    for band in sorted(present):
        members = [p for p in parsed if p[0] == band]
        for problem in check_light_directions([p[2] for p in members], [p[6] for p in members]):
            problems.append(problem if problem.startswith(name) else f"{name}: band {band}: {problem}")

    cache = _ImageCache(problems)
    dark = cache.get(folder / dark_file) if isinstance(dark_file, str) and dark_file else None

    def linear(image, channel, band):
        """Dark-subtracted, linear, unmixed, one channel; NaN where saturated."""
        scale = _full_scale(image.dtype, full_scale)
        # Normalise before picking the channel, so that a saturated channel makes the mean NaN too.
        values = _normalise(image, scale, saturation, gamma)
        if dark is not None:
            values = values - np.nan_to_num(_normalise(dark, scale, 2.0, gamma))
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
        for _, file, light, intensity, wavelength, channel, label, flat_file in members:
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
            by_band[band] = BandImages(band, np.stack(images), lights, tuple(str(p[1]) for p in members), members[0][4])

    shape = cache.reference[1] if cache.reference else None
    mask = None
    if manifest.get("mask") is not None:
        if not isinstance(manifest["mask"], str):
            problems.append(f"{name}: field 'mask' must name an image file")
        else:
            mask = _read_mask(folder / manifest["mask"], shape, problems)
    if problems:
        raise AcquisitionError(manifest_path, problems)
    if mask is None:
        mask = np.ones(shape, dtype=bool)
    return Acquisition(folder, "manifest", by_band, float(declared_pixel), False, mask)


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


def _load_diligent(folder, pixel_um, bands, saturation):
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
    if pixel_um is not None and not _positive_number(pixel_um):
        problems.append(f"pixel size must be a positive number of micrometres, got {pixel_um!r}")
    if problems:
        raise AcquisitionError(folder, problems)
    wanted = _check_bands_requested(folder, bands, set(BANDS))

    cache = _ImageCache(problems)
    raw = [cache.get(folder / n) for n in names]
    if not problems and raw[0].ndim != 3:
        problems.append(f"{folder / names[0]}: DiLiGenT images are RGB; this one has a single channel")
    if problems:
        raise AcquisitionError(folder, problems)
    shape, dtype = cache.reference[1], cache.reference[2]
    mask = _read_mask(folder / "mask.png", shape, problems) if (folder / "mask.png").is_file() else np.ones(shape, bool)
    if problems:
        raise AcquisitionError(folder, problems)

    scale = _full_scale(dtype, None)
    per_light = intensities if intensities is not None else np.ones((len(names), 3))
    channels = {}
    for band in wanted:
        needed = ("red", "green", "blue") if band == "white" else (band,)
        for colour in needed:
            if colour not in channels:
                c = CHANNEL_INDEX[colour]
                channels[colour] = np.stack(
                    [_normalise(image[..., c], scale, saturation, 1.0) / np.float32(per_light[i, c]) for i, image in enumerate(raw)]
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


def write_acquisition(folder, bands, pixel_um, *, mask=None, description=None, intensities=None):
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
            entry = {"file": name, "band": band, "light": [round(float(v), 9) for v in light]}
            if intensities and band in intensities:
                entry["intensity"] = float(intensities[band])
            if DEFAULT_WAVELENGTH_NM[band] is not None:
                entry["wavelength_nm"] = DEFAULT_WAVELENGTH_NM[band]
            entries.append(entry)
    manifest = {"format": FORMAT_NAME, "version": FORMAT_VERSION, "pixel_size_um": float(pixel_um)}
    if description:
        manifest["description"] = description
    if mask is not None:
        write_png(folder / "mask.png", np.where(np.asarray(mask, dtype=bool), 255, 0).astype(np.uint8))
        manifest["mask"] = "mask.png"
    manifest["images"] = entries
    path = folder / MANIFEST_NAME
    path.write_text(json.dumps(manifest, indent=2) + "\n", encoding="utf-8")
    return path
