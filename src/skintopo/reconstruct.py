"""Per-band reconstruction: acquisition -> normals -> height map, as one call.

This composes the stages for every band of an acquisition; each stage stays usable alone
(:func:`skintopo.normals.photometric_stereo`, :func:`skintopo.height.integrate_normals`).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from skintopo.acquisition import Acquisition
from skintopo.height import DEFAULT_INTEGRATOR, integrate_normals
from skintopo.heightmap import HeightMap
from skintopo.errors import SkinTopoError
from skintopo.normals import DEFAULT_SHADOW_FRACTION, DEFAULT_SOLVER, PhotometricStereoResult, photometric_stereo, specular_free_images


@dataclass(frozen=True, eq=False)
class BandReconstruction:
    """Normals, albedo and height of one band, with the time each step took (seconds)."""

    band: str
    stereo: PhotometricStereoResult
    height: HeightMap
    seconds_normals: float
    seconds_integration: float


SPECULAR_FREE = "specular-free"


def band_images(acquisition: Acquisition, band):
    """(images, lights) of a band, or of the derived ``specular-free`` band (SUV projection of
    red, green and blue, which must share their lights; see
    :func:`skintopo.normals.specular_free_images`)."""
    if band != SPECULAR_FREE:
        return acquisition.bands[band].images, acquisition.bands[band].lights
    missing = [b for b in ("red", "green", "blue") if b not in acquisition.bands]
    if missing:
        raise SkinTopoError(f"the specular-free band needs red, green and blue; missing {missing}")
    lights = acquisition.bands["red"].lights
    if any(acquisition.bands[b].lights.shape != lights.shape or not np.allclose(acquisition.bands[b].lights, lights, atol=1e-6) for b in ("green", "blue")):
        raise SkinTopoError("the specular-free band needs red, green and blue images taken under the same lights, in the same order")
    return specular_free_images(*(acquisition.bands[b].images for b in ("red", "green", "blue"))), lights


def reconstruct_band(acquisition: Acquisition, band, *, integrator=DEFAULT_INTEGRATOR, shadow_fraction=DEFAULT_SHADOW_FRACTION,
                     solver=DEFAULT_SOLVER):
    """Photometric stereo and integration for one band of ``acquisition``.

    The height map keeps only pixels inside the acquisition mask with a valid normal.
    """
    images, lights = band_images(acquisition, band)
    start = time.perf_counter()
    stereo = photometric_stereo(images, lights, mask=acquisition.mask, shadow_fraction=shadow_fraction, solver=solver)
    middle = time.perf_counter()
    height = integrate_normals(stereo.normals, acquisition.pixel_um, mask=stereo.valid, method=integrator)
    end = time.perf_counter()
    return BandReconstruction(band, stereo, height, middle - start, end - middle)


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
