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

Specular lobe (6 lights or more, ``specular_lobe=True``): a shiny surface adds to the
Lambertian part a lobe around the mirror direction, which bends the least-squares normal
toward the lights it comes from; a broad lobe (a sheen) touches every observation, so no
exclusion can remove it. Each pixel is then fitted as I_i = g . l_i + S D(n . h_i; m) / (n . v)
(Beckmann facet distribution D, h_i the half vector of light i and the view v), S >= 0 per
pixel and one roughness m for the field (:func:`_fit_specular_lobe`). With 4 lights the lobe's
unknown would leave no redundancy, so none is fitted there. Measured: DiLiGenT ball, white,
96 lights, 2.90 -> 2.28 degrees; numbers on rendered coats in docs/method.md. The robust
solver fits the lobe to the observations it keeps and, per pixel, keeps the default's fit
instead where that explains the same number of observations better (least trimmed squares,
:func:`_least_trimmed_choice`): a broad sheen otherwise made it drop the observations that fix
the lobe.
"""

from __future__ import annotations

from dataclasses import dataclass, field

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
    specular_roughness : float or None
        The Beckmann roughness m of the specular lobe fitted with the normals (module
        notes), None when no lobe was fitted (fewer than ``SPECULAR_LOBE_MIN_LIGHTS`` lights,
        or ``specular_lobe=False``).
    """

    normals: np.ndarray
    albedo: np.ndarray
    residual: np.ndarray
    lights_used: np.ndarray
    valid: np.ndarray
    used: np.ndarray
    specular_roughness: float | None = None


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
SPECULAR_LOBE_MIN_LIGHTS = 6  # the lobe adds one unknown to the three of g: below this, too few observations left to judge it
LOBE_ROUGHNESS_GRID = (0.1, 0.15, 0.2, 0.25, 0.3, 0.35, 0.4, 0.5)  # Beckmann m searched
LOBE_ITERATIONS = 3  # lobe (from the normals) <-> normals passes (2, 3, 4 on bench_shiny's coated cases: mean default 4.75, 4.54, 4.56 deg, robust 1.52, 1.37, 1.75)
LOBE_NEWTON_STEPS = 2  # Gauss-Newton steps of g and S together after the linear fits
LOBE_MAX_OVER_BRIGHTEST = 2.0  # a fitted specular part larger than this times the brightest observation is refused
LOBE_BLOCK_PIXELS = 16384  # pixels fitted together (12 lights: 0.8 MB per array)
LOBE_READMIT = 0.1  # robust solver: an observation within this fraction of the albedo of the lobe model is used again
LOBE_IDENTIFIABLE = 1e-3  # S is fitted only where this share of the lobe's power is not a Lambertian shading
LOBE_SAMPLE_PIXELS = 65536  # the roughness is chosen on at most about this many pixels (every k-th)


def _half_vectors(lights, view=None):
    """Unit half vectors h_i of each light l_i and the view v (default (0, 0, 1)), single
    precision; ``lights`` (m, 3), or (m, rows, columns, 3) with ``view`` (rows, columns, 3)."""
    lights = np.asarray(lights, dtype=np.float32)
    view = np.array([0.0, 0.0, 1.0], dtype=np.float32) if view is None else np.asarray(view, dtype=np.float32)
    total = lights + view
    return total / np.linalg.norm(total, axis=-1, keepdims=True)


class SpecularLobe:
    """Microfacet lobe D(n . h; m) / (n . v) per light, zero where n . l <= 0 or where
    ``visible`` is False; call it with a roughness m for the (lights, rows, columns) stack.

    D = exp(-tan^2 alpha / m^2) / (m^2 cos^4 alpha) (Beckmann, without its 1/pi, which the
    fitted scale takes), alpha the angle between n and the half vector h of l and v. The
    geometry (tan^2 alpha and the factor that does not depend on m) is computed once, so a
    search over m costs one exponential per candidate. Single precision (1 - cos^2 near the
    peak keeps about 1e-7). Used by the photometric-stereo lobe fit and by
    :mod:`skintopo.physics`.

    ``lights``: unit directions (m, 3) with the orthographic view v = (0, 0, 1), or per pixel
    (m, rows, columns, 3) with ``view`` (rows, columns, 3) per pixel and ``strength``
    (m, rows, columns), each light's irradiance there (near LEDs, a perspective camera: the
    lobe is E_i D / (n . v)).
    """

    def __init__(self, normals, lights, visible=True, view=None, strength=1.0):
        normals, lights = np.asarray(normals, dtype=np.float32), np.asarray(lights, dtype=np.float32)
        halves = _half_vectors(lights, view)
        product = "rck,mk->mrc" if lights.ndim == 2 else "rck,mrck->mrc"
        cosine = np.clip(np.einsum(product, normals, halves), 1e-6, 1.0)
        self.tan2 = (1 - cosine**2) / cosine**2
        lit = (np.einsum(product, normals, lights) > 0) & visible
        facing = normals[..., 2] if view is None else np.einsum("rck,rck->rc", normals, np.asarray(view, dtype=np.float32))
        self.factor = np.where(lit, np.asarray(strength, dtype=np.float32) / (cosine**4 * np.clip(facing, 0.2, 1.0)), 0.0)

    def __call__(self, roughness):
        return np.exp(self.tan2 * np.float32(-1.0 / roughness**2)) * (self.factor / np.float32(roughness**2))


def _plausible_lobe(scale, phi, intensity, weight):
    """Pixels whose fitted specular part S phi_i stays under ``LOBE_MAX_OVER_BRIGHTEST`` times
    their brightest used observation at every used light (a larger lobe is a fit of noise
    or of a degenerate geometry, not light that was observed)."""
    with np.errstate(invalid="ignore", over="ignore"):
        lobe = (scale.astype(np.float32) * phi * weight).max(axis=0)
        return lobe <= LOBE_MAX_OVER_BRIGHTEST * (intensity * weight).max(axis=0)


def _sum_of_squares(values):
    """Sum of squares over the first axis, in double precision (inf where it overflows)."""
    values = values.astype(np.float64)
    return np.add.reduce(values * values, axis=0)


def _gauss_newton_step(solution, scale, phi, intensity, weight, lights, roughness):
    """One Gauss-Newton step of the lobe model I_i = g . l_i + S phi_i(n), n = g / |g|, for
    g and S together (the lobe moves with the normal: d phi_i / d g = phi_i (2 / (m^2 c^3) -
    4 / c) (I - n n^T) h_i / |g|, c = n . h_i, and the 1 / n_z factor's term); S kept >= 0,
    and a pixel's step kept only where it lowers its residual (a sharp lobe is far from linear
    in n: unguarded steps diverged on sharp simulated highlights). ``phi``: the lobe at the
    normals of ``solution``. Returns g, S and the lobe phi at the kept normals."""
    albedo = np.linalg.norm(solution, axis=0)
    normal = (solution / albedo).astype(np.float32)  # (3, pixels)
    halves = _half_vectors(lights)
    cosine = np.clip(halves @ normal, 0.1, 1.0)  # beyond 84 degrees from h the lobe is nil (exp(-99 / m^2))
    rate = phi * (np.float32(2 / roughness**2) / cosine**3 - 4 / cosine)  # d phi / d c
    facing = (normal[2] > 0.2) & (normal[2] < 1.0)  # where phi's 1 / n_z factor is not clipped
    # d phi / d n per component, (lights, pixels) each, then projected on the tangent plane
    # (the part along n does not turn the normal) and divided by |g|
    gradient = [rate * halves[:, k, None] for k in range(3)]
    gradient[2] -= np.where(facing, phi / np.clip(normal[2], 0.2, 1.0), np.float32(0))
    along_normal = gradient[0] * normal[0] + gradient[1] * normal[1] + gradient[2] * normal[2]
    # the normal equations in double precision (a block of pixels at a time: small arrays)
    turn = scale / albedo
    jacobian = [lights[:, k, None] + turn * (gradient[k] - along_normal * normal[k]).astype(np.float64) for k in range(3)]
    jacobian.append(phi.astype(np.float64))
    residual = weight * (intensity - lights @ solution.astype(np.float32) - scale.astype(np.float32) * phi)
    weighted = [weight * column for column in jacobian]
    with np.errstate(invalid="ignore", over="ignore", divide="ignore"):
        # the symmetric 4 x 4 normal equations [A b; b^T c] [dg; dS] = [r; t], solved by the
        # Schur complement as in the linear fit (no batched general solver: 5x faster)
        upper = [(weighted[a] * jacobian[b]).sum(axis=0) for a, b in _UPPER]
        cross = [(weighted[a] * jacobian[3]).sum(axis=0) for a in range(3)]
        right = [(column * residual).sum(axis=0) for column in jacobian]
        first, _ = solve_symmetric_3x3(upper, right[:3])
        along, _ = solve_symmetric_3x3(upper, cross)
        remainder = (weighted[3] * jacobian[3]).sum(axis=0) - sum(c * a for c, a in zip(cross, along))
        scale_step = (right[3] - sum(c * f for c, f in zip(cross, first))) / remainder
        step = np.concatenate([(first - scale_step * along).T, scale_step[:, None]], axis=1)
    with np.errstate(invalid="ignore", over="ignore", divide="ignore"):
        trial = solution + np.nan_to_num(step[:, :3].T)
        trial_scale = np.maximum(scale + np.nan_to_num(step[:, 3]), 0.0)
        trial_phi = SpecularLobe((trial / np.linalg.norm(trial, axis=0)).T[None].astype(np.float32), lights)(roughness)[:, 0]
        trial_residual = weight * (intensity - lights @ trial.astype(np.float32) - trial_scale.astype(np.float32) * trial_phi)
        # a step is kept only where it lowers the pixel's residual (the lobe is far from linear in n)
        better = (np.isfinite(step).all(axis=1) & (_sum_of_squares(trial_residual) < _sum_of_squares(residual))
                  & _plausible_lobe(trial_scale, trial_phi, intensity, weight))
    return np.where(better, trial, solution), np.where(better, trial_scale, scale), np.where(better, trial_phi, phi)


def _fit_specular_lobe(observed, candidates, usable, lights, g, *, readmit):
    """Normals with a specular lobe: I_i = g . l_i + S phi_i, phi_i = D(n . h_i; m) / (n . v)
    (:class:`SpecularLobe`), S >= 0 per pixel, one roughness m for the field.

    ``LOBE_ITERATIONS`` times: m, the grid value whose lobe, scaled per pixel, best explains
    the excess of the observations (the shadow rule's ``candidates``) over the current g . l
    (from the robust solver's normals a sharp highlight shows as a narrow excess, a broad
    sheen as a wide one); the lobe of the current normals; and g, S by least squares over the
    ``usable`` observations (4 x 4 normal equations per pixel, solved by their Schur
    complement; S <= 0 falls back to the Lambertian g). With ``readmit`` (robust solver) the
    observations are then those within ``LOBE_READMIT`` albedo of the model, among the
    candidates: a highlight the lobe explains is used again, one it does not stays out.
    Then ``LOBE_NEWTON_STEPS`` Gauss-Newton steps of g and S together
    (:func:`_gauss_newton_step`): the linear fits hold the lobe where the last normals put it.
    m is chosen this way on at most about ``LOBE_SAMPLE_PIXELS`` pixels (every k-th); all
    pixels are then fitted with it, in blocks of ``LOBE_BLOCK_PIXELS`` (arrays that stay in
    the processor's cache: 3-4x faster than whole-field passes). Pixels with fewer than
    ``SPECULAR_LOBE_MIN_LIGHTS`` usable observations keep their Lambertian fit.

    Hand-written: no library fits a per-pixel Lambertian-plus-microfacet model to photometric
    stereo data (the robust references, Wu et al. 2010 and Ikehata et al. 2012, reject the
    specular part as outliers, which leaves a broad sheen in the fit).

    Returns g (3, P), the observations used (m, P), the fitted specular part (m, P) and m.
    """
    fitted = np.isfinite(g).all(axis=0) & (usable.sum(axis=0) >= SPECULAR_LOBE_MIN_LIGHTS)
    pixels = np.flatnonzero(fitted)
    specular = np.zeros(observed.shape, dtype=np.float32)
    if pixels.size == 0:
        return g, usable, specular, None
    lights32 = lights.astype(np.float32)
    sample = pixels[:: max(1, pixels.size // LOBE_SAMPLE_PIXELS)]
    *_, roughness = _lobe_fit(observed[:, sample], candidates[:, sample], usable[:, sample], lights32, g[:, sample], readmit)
    g, usable = g.copy(), usable.copy()
    for start in range(0, pixels.size, LOBE_BLOCK_PIXELS):
        block = pixels[start : start + LOBE_BLOCK_PIXELS]
        solution, weight, part, _ = _lobe_fit(observed[:, block], candidates[:, block], usable[:, block], lights32, g[:, block], readmit,
                                              roughness)
        g[:, block], usable[:, block], specular[:, block] = solution, weight, part  # a pixel it could not fit keeps its g
    return g, usable, specular, float(roughness)


def _lobe_fit(intensity, allowed, weight, lights, g, readmit, roughness=None):
    """The iterations of :func:`_fit_specular_lobe` on some pixels (all columns), m chosen at
    each iteration when ``roughness`` is None. Returns g (float64), the observations used, the
    specular part and m."""
    solution, initial_weight = g.astype(np.float64), weight

    def lobe_of(solution):
        return SpecularLobe((solution / np.linalg.norm(solution, axis=0)).T[None], lights)

    def total(values):
        return np.add.reduce(values, axis=0, dtype=np.float64)

    def best_roughness(solution):  # the grid's m whose lobe, scaled per pixel, best explains the excess over g . l
        excess = np.where(allowed, intensity - lights @ solution.astype(np.float32), np.float32(0))
        lobes, misfit = lobe_of(solution), []
        for candidate in LOBE_ROUGHNESS_GRID:
            phi = lobes(candidate)[:, 0] * allowed
            scale = np.maximum(total(phi * excess) / np.maximum(total(phi * phi), 1e-30), 0.0).astype(np.float32)
            misfit.append(float(_sum_of_squares(excess - scale * phi).sum()))
        return LOBE_ROUGHNESS_GRID[int(np.argmin(misfit))]

    upper = np.stack([lights[:, i] * lights[:, j] for i, j in _UPPER])  # (6, m)
    chosen = roughness
    for _ in range(LOBE_ITERATIONS):
        roughness = best_roughness(solution) if chosen is None else chosen
        phi = lobe_of(solution)(roughness)[:, 0]
        w = weight.astype(np.float32)
        # [A b; b^T c] [g; S] = [r; t] by its Schur complement: with A^-1 r (the Lambertian g)
        # and A^-1 b, S = (t - b . A^-1 r) / (c - b . A^-1 b) and g = A^-1 r - S A^-1 b
        weighted_phi = w * phi
        normal_matrix = (upper @ w).astype(np.float64)
        cross, right = (lights.T @ weighted_phi).astype(np.float64), (lights.T @ (w * intensity)).astype(np.float64)
        lambertian, _ = solve_symmetric_3x3(normal_matrix, right)
        along, _ = solve_symmetric_3x3(normal_matrix, cross)
        lobe_power = total(weighted_phi * phi)
        remainder = lobe_power - (cross * along).sum(axis=0)  # the lobe's part that no Lambertian g explains
        with np.errstate(invalid="ignore", divide="ignore"):
            scale = (total(weighted_phi * intensity) - (cross * lambertian).sum(axis=0)) / remainder
        # no lobe where S <= 0 (or NaN), or where the lobe is (nearly) a Lambertian shading (S unidentifiable)
        scale = np.where((scale > 0) & (remainder > LOBE_IDENTIFIABLE * lobe_power) & _plausible_lobe(scale, phi, intensity, w), scale, 0.0)
        solution = lambertian - scale * along
        if readmit:
            albedo = np.linalg.norm(solution, axis=0).astype(np.float32)
            model = lights @ solution.astype(np.float32) + scale.astype(np.float32) * phi
            closer = allowed & (np.abs(intensity - model) <= np.float32(LOBE_READMIT) * albedo)
            weight = np.where(closer.sum(axis=0) >= SPECULAR_LOBE_MIN_LIGHTS, closer, weight)
    w = weight.astype(np.float32)
    phi = lobe_of(solution)(roughness)[:, 0]  # the linear fit's lobe was that of the normals before it
    for _ in range(LOBE_NEWTON_STEPS):
        solution, scale, phi = _gauss_newton_step(solution, scale, phi, intensity, w, lights, roughness)
    # S was fitted to the lobe of the normals before the last update: where the lobe of the
    # final normals makes an implausible specular part, the pixel keeps its Lambertian fit
    kept = np.isfinite(solution).all(axis=0) & _plausible_lobe(scale, phi, intensity, w)
    part = np.where(kept, scale.astype(np.float32) * phi, np.float32(0))
    return np.where(kept, solution, g), np.where(kept, weight, initial_weight), part, roughness


def _least_trimmed_choice(observed, candidates, lights, robust, alternative):
    """Per pixel, the fit (g, observations used, specular part) of the two, ``robust`` (the
    lobe fitted to the observations the robust solver kept) or ``alternative`` (the lobe
    fitted to all of them, the default solver's), whose k smallest squared residuals over the
    ``candidates`` (the observations the shadow rule keeps) sum lower, k = the number of
    observations the robust fit used: the least-trimmed-squares criterion (Rousseeuw 1984).
    A broad sheen makes the robust solver leave out the brightest observations, with them
    the lobe's scale, and the remaining ones are biased; the lobe fitted to all of them then
    explains the same k observations better. A highlight the lobe cannot explain leaves
    the alternative's normals bent and its k best residuals larger."""
    trimmed = []
    rank = np.arange(observed.shape[0])[:, None]
    keep = robust[1].sum(axis=0)
    for g, _, specular in (robust, alternative):
        error = np.where(candidates, observed - lights.astype(np.float32) @ g.astype(np.float32) - specular, np.float32(np.inf))
        error *= error
        error.sort(axis=0)
        trimmed.append(np.where(rank < keep, error, np.float32(0)).sum(axis=0))
    with np.errstate(invalid="ignore"):
        other = trimmed[1] < trimmed[0]  # False where either is NaN: the robust fit stays
    return tuple(np.where(other, b, a) for a, b in zip(robust, alternative))


def photometric_stereo(images, lights, *, mask=None, shadow_fraction=DEFAULT_SHADOW_FRACTION, solver=DEFAULT_SOLVER,
                       exclude=None, highlights=None, robust_threshold=DEFAULT_ROBUST_THRESHOLD, max_iterations=12,
                       specular_lobe=True):
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
    specular_lobe : bool
        With ``SPECULAR_LOBE_MIN_LIGHTS`` lights or more, fit a specular lobe together with
        the normals (module notes): I_i = g . l_i + S D(n . h_i; m) / (n . v). False gives
        the Lambertian fit alone (with ``shadow_fraction=0``: textbook least squares).

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
    lobe = specular_lobe and m >= SPECULAR_LOBE_MIN_LIGHTS
    if lobe:  # the observations the lobe may use again (the robust solver zeroes those it drops)
        candidates, observed = usable.copy(), intensity.copy()
    if solver == "robust":
        least_squares = g  # the default's starting point, for _least_trimmed_choice
        g, count = _reject_outliers(intensity, usable, lights, g, count, threshold=robust_threshold, max_iterations=max_iterations,
                                    few_lights_rule=highlights is None)
    specular, roughness = np.float32(0), None
    if lobe:
        g, usable, specular, roughness = _fit_specular_lobe(observed, candidates, usable, lights, g, readmit=solver == "robust")
        if solver == "robust":
            g, usable, specular = _least_trimmed_choice(observed, candidates, lights, (g, usable, specular),
                                                        _fit_specular_lobe(observed, candidates, candidates, lights, least_squares,
                                                                           readmit=False)[:3])
        intensity = np.where(usable, observed, np.float32(0))
        count = np.add.reduce(usable, axis=0, dtype=np.int16)

    albedo = np.sqrt(g[0] * g[0] + g[1] * g[1] + g[2] * g[2])
    with np.errstate(invalid="ignore"):
        good = albedo > 0  # False for NaN
    g[:, ~good] = np.nan
    albedo[~good] = np.nan
    error = np.where(usable, intensity - lights.astype(np.float32) @ g - specular, np.float32(0))
    error *= error
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
        specular_roughness=roughness,
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
    s_i, all (m, rows, columns) in the images' units; ``colour``: band -> the specular
    colour's factor (mean 1 over red, green and blue; all 1 for a neutral surface), so that
    band c's specular part is s_i colour[c] (:meth:`band_specular`)."""

    diffuse: dict
    specular: np.ndarray
    colour: dict = field(default_factory=lambda: {"red": 1.0, "green": 1.0, "blue": 1.0, "white": 1.0})

    def band_specular(self, band="white"):
        """The specular part in ``band``'s images (white: the mean of the three bands')."""
        factor = self.colour[band]
        return self.specular if factor == 1.0 else self.specular * np.float32(factor)

    def highlights(self, images, ratio=HIGHLIGHT_RATIO, band="white"):
        """Observations of ``images`` (``band``'s, taken under the same lights, intensity-
        corrected: red, green, blue or white) whose specular part exceeds ``ratio`` times
        their diffuse part, images - specular."""
        specular = self.band_specular(band)
        with np.errstate(invalid="ignore"):
            return specular > ratio * np.maximum(np.asarray(images, dtype=np.float32) - specular, 0)


def checked_specular_colour(colour):
    """``colour`` (the surface reflection's relative strength in red, green and blue) as three
    floats, or a :class:`SkinTopoError` when it is not three finite positive numbers."""
    values = tuple(colour) if np.ndim(colour) == 1 else ()
    if len(values) != 3 or not all(isinstance(v, (int, float, np.number)) and np.isfinite(v) and v > 0 for v in values):
        raise SkinTopoError(f"specular_colour must be three positive numbers (red, green, blue), got {colour!r}")
    return tuple(float(v) for v in values)


def separate_specular(red, green, blue, *, smoothing_px=5, lit_fraction=0.1, specular_colour=None):
    """Split each observation into a diffuse part with the skin's colour and a specular part
    with the light's colour, from the three bands taken under the same lights.

    Dichromatic reflection (Shafer 1985), with the bands radiometrically calibrated against
    each other (each light's relative intensity per band divided out, so the light is white):
    observation i of a pixel is v_i = d_i a + s_i w, with a the pixel's diffuse colour
    (rho_red, rho_green, rho_blue), d_i its diffuse shading, s_i >= 0 the surface (specular)
    reflection and w its colour: w = (1, 1, 1) under the neutral-interface assumption (Lee,
    Breneman & Schulte 1990: the surface reflects every band alike), the default; a surface
    whose refractive index changes with the wavelength reflects the bands in proportion to
    their Fresnel reflectances, ``specular_colour``. Write each v_i as its component along
    w_hat = w / |w|, v_par = d_i a . w_hat + |w| s_i, and the rest, |v_perp| = d_i |a_perp|
    (specular-free, as in :func:`specular_free_images` for white). The least specular
    observation has the smallest ratio v_par / |v_perp|; it fixes k = a . w_hat / |a_perp|
    (its s_i taken as 0), and then

        s_i w_c = max(0, v_par,i - k |v_perp,i|) w_hat_c,   diffuse_c,i = v_c,i - s_i w_c.

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
    specular_colour : sequence of 3 positive floats, optional
        The surface reflection's relative strength in red, green and blue (any scale);
        default (1, 1, 1).

    Returns
    -------
    SpecularSeparation
        ``specular`` is s_i with w scaled to a mean of 1 (for white: the specular part of
        every band), ``colour`` that w, ``diffuse`` each band's images minus its own.
    """
    import scipy.ndimage

    v = np.stack([np.asarray(c, dtype=np.float32) for c in (red, green, blue)], axis=-1)
    if v.ndim != 4:
        raise ValueError(f"expected three stacks of images (m, rows, columns), got shape {v.shape[:-1]}")
    colour = np.ones(3) if specular_colour is None else np.asarray(checked_specular_colour(specular_colour))
    colour = colour / colour.mean()
    along = (colour / np.linalg.norm(colour)).astype(np.float32)  # w_hat
    parallel = v @ along
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
        with np.errstate(invalid="ignore"):  # s_i with w scaled to mean 1: |w| = |colour|
            specular = np.maximum(parallel - k * perpendicular, 0) / np.float32(np.linalg.norm(colour))
        specular = np.where(np.isfinite(specular), specular, np.float32(0)).astype(np.float32)
    factors = dict(zip(("red", "green", "blue"), colour.tolist())) | {"white": 1.0}
    diffuse = {band: v[..., i] - specular * np.float32(factors[band]) for i, band in enumerate(("red", "green", "blue"))}
    return SpecularSeparation(diffuse, specular, factors)
