"""Compiled per-pixel loops of near-field photometric stereo (:mod:`skintopo.nearfield`).

Hand-written with Numba because no library does these loops, and NumPy pays for them in
memory traffic rather than arithmetic:

* the per-pixel least squares with each pixel's own light matrix: NumPy builds the (LEDs, 3,
  pixels) light vectors and the normal equations' six sums as separate whole-array passes,
  three times per pixel for the shadow rule; here each pixel's light vectors live in
  registers and its three small solves follow (1000 x 1000 on two threads: 51 ms with the
  shadow rule, 31 ms without; the NumPy version took about 80 ms a call);
* the fixed point that finds where each node of the skin-plane grid lies on the image:
  NumPy re-projects and re-interpolates the whole array of nodes still moving at every step;
  here each node iterates alone (about 30 instead of 120 ms at 1000 x 1000);
* the slopes of log depth from the normals (one pass instead of a dozen array operations).

The arithmetic is that of the NumPy formulas the docstrings of :mod:`skintopo.nearfield`
give, in double precision (the NumPy version summed in float32: on the simulated forehead
the heights' error after form removal changed from 1.61026 to 1.61028 um). ``cache=True``:
compiled once per installation (a few seconds, on the first call), loaded from the cache
afterwards; ``error_model="numpy"``: a division by zero gives inf or NaN, as in NumPy.
"""

import math

import numba
import numpy as np


@numba.njit(nogil=True, cache=True, error_model="numpy", inline="always")
def _weighted_fit(s, values, weights, g):
    """g = (S^T W S)^-1 S^T W I for one pixel (m LEDs; W diagonal 0/1); NaN where fewer than 3
    observations remain or the used lights do not span 3-D (det below 1e-6 (trace / 3)^3).
    Returns the number of observations used."""
    a00 = a01 = a02 = a11 = a12 = a22 = b0 = b1 = b2 = count = 0.0
    for i in range(s.shape[0]):
        w = weights[i]
        if w == 0.0:
            continue
        s0, s1, s2, v = s[i, 0], s[i, 1], s[i, 2], values[i]
        a00 += w * s0 * s0
        a01 += w * s0 * s1
        a02 += w * s0 * s2
        a11 += w * s1 * s1
        a12 += w * s1 * s2
        a22 += w * s2 * s2
        b0 += w * s0 * v
        b1 += w * s1 * v
        b2 += w * s2 * v
        count += w
    c00 = a11 * a22 - a12 * a12
    c01 = a02 * a12 - a01 * a22
    c02 = a01 * a12 - a02 * a11
    det = a00 * c00 + a01 * c01 + a02 * c02
    trace = (a00 + a11 + a22) / 3
    if count >= 3 and abs(det) > 1e-6 * trace * trace * trace:
        c11 = a00 * a22 - a02 * a02
        c12 = a01 * a02 - a00 * a12
        c22 = a00 * a11 - a01 * a01
        inverse = 1.0 / det
        g[0] = (c00 * b0 + c01 * b1 + c02 * b2) * inverse
        g[1] = (c01 * b0 + c11 * b1 + c12 * b2) * inverse
        g[2] = (c02 * b0 + c12 * b1 + c22 * b2) * inverse
    else:
        g[0] = g[1] = g[2] = np.nan
    return count


@numba.njit(nogil=True, cache=True, error_model="numpy")
def per_pixel_solve(intensity, rays, depth, positions, directions, mu, phi, shadow_fraction, used_in, use_given, normals_out, albedo_out,
                    residual_out, used_out):
    """Near-field least squares of every pixel of a block (see
    :func:`skintopo.nearfield.per_pixel_photometric_stereo` for the shadow rule and the
    residual, :meth:`skintopo.device.Led.light_vectors` for the light vectors, which are taken
    times ``phi`` (the band's intensity times the squared working distance)).

    intensity (m, P); rays (3, P); depth (P,) mm; positions, directions (m, 3); mu, phi (m,);
    used_in (m, P) bool, read when ``use_given``. Writes normals_out (3, P) (g / |g|),
    albedo_out (P,) (|g|), residual_out (P,) and used_out (m, P)."""
    m, count = intensity.shape
    s = np.empty((m, 3))
    values = np.empty(m)
    finite = np.empty(m)
    normalised = np.empty(m)  # I_i / |s_i|
    weights = np.empty(m)
    g = np.empty(3)
    g_other = np.empty(3)
    for p in range(count):
        d = depth[p]
        px, py, pz = d * rays[0, p], d * rays[1, p], d * rays[2, p]
        for i in range(m):
            tx, ty, tz = positions[i, 0] - px, positions[i, 1] - py, positions[i, 2] - pz
            inverse = 1.0 / math.sqrt(tx * tx + ty * ty + tz * tz)
            cos_theta = -(tx * directions[i, 0] + ty * directions[i, 1] + tz * directions[i, 2]) * inverse
            lobe = max(cos_theta, 0.0)
            if mu[i] != 1.0:  # pow() is the loop's most costly call: skipped for the common Lambertian LED
                lobe = lobe ** mu[i]
            norm = lobe * (inverse * inverse * phi[i])  # |s_i|
            strength = norm * inverse
            s[i, 0], s[i, 1], s[i, 2] = tx * strength, ty * strength, tz * strength
            v = intensity[i, p]
            if math.isfinite(v):
                values[i], finite[i] = v, 1.0
            else:
                values[i], finite[i] = 0.0, 0.0
            normalised[i] = values[i] / max(norm, 1e-30)
        if use_given:
            for i in range(m):
                weights[i] = 1.0 if used_in[i, p] else 0.0
        else:
            # rho_0 = the smaller albedo of the fits with every observation and without the brightest
            _weighted_fit(s, values, finite, g)
            brightest, best = 0, -np.inf
            for i in range(m):
                weights[i] = finite[i]
                if finite[i] > 0 and normalised[i] > best:
                    brightest, best = i, normalised[i]
            weights[brightest] = 0.0
            _weighted_fit(s, values, weights, g_other)
            rho_all = math.sqrt(g[0] * g[0] + g[1] * g[1] + g[2] * g[2])
            rho_other = math.sqrt(g_other[0] * g_other[0] + g_other[1] * g_other[1] + g_other[2] * g_other[2])
            rho0 = rho_other if math.isnan(rho_all) else (rho_all if math.isnan(rho_other) else min(rho_all, rho_other))  # np.fmin
            for i in range(m):
                weights[i] = finite[i] if not (normalised[i] < shadow_fraction * rho0) else 0.0
        _weighted_fit(s, values, weights, g)
        misfit = energy = 0.0
        for i in range(m):
            used_out[i, p] = weights[i] > 0
            if weights[i] > 0:
                e = values[i] - (s[i, 0] * g[0] + s[i, 1] * g[1] + s[i, 2] * g[2])
                misfit += e * e
                energy += values[i] * values[i]
        rho = math.sqrt(g[0] * g[0] + g[1] * g[1] + g[2] * g[2])
        normals_out[0, p], normals_out[1, p], normals_out[2, p] = g[0] / rho, g[1] / rho, g[2] / rho
        albedo_out[p] = rho
        residual_out[p] = misfit / max(energy, 1e-30)


@numba.njit(nogil=True, cache=True, error_model="numpy")
def surface_grid_fixed_point(filled, valid, x, y, depth, focal_px, centre_u, centre_v, k1, k2, tolerance_px, max_iterations, column, row,
                             inside):
    """For each node (x, y) (mm) the depth d where the camera ray meets the height field:
    (column, row) = project(x, y, -d), d = filled(row, column) read bilinearly (indices
    clamped to the image, as ``scipy.ndimage.map_coordinates(order=1, mode="nearest")``),
    from the start ``depth``, until the projection of the last d moves by less than
    ``tolerance_px`` from where d was read. Updates ``depth`` in place; writes the (column,
    row) d was read at, or, when ``max_iterations`` ran out, the projection of the last d;
    ``inside``: whether that point lies on the image with the bilinear weight of the
    ``valid`` pixels above 0.999 (a node read from valid pixels only)."""
    rows, columns = filled.shape
    for n in range(x.size):
        d = depth[n]
        u = v = read_u = read_v = 0.0
        for iteration in range(max_iterations + 1):
            xn, yn = x[n] / d, y[n] / d
            r2 = xn * xn + yn * yn
            factor = 1.0 + k1 * r2 + k2 * r2 * r2
            u, v = centre_u + xn * factor * focal_px, centre_v - yn * factor * focal_px
            if iteration > 0 and abs(u - read_u) < tolerance_px and abs(v - read_v) < tolerance_px:
                u, v = read_u, read_v  # settled: d is the depth read there
                break
            if iteration == max_iterations:
                break
            cu, cv = min(max(u, 0.0), columns - 1.0), min(max(v, 0.0), rows - 1.0)
            i0, j0 = min(int(cv), rows - 2), min(int(cu), columns - 2)
            tv, tu = cv - i0, cu - j0
            d = ((1 - tv) * ((1 - tu) * filled[i0, j0] + tu * filled[i0, j0 + 1])
                 + tv * ((1 - tu) * filled[i0 + 1, j0] + tu * filled[i0 + 1, j0 + 1]))
            read_u, read_v = u, v
        depth[n], column[n], row[n] = d, u, v
        if 0.0 <= u <= columns - 1.0 and 0.0 <= v <= rows - 1.0:
            i0, j0 = min(int(v), rows - 2), min(int(u), columns - 2)
            tv, tu = v - i0, u - j0
            share = ((1 - tv) * ((1 - tu) * valid[i0, j0] + tu * valid[i0, j0 + 1])
                     + tv * ((1 - tu) * valid[i0 + 1, j0] + tu * valid[i0 + 1, j0 + 1]))
            inside[n] = share > 0.999
        else:
            inside[n] = False


@numba.njit(nogil=True, cache=True, error_model="numpy")
def log_depth_slopes(g, rays, rays_u, rays_v, slope_u, slope_v):
    """The slopes of log depth from the normals g (3, P) (any length: only ratios enter;
    :mod:`skintopo.nearfield`, step 3):
    d(log d)/du = -(g . w_u) / (g . w) along columns, and the negative of d(log d)/dv along
    rows (+(g . w_v) / (g . w): the integrators take y up). ``rays_u``, ``rays_v``: (3, P), or
    (3, 1) when the same for every pixel (no lens distortion). NaN where g is."""
    per_pixel = rays_u.shape[1] > 1
    for p in range(g.shape[1]):
        k = p if per_pixel else 0
        along = g[0, p] * rays[0, p] + g[1, p] * rays[1, p] + g[2, p] * rays[2, p]
        slope_u[p] = -(g[0, p] * rays_u[0, k] + g[1, p] * rays_u[1, k] + g[2, p] * rays_u[2, k]) / along
        slope_v[p] = (g[0, p] * rays_v[0, k] + g[1, p] * rays_v[1, k] + g[2, p] * rays_v[2, k]) / along
