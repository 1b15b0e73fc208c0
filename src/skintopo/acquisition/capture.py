"""The data model of one capture: constants, :class:`BandImages` and :class:`Acquisition`."""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from skintopo.defaults import BANDS
from skintopo.errors import AcquisitionError


MANIFEST_NAME = "acquisition.json"


FORMAT_NAME = "skintopo-acquisition"


FORMAT_VERSION = 1


DEFAULT_WAVELENGTH_NM = {"red": 625.0, "green": 523.0, "blue": 462.0, "white": None}


CHANNEL_INDEX = {"red": 0, "green": 1, "blue": 2}


CHANNELS = ("red", "green", "blue", "mean")


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
    leds : tuple of str or None
        With a device (:mod:`skintopo.device`), the LED of each image; ``lights`` then holds
        the directions from the field centre to those LEDs (what a distant-light method
        would assume).
    """

    band: str
    images: np.ndarray
    lights: np.ndarray
    files: tuple
    wavelength_nm: float | None
    leds: tuple | None = None


@dataclass(frozen=True)
class WhiteReference:
    """A white reference target of known diffuse reflectance in the images (manifest field
    ``white_reference``): its box in pixels, rows ``row_start:row_stop``, columns
    ``column_start:column_stop`` (Python slices, so stop is one past the last), and its
    reflectance per band in (0, 1]."""

    box_px: tuple
    reflectance: dict

    @property
    def slices(self):
        """(rows, columns) slices of the box."""
        top, left, bottom, right = self.box_px
        return slice(top, bottom), slice(left, right)


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
    device : skintopo.device.Device or None
        The camera and near-field LEDs the images were taken with; None: distant lights and
        an orthographic camera.
    white_reference : WhiteReference or None
        A white target of known reflectance in the images, for absolute reflectance
        (:mod:`skintopo.chromophores`).
    """

    source: Path
    layout: str
    bands: dict
    pixel_um: float
    pixel_um_assumed: bool
    mask: np.ndarray
    device: object = None
    white_reference: WhiteReference | None = None

    @property
    def shape(self):
        """Image shape (rows, columns)."""
        return self.mask.shape


def check_bands_requested(source, bands, present):
    if bands is None:
        return [b for b in BANDS if b in present]
    unknown = [b for b in bands if b not in BANDS]
    if unknown:
        raise AcquisitionError(source, [f"unknown band(s) {unknown}; choose from {list(BANDS)}"])
    missing = [b for b in bands if b not in present]
    if missing:
        raise AcquisitionError(source, [f"band(s) {missing} not in this acquisition (it has {sorted(present)})"])
    return list(bands)


def positive_number(value):
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value) and value > 0
