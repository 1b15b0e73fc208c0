"""Lambertian photometric stereo: unit normals, albedo and residual per pixel, for one band.

Under a distant light of unit direction s_i, a Lambertian surface point of albedo rho and
unit normal n has intensity I_i = rho n . s_i (paper eq. 3-7). With g = rho n and the m x 3
light matrix S, least squares gives (paper eq. 8)

    g = (S^T S)^-1 S^T I,   rho = |g|,   n = g / |g|.

Observations that are saturated (NaN in the input) or in shadow are left out per pixel.

Shadow rule: an observation is shadowed when I_i < f rho_0, f = ``shadow_fraction``, where
rho_0 is the smaller of the albedos of two first fits of the pixel: one of all its finite
observations, one without its brightest observation (the highlight, if there is one). In
attached or cast shadow n . s_i <= 0 or the light is blocked, so I_i is near 0 whatever the
albedo; rho_0 scales the threshold to the pixel's brightness without depending on any single
observation.
The former rule (f times the pixel's *brightest* observation) was fooled by highlights: under
a highlight the brightest observation is the highlight, several times the diffuse level, and
good diffuse observations fell under the threshold and were thrown away, leaving the fit to
the highlight (measured on simulated shiny spheres and skin: 24 degrees instead of 15 for
plain least squares). A first fit pulled up by a highlight raises rho_0 far less than the
highlight raises the maximum, because the fit spreads it over all observations, and the fit
without the brightest observation is free of it. Pixels whose observations
are all usable share one pseudo-inverse; the others solve their own 3 x 3 normal equations
S^T W S g = S^T W I with W the 0/1 weights, all at once (no loop over pixels). A pixel left
with fewer than 3 lights, or with lights that no longer span 3-D, is invalid (NaN).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from skintopo.defaults import DEFAULT_SHADOW_FRACTION, DEFAULT_SOLVER, SOLVERS
from skintopo.lights import check_light_directions
from skintopo._linalg import solve_symmetric_3x3
from skintopo.errors import SkinTopoError


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
    used : ndarray of bool, shape (m, rows, columns)
        Which observations entered each pixel's fit.
    """

    normals: np.ndarray
    albedo: np.ndarray
    residual: np.ndarray
    lights_used: np.ndarray
    valid: np.ndarray
    used: np.ndarray


_UPPER = [(0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2)]  # upper entries of a symmetric 3 x 3


def _fit(intensity, usable, lights):
    """g = rho n for every pixel from the usable observations (intensity already 0 elsewhere).

    One pseudo-inverse serves every pixel whose observations are all usable; the others solve
    their own weighted 3 x 3 normal equations S^T W S g = S^T W I at once. Pixels with fewer
    than 3 usable observations, or whose remaining lights no longer span 3-D, get NaN.
    """
    m = lights.shape[0]
    count = np.add.reduce(usable, axis=0, dtype=np.int16)
    full = count == m
    pinv = np.linalg.pinv(lights).astype(np.float32)
    if full.all():
        return pinv @ intensity, count
    g = np.full((3, intensity.shape[1]), np.nan, dtype=np.float32)
    g[:, full] = pinv @ intensity[:, full]
    partial = ~full & (count >= 3)
    if partial.any():
        weights = usable[:, partial].T.astype(np.float64)  # (k, m)
        outer = np.stack([lights[:, i] * lights[:, j] for i, j in _UPPER], axis=1)  # (m, 6)
        solution, det = solve_symmetric_3x3((weights @ outer).T, ((weights * intensity[:, partial].T) @ lights).T)
        # Remaining lights must still span 3-D: det(S^T W S) against its scale (trace/3)^3.
        scale = ((weights @ outer[:, [0, 3, 5]]).sum(axis=1) / 3) ** 3
        solution[:, ~(np.abs(det) > 1e-6 * scale)] = np.nan
        g[:, partial] = solution
    return g, count


def _fit_without_brightest(intensity, usable, lights):
    """g of each pixel fitted without its brightest observation. Pixels whose other
    observations are all usable share one pseudo-inverse per left-out light (a loop over the
    lights, not the pixels); the rest, and light sets that no longer span 3-D, go through
    :func:`_fit`."""
    m = lights.shape[0]
    brightest = np.argmax(intensity, axis=0)
    g = np.full((3, intensity.shape[1]), np.nan, dtype=np.float32)
    general = ~usable.all(axis=0)
    for j in range(m):
        keep = np.arange(m) != j
        chosen = ~general & (brightest == j)
        if not chosen.any():
            continue
        singular = np.linalg.svd(lights[keep], compute_uv=False)
        if m - 1 < 3 or singular[-1] < 1e-3 * singular[0]:
            general |= chosen
            continue
        g[:, chosen] = np.linalg.pinv(lights[keep]).astype(np.float32) @ intensity[keep][:, chosen]
    if general.any():
        without = usable[:, general].copy()
        without[brightest[general], np.arange(general.sum())] = False
        g[:, general], _ = _fit(np.where(without, intensity[:, general], np.float32(0)), without, lights)
    return g


def _fit_residual(intensity, usable, lights):
    """Fit and the RMS residual of each pixel's usable observations."""
    g, count = _fit(intensity, usable, lights)
    error = np.where(usable, intensity - lights.astype(np.float32) @ g, 0.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        return g, count, np.sqrt((error * error).sum(axis=0) / count)


def _reject_outliers(intensity, usable, lights, g, count, *, threshold, max_iterations, few_lights_rule=True):
    """Robust solver: drop, per pixel, observations the Lambertian fit cannot explain, while
    the RMS residual exceeds ``threshold`` times the albedo, never going below 3 lights.

    Few lights (m <= 8): each candidate is left out in turn and the one whose removal leaves
    the smallest residual is dropped when it is clearly better than the next; when several
    removals explain the data equally well (always with 4 lights: any 3 fit exactly), the
    brightest of them is taken as the outlier, i.e. a specular highlight is assumed. Cast
    shadows are left to the shadow threshold; a pixel with both a highlight and an
    unthresholded shadow under 4 lights cannot be repaired. Many lights: the ceil(2% of m) observations with the
    largest residuals are dropped per pass. Pixels that changed are refitted.
    """
    m = lights.shape[0]
    if m <= 8 and not few_lights_rule:
        return g, count
    lights32 = lights.astype(np.float32)
    active = np.flatnonzero(count > 3)
    for _ in range(max_iterations):
        if active.size == 0:
            break
        sub_g = g[:, active]
        albedo = np.sqrt((sub_g * sub_g).sum(axis=0))
        error = np.where(usable[:, active], intensity[:, active] - lights32 @ sub_g, 0.0)
        with np.errstate(invalid="ignore", divide="ignore"):
            rms = np.sqrt((error * error).sum(axis=0) / count[active])
        suspect = rms > threshold * albedo
        if not suspect.any():
            break
        active = active[suspect]
        sub_usable = usable[:, active]
        remaining = count[active].astype(np.int32)
        if m <= 8:
            scores = np.full((m, active.size), np.inf)
            excess = np.zeros((m, active.size), dtype=np.float32)  # observation j above the fit of the others
            for j in range(m):
                trial = sub_usable.copy()
                trial[j] = False
                candidate = sub_usable[j] & (remaining > 3)
                if candidate.any():
                    g_others, _, left = _fit_residual(intensity[:, active][:, candidate], trial[:, candidate], lights)
                    scores[j, candidate] = left
                    excess[j, candidate] = intensity[j, active[candidate]] - lights32[j] @ g_others
            order = np.sort(scores, axis=0)
            sub_albedo = albedo[suspect]
            # Removals that explain the data equally well are ties; among tied candidates a
            # specular outlier is the one brighter than the fit (positive residual), and only
            # when it is brighter than the others predict by a clear margin: a highlight, not
            # the few-percent departures of translucent skin from Lambert's law.
            ties = scores <= order[0] + 1e-3 * sub_albedo
            brightest = np.argmax(np.where(ties, intensity[:, active], -np.inf), axis=0)
            clear = (ties.sum(axis=0) == 1) & (order[0] < 0.5 * order[1])
            tied = (ties.sum(axis=0) > 1) & (excess[brightest, np.arange(active.size)] > HIGHLIGHT_EXCESS * sub_albedo)
            unique = np.isfinite(order[0]) & (clear | tied)
            best = np.where(tied, brightest, np.argmin(scores, axis=0))
            drop_rows, drop_cols = best[unique], np.flatnonzero(unique)
        else:
            per_pass = max(1, int(np.ceil(0.02 * m)))
            residual = np.where(sub_usable, np.abs(error[:, suspect]), -1.0)
            worst = np.argsort(-residual, axis=0)[:per_pass]
            rank = np.arange(per_pass)[:, None]
            allowed = (rank < (remaining - 3)[None, :]) & (np.take_along_axis(residual, worst, axis=0) > 0)
            drop_rows, drop_cols = worst[allowed], np.broadcast_to(np.arange(active.size), worst.shape)[allowed]
        if drop_rows.size == 0:
            break
        usable[drop_rows, active[drop_cols]] = False
        refit = np.unique(active[drop_cols])
        intensity[:, refit] = np.where(usable[:, refit], intensity[:, refit], np.float32(0))
        g[:, refit], count[refit] = _fit(intensity[:, refit], usable[:, refit], lights)
        active = refit[count[refit] > 3]
    return g, count


DEFAULT_ROBUST_THRESHOLD = 0.02
HIGHLIGHT_EXCESS = 0.3  # few lights: a tied observation is dropped as a highlight only this far (x albedo) above the others' fit


def photometric_stereo(images, lights, *, mask=None, shadow_fraction=DEFAULT_SHADOW_FRACTION, solver=DEFAULT_SOLVER,
                       exclude=None, highlights=None, robust_threshold=DEFAULT_ROBUST_THRESHOLD, max_iterations=12):
    """Per-pixel Lambertian least squares, n = (S^T S)^-1 S^T I, optionally robust.

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
        An observation below ``shadow_fraction`` times the pixel's albedo from a first fit of
        all its observations is taken as shadowed and left out (module notes). 0 keeps every
        finite observation.
    solver : ``"least-squares"`` or ``"robust"``
        ``robust`` then drops, per pixel, observations the Lambertian fit cannot explain
        (specular highlights, cast shadows) while the RMS residual exceeds
        ``robust_threshold`` times the albedo, never going below 3 lights, and refits (see
        ``_reject_outliers``). With 5 or more lights one outlier is identified by leaving
        each light out in turn; with 4 lights no single band can tell which light is wrong
        (any 3 fit exactly), so the robust solver equals least squares there, and the other
        bands' evidence is what can help (``specular-free`` band,
        :func:`specular_free_images`).
    exclude : array_like of bool, shape (m, rows, columns), optional
        Observations to leave out from the start.
    highlights : array_like of bool, shape (m, rows, columns), optional
        Observations found to be specular highlights by other evidence (the other bands:
        :meth:`SpecularSeparation.highlights`). They are left out; and since that evidence
        is what a few lights cannot give, the robust solver then skips its few-lights rule
        (for 8 lights or fewer, the brightest of equally good removals) and keeps only the
        residual rejection of many lights.

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
        raise ValueError(f"expected images of shape (m={lights.shape[0]}, rows, columns), got {images.shape}")
    if not 0 <= shadow_fraction < 1:
        raise SkinTopoError(f"shadow_fraction must be in [0, 1), got {shadow_fraction}")
    if solver not in SOLVERS:
        raise SkinTopoError(f"unknown solver {solver!r}; choose from {list(SOLVERS)}")
    m, rows, columns = images.shape
    if mask is None:
        mask = np.ones((rows, columns), dtype=bool)
    mask = np.asarray(mask, dtype=bool)
    if mask.shape != (rows, columns):
        raise ValueError(f"mask shape {mask.shape} differs from image shape {(rows, columns)}")

    flat_mask = mask.ravel()
    whole_field = bool(flat_mask.all())
    intensity = images.reshape(m, -1)
    if not whole_field:
        intensity = intensity[:, flat_mask]  # (m, P)
    usable = np.isfinite(intensity)
    for left_out in (exclude, highlights):
        if left_out is not None:
            left_out = np.asarray(left_out, dtype=bool).reshape(m, -1)
            usable &= ~(left_out if whole_field else left_out[:, flat_mask])
    peak = np.fmax.reduce(np.where(usable, intensity, np.nan), axis=0)  # ignores NaN; NaN only if all are NaN
    with np.errstate(invalid="ignore"):
        usable &= peak > 0  # a pixel dark under every light has no normal
    intensity = np.where(usable, intensity, np.float32(0))
    g, count = _fit(intensity, usable, lights)
    if shadow_fraction > 0:  # the shadow rule (module notes): relative to a first fit's albedo
        fraction = np.float32(shadow_fraction)
        with np.errstate(invalid="ignore"):
            shadowed = usable & ~(intensity > fraction * np.sqrt((g * g).sum(axis=0)))
        # The fit without the brightest observation can only lower the threshold: it is needed
        # only where some observation is under the threshold of the full fit.
        candidates = np.flatnonzero(shadowed.any(axis=0))
        if candidates.size:
            g_without = _fit_without_brightest(intensity[:, candidates], usable[:, candidates], lights)
            albedo = np.fmin(np.sqrt((g[:, candidates] ** 2).sum(axis=0)), np.sqrt((g_without * g_without).sum(axis=0)))
            with np.errstate(invalid="ignore"):
                dark = usable[:, candidates] & ~(intensity[:, candidates] > fraction * albedo)
            refit = candidates[dark.any(axis=0)]  # the pixels with a shadowed observation
            usable[:, candidates] &= ~dark
            intensity[:, refit] = np.where(usable[:, refit], intensity[:, refit], np.float32(0))
            g[:, refit], count[refit] = _fit(intensity[:, refit], usable[:, refit], lights)
    if solver == "robust":
        g, count = _reject_outliers(intensity, usable, lights, g, count, threshold=robust_threshold, max_iterations=max_iterations,
                                    few_lights_rule=highlights is None)

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

    used = np.zeros((m, rows * columns), dtype=bool)
    used[:, flat_mask] = usable
    return PhotometricStereoResult(
        normals=to_image(normal),
        albedo=to_image(albedo),
        residual=to_image(residual),
        lights_used=to_image(count, fill=0),
        valid=to_image(good, fill=False),
        used=used.reshape(m, rows, columns),
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


def specular_free_images(red, green, blue):
    """Specular-invariant shading from three colour bands under the same lights (SUV colour
    space, Mallick, Zickler, Kriegman & Belhumeur, CVPR 2005).

    With the bands radiometrically calibrated against each other (relative LED intensities
    divided out), skin's surface (specular) reflection has the colour of the light, s = (1, 1,
    1) / sqrt(3), while the diffuse part has the skin's colour. Removing each observation's
    component along s leaves a two-channel diffuse signal whose magnitude is |rho_perp| n . l:
    Lambertian, with the highlights gone. This is how the other bands' evidence removes the
    specular lobe that a single band of 4 lights cannot reject.

    Parameters
    ----------
    red, green, blue : ndarray, shape (m, rows, columns)
        Intensity-corrected images of the three bands, observation i under the same light.

    Returns
    -------
    ndarray, shape (m, rows, columns)
    """
    rgb = np.stack([np.asarray(red, np.float32), np.asarray(green, np.float32), np.asarray(blue, np.float32)], axis=-1)
    white = np.full(3, 1 / np.sqrt(3), dtype=np.float32)
    diffuse = rgb - (rgb @ white)[..., None] * white
    return np.sqrt((diffuse * diffuse).sum(axis=-1))


HIGHLIGHT_RATIO = 0.5  # an observation whose estimated specular part exceeds this fraction of its diffuse part is left out


@dataclass(frozen=True, eq=False)
class SpecularSeparation:
    """Output of :func:`separate_specular`: each band's diffuse images and the specular part
    (the same in every band), all (m, rows, columns) in the images' units."""

    diffuse: dict
    specular: np.ndarray

    def highlights(self, images, ratio=HIGHLIGHT_RATIO):
        """Observations of ``images`` (any band taken under the same lights, intensity-
        corrected: red, green, blue or white) whose specular part exceeds ``ratio`` times
        their diffuse part, images - specular."""
        with np.errstate(invalid="ignore"):
            return self.specular > ratio * np.maximum(np.asarray(images, dtype=np.float32) - self.specular, 0)


def separate_specular(red, green, blue, *, smoothing_px=5, lit_fraction=0.1):
    """Split each observation into a diffuse part with the skin's colour and a specular part
    with the light's colour, from the three bands taken under the same lights.

    Dichromatic reflection (Shafer 1985), with the bands radiometrically calibrated against
    each other (each light's relative intensity per band divided out, so the light is white,
    w = (1, 1, 1)): observation i of a pixel is v_i = d_i a + s_i w, with a the pixel's
    diffuse colour (rho_red, rho_green, rho_blue), d_i its diffuse shading and s_i >= 0 the
    surface (specular) reflection, equal in all bands. Write each v_i as its component along
    w_hat = w / sqrt(3), v_par = d_i a . w_hat + sqrt(3) s_i, and the rest, |v_perp| = d_i
    |a_perp| (specular-free, as in :func:`specular_free_images`). The least specular
    observation has the smallest ratio v_par / |v_perp|; it fixes k = a . w_hat / |a_perp|
    (its s_i taken as 0), and then

        s_i = max(0, v_par,i - k |v_perp,i|) / sqrt(3),   diffuse_c,i = v_c,i - s_i.

    k is a colour property that varies slowly over skin: the per-pixel minimum (over the
    observations whose |v_perp| is at least ``lit_fraction`` of the pixel's largest) is median
    filtered over ``smoothing_px`` pixels, which removes most of the noise bias of a minimum.
    With a broad specular lobe every observation carries some specular light and k is
    overestimated where no observation is free of it: part of the specular stays. Translucency
    and interreflection change the diffuse colour from one observation to the next, which the
    model does not describe (measured on the simulator, see the module tests).

    Parameters
    ----------
    red, green, blue : array_like, shape (m, rows, columns)
        Intensity-corrected images, observation i under the same light in every band; NaN
        marks a saturated observation (kept NaN).

    Returns
    -------
    SpecularSeparation
    """
    import scipy.ndimage

    v = np.stack([np.asarray(c, dtype=np.float32) for c in (red, green, blue)], axis=-1)
    if v.ndim != 4:
        raise ValueError(f"expected three stacks of images (m, rows, columns), got shape {v.shape[:-1]}")
    parallel = v.sum(axis=-1) / np.float32(np.sqrt(3))
    perpendicular = np.sqrt(np.maximum((v * v).sum(axis=-1) - parallel * parallel, 0))
    with np.errstate(invalid="ignore", divide="ignore"):
        lit = perpendicular > lit_fraction * np.fmax.reduce(perpendicular, axis=0)
        ratio = np.where(lit & np.isfinite(parallel), parallel / perpendicular, np.inf)
    k = np.min(ratio, axis=0)
    finite = np.isfinite(k)
    if not finite.any():
        specular = np.zeros(parallel.shape, dtype=np.float32)
    else:
        k = np.where(finite, k, np.median(k[finite]))
        if smoothing_px > 1:
            k = scipy.ndimage.median_filter(k, size=smoothing_px, mode="nearest")
        with np.errstate(invalid="ignore"):
            specular = np.maximum(parallel - k * perpendicular, 0) / np.float32(np.sqrt(3))
        specular = np.where(np.isfinite(specular), specular, np.float32(0)).astype(np.float32)
    diffuse = {band: v[..., i] - specular for i, band in enumerate(("red", "green", "blue"))}
    return SpecularSeparation(diffuse, specular)
