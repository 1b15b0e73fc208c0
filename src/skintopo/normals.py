"""Lambertian photometric stereo: unit normals, albedo and residual per pixel, for one band.

Under a distant light of unit direction s_i, a Lambertian surface point of albedo rho and
unit normal n has intensity I_i = rho n . s_i (paper eq. 3-7). With g = rho n and the m x 3
light matrix S, least squares gives (paper eq. 8)

    g = (S^T S)^-1 S^T I,   rho = |g|,   n = g / |g|.

Observations that are saturated (NaN in the input) or in shadow (below ``shadow_fraction``
of the pixel's brightest observation) are left out per pixel. Pixels whose observations
are all usable share one pseudo-inverse; the others solve their own 3 x 3 normal equations
S^T W S g = S^T W I with W the 0/1 weights, all at once (no loop over pixels). A pixel left
with fewer than 3 lights, or with lights that no longer span 3-D, is invalid (NaN).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from skintopo.acquisition import check_light_directions
from skintopo._linalg import solve_symmetric_3x3
from skintopo.errors import SkinTopoError

DEFAULT_SHADOW_FRACTION = 0.05


@dataclass(frozen=True, eq=False)
class PhotometricStereoResult:
    """Output of :func:`photometric_stereo`.

    Attributes
    ----------
    normals : ndarray, shape (rows, columns, 3), float32
        Unit normals in the camera frame (x right, y up, z toward the camera); NaN where invalid.
    albedo : ndarray, shape (rows, columns), float32
        rho = |g|, in the units of the images (fraction of full scale per unit light); NaN where invalid.
    residual : ndarray, shape (rows, columns), float32
        RMS of I_i - g . s_i over the observations used; NaN where invalid.
    lights_used : ndarray, shape (rows, columns), int16
        Number of usable observations at each pixel (0 outside the mask); below 3 the pixel
        is invalid.
    valid : ndarray of bool, shape (rows, columns)
    """

    normals: np.ndarray
    albedo: np.ndarray
    residual: np.ndarray
    lights_used: np.ndarray
    valid: np.ndarray


def photometric_stereo(images, lights, *, mask=None, shadow_fraction=DEFAULT_SHADOW_FRACTION):
    """Per-pixel Lambertian least squares, n = (S^T S)^-1 S^T I.

    Parameters
    ----------
    images : array_like, shape (m, rows, columns)
        Linear intensities, already divided by each light's relative intensity. NaN marks an
        observation to leave out (saturated).
    lights : array_like, shape (m, 3)
        Unit light directions in the camera frame.
    mask : array_like of bool, shape (rows, columns), optional
        Pixels to solve; the others are invalid.
    shadow_fraction : float
        An observation below ``shadow_fraction`` times the pixel's brightest observation is
        taken as shadowed and left out. 0 keeps every finite observation.

    Returns
    -------
    PhotometricStereoResult

    Raises
    ------
    SkinTopoError
        When the light set is unusable (fewer than 3, not unit vectors, coplanar) or the
        shapes disagree.
    """
    images = np.asarray(images, dtype=np.float32)
    lights = np.asarray(lights, dtype=np.float64)
    problems = check_light_directions(lights)
    if problems:
        raise SkinTopoError("; ".join(problems))
    if images.ndim != 3 or images.shape[0] != lights.shape[0]:
        raise SkinTopoError(f"expected images of shape (m={lights.shape[0]}, rows, columns), got {images.shape}")
    if not 0 <= shadow_fraction < 1:
        raise SkinTopoError(f"shadow_fraction must be in [0, 1), got {shadow_fraction}")
    m, rows, columns = images.shape
    if mask is None:
        mask = np.ones((rows, columns), dtype=bool)
    mask = np.asarray(mask, dtype=bool)
    if mask.shape != (rows, columns):
        raise SkinTopoError(f"mask shape {mask.shape} differs from image shape {(rows, columns)}")

    flat_mask = mask.ravel()
    whole_field = bool(flat_mask.all())
    intensity = images.reshape(m, -1)
    if not whole_field:
        intensity = intensity[:, flat_mask]  # (m, P)
    usable = np.isfinite(intensity)
    peak = np.fmax.reduce(intensity, axis=0)  # ignores NaN; NaN only if all are NaN
    if shadow_fraction > 0:
        with np.errstate(invalid="ignore"):
            usable &= intensity > np.float32(shadow_fraction) * peak
    with np.errstate(invalid="ignore"):
        usable &= peak > 0  # a pixel dark under every light has no normal
    intensity = np.where(usable, intensity, np.float32(0))
    count = np.add.reduce(usable, axis=0, dtype=np.int16)

    full = count == m
    pinv = np.linalg.pinv(lights).astype(np.float32)
    if full.all():
        g = pinv @ intensity  # one pseudo-inverse for every pixel, (3, P)
    else:
        g = np.full((3, intensity.shape[1]), np.nan, dtype=np.float32)
        g[:, full] = pinv @ intensity[:, full]  # one pseudo-inverse for all fully lit pixels
        partial = ~full & (count >= 3)
        if partial.any():
            weights = usable[:, partial].T.astype(np.float64)  # (k, m)
            upper = [(0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2)]
            outer = np.stack([lights[:, i] * lights[:, j] for i, j in upper], axis=1)  # (m, 6)
            solution, det = solve_symmetric_3x3(weights @ outer, (weights * intensity[:, partial].T) @ lights)
            # Remaining lights must still span 3-D: det(S^T W S) against its scale (trace/3)^3.
            scale = ((weights @ outer[:, [0, 3, 5]]).sum(axis=1) / 3) ** 3
            solution[~(np.abs(det) > 1e-6 * scale)] = np.nan
            g[:, partial] = solution.T

    albedo = np.sqrt(g[0] * g[0] + g[1] * g[1] + g[2] * g[2])
    with np.errstate(invalid="ignore"):
        good = albedo > 0  # False for NaN
    g[:, ~good] = np.nan
    albedo[~good] = np.nan
    error = intensity - lights.astype(np.float32) @ g
    error *= error
    error[~usable] = 0
    with np.errstate(invalid="ignore", divide="ignore"):
        residual = np.sqrt(np.add.reduce(error, axis=0) / count)
        normal = (g / albedo).T  # (P, 3)

    def to_image(values, fill=np.nan):
        if whole_field:
            return values.reshape((rows, columns) + values.shape[1:])
        out = np.full((rows * columns,) + values.shape[1:], fill, dtype=values.dtype)
        out[flat_mask] = values
        return out.reshape((rows, columns) + values.shape[1:])

    return PhotometricStereoResult(
        normals=to_image(normal),
        albedo=to_image(albedo),
        residual=to_image(residual),
        lights_used=to_image(count, fill=0),
        valid=to_image(good, fill=False),
    )


def angular_error_degrees(normals, reference):
    """Angle between two normal fields in degrees, per pixel (NaN where either is invalid).

    theta = arccos(clip(n . n_ref, -1, 1)); both inputs are normalised first.
    """
    normals = np.asarray(normals, dtype=np.float64)
    reference = np.asarray(reference, dtype=np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        a = normals / np.linalg.norm(normals, axis=-1, keepdims=True)
        b = reference / np.linalg.norm(reference, axis=-1, keepdims=True)
    return np.degrees(np.arccos(np.clip((a * b).sum(axis=-1), -1.0, 1.0)))


def render_lambertian(normals, albedo, lights):
    """The forward model the solver inverts: I_i = rho max(0, n . s_i) (paper eq. 2-7).

    Attached shadows only (no cast shadows, no interreflection); for the physically based
    renderer see the simulator.

    Parameters
    ----------
    normals : array_like, shape (rows, columns, 3)
    albedo : float or array_like, shape (rows, columns)
    lights : array_like, shape (m, 3)

    Returns
    -------
    ndarray, shape (m, rows, columns)
    """
    shading = np.einsum("rci,mi->mrc", np.asarray(normals, dtype=np.float64), np.asarray(lights, dtype=np.float64))
    return np.asarray(albedo) * np.maximum(shading, 0.0)
