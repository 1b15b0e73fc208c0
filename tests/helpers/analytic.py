"""Analytic test surfaces with exact slopes, in micrometres, on a pixel grid.

Coordinates follow the camera frame: x = column * dx to the right, y = -row * dy (up).
Each function returns (z, p, q) with p = dz/dx and q = dz/dy evaluated exactly at pixel centres.
"""

import numpy as np


def grid(shape, spacing):
    rows, columns = shape
    x = np.arange(columns)[None, :] * spacing + np.zeros((rows, 1))
    y = -np.arange(rows)[:, None] * spacing + np.zeros((1, columns))
    return x, y


def plane_and_bump(shape=(120, 150), spacing=10.0):
    x, y = grid(shape, spacing)
    x0, y0, sigma, amplitude = x.mean() + 83.0, y.mean() - 41.0, 14 * spacing, 300.0
    bump = amplitude * np.exp(-((x - x0) ** 2 + (y - y0) ** 2) / (2 * sigma**2))
    z = 0.3 * x - 0.2 * y + bump
    p = 0.3 - bump * (x - x0) / sigma**2
    q = -0.2 - bump * (y - y0) / sigma**2
    return z, p, q


def nonperiodic_sinusoid(shape=(120, 150), spacing=10.0):
    x, y = grid(shape, spacing)
    kx, ky, amplitude = 2 * np.pi / (37.3 * spacing), 2 * np.pi / (53.1 * spacing), 80.0
    z = amplitude * np.sin(kx * x + 0.4) * np.cos(ky * y - 1.1)
    p = amplitude * kx * np.cos(kx * x + 0.4) * np.cos(ky * y - 1.1)
    q = -amplitude * ky * np.sin(kx * x + 0.4) * np.sin(ky * y - 1.1)
    return z, p, q


def paraboloid_with_wrinkles(shape=(120, 150), spacing=10.0):
    x, y = grid(shape, spacing)
    xc, yc, curvature = x.mean() + 50, y.mean() + 20, 2e-4
    angle, period, amplitude = np.radians(30), 12 * spacing, 5.0
    k = 2 * np.pi / period
    phase = k * (x * np.cos(angle) + y * np.sin(angle))
    z = curvature * ((x - xc) ** 2 + (y - yc) ** 2) + amplitude * np.sin(phase)
    p = 2 * curvature * (x - xc) + amplitude * k * np.cos(angle) * np.cos(phase)
    q = 2 * curvature * (y - yc) + amplitude * k * np.sin(angle) * np.cos(phase)
    return z, p, q


SURFACES = {
    "plane+bump": plane_and_bump,
    "nonperiodic-sinusoid": nonperiodic_sinusoid,
    "paraboloid+wrinkles": paraboloid_with_wrinkles,
}


def normals_from_slopes(p, q):
    """Unit normals (-p, -q, 1)/|.| in the camera frame."""
    n = np.stack([-p, -q, np.ones_like(p)], axis=-1)
    return n / np.linalg.norm(n, axis=-1, keepdims=True)


def rms_error_after_offset(z, truth, mask=None):
    """RMS of (z - truth) after removing the mean difference (the unknown constant)."""
    mask = np.isfinite(z) if mask is None else mask & np.isfinite(z)
    d = z[mask] - truth[mask]
    return float(np.sqrt(np.mean((d - d.mean()) ** 2)))


def four_lights(slant_degrees=45.0, first_tilt_degrees=0.0):
    """The paper's geometry: 4 lights at one slant, 90 degrees apart in tilt."""
    slant = np.radians(slant_degrees)
    tilt = np.radians(first_tilt_degrees + 90.0 * np.arange(4))
    return np.stack([np.sin(slant) * np.cos(tilt), np.sin(slant) * np.sin(tilt), np.full(4, np.cos(slant))], axis=1)


def fbm(size, hurst, seed):
    rng = np.random.default_rng(seed)
    k = np.hypot(np.fft.fftfreq(size)[:, None], np.fft.fftfreq(size)[None, :])
    k[0, 0] = np.inf
    spectrum = k ** (-(hurst + 1)) * (rng.standard_normal((size, size)) + 1j * rng.standard_normal((size, size)))
    return np.real(np.fft.ifft2(spectrum))
