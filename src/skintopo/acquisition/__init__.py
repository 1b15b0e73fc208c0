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
      "white_reference": {                # optional; a white target of known diffuse reflectance
        "box_px": [0, 0, 40, 40],         # in the images: rows 0:40, columns 0:40 (keep it
        "reflectance": 0.95},             # out of "mask"); one value or one per band (red, green,
                                          # blue): the albedo becomes absolute reflectance
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
no auto-brightness, no white balance), kept in linear units: nothing is guessed about gamma. 16-bit RGB PNGs are read with imagecodecs (libpng), because Pillow (and readers built on
it) silently reduces them to 8 bits.

Every problem found while reading is collected and reported at once in an
:class:`~skintopo.errors.AcquisitionError` naming the file and the field.

Modules: :mod:`~skintopo.acquisition.capture` (the data model), :mod:`~skintopo.acquisition.manifest`
(validation and writing), :mod:`~skintopo.acquisition.diligent`, :mod:`~skintopo.acquisition.images`
(readers), :mod:`~skintopo.acquisition.radiometry` (dark frame, transfer function, saturation,
flat field, cross-talk) and :mod:`~skintopo.lights` (light checks).
"""

from __future__ import annotations

from pathlib import Path

from skintopo.acquisition.capture import BANDS, MANIFEST_NAME, Acquisition, BandImages, WhiteReference
from skintopo.acquisition.diligent import load_diligent
from skintopo.acquisition.images import RAW_SUFFIXES, read_image
from skintopo.lights import check_light_directions
from skintopo.acquisition.manifest import load_manifest, write_acquisition
from skintopo.defaults import DEFAULT_SATURATION
from skintopo.errors import AcquisitionError

__all__ = ["BANDS", "DEFAULT_SATURATION", "MANIFEST_NAME", "RAW_SUFFIXES", "Acquisition", "BandImages", "check_light_directions",
           "load_acquisition", "read_image", "write_acquisition", "WhiteReference"]


def load_acquisition(path, *, pixel_um=None, bands=None, saturation=DEFAULT_SATURATION, bytes_per_pixel=None):
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
    bytes_per_pixel : float, optional
        Memory that processing the acquisition will need per pixel beyond its images (e.g.
        :data:`skintopo.pipeline.PROCESSING_BYTES_PER_PIXEL`). When given, a field that will
        not fit in the memory available is refused once its first image is read, naming the
        size needed.

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
        return load_manifest(path, pixel_um, bands, saturation, bytes_per_pixel)
    if not path.is_dir():
        raise AcquisitionError(path, ["no such acquisition folder or manifest"])
    if (path / MANIFEST_NAME).is_file():
        return load_manifest(path / MANIFEST_NAME, pixel_um, bands, saturation, bytes_per_pixel)
    if (path / "filenames.txt").is_file() and (path / "light_directions.txt").is_file():
        return load_diligent(path, pixel_um, bands, saturation, bytes_per_pixel)
    raise AcquisitionError(
        path, [f"neither {MANIFEST_NAME} nor a DiLiGenT layout (filenames.txt, light_directions.txt) found"]
    )
