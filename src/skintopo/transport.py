"""Light transport over a height field: cast shadows and the interreflection operator.

Shared by the simulator (:mod:`skintopo.synth.render`, which renders with them) and the
physically based height (:mod:`skintopo.physics`, which inverts them), so both use one
definition of which skin a point sees.

Interreflection (radiosity gather)
    (K B)(x) = (1/pi) integral of B(y(omega)) (n_x . omega) d omega over the directions in
    which x sees other skin: the radiosity kernel V(x,y) (n_x.(y-x))+ (n_y.(x-y))+ /
    (pi |x-y|^4) dA_y rewritten over the hemisphere of x. It is evaluated by horizon
    marching: along ``n_azimuth`` azimuths and radial steps up to ``radius_um``, each sample
    that rises above the current horizon covers the band of elevations between the old and
    the new horizon, whose projected solid angle is exact:

        Omega = dphi [a (e/2 + sin 2e / 4) + n_z sin^2(e) / 2]  from e_old to e_new,
        a = n_x cos(phi) + n_y sin(phi),

    starting at the tangent-plane elevation atan(-a / n_z). The band takes the radiosity of
    that sample. Rows of K sum to at most 1 (the hemisphere's projected solid angle is pi).

Cast shadows
    x is shadowed when the terrain along the light's azimuth rises above the light's
    elevation (horizon test).

Hand-written: no maintained Python library computes horizon-based form factors or cast
shadows of a height field on a pixel grid (ray tracers such as Mitsuba work on meshes and
are far slower for a gather over every pixel).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse


def _radial_steps(radius_px):
    """Radial distances in pixels: every pixel to 8, then growing by 15% per step."""
    steps = [float(r) for r in range(1, min(8, int(radius_px)) + 1)]
    while steps[-1] * 1.15 <= radius_px:
        steps.append(steps[-1] * 1.15)
    return steps


def _march(z, pixel, azimuth, steps):
    """For each radial step along ``azimuth``, yield the source and target slices of the
    pixels whose sample stays in the field, the target's rise above the source (z difference)
    and their horizontal distance. Offsets are rounded to whole pixels; repeats are skipped."""
    rows, columns = z.shape
    previous = None
    for r in steps:
        dc = int(round(r * np.cos(azimuth)))
        dr = int(round(-r * np.sin(azimuth)))  # y up: rows go the other way
        if (dr, dc) == previous or (dr, dc) == (0, 0) or abs(dr) >= rows or abs(dc) >= columns:
            continue
        previous = (dr, dc)
        source = (slice(max(0, -dr), rows - max(0, dr)), slice(max(0, -dc), columns - max(0, dc)))
        target = (slice(max(0, dr), rows - max(0, -dr)), slice(max(0, dc), columns - max(0, -dc)))
        distance = pixel * np.hypot(dr, dc)
        yield source, target, z[target] - z[source], distance


def cast_shadow(z, pixel, light):
    """True where ``light`` (unit vector) is hidden by the terrain along its azimuth."""
    light = np.asarray(light, dtype=float)
    horizontal = np.hypot(light[0], light[1])
    shadow = np.zeros(z.shape, dtype=bool)
    if horizontal < 1e-9:
        return shadow
    slope = light[2] / horizontal  # tangent of the light's elevation
    reach = int(np.ceil(np.ptp(z) / (pixel * slope))) + 1
    azimuth = np.arctan2(light[1], light[0])
    for source, _, rise, distance in _march(z, pixel, azimuth, [float(r) for r in range(1, reach + 1)]):
        shadow[source] |= rise > slope * distance
    return shadow


def interreflection_operator(z, normals, pixel, *, radius_um, n_azimuth=16, min_weight=1e-7):
    """Sparse matrix K (P x P, P = rows * columns) of the interreflection gather.

    (K B)[x] = sum over y of K[x, y] B[y] approximates (1/pi) times the integral of B over the
    part of x's hemisphere covered by skin, weighted by n_x . omega (see the module notes).
    Each row sums to at most 1.
    """
    rows, columns = z.shape
    index = np.arange(rows * columns).reshape(rows, columns)
    steps = _radial_steps(max(1.0, radius_um / pixel))
    d_azimuth = 2 * np.pi / n_azimuth
    nx, ny, nz = normals[..., 0], normals[..., 1], normals[..., 2]
    sources, targets, weights = [], [], []
    for j in range(n_azimuth):
        azimuth = (j + 0.5) * d_azimuth
        a = (nx * np.cos(azimuth) + ny * np.sin(azimuth)).ravel()
        n_z = nz.ravel()

        def primitive(e, pixels):
            return a[pixels] * (e / 2 + np.sin(2 * e) / 4) + n_z[pixels] * np.sin(e) ** 2 / 2

        horizon = np.arctan2(-a, n_z)  # tangent-plane elevation: n . omega = 0
        covered = primitive(horizon, slice(None))  # the primitive at the current horizon, per pixel
        for source, target, rise, distance in _march(z, pixel, azimuth, steps):
            elevation = np.arctan(rise / distance)
            pixels = index[source].ravel()
            rises = elevation.ravel() > horizon[pixels]
            if not rises.any():
                continue
            pixels, new = pixels[rises], elevation.ravel()[rises]
            above = primitive(new, pixels)
            weight = (above - covered[pixels]) * (d_azimuth / np.pi)
            horizon[pixels], covered[pixels] = new, above
            keep = weight > min_weight
            sources.append(pixels[keep])
            targets.append(index[target].ravel()[rises][keep])
            weights.append(weight[keep])
    if not sources:
        return scipy.sparse.csr_matrix((rows * columns, rows * columns))
    return scipy.sparse.csr_matrix(
        (np.concatenate(weights), (np.concatenate(sources), np.concatenate(targets))), shape=(rows * columns, rows * columns)
    )
