"""Fractal dimension of a height map: partitioning, cube counting, triangulation and power
spectrum, reproducing Gwyddion's definitions (libprocess/fractals.c, as written down in
``shared/reference/fractal-methods.md``) exactly by default.

Common steps (Gwyddion): only the x resolution sets the scale, k = round(log2(columns));
the whole field is resampled bilinearly, with pixel-centre mapping, to (2^k + 1) x (2^k + 1)
samples (aspect ratio and physical units are ignored); each method yields points (x_i, y_i)
and D comes from the slope a of the ordinary least-squares line through all of them.

* partitioning: for l = 1..k-1, tiles of r = 2^l pixels from the origin, c = 2^k / r - 1
  tiles per axis (the last row and column of tiles skipped); mean of the tiles' population
  variances; x = ln r, y = ln(mean variance), D = 3 - a/2.
* cube counting: h = max - min; for l = 0..k-1, m = 2^(l+1) columns per side each
  s = 2^k / m pixels wide and (s + 1)^2 samples (shared edges), cube height eps = h / m;
  heights from the global minimum, a column holds m - floor(min/eps) - floor((h - max)/eps)
  cubes; x = (l + 1 - k) ln 2, y = ln N, D = a.
* triangulation: z scaled by 2^k / h; for l = 0..k, corners every s = 2^k / 2^l pixels,
  each cell split into two triangles along the (i+1, j)-(i, j+1) diagonal, areas summed to
  S; x = (l - k) ln 2, y = ln S, D = 2 + a.
* power spectrum (rows), on the field as it is (NOT resampled: Gwyddion's
  ``gwy_data_field_fractal_psdf`` calls ``gwy_data_field_psdf`` on the original field):
  each row minus its least-squares line, Hann window w_i = 0.5 - 0.5 cos(2 pi (i + 0.5) / N),
  FFT scaled by 1/sqrt(N) and rescaled so that the spectrum's RMS without DC equals the RMS
  of the ORIGINAL row about its mean (``gwy_preserve_rms_simple`` reads the input before
  levelling); |F_k|^2 summed over rows for k < floor(N/2), times 1/(2 pi rows) (pixel units),
  DC dropped, giving P_1 .. P_{M}, M = floor(N/2) - 1. Gwyddion 2.66 and later (our default):
  x_i = ln i, y_i = ln P_{i+1} for i = 1 .. M - 1 -- the abscissa is the index in the
  DC-less curve, so frequency k is plotted at ln(k - 1) and the first frequency is not
  used. Gwyddion 2.65 and earlier (``legacy_resampling=True``) first resample P_1 .. P_M
  linearly (pixel-centre) to N points, then the same. D = 3.5 + a/2. (Read from the
  Gwyddion 2.62 and 2.67 sources, libprocess/fractals.c, stats-acfpsdf.c and inttrans.c.)

The cube-counting and triangulation estimators are biased low on fractional Brownian
surfaces (Gwyddion, 257 x 257, H = 0.5: 2.353 and 2.403 for a true 2.5): always report which
estimator a number came from.

A physically scaled variant, ``power-spectrum-areal``: the radially averaged 2-D power
spectral density of the levelled, Hann-windowed map in physical frequency (1/um), fitted
between the second frequency bin and half the Nyquist frequency (above that the optics and
pixel averaging bend the spectrum); for a self-affine surface PSD ~ f^-(2H + 2) and
D = 3 - H = (8 + slope) / 2. It uses the field's real aspect and units, which Gwyddion's
row-wise estimator ignores.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.fft
import scipy.ndimage

from skintopo.errors import SkinTopoError
from skintopo.filters import linear_weights
from skintopo.height import fill_from_nearest
from skintopo.heightmap import HeightMap
from skintopo.texture.areal import row_blocks

METHODS = ("partitioning", "cube-counting", "triangulation", "power-spectrum")
RESAMPLED_METHODS = ("partitioning", "cube-counting", "triangulation")  # work on resample_for_fractal's field
MIN_COLUMNS = 8


@dataclass(frozen=True)
class FractalResult:
    """D and the log-log points it was fitted to (x, y), with the fit's slope and intercept."""

    method: str
    dimension: float
    x: np.ndarray
    y: np.ndarray
    slope: float
    intercept: float


def _complete_field(height: HeightMap):
    """The height values as a complete array; Gwyddion works on complete fields, so missing
    points are filled from their nearest valid neighbour."""
    z = np.asarray(height.z, dtype=float)
    if not height.mask.all():
        if not height.mask.any():
            raise SkinTopoError("the height map has no valid points")
        (z,) = fill_from_nearest(height.mask, z)
    rows, columns = z.shape
    if columns < MIN_COLUMNS or rows < 2:
        raise SkinTopoError(f"fractal dimension needs a map at least {MIN_COLUMNS} columns wide, got {rows} x {columns}")
    return z


def resample_for_fractal(height: HeightMap):
    """Bilinear, pixel-centre resampling of the whole field to (2^k + 1)^2, k = round(log2 xres).

    Gwyddion's bilinear resampling is the product of two linear ones, so it is done one axis
    at a time (same numbers, fewer operations), block by block of output rows.
    Returns (z, k); pass it as ``resampled=`` to several estimators to resample only once."""
    z = _complete_field(height)
    rows, columns = z.shape
    k = int(round(np.log2(columns)))
    n = 2**k + 1
    # pixel-centre mapping: output point i of n sits at (i + 0.5) size / n - 0.5 of the input
    column_lower, column_fraction = linear_weights((np.arange(n) + 0.5) * columns / n - 0.5, columns)
    row_lower, row_fraction = linear_weights((np.arange(n) + 0.5) * rows / n - 0.5, rows)
    out = np.empty((n, n))
    for start, stop in row_blocks(n):
        first = row_lower[start]
        block = z[first : row_lower[stop - 1] + 2]
        along_rows = _interpolate(block, column_lower, column_fraction[None, :], axis=1)
        out[start:stop] = _interpolate(along_rows, row_lower[start:stop] - first, row_fraction[start:stop, None], axis=0)
    return out, k


def _interpolate(z, lower, fraction, axis):
    start = z.take(lower, axis=axis)
    return start + fraction * (z.take(lower + 1, axis=axis) - start)


def _fit(method, x, y, dimension_of_slope):
    x, y = np.asarray(x, float), np.asarray(y, float)
    ok = np.isfinite(x) & np.isfinite(y)
    if ok.sum() < 2:
        raise SkinTopoError(f"{method}: fewer than 2 usable scales (is the map flat or too small?)")
    slope, intercept = np.polyfit(x[ok], y[ok], 1)
    return FractalResult(method, float(dimension_of_slope(slope)), x, y, float(slope), float(intercept))


def partitioning(height: HeightMap, resampled=None) -> FractalResult:
    """Variance (partitioning) method, Gwyddion's definition: D = 3 - a/2."""
    z, k = resampled or resample_for_fractal(height)
    # Tile statistics level by level: the 2 x 2 tiles directly, then each level's tiles from
    # their four children (count, mean and sum of squared deviations combined exactly, Chan,
    # Golub & LeVeque 1983), so the whole pyramid costs about one pass over the map.
    size = 2**k
    quads = (z[:size:2, :size:2], z[1:size:2, :size:2], z[:size:2, 1:size:2], z[1:size:2, 1:size:2])
    mean = sum(quads) / 4
    squares = sum((q - mean) ** 2 for q in quads)  # sum of squared deviations per tile
    points = 4
    xs, ys = [], []
    for level in range(1, k):
        r = 2**level
        c = size // r - 1  # the last row and column of tiles are skipped
        variance = squares[:c, :c].mean() / points
        xs.append(np.log(r))
        ys.append(np.log(variance) if variance > 0 else np.nan)
        if level + 1 < k:
            children = (mean[::2, ::2], mean[1::2, ::2], mean[::2, 1::2], mean[1::2, 1::2])
            parent = sum(children) / 4
            squares = (
                squares[::2, ::2] + squares[1::2, ::2] + squares[::2, 1::2] + squares[1::2, 1::2]
                + points * sum((child - parent) ** 2 for child in children)
            )
            mean, points = parent, 4 * points
    return _fit("partitioning", xs, ys, lambda a: 3 - a / 2)


def cube_counting(height: HeightMap, resampled=None) -> FractalResult:
    """Cube counting, Gwyddion's definition: D = a."""
    z, k = resampled or resample_for_fractal(height)
    bottom = z.min()  # heights are counted from the global minimum
    h = z.max() - bottom
    if h <= 0:
        raise SkinTopoError("cube counting: the map is flat")
    # Column extremes level by level: the finest columns (2 x 2 samples) from adjacent rows,
    # then adjacent columns, in row blocks (with their count and their 2 x 2 pooling into
    # the next level); each coarser column (sharing its edges) as the extreme of its four
    # children.
    size = 2**k
    counts = {k - 1: 0.0}
    low, high = np.empty((size // 2, size // 2)), np.empty((size // 2, size // 2))
    for start, stop in row_blocks(size):  # even block bounds: the 2 x 2 pooling stays inside
        block = z[start : stop + 1]
        block_low, block_high = np.minimum(block[:-1], block[1:]), np.maximum(block[:-1], block[1:])
        block_low, block_high = np.minimum(block_low[:, :-1], block_low[:, 1:]), np.maximum(block_high[:, :-1], block_high[:, 1:])
        block_low -= bottom  # min(a, b) - c = min(a - c, b - c) exactly (rounding is monotonic)
        block_high -= bottom
        counts[k - 1] += _cube_count(block_low, block_high, h, size)
        low[start // 2 : stop // 2], high[start // 2 : stop // 2] = _pool(block_low, np.minimum), _pool(block_high, np.maximum)
    for level in range(k - 2, -1, -1):
        counts[level] = _cube_count(low, high, h, 2 ** (level + 1))
        if level:
            low, high = _pool(low, np.minimum), _pool(high, np.maximum)
    xs = [(level + 1 - k) * np.log(2) for level in range(k)]
    ys = [np.log(counts[level]) for level in range(k)]
    return _fit("cube-counting", xs, ys, lambda a: a)


def _cube_count(low, high, h, m):
    """Cubes of height eps = h / m over columns with extremes (low, high) of the heights
    above the global minimum: m - floor(low/eps) - floor((h - high)/eps) each, summed term by
    term (whole numbers: exact in floating point)."""
    eps = h / m
    below = np.floor(np.divide(low, eps))
    above = np.subtract(h, high)
    above /= eps
    return m * low.size - below.sum() - np.floor(above, out=above).sum()


def _pool(a, extreme):
    """2 x 2 pooling by ``extreme`` (np.minimum or np.maximum)."""
    return extreme(extreme(a[::2, ::2], a[1::2, ::2]), extreme(a[::2, 1::2], a[1::2, 1::2]))


def triangulation(height: HeightMap, resampled=None) -> FractalResult:
    """Triangulation, Gwyddion's definition: D = 2 + a."""
    z, k = resampled or resample_for_fractal(height)
    h = z.max() - z.min()
    if h <= 0:
        raise SkinTopoError("triangulation: the map is flat")
    scale = 2**k / h  # heights scaled to the lateral range; applied to the sums instead of the map
    xs, ys = [], []
    for level in range(k + 1):
        s = 2**k // 2**level
        corners = z[::s, ::s]
        total = sum(_triangle_leg_sum(corners[start : stop + 1], s / scale) for start, stop in row_blocks(corners.shape[0] - 1))
        xs.append((level - k) * np.log(2))
        ys.append(np.log(0.5 * s * scale * total))
    return _fit("triangulation", xs, ys, lambda a: 2 + a)


def _triangle_leg_sum(corners, step):
    """Sum of sqrt(step^2 + a^2 + b^2) over the two triangles of every cell of ``corners``
    (lateral step ``step``, in the units of the heights): (i,j)-(i+1,j)-(i,j+1) and
    (i+1,j+1)-(i+1,j)-(i,j+1), both right-angled in plan, with a, b the height differences
    along their legs. Times step/2 it is their total area (half the cross product of the legs;
    Gwyddion evaluates the same area by Heron's formula)."""
    along_rows = np.square(np.diff(corners, axis=0))  # (i+1, j) - (i, j)
    along_rows += step * step
    along_columns = np.square(np.diff(corners, axis=1))  # (i, j+1) - (i, j)
    total = 0.0
    for legs in ((along_rows[:, :-1], along_columns[:-1]), (along_rows[:, 1:], along_columns[1:])):
        squared = np.add(*legs)
        total += np.sqrt(squared, out=squared).sum()
    return total


def row_power_spectrum(height: HeightMap) -> np.ndarray:
    """Gwyddion's one-dimensional PSDF of the rows (``gwy_data_field_psdf``, horizontal, Hann
    window, RMS preserved, line levelling) in pixel units, without its DC term: P_1 .. P_M,
    M = floor(N/2) - 1 (see the module notes)."""
    z = _complete_field(height)
    rows, n = z.shape
    index = np.arange(n)
    centred = index - (n - 1) / 2
    centred_squares = np.dot(centred, centred)
    window = 0.5 - 0.5 * np.cos(2 * np.pi * (index + 0.5) / n)
    # RMS of the spectrum without DC, over all N terms (the rfft's mirrored half counted twice)
    mirrored = np.ones(n // 2 + 1)
    mirrored[0] = 0.0
    mirrored[1 : (n + 1) // 2] = 2.0
    curve = np.zeros(n // 2)
    for start, stop in row_blocks(rows):  # rows are independent: block by block, in cache
        block = z[start:stop]
        row_slope = (block @ centred)[:, None] / centred_squares  # least-squares line of each row
        detrended = block - block.mean(axis=1, keepdims=True) - row_slope * centred[None, :]
        # n var(row) = sum of squared residuals + slope^2 sum c^2 (the residuals are orthogonal
        # to the line), so the original row's mean square comes from the detrended row
        original_ms = (np.einsum("ij,ij->i", detrended, detrended) + row_slope[:, 0] ** 2 * centred_squares) / n
        detrended *= window
        spectrum = scipy.fft.rfft(detrended, axis=1)
        power = np.square(spectrum.real)  # n times the spectrum's power, scaled below
        power += np.square(spectrum.imag)
        spectrum_ms = (power @ mirrored) / (n * n)
        with np.errstate(invalid="ignore", divide="ignore"):
            scale = np.where(spectrum_ms > 0, original_ms / spectrum_ms, 1.0) / n
        curve += scale @ power[:, : n // 2]
    return curve[1:] / (2 * np.pi * rows)


def power_spectrum(height: HeightMap, resampled=None, legacy_resampling=False) -> FractalResult:
    """Row-wise power spectrum method, Gwyddion's definition: D = 3.5 + a/2.

    Default: Gwyddion 2.66 and later; ``legacy_resampling=True``: 2.65 and earlier. Works on
    the field as it is (``resampled`` is accepted for a uniform signature and ignored)."""
    curve = row_power_spectrum(height)
    if legacy_resampling:
        n = height.z.shape[1]
        q = curve.size / n
        curve = scipy.ndimage.map_coordinates(curve, [q * np.arange(n) + (q - 1) / 2], order=1, mode="nearest")
    i = np.arange(1, curve.size)
    with np.errstate(divide="ignore"):
        return _fit("power-spectrum", np.log(i), np.log(curve[1:]), lambda a: 3.5 + a / 2)


def power_spectrum_areal(height: HeightMap, resampled=None) -> FractalResult:
    """Physically scaled variant: radially averaged 2-D PSD, D = (8 + slope) / 2
    (``resampled`` is accepted for a uniform signature and ignored: this one uses the field as it is)."""
    z = np.where(height.mask, height.z, np.nan)
    valid = np.isfinite(z)
    if valid.sum() < 64:
        raise SkinTopoError("power-spectrum-areal: too few valid points")
    rows, columns = z.shape
    r, c = np.mgrid[:rows, :columns]
    design = np.column_stack([np.ones(valid.sum()), r[valid], c[valid]])
    coefficients, *_ = np.linalg.lstsq(design, z[valid], rcond=None)
    levelled = np.where(valid, z - (coefficients[0] + coefficients[1] * r + coefficients[2] * c), 0.0)
    window = np.outer(np.hanning(rows), np.hanning(columns))
    power = np.abs(scipy.fft.fft2(levelled * window)) ** 2
    dy, dx = height.spacing
    f = np.hypot(scipy.fft.fftfreq(rows, dy)[:, None], scipy.fft.fftfreq(columns, dx)[None, :])
    f_step = 1.0 / (max(rows * dy, columns * dx))
    bins = np.round(f / f_step).astype(int)
    nyquist = 0.5 / max(dx, dy)
    top = int(0.5 * nyquist / f_step)
    sums = np.bincount(bins.ravel(), weights=power.ravel())
    counts = np.bincount(bins.ravel())
    chosen = np.arange(2, min(top, sums.size))
    chosen = chosen[counts[chosen] > 0]
    return _fit("power-spectrum-areal", np.log(chosen * f_step), np.log(sums[chosen] / counts[chosen]), lambda a: (8 + a) / 2)


ESTIMATORS = {
    "partitioning": partitioning,
    "cube-counting": cube_counting,
    "triangulation": triangulation,
    "power-spectrum": power_spectrum,
    "power-spectrum-areal": power_spectrum_areal,
}


def fractal_dimension(height: HeightMap, method="cube-counting", resampled=None) -> FractalResult:
    """Fractal dimension by one of :data:`ESTIMATORS` (see the module notes)."""
    if method not in ESTIMATORS:
        raise SkinTopoError(f"unknown fractal method {method!r}; choose from {sorted(ESTIMATORS)}")
    return ESTIMATORS[method](height, resampled)
