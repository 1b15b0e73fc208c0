"""Per-band reconstruction: acquisition -> normals -> height map, as one call.

This composes the stages for every band of an acquisition; each stage stays usable alone
(:func:`skintopo.normals.photometric_stereo`, :func:`skintopo.height.integrate_normals`).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace

import numpy as np

from skintopo.acquisition import Acquisition
from skintopo.defaults import DEFAULT_HIGHLIGHTS, HIGHLIGHT_MODES, SPECULAR_FREE
from skintopo.height import DEFAULT_INTEGRATOR, integrate_normals
from skintopo.heightmap import HeightMap
from skintopo.nearfield import near_field_photometric_stereo
from skintopo.errors import SkinTopoError
from skintopo.normals import (
    DEFAULT_SHADOW_FRACTION,
    DEFAULT_SOLVER,
    PhotometricStereoResult,
    photometric_stereo,
    separate_specular,
    specular_free_images,
)


@dataclass(frozen=True, eq=False)
class BandReconstruction:
    """Normals, albedo and height of one band, with the time each step took (seconds)."""

    band: str
    stereo: PhotometricStereoResult
    height: HeightMap | None  # None when reconstructed without integration
    seconds_normals: float
    seconds_integration: float
    near_field: object = None  # the NearFieldResult of a device acquisition (normals and integration alternate: all time in seconds_normals)


def rgb_share_lights(acquisition: Acquisition):
    """True when red, green and blue are all present and taken under the same lights, in order."""
    if any(b not in acquisition.bands for b in ("red", "green", "blue")):
        return False
    lights = acquisition.bands["red"].lights
    return all(acquisition.bands[b].lights.shape == lights.shape and np.allclose(acquisition.bands[b].lights, lights, atol=1e-6)
               for b in ("green", "blue"))


def specular_separation(acquisition: Acquisition, specular_colour=None):
    """:func:`skintopo.normals.separate_specular` of the acquisition's red, green and blue
    images (the surface reflection of ``specular_colour``, default white), or None when the
    three bands are not all there under the same lights."""
    if not rgb_share_lights(acquisition):
        return None
    return separate_specular(*(acquisition.bands[b].images for b in ("red", "green", "blue")), specular_colour=specular_colour)


def band_images(acquisition: Acquisition, band, separation=None):
    """(images, lights, highlights) of a band: the images as captured and, with a
    :class:`~skintopo.normals.SpecularSeparation` and the band taken under the red band's
    lights, the observations it flags as highlights, else None. ``specular-free`` is the SUV
    projection of red, green and blue (:func:`skintopo.normals.specular_free_images`)."""
    if band == SPECULAR_FREE:
        missing = [b for b in ("red", "green", "blue") if b not in acquisition.bands]
        if missing:
            raise SkinTopoError(f"the specular-free band needs red, green and blue; missing {missing}")
        if not rgb_share_lights(acquisition):
            raise SkinTopoError("the specular-free band needs red, green and blue images taken under the same lights, in the same order")
        return specular_free_images(*(acquisition.bands[b].images for b in ("red", "green", "blue"))), acquisition.bands["red"].lights, None
    images, lights = acquisition.bands[band].images, acquisition.bands[band].lights
    red_lights = acquisition.bands["red"].lights if "red" in acquisition.bands else None
    if separation is None or lights.shape != red_lights.shape or not np.allclose(lights, red_lights, atol=1e-6):
        return images, lights, None
    return images, lights, separation.highlights(images, band=band)


def reconstruct_band(acquisition: Acquisition, band, *, integrator=DEFAULT_INTEGRATOR, shadow_fraction=DEFAULT_SHADOW_FRACTION,
                     solver=DEFAULT_SOLVER, highlights=DEFAULT_HIGHLIGHTS, separation=None, start=None, integrate=True,
                     specular_colour=None):
    """Photometric stereo and integration for one band of ``acquisition``.

    ``highlights="cross-band"`` leaves out the observations that :func:`specular_separation`
    (computed here unless ``separation`` is given; with the surface reflection of
    ``specular_colour``, default white) flags as highlights, and the robust
    solver then relies on those flags instead of its few-lights rule; ``"none"`` (default)
    fits every observation the shadow and saturation rules keep. The height map keeps only pixels inside the acquisition mask
    with a valid normal. ``start``: with a device, another band's :class:`BandReconstruction`
    of the same capture, whose depth and scale the near-field solver starts from
    (:func:`skintopo.nearfield.near_field_photometric_stereo`). ``integrate=False``: normals
    and albedo only, the height None (when the caller integrates the normals itself, as the
    spectral correction does; a device's near-field solver always makes the height).
    """
    if highlights not in HIGHLIGHT_MODES:
        raise SkinTopoError(f"unknown highlight handling {highlights!r}; choose from {list(HIGHLIGHT_MODES)}")
    if acquisition.device is not None:
        return _near_field_band(acquisition, band, integrator=integrator, shadow_fraction=shadow_fraction, solver=solver,
                                highlights=highlights, separation=separation, start=None if start is None else start.near_field,
                                specular_colour=specular_colour)
    if highlights == "cross-band" and separation is None and band != SPECULAR_FREE:
        separation = specular_separation(acquisition, specular_colour)
    images, lights, flagged = band_images(acquisition, band, separation if highlights == "cross-band" else None)
    start = time.perf_counter()
    stereo = photometric_stereo(images, lights, mask=acquisition.mask, shadow_fraction=shadow_fraction, solver=solver, highlights=flagged)
    middle = time.perf_counter()
    height = integrate_normals(stereo.normals, acquisition.pixel_um, mask=stereo.valid, method=integrator) if integrate else None
    end = time.perf_counter()
    return BandReconstruction(band, stereo, height, middle - start, end - middle)


def _near_field_band(acquisition: Acquisition, band, *, integrator, shadow_fraction, solver, highlights, separation=None, start=None,
                     specular_colour=None):
    """A band of a device acquisition through near-field photometric stereo
    (:mod:`skintopo.nearfield`): the height on the skin-plane grid, the normals resampled to
    it. ``highlights="cross-band"`` solves the diffuse images of the dichromatic separation
    (:func:`specular_separation`: the images minus their specular part), not the images with
    flagged observations left out: on a curved forehead under near LEDs the highlights are
    broad and weak, and no observation is flagged while together they bend the form (measured
    at 1000 px: 84 um RMS after form removal with them, 21 without; Method and validation,
    "The real device"). The robust
    solver is a distant-light method."""
    if solver != DEFAULT_SOLVER:
        raise SkinTopoError(f"{acquisition.source}: near-field photometric stereo (the acquisition has a device) uses the "
                            f"{DEFAULT_SOLVER} solver; got {solver!r}")
    if band == SPECULAR_FREE:
        raise SkinTopoError(f"{acquisition.source}: the specular-free band is not available with a device (near-field LEDs)")
    images = acquisition.bands[band]
    values = images.images
    if highlights == "cross-band":
        separation = separation or specular_separation(acquisition, specular_colour)
        if separation is None:
            raise SkinTopoError(f"{acquisition.source}: cross-band highlights need red, green and blue images under the same LEDs")
        values = values - separation.band_specular(band)
    device = acquisition.device
    band_device = replace(device, leds=tuple(device.led(name) for name in images.leds))
    started = time.perf_counter()
    result = near_field_photometric_stereo(values, band_device, band, mask=acquisition.mask, shadow_fraction=shadow_fraction,
                                           integrator=integrator, start=start)
    seconds = time.perf_counter() - started
    return BandReconstruction(band, result.stereo_on_surface_grid(), result.height, seconds, 0.0, result)


def band_statistics(result: BandReconstruction):
    """A few numbers that tell whether a band's reconstruction is sound."""
    valid = result.stereo.valid
    z = result.height.z[result.height.mask]
    return {
        "valid_fraction": float(valid.mean()),
        "median_lights_used": float(np.median(result.stereo.lights_used[valid])) if valid.any() else 0.0,
        "mean_residual": float(np.nanmean(result.stereo.residual)) if valid.any() else float("nan"),
        "mean_albedo": float(np.nanmean(result.stereo.albedo)) if valid.any() else float("nan"),
        "height_range_um": float(np.ptp(z)) if z.size else float("nan"),
        "seconds_normals": result.seconds_normals,
        "seconds_integration": result.seconds_integration,
    }
