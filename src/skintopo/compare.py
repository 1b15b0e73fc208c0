"""Before/after comparison between visits: registration, difference map, parameter changes.

Registration of a follow-up height map onto the baseline (rigid: rotation and translation,
optionally a small scale), in two steps:

1. coarse: rotation from the phase correlation of the log-polar magnitude spectra (Reddy &
   Chatterji 1996, via scikit-image), then the translation by phase correlation;
2. fine: the parameters minimising a robust (Cauchy) misfit between the baseline and the
   warped follow-up (cubic splines, form-levelled maps, interior only), so that what changed
   between the visits (a treated wrinkle) weighs little. The Cauchy scale is 2.385 x the
   median absolute residual after the coarse step.

The residual misalignment is measured afterwards: tile-wise phase correlation (4 x 4 tiles)
between the baseline and the registered follow-up; its RMS, in pixels, is reported.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.ndimage
import scipy.optimize
from skimage.registration import phase_cross_correlation
from skimage.transform import warp_polar

from skintopo.errors import SkinTopoError
from skintopo.filters import polynomial_form
from skintopo.heightmap import HeightMap

CAUCHY_FACTOR = 2.385


@dataclass(frozen=True)
class Registration:
    """Follow-up -> baseline transform (pixels, degrees counter-clockwise in the image as
    displayed, scale) and the residual misalignment after it (pixels RMS)."""

    shift_px: tuple
    rotation_deg: float
    scale: float
    residual_px: float


def _levelled(height: HeightMap):
    return np.where(height.mask, height.z - polynomial_form(height.z, height.spacing, 2, height.mask), 0.0)


def _warp(image, shift, angle_deg, scale, order=3, cval=np.nan):
    """Sample ``image`` at the follow-up positions of baseline pixels: x_f = s R (x_b - c) + c - t."""
    rows, columns = image.shape
    centre = np.array([(rows - 1) / 2, (columns - 1) / 2])
    theta = np.radians(angle_deg)
    rotation = np.array([[np.cos(theta), np.sin(theta)], [-np.sin(theta), np.cos(theta)]]) * scale
    offset = centre - rotation @ centre - np.asarray(shift)
    return scipy.ndimage.affine_transform(image, rotation, offset=offset, order=order, mode="constant", cval=cval, prefilter=True)


def _coarse(fixed, moving):
    radius = min(fixed.shape) // 2
    window = np.outer(np.hanning(fixed.shape[0]), np.hanning(fixed.shape[1]))
    spectra = [np.abs(np.fft.fftshift(np.fft.fft2(image * window))) for image in (fixed, moving)]
    polar = [warp_polar(np.log1p(s), radius=radius, scaling="log") for s in spectra]
    shifts, _, _ = phase_cross_correlation(polar[0], polar[1], upsample_factor=20)
    angle = -shifts[0] * 360.0 / polar[0].shape[0]
    angle = (angle + 90) % 180 - 90  # the magnitude spectrum is point-symmetric: angles modulo 180
    best = None
    for candidate in (angle, angle + 180):
        rotated = np.nan_to_num(_warp(moving, (0, 0), candidate, 1.0, order=1))
        shift, error, _ = phase_cross_correlation(fixed, rotated, upsample_factor=10)
        if best is None or error < best[2]:
            best = (candidate, shift, error)
    return best[0], best[1]


def register_visits(baseline: HeightMap, follow_up: HeightMap, *, allow_scale=False, margin_fraction=0.15):
    """Rigid (optionally similarity) registration of ``follow_up`` onto ``baseline``.

    Returns
    -------
    aligned : HeightMap
        The follow-up resampled on the baseline grid (NaN where it has no data).
    registration : Registration
    """
    if not np.allclose(baseline.spacing, follow_up.spacing, rtol=1e-6):
        raise SkinTopoError(
            f"the visits have different pixel sizes ({baseline.spacing[1]:g} and {follow_up.spacing[1]:g} um): "
            "refusing to compare (resample one to the other's pixel size first)"
        )
    if baseline.shape != follow_up.shape:
        raise SkinTopoError(f"the visits have different sizes ({baseline.shape} and {follow_up.shape} pixels)")
    fixed, moving = _levelled(baseline), _levelled(follow_up)
    angle, shift = _coarse(fixed, moving)
    rows, columns = fixed.shape
    margin = int(margin_fraction * min(rows, columns)) + int(np.ceil(np.abs(shift).max()))
    interior = (slice(margin, rows - margin), slice(margin, columns - margin))
    if min(rows, columns) - 2 * margin < 16:
        raise SkinTopoError(f"the visits do not overlap enough to compare (coarse shift {shift[0]:.1f}, {shift[1]:.1f} pixels)")
    target = fixed[interior]

    def residual(parameters):
        dy, dx, theta = parameters[:3]
        scale = parameters[3] if allow_scale else 1.0
        return _warp(moving, (dy, dx), theta, scale)[interior] - target

    start = np.array([shift[0], shift[1], angle] + ([1.0] if allow_scale else []))
    first = residual(start)
    ok = np.isfinite(first)
    if ok.mean() < 0.5 or np.corrcoef(first[ok] + target[ok], target[ok])[0, 1] < 0.3:
        raise SkinTopoError("the visits do not overlap: no consistent alignment of the same skin was found")
    scale_c = CAUCHY_FACTOR * 1.4826 * np.median(np.abs(first[ok] - np.median(first[ok])))

    def cost(parameters):
        r = residual(parameters)
        r = r[np.isfinite(r)]
        return float(np.mean(np.log1p((r / scale_c) ** 2)))

    result = scipy.optimize.minimize(cost, start, method="Powell", options={"xtol": 1e-4, "ftol": 1e-9, "maxfev": 4000})
    parameters = result.x
    dy, dx, theta = parameters[:3]
    scale = float(parameters[3]) if allow_scale else 1.0
    aligned = _warp(np.where(follow_up.mask, follow_up.z, np.nan), (dy, dx), theta, scale, order=1)
    aligned_height = HeightMap(aligned, baseline.spacing)
    misalignment = residual_misalignment(fixed, np.nan_to_num(_warp(moving, (dy, dx), theta, scale)))
    return aligned_height, Registration((float(dy), float(dx)), float(theta), scale, misalignment)


def residual_misalignment(fixed, moving, tiles=4):
    """RMS (pixels) of the tile-wise phase-correlation shifts between two aligned maps."""
    rows, columns = fixed.shape
    th, tw = rows // tiles, columns // tiles
    shifts = []
    for i in range(tiles):
        for j in range(tiles):
            a = fixed[i * th : (i + 1) * th, j * tw : (j + 1) * tw]
            b = moving[i * th : (i + 1) * th, j * tw : (j + 1) * tw]
            if a.std() > 0 and b.std() > 0:
                shifts.append(phase_cross_correlation(a, b, upsample_factor=20)[0])
    return float(np.sqrt(np.mean(np.sum(np.square(shifts), axis=1)))) if shifts else float("nan")
