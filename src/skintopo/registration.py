"""Registration of two height maps of the same skin: a follow-up visit onto its baseline
(:mod:`skintopo.compare`), a reconstruction onto its ground truth (:mod:`skintopo.evaluation`).

Rigid (rotation and translation, optionally a small scale; or translation alone), in two steps:

1. coarse: rotation from the phase correlation of the log-polar magnitude spectra (Reddy &
   Chatterji 1996, via scikit-image), then the translation by phase correlation;
2. fine: the parameters minimising a robust (Cauchy) misfit sum log(1 + (r / c)^2) between
   the reference and the warped moving map (cubic splines filtered once, maps levelled by
   their least-squares quadratic form, interior only; ``scipy.optimize.least_squares`` with
   ``loss="cauchy"``), so that what differs between the maps (a treated wrinkle, a
   reconstruction's error) weighs little. The Cauchy scale c is 2.385 x the median absolute
   residual after the coarse step.

Maps that do not correlate (> ``MIN_CORRELATION``) once aligned are refused as not of the
same skin, and so are maps of different pixel sizes or sizes.

The residual misalignment is measured afterwards (:func:`residual_misalignment`): local
shifts by Lucas-Kanade least squares in 4 x 4 tiles between the reference and the registered
map; their RMS, in pixels, is reported. :func:`apply_registration` carries another image of
the moving map (its albedo) by the same transform.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.ndimage
import scipy.optimize
from skimage.registration import phase_cross_correlation
from skimage.transform import warp_polar

from skintopo.errors import SkinTopoError
from skintopo.filters import level
from skintopo.height import fill_from_nearest
from skintopo.heightmap import HeightMap

CAUCHY_FACTOR = 2.385
MIN_CORRELATION = 0.3  # of the levelled maps once aligned; unrelated surfaces give about 0


@dataclass(frozen=True)
class Registration:
    """Moving -> reference transform (pixels, degrees counter-clockwise in the image as
    displayed, scale) and the residual misalignment after it (pixels RMS)."""

    shift_px: tuple
    rotation_deg: float
    scale: float
    residual_px: float


def _levelled(height: HeightMap):
    """The height without its least-squares quadratic form, 0 where it has no data."""
    return np.where(height.mask, level(height, order=2).z, 0.0)


def _warp(image, shift, angle_deg, scale, order=3, cval=np.nan, prefilter=True):
    """Sample ``image`` at the moving map's positions of the reference pixels: x_m = s R (x_r - c) + c - t.

    ``prefilter=False`` takes ``image`` as spline coefficients already
    (``scipy.ndimage.spline_filter``), so that repeated warps of one image filter it once."""
    rows, columns = image.shape
    centre = np.array([(rows - 1) / 2, (columns - 1) / 2])
    theta = np.radians(angle_deg)
    rotation = np.array([[np.cos(theta), np.sin(theta)], [-np.sin(theta), np.cos(theta)]]) * scale
    offset = centre - rotation @ centre - np.asarray(shift)
    return scipy.ndimage.affine_transform(image, rotation, offset=offset, order=order, mode="constant", cval=cval, prefilter=prefilter)


def _translation(fixed, moving):
    """The translation by phase correlation (upsampled 20 x: 0.05 pixel)."""
    return phase_cross_correlation(fixed, moving, upsample_factor=20)[0]


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


def check_comparable(reference: HeightMap, moving: HeightMap):
    """Refuse two height maps with different pixel sizes (resampling silently would change
    every texture parameter) or sizes."""
    if not np.allclose(reference.spacing, moving.spacing, rtol=1e-6):
        raise SkinTopoError(
            f"the height maps have different pixel sizes ({reference.spacing[1]:g} and {moving.spacing[1]:g} um): "
            "refusing to compare (resample one to the other's pixel size first)"
        )
    if reference.shape != moving.shape:
        raise SkinTopoError(f"the height maps have different sizes ({reference.shape} and {moving.shape} pixels)")


def register_height_maps(reference: HeightMap, moving: HeightMap, *, rotation=True, allow_scale=False, margin_fraction=0.15):
    """Rigid (optionally similarity; ``rotation=False``: translation only) registration of
    ``moving`` onto ``reference`` (see the module notes).

    Returns
    -------
    aligned : HeightMap
        ``moving`` resampled (cubic B-spline, :func:`_warp_height`) on the reference grid (NaN where it has no data).
    registration : Registration
    """
    check_comparable(reference, moving)
    fixed, levelled = _levelled(reference), _levelled(moving)
    angle, shift = _coarse(fixed, levelled) if rotation else (0.0, _translation(fixed, levelled))
    rows, columns = fixed.shape
    margin = int(margin_fraction * min(rows, columns)) + int(np.ceil(np.abs(shift).max()))
    interior = (slice(margin, rows - margin), slice(margin, columns - margin))
    if min(rows, columns) - 2 * margin < 16:
        raise SkinTopoError(f"the height maps do not overlap enough to compare (coarse shift {shift[0]:.1f}, {shift[1]:.1f} pixels)")
    target = fixed[interior]
    coefficients = scipy.ndimage.spline_filter(levelled, order=3)  # once, not at every evaluation

    def transform(parameters):  # (dy, dx, rotation, scale), whichever are free
        theta = parameters[2] if rotation else 0.0
        return parameters[0], parameters[1], theta, (parameters[-1] if allow_scale else 1.0)

    def residual(parameters):
        dy, dx, theta, scale = transform(parameters)
        return _warp(coefficients, (dy, dx), theta, scale, prefilter=False)[interior] - target

    start = np.array([shift[0], shift[1]] + ([angle] if rotation else []) + ([1.0] if allow_scale else []))
    first = residual(start)
    ok = np.isfinite(first)
    correlation = np.corrcoef(first[ok] + target[ok], target[ok])[0, 1] if ok.sum() > 16 else 0.0
    if ok.mean() < 0.5 or not correlation > MIN_CORRELATION:
        raise SkinTopoError(f"the height maps do not overlap: no consistent alignment of the same skin was found (correlation "
                            f"{correlation:.2f} at the best shift, needs > {MIN_CORRELATION}); are these maps of the same skin?")
    scale_c = CAUCHY_FACTOR * 1.4826 * np.median(np.abs(first[ok] - np.median(first[ok])))

    def finite_residual(parameters):  # a sample warped in from outside the moving map weighs nothing
        r = residual(parameters).ravel()
        return np.where(np.isfinite(r), r, 0.0)

    # sum of log(1 + (r / c)^2): the Cauchy misfit, by trust-region least squares
    result = scipy.optimize.least_squares(finite_residual, start, loss="cauchy", f_scale=scale_c, x_scale=np.ones_like(start),
                                          diff_step=1e-4, xtol=1e-8, ftol=1e-10)
    dy, dx, theta, scale = (float(value) for value in transform(result.x))
    misalignment = residual_misalignment(fixed, np.nan_to_num(_warp(levelled, (dy, dx), theta, scale)))
    registration = Registration((dy, dx), theta, scale, misalignment)
    # a transform that moves no point by 1/1000 pixel is none (resampling would only lose the border)
    radius = 0.5 * np.hypot(rows, columns)
    if max(abs(dy), abs(dx), radius * abs(np.radians(theta)), radius * abs(scale - 1)) < 1e-3:
        return moving, registration
    return _warp_height(moving, (dy, dx), theta, scale, reference.spacing), registration


def _warp_height(moving: HeightMap, shift, angle_deg, scale, spacing):
    """The moving height map resampled by cubic B-spline interpolation (SciPy's
    ``affine_transform``, order 3), valid where the 2 x 2 samples around each point are (as
    bilinear resampling had it).

    Bilinear interpolation smooths: at a half-pixel shift it averages two samples, so a
    follow-up's wrinkles read shallower and wider than the unmoved baseline's (100 simulated
    repeat pairs of 3 wrinkles, 20 um pixels, shifts of up to 2 px: mean change of max and mean
    depth -0.05 to -0.37%, of width +0.12 to +0.23%; 50 of those pairs again with the spline:
    -0.12 to +0.10% and -0.09 to +0.07%, and the RMS change lower for 16 of the 18 wrinkle
    measures). The spline's prefilter reads the whole map, so the pixels without data are
    first given their nearest valid height: a point beside a hole also reads it through the
    spline's outer samples, each of which weighs at most 0.13. Requiring all 4 x 4 samples
    valid instead widened every hole of a reconstruction (scattered invalid pixels in shadowed
    wrinkle floors) and moved its wrinkles' max depth by up to 1 um.
    """
    filled, = fill_from_nearest(moving.mask, moving.z)
    valid = _warp(moving.mask.astype(float), shift, angle_deg, scale, order=1, cval=0.0) > 1 - 1e-6
    return HeightMap(_warp(filled, shift, angle_deg, scale, order=3, cval=0.0), spacing, valid)


def apply_registration(image, registration: Registration, *, order=1):
    """An image of the moving map (a follow-up's albedo, say) resampled onto the reference grid
    with the transform found from the height maps (bilinear by default; NaN outside)."""
    image = np.asarray(image, dtype=float)
    if image.ndim != 2:
        raise ValueError(f"apply_registration needs a single-channel image, got shape {image.shape}")
    return _warp(image, registration.shift_px, registration.rotation_deg, registration.scale, order=order)


def residual_misalignment(fixed, moving, tiles=4):
    """RMS (pixels) of the local shifts between two registered maps, one per tile of a
    tiles x tiles grid, each found by Lucas-Kanade least squares (the shift d minimising
    sum (moving(x + d) - fixed(x))^2 over the tile, linearised and iterated three times).
    Phase correlation is not used here: for sub-pixel shifts of smooth content its peak
    stays on the integer lag (a 0.5 px offset of a smooth albedo read as 0.0 in a test)."""
    rows, columns = fixed.shape
    th, tw = rows // tiles, columns // tiles
    border = 3  # pixels at each tile edge left out of the sums (the shifted tile's edge values are guessed)
    shifts = []
    for i in range(tiles):
        for j in range(tiles):
            a = np.asarray(fixed[i * th : (i + 1) * th, j * tw : (j + 1) * tw], dtype=float)
            b = np.asarray(moving[i * th : (i + 1) * th, j * tw : (j + 1) * tw], dtype=float)
            inner = (slice(border, -border), slice(border, -border))
            gradient = np.stack([g[inner].ravel() for g in np.gradient(a)], axis=1)
            normal = gradient.T @ gradient
            if a.shape[0] <= 2 * border or a.shape[1] <= 2 * border or np.linalg.cond(normal) > 1e8:
                continue  # a flat or tiny tile says nothing about alignment
            d = np.zeros(2)
            for _ in range(3):
                back = scipy.ndimage.shift(b, -d, order=3, mode="nearest")  # moving(x + d)
                d -= np.linalg.solve(normal, gradient.T @ (back[inner] - a[inner]).ravel())
            shifts.append(d)
    return float(np.sqrt(np.mean(np.sum(np.square(shifts), axis=1)))) if shifts else float("nan")
