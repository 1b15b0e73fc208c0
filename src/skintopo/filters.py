"""Filtering and form removal of height maps (ISO 16610-61 areal Gaussian filter), and
profile extraction.

Areal Gaussian filter (ISO 16610-61)
    Weighting function s(x, y) = 1 / (alpha^2 lambda_c^2) exp(-pi (x^2 + y^2) / (alpha lambda_c)^2),
    alpha = sqrt(ln 2 / pi) (paper eq. 9 with lambda_xc = lambda_yc). It is separable and equal
    to a Gaussian of standard deviation sigma = alpha lambda_c / sqrt(2 pi); its amplitude
    transmission for a wavelength lambda is exp(-pi (alpha lambda_c / lambda)^2), 50% at the
    cut-off. The low-pass output is the mean (form/waviness) surface, the high-pass z - low
    the roughness.

    Edges and masks: the filter is evaluated as a *first-order Gaussian regression* (a
    weighted least-squares plane fitted at every point with the Gaussian weights restricted
    to the valid points, ISO 16610-21 / -71 end-effect handling). Inside the field, where
    the weights are symmetric, this equals the plain Gaussian filter; near the border or a
    masked region it does not lean toward the missing side, and any plane passes unchanged
    everywhere. Where too few valid points carry weight to fix a plane, the zeroth-order
    (normalised) mean is used.

Morphological closing with a line segment (ISO 16610-41 / -81 closing filter, flat
structuring element)
    C(z) = erosion(dilation(z)), dilation = max and erosion = min of z over the segment
    centred on each point. It is the upper envelope traced by the segment held level: it
    fills every valley narrower than the segment along its direction and leaves all else
    unchanged. With a segment laid along a wrinkle, the microrelief furrows that cross the
    wrinkle are filled while the wrinkle (long in that direction) keeps its depth.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import numpy as np
import scipy.fft
import scipy.ndimage

from skintopo._linalg import solve_symmetric_3x3
from skintopo.errors import SkinTopoError
from skintopo.heightmap import HeightMap, pixel_spacing

ALPHA = np.sqrt(np.log(2) / np.pi)
_TRUNCATE = 4.0  # kernel half-width in standard deviations (transmission error < 1e-3)


def gaussian_sigma_px(cutoff_um, pixel_um):
    """Standard deviation in pixels of the ISO Gaussian weighting function for a cut-off."""
    return ALPHA * cutoff_um / np.sqrt(2 * np.pi) / pixel_um


def gaussian_transmission(wavelength_um, cutoff_um):
    """Amplitude transmission of the low-pass: exp(-pi (alpha lambda_c / lambda)^2)."""
    return np.exp(-np.pi * (ALPHA * cutoff_um / np.asarray(wavelength_um, dtype=float)) ** 2)


# From this width on, Gaussian smoothing by FFT (on every core) is faster than direct
# convolution (one core): 3 images of 1024 x 1024 on two cores, direct / FFT: 72 / 38 ms at
# sigma 2.5 px, 108 / 46 ms at 5.6 px, 60 / 54 ms at 1.5 px (2026-12-03; it was 8 px, measured
# with one core). The two differ by the direct kernel's truncation at 4 sigma (about 3e-5 of
# the image's range).
_FFT_SIGMA_PX = 2.0


def _fft_lengths(shape, sigmas):
    """FFT lengths of a Gaussian filtering of an image of ``shape``: each axis padded by 4
    sigma, so that nothing wraps around into the data."""
    return [scipy.fft.next_fast_len(n + 2 * int(np.ceil(_TRUNCATE * s)), real=True) for n, s in zip(shape, sigmas)]


def _moment_kernel(sigma, order):
    """The sampled kernel d^order g(d), d = -r..r (r = 4 sigma rounded), g the Gaussian
    normalised to unit sum (scipy.ndimage.gaussian_filter1d's kernel for order 0)."""
    radius = int(_TRUNCATE * sigma + 0.5)
    d = np.arange(-radius, radius + 1, dtype=float)
    g = np.exp(-0.5 / sigma**2 * d**2)
    return d**order * (g / g.sum())


def _moment_transfer(sigma, frequency, order):
    """Transfer function of the convolution that gives sum_x' (x' - x)^order g(x' - x) f(x'),
    g the Gaussian of standard deviation ``sigma`` (pixels), at ``frequency`` (cycles per
    pixel), G(f) = exp(-2 pi^2 sigma^2 f^2): G for order 0, 2 pi i sigma^2 f G for order 1,
    sigma^2 (1 - 4 pi^2 sigma^2 f^2) G for order 2 (the Fourier transforms of -u g(u) and
    u^2 g(u), u = x - x', by differentiating G)."""
    transfer = np.exp(-2 * np.pi**2 * (sigma * frequency) ** 2)
    if order == 1:
        return 2j * np.pi * sigma**2 * frequency * transfer
    if order == 2:
        return sigma**2 * (1 - 4 * np.pi**2 * sigma**2 * frequency**2) * transfer
    return transfer


def gaussian_moments(image, sigmas, orders, out=None):
    """Gaussian-weighted moments of ``image`` about every point, zero outside the field:
    M_pq(y, x) = sum_(y', x') (y' - y)^p (x' - x)^q g(y' - y) g(x' - x) f(y', x'), for each
    (p, q) of ``orders`` (p, q in 0..2); (0, 0) is the Gaussian smoothing. ``sigmas``: the
    standard deviations (rows, columns) in pixels. Returns (len(orders), rows, columns)
    (written into ``out`` when given).

    Narrow kernels: direct separable correlation with the sampled kernels d^k g(d), truncated
    at 4 sigma. Wide ones: one FFT of the image on a grid padded by 4 sigma (nothing wraps
    around) and one inverse FFT per moment, with the kernels' transfer functions
    (:func:`_moment_transfer`), whose cost does not grow with the kernel. Computing the
    moments about each point directly, rather than smoothing y' f and x' f and subtracting
    y and x times the smoothing, saves a forward FFT per moment and the cancellation
    between large terms far from the centre.

    A float32 ``image`` is filtered in single precision (the FFTs take half the time; relative
    rounding about 1e-7), for callers that need no more (a structure tensor's orientation);
    anything else in double precision.
    """
    image = np.asarray(image)
    image = image if image.dtype == np.float32 else image.astype(np.float64, copy=False)
    out = np.empty((len(orders), *image.shape), image.dtype) if out is None else out
    if max(sigmas) < _FFT_SIGMA_PX:
        for index, (p, q) in enumerate(orders):
            along_rows = scipy.ndimage.correlate1d(image, _moment_kernel(sigmas[0], p), axis=0, mode="constant")
            out[index] = scipy.ndimage.correlate1d(along_rows, _moment_kernel(sigmas[1], q), axis=1, mode="constant")
        return out
    rows, columns = image.shape
    shape = _fft_lengths(image.shape, sigmas)
    spectrum = scipy.fft.rfft2(image, s=shape, workers=-1)
    frequency_rows, frequency_columns = scipy.fft.fftfreq(shape[0]), scipy.fft.rfftfreq(shape[1])
    for index, (p, q) in enumerate(orders):
        product = spectrum * _moment_transfer(sigmas[0], frequency_rows, p)[:, None].astype(spectrum.dtype)
        product *= _moment_transfer(sigmas[1], frequency_columns, q)[None, :].astype(spectrum.dtype)
        # The padding sits after the data (rfft2 pads at the end); circular wrap-around only
        # reaches into the padding, which is at least 4 sigma wide on each side.
        out[index] = scipy.fft.irfft2(product, s=shape, workers=-1, overwrite_x=True)[:rows, :columns]
    return out


def _moments_of_ones(length, sigma, direct):
    """(m0, m1, m2): the moments sum_t' (t' - t)^k g(t' - t), k = 0, 1, 2, over a line of
    ``length`` points, at each of them: along one axis, the weight's moments of a full field
    (whose 2-D moments are their outer products). ``direct``: the sampled kernels, as
    :func:`gaussian_moments` uses for narrow kernels; otherwise the transfer functions."""
    ones = np.ones(length)
    if direct:
        return tuple(scipy.ndimage.correlate1d(ones, _moment_kernel(sigma, k), mode="constant") for k in range(3))
    n = _fft_lengths((length,), (sigma,))[0]
    spectrum, frequency = scipy.fft.rfft(ones, n=n), scipy.fft.rfftfreq(n)
    return tuple(scipy.fft.irfft(spectrum * _moment_transfer(sigma, frequency, k), n=n)[:length] for k in range(3))


def areal_gaussian_filter(z, spacing, cutoff_um, mask=None):
    """Low-pass (mean surface) of an areal Gaussian filter, ISO 16610-61, with first-order
    regression at edges and masked points.

    Parameters
    ----------
    z : array_like (rows, columns)
        Heights in micrometres; NaN = missing.
    spacing : float or (dy, dx)
        Pixel spacing in micrometres.
    cutoff_um : float
        Nesting index lambda_c in micrometres (the wavelength passed at 50%).
    mask : array_like of bool, optional
        Valid points (default: the finite ones).

    Returns
    -------
    ndarray
        The low-pass surface, defined at every point that has valid data within reach
        (NaN elsewhere). The high-pass (roughness) is ``z - low``.
    """
    z = np.asarray(z, dtype=np.float64)
    if z.ndim != 2:
        raise ValueError(f"expected a 2-D height map, got shape {z.shape}")
    if not (cutoff_um > 0):
        raise SkinTopoError(f"cut-off must be positive, got {cutoff_um} um")
    dy, dx = pixel_spacing(spacing)
    sigmas = (gaussian_sigma_px(cutoff_um, dy), gaussian_sigma_px(cutoff_um, dx))
    valid = np.isfinite(z) if mask is None else (np.asarray(mask, dtype=bool) & np.isfinite(z))
    if not valid.any():
        raise SkinTopoError("the height map has no valid points to filter")
    values = np.where(valid, z, 0.0)
    plane, zeroth, det, s0 = _full_field_plane(values, sigmas) if valid.all() else _masked_plane(values, valid, sigmas)
    with np.errstate(invalid="ignore"):
        # Conditioning of the plane fit: det against the determinant of a full symmetric
        # window, s0 * (s0 sigma_x^2) * (s0 sigma_y^2).
        good = det > 1e-3 * s0**3 * sigmas[0] ** 2 * sigmas[1] ** 2
    low = np.where(good, plane, zeroth)
    reach = s0 > 1e-6 * s0.max()
    return np.where(reach, low, np.nan)


def _full_field_plane(values, sigmas):
    """The regression's plane heights where every point is valid: the weight is 1 everywhere,
    so its moments about each point are outer products of 1-D moments (u along the rows, v
    along the columns, :func:`_moments_of_ones`) and so are the cofactors of the 3 x 3 normal
    equations; the determinant is even one outer product, u0 (u0 u_yy - u_y^2) (x) v0 (v0 v_xx
    - v_x^2). Only the three data moments are 2-D filterings (one forward FFT, three inverse),
    and the filter holds about 8 field-sized arrays at its peak. Returns (plane, weighted mean, determinant, s0)."""
    direct = max(sigmas) < _FFT_SIGMA_PX  # the kernels of gaussian_moments
    (u0, uy, uyy), (v0, vx, vxx) = (_moments_of_ones(n, sigma, direct) for n, sigma in zip(values.shape, sigmas))
    sz, mxz, myz = gaussian_moments(values, sigmas, ((0, 0), (0, 1), (1, 0)))
    # numerator of the intercept by the adjugate's first row (c00, c01, c02) . (sz, mxz, myz)
    numerator = np.outer(u0 * uyy, v0 * vxx) - np.outer(uy * uy, vx * vx)  # c00 = mxx myy - mxy^2
    numerator *= sz
    mxz *= np.outer(uy * uy - u0 * uyy, v0 * vx)  # c01 = my mxy - mx myy
    numerator += mxz
    myz *= np.outer(u0 * uy, vx * vx - v0 * vxx)  # c02 = mx mxy - my mxx
    numerator += myz
    det = np.outer(u0 * (u0 * uyy - uy * uy), v0 * (v0 * vxx - vx * vx))
    with np.errstate(invalid="ignore", divide="ignore"):
        numerator /= det
        s0 = np.outer(u0, v0)
        return numerator, sz / s0, det, s0


def _masked_plane(values, valid, sigmas):
    """The regression's plane heights with missing points: the six moments of the weight (1
    where valid) and the three of the data about each point, each a 2-D filtering (two
    forward FFTs, nine inverse; the filter holds about 20 field-sized arrays at its peak).
    Returns (plane, weighted mean, determinant, s0)."""
    rows, columns = values.shape
    moments = np.empty((9, rows, columns))  # (p, q) of (y' - y)^p (x' - x)^q: the weight's six, then the data's three
    gaussian_moments(valid.astype(np.float64), sigmas, ((0, 0), (0, 1), (1, 0), (0, 2), (1, 1), (2, 0)), out=moments[:6])
    gaussian_moments(values, sigmas, ((0, 0), (0, 1), (1, 0)), out=moments[6:])
    s0, sx, sy, sxx, sxy, syy, sz, sxz, syz = moments
    solution, det = solve_symmetric_3x3([c.ravel() for c in (s0, sx, sy, sxx, sxy, syy)], [c.ravel() for c in (sz, sxz, syz)], components=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        return solution[0].reshape(rows, columns), sz / s0, det.reshape(rows, columns), s0


def gaussian_highpass(height: HeightMap, cutoff_um):
    """Roughness surface: the height minus its ISO Gaussian low-pass, as a HeightMap."""
    low = areal_gaussian_filter(height.z, height.spacing, cutoff_um, height.mask)
    return HeightMap(height.z - low, height.spacing, height.mask)


def gaussian_bandpass(height: HeightMap, short_cutoff_um, long_cutoff_um, long_samples_per_sigma=None):
    """Band-pass: low-pass at ``short_cutoff_um`` (lambda_s, removes fine detail) minus the
    low-pass at ``long_cutoff_um`` (lambda_c, removes form and waviness). With
    ``long_samples_per_sigma``, the lambda_c low-pass is :func:`coarse_areal_gaussian_filter`
    with that many samples per Gaussian sigma (block means; much cheaper for a wide cut-off)."""
    if not short_cutoff_um < long_cutoff_um:
        raise SkinTopoError(f"the short cut-off ({short_cutoff_um} um) must be below the long one ({long_cutoff_um} um)")
    fine = areal_gaussian_filter(height.z, height.spacing, short_cutoff_um, height.mask)
    if long_samples_per_sigma is None:
        coarse = areal_gaussian_filter(height.z, height.spacing, long_cutoff_um, height.mask)
    else:
        coarse = coarse_areal_gaussian_filter(height.z, height.spacing, long_cutoff_um, height.mask, long_samples_per_sigma)
    return HeightMap(fine - coarse, height.spacing, height.mask)


def polynomial_form(z, spacing, order=1, mask=None):
    """Least-squares polynomial form of total degree ``order`` (1 = plane), in micrometres.

    Fits z ~ sum c_ij x^i y^j over the valid points (i + j <= order) with coordinates scaled
    to [-1, 1] for conditioning, and returns the fitted form at every point. Subtract it to
    level the surface (form removal, ISO 25178-2 "F-operator").
    """
    z = np.asarray(z, dtype=np.float64)
    valid = np.isfinite(z) if mask is None else (np.asarray(mask, dtype=bool) & np.isfinite(z))
    terms = (order + 1) * (order + 2) // 2
    if order < 0 or valid.sum() < terms:
        raise SkinTopoError(f"a form of order {order} needs at least {terms} valid points, got {int(valid.sum())}")
    rows, columns = z.shape
    # The monomials u^i v^j are separable, so every sum the normal equations need is a
    # product of small matrices: sum_valid u^a v^b z = (V^T (w z) U)[b, a], with w the 0/1
    # validity weight, U[c, a] = u_c^a and V[r, b] = v_r^b. No (pixels x terms) basis array.
    u_powers = np.linspace(-1, 1, columns)[:, None] ** np.arange(2 * order + 1)[None, :]
    v_powers = np.linspace(-1, 1, rows)[:, None] ** np.arange(2 * order + 1)[None, :]
    if valid.all():  # every point: the moments are products of two sums
        moments = np.outer(v_powers.sum(axis=0), u_powers.sum(axis=0))  # [b, a] = sum u^a v^b
        data = v_powers[:, : order + 1].T @ (z @ u_powers[:, : order + 1])
    else:
        moments = v_powers.T @ (valid.astype(np.float64) @ u_powers)
        data = v_powers[:, : order + 1].T @ (np.where(valid, z, 0.0) @ u_powers[:, : order + 1])
    exponents = [(i, j) for i in range(order + 1) for j in range(order + 1 - i)]
    gram = np.array([[moments[j + jj, i + ii] for (ii, jj) in exponents] for (i, j) in exponents])
    # Normal equations: the monomials on [-1, 1] are well conditioned for the low orders used
    # here, so a singular system means the valid points cannot pin the form down.
    if np.linalg.cond(gram) > 1e12:
        raise SkinTopoError(
            f"a form of order {order} cannot be fitted: the {int(valid.sum())} valid points of the {rows} x {columns} map"
            " lie on too few rows or columns"
        )
    coefficients = np.linalg.solve(gram, np.array([data[j, i] for (i, j) in exponents]))
    table = np.zeros((order + 1, order + 1))  # [j, i]: coefficient of u^i v^j
    for (i, j), c in zip(exponents, coefficients):
        table[j, i] = c
    return v_powers[:, : order + 1] @ table @ u_powers[:, : order + 1].T


def sphere_fit(height: HeightMap):
    """Least-squares sphere through a height map's valid points: (radius, centre) in um.

    The algebraic fit (Kasa 1976): |p|^2 = 2 c . p + k is linear in the centre c and
    k = R^2 - |c|^2, solved by least squares over the points p = (x, y, z) (x right, y up,
    from the map's centre). Unbiased for noise small against the radius (skin: um against
    mm). The radius is the form's radius of curvature (a forehead's is about 80 mm).
    """
    rows, columns = height.shape
    dy, dx = height.spacing
    valid = height.mask & np.isfinite(height.z)
    if valid.sum() < 4:
        raise SkinTopoError(f"a sphere needs at least 4 valid points, got {int(valid.sum())}")
    y, x = np.nonzero(valid)
    points = np.stack([(x - (columns - 1) / 2) * dx, ((rows - 1) / 2 - y) * dy, height.z[valid]], axis=1)
    offset = points.mean(axis=0)  # conditioning: centre the points first
    local = points - offset
    system = np.column_stack([2 * local, np.ones(len(local))])
    solution = np.linalg.lstsq(system, np.sum(local**2, axis=1), rcond=None)[0]
    centre = solution[:3]
    radius = float(np.sqrt(solution[3] + centre @ centre))
    return radius, centre + offset


def coarse_areal_gaussian_filter(z, spacing, cutoff_um, mask, samples_per_sigma=8):
    """:func:`areal_gaussian_filter` of a wide filter computed on a grid of block means of the
    valid points, with at least ``samples_per_sigma`` samples per Gaussian sigma, and
    interpolated back (bilinear, block centres). A 2.5 mm regression of a 20 um map runs on a
    grid 2 x coarser per axis (0.53 s -> 0.16 s at 1000 x 1000); the Gaussian's transfer at
    the coarse grid's Nyquist frequency is below 1e-100, so what the block means alias is
    filtered out. It differs from the full filter where the regression fills masked points
    (the blocks at a mask's edge are partly valid): on a levelled simulated forehead (400 x 400,
    20 um pixels, a 40-row masked band beside a 100 um wrinkle), by at most 0.24 um (99th
    percentile 0.06 um) when the band's edges fall on block edges, but by up to 1.1 um (99th
    percentile 0.9 um) when they fall inside blocks (one row of data more or less at the edge,
    which the full filter's extrapolation feels and the block grid cannot resolve); 4 samples
    per sigma gave 1.0 um in the first case. Known limit, measured (issue 25): exact block sums
    of the regression's moments would remove the alignment dependence."""
    dy, dx = pixel_spacing(spacing)
    factor = max(1, int(min(gaussian_sigma_px(cutoff_um, dy), gaussian_sigma_px(cutoff_um, dx)) / samples_per_sigma))
    if factor == 1:
        return areal_gaussian_filter(z, spacing, cutoff_um, mask)
    valid = np.asarray(mask, dtype=bool) & np.isfinite(z)
    weight, total = block_mean(valid, factor), block_mean(np.where(valid, z, 0.0), factor)
    coarse_valid = weight > 0
    low = areal_gaussian_filter(np.where(coarse_valid, total / np.where(coarse_valid, weight, 1.0), 0.0), (dy * factor, dx * factor),
                                cutoff_um, coarse_valid)
    return bilinear_resize(low, np.shape(z), factor, offset=(factor - 1) / 2)  # read at the blocks' centres


def linear_weights(coordinates, size):
    """(lower sample, fraction) of linear interpolation of ``size`` samples at ``coordinates``
    (in samples), clamped to the ends: the value there is z[lower] + fraction (z[lower + 1] -
    z[lower]) (lower + 1 clamped to the last sample when ``size`` is 1)."""
    coordinates = np.clip(coordinates, 0, size - 1)
    lower = np.minimum(coordinates.astype(np.intp), max(size - 2, 0))
    return lower, coordinates - lower


def bilinear_resize(values, shape, factor, offset=0.0):
    """``values`` interpolated bilinearly onto a grid of ``shape`` whose pixel (i, j) lies at
    ((i - offset) / factor, (j - offset) / factor) of ``values`` (edges clamped), e.g. block
    means back on their pixels (offset (factor - 1) / 2) or every ``factor``-th node back on
    all nodes (offset 0). Equal to ``scipy.ndimage.map_coordinates(order=1, mode="nearest")``
    at those points (to rounding), made separably along rows then columns on a regular grid:
    about 7x faster at 1000 x 1000 (no coordinate arrays, no per-point weights). A stack
    (..., rows, columns) is resized image by image, in the precision of ``values``. Columns
    first: gathering along the last axis is the slow step, and it runs on the input's rows
    (fewer when enlarging; 3x faster for 4 x 250^2 -> 1000^2)."""
    n_rows, n_columns = values.shape[-2:]
    (r0, t), (c0, u) = (linear_weights((np.arange(n_out) - offset) / factor, n_in) for n_out, n_in in zip(shape, (n_rows, n_columns)))
    r1, c1 = np.minimum(r0 + 1, n_rows - 1), np.minimum(c0 + 1, n_columns - 1)
    dtype = values.dtype if np.issubdtype(values.dtype, np.floating) else float
    t, u = t.astype(dtype), u.astype(dtype)
    columns = values[..., c0] * (1 - u) + values[..., c1] * u
    return columns[..., r0, :] * (1 - t)[:, None] + columns[..., r1, :] * t[:, None]


def block_means_of_valid(z, valid, spacing, factor, min_valid=0.5):
    """(means of the valid heights over factor x factor blocks, the blocks whose valid share
    exceeds ``min_valid``, the blocks' spacing); heights are 0 in the other blocks."""
    dy, dx = pixel_spacing(spacing)
    weight = block_mean(valid.astype(float), factor)
    coarse_valid = weight > min_valid
    means = np.where(coarse_valid, block_mean(np.where(valid, z, 0.0), factor) / np.where(coarse_valid, weight, 1.0), 0.0)
    return means, coarse_valid, (dy * factor, dx * factor)


def expanded_blocks(coarse, shape, factor):
    """A block image back on the pixels of ``shape``: each pixel takes its block's value."""
    rows, columns = shape
    return coarse[np.arange(rows)[:, None] // factor, np.arange(columns)[None, :] // factor]


def block_mean(image, factor, partial_blocks="pad"):
    """Means over ``factor`` x ``factor`` blocks of the last two axes (one image or a stack).

    ``partial_blocks="pad"`` zero-pads the image to whole blocks (weigh by the block mean of a
    validity image to undo the padding where it matters); ``"trim"`` leaves out the rows and
    columns beyond the last whole block. Floating-point input keeps its precision (float32
    stays float32); other input is averaged in float64. Summed with strided slices, rows then
    columns (a loop over offsets in the block, not over pixels): 4-8x faster than a reshape and
    ``mean`` over the block axes, whose reduction runs along non-contiguous axes (measured at
    1000 x 1000); equal to it up to rounding."""
    if partial_blocks not in ("pad", "trim"):
        raise ValueError(f"partial_blocks must be 'pad' or 'trim', not {partial_blocks!r}")
    image = np.asarray(image)
    dtype = image.dtype if np.issubdtype(image.dtype, np.floating) else np.dtype(np.float64)
    image = image.astype(dtype, copy=False)
    if factor == 1:
        return image
    rows, columns = image.shape[-2:]
    if partial_blocks == "trim":
        image = image[..., : rows // factor * factor, : columns // factor * factor]
    elif rows % factor or columns % factor:
        padded = np.zeros((*image.shape[:-2], -(-rows // factor) * factor, -(-columns // factor) * factor), dtype)
        padded[..., :rows, :columns] = image
        image = padded
    by_rows = image[..., ::factor, :].copy()
    for offset in range(1, factor):
        by_rows += image[..., offset::factor, :]
    total = by_rows[..., ::factor].copy()
    for offset in range(1, factor):
        total += by_rows[..., offset::factor]
    return total / dtype.type(factor * factor)


def ellipse_axes(labels):
    """Per label of a label image (index = label; 0 unused): the area in pixels and the major
    and minor axis lengths (pixels) of the ellipse with the same second moments, 4 sqrt(lambda)
    of the eigenvalues of the pixel coordinates' covariance (scikit-image's
    ``axis_major_length`` / ``axis_minor_length``), from sums over all labels at once:
    regionprops computes each region's inertia tensor alone (0.2 s for the 400 candidate
    pores of a 1024 x 1024 forehead)."""
    count = int(labels.max())
    rows, columns = np.nonzero(labels)
    ids = labels[rows, columns]
    area = np.bincount(ids, minlength=count + 1).astype(float)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean_row = np.bincount(ids, rows, count + 1) / area
        mean_column = np.bincount(ids, columns, count + 1) / area
        d_row, d_column = rows - mean_row[ids], columns - mean_column[ids]
        a = np.bincount(ids, d_row * d_row, count + 1) / area
        c = np.bincount(ids, d_column * d_column, count + 1) / area
        b = np.bincount(ids, d_row * d_column, count + 1) / area
    root = np.sqrt(((a - c) / 2) ** 2 + b * b)
    major, minor = (a + c) / 2 + root, np.maximum((a + c) / 2 - root, 0.0)
    return area, 4 * np.sqrt(np.nan_to_num(major)), 4 * np.sqrt(np.nan_to_num(minor))


def line_segment_footprint(length_um, angle_deg, spacing):
    """Digital line segment (boolean footprint, centrally symmetric) of physical length
    ``length_um`` at ``angle_deg`` counter-clockwise from +x (x right, y up; rows run down)."""
    dy, dx = pixel_spacing(spacing)
    theta = np.radians(angle_deg)
    half_columns = 0.5 * length_um * np.cos(theta) / dx
    half_rows = -0.5 * length_um * np.sin(theta) / dy
    # One pixel per step along the dominant axis, the other coordinate rounded: symmetric
    # about the centre, since rint(-v) = -rint(v).
    major = max(abs(half_columns), abs(half_rows))
    steps = np.arange(-int(round(major)), int(round(major)) + 1)
    fraction = steps / major if major > 0 else np.zeros(1)
    rows, columns = np.rint(fraction * half_rows).astype(int), np.rint(fraction * half_columns).astype(int)
    reach_rows, reach_columns = int(np.abs(rows).max()), int(np.abs(columns).max())
    footprint = np.zeros((2 * reach_rows + 1, 2 * reach_columns + 1), dtype=bool)
    footprint[rows + reach_rows, columns + reach_columns] = True
    return footprint


def _masked_closing(lowered, invalid, footprint):
    """Grey dilation then erosion of ``lowered`` (the heights, masked points at -inf) with the
    flat ``footprint``, masked points +inf in the erosion: SciPy's ``grey_dilation`` /
    ``grey_erosion`` (mode "constant", cval -inf / +inf) bit for bit, since a maximum or a
    minimum involves no rounding. Valid points get a finite value (each is in its own
    segment); masked ones +inf or whatever the erosion left there.

    OpenCV's ``dilate`` / ``erode`` (vectorised over rows, the GIL released): a 31-pixel
    segment on a 1024 x 1024 map of float64 takes 2-8 ms per pass by the angle (23 ms at 22.5
    degrees through SciPy's generic N-d iterator, 2026-12-04; float32, as
    :func:`_closing_input` gives, 3-5x less), as fast as the compiled loop it
    replaces without its 0.6 s of loading per process (Numba's import and cache). Van Herk /
    Gil-Werman running extrema would need the same digital line through every pixel, which a
    rounded line at most angles is not."""
    # here, not at the top: only the closings need OpenCV (0.08 s to import)
    import cv2

    kernel = footprint.astype(np.uint8)
    closed = cv2.dilate(lowered, kernel, borderType=cv2.BORDER_CONSTANT, borderValue=-np.inf)
    np.copyto(closed, np.inf, where=invalid)
    return cv2.erode(closed, kernel, dst=closed, borderType=cv2.BORDER_CONSTANT, borderValue=np.inf)


def _closing_input(z, mask):
    """(heights as float64, valid points, the heights less ``offset`` in single precision with
    masked points at -inf, ``offset``). The closings run in single precision, 3-5x faster in
    OpenCV than in double (a 17-pixel segment on 1024 x 1024: 10 -> 2 ms a closing): rounding
    is monotone, so it commutes with the maxima and minima, and the closing of the rounded
    heights is the exact closing rounded (:func:`_exact_where_unchanged` then gives a point
    the closing leaves at its own height that height exactly). The heights are centred on
    their mid-range first, so the rounding (half an ulp, at most 2^-24 of the half-range:
    3e-6 um over a 100 um range) does not grow with an offset. On the simulated foreheads and
    pore fields the segmentation and the pores found are identical, the measures within 2e-7
    relative."""
    z = np.asarray(z, dtype=np.float64)
    valid = np.isfinite(z) if mask is None else (np.asarray(mask, dtype=bool) & np.isfinite(z))
    offset = 0.5 * (z[valid].min() + z[valid].max()) if valid.any() else 0.0
    return z, valid, np.where(valid, z - offset, -np.inf).astype(np.float32), offset


def line_segment_closing(z, spacing, length_um, angle_deg, mask=None):
    """Closing filter with a level line segment (see the module notes): fills valleys
    narrower than ``length_um`` along ``angle_deg``.

    Masked points take no part: they are left out of the maximum and of the minimum (a
    point whose whole segment is masked stays as it was). Returns a new array.
    """
    z, valid, lowered, offset = _closing_input(z, mask)
    closed = _masked_closing(lowered, ~valid, line_segment_footprint(length_um, angle_deg, spacing))
    return _exact_where_unchanged(closed, lowered, z, valid, offset)


def _exact_where_unchanged(closed, lowered, z, valid, offset):
    """A single-precision closing (of ``lowered``, :func:`_closing_input`) back in double
    precision: the heights ``z`` themselves where the closing left a point at its own
    (rounded) height and where it is masked, the closing plus ``offset`` elsewhere."""
    return np.where(~valid | (closed == lowered), z, closed + offset)


def line_segment_closing_extremes(z, spacing, length_um, angles_deg, mask=None, return_lowest_index=False):
    """(lowest, highest): the pointwise minimum and maximum of :func:`line_segment_closing` over
    ``angles_deg``; with ``return_lowest_index``, also the index into ``angles_deg`` of the
    closing that gave the minimum (the first of equal ones): the direction along which a
    valley survives. The closings run on two threads (OpenCV's filters release the GIL) and
    are folded in as they come, so two maps are held, not one per angle."""
    z, valid, lowered, offset = _closing_input(z, mask)
    invalid = ~valid
    lowest = highest = index = None
    with ThreadPoolExecutor(max_workers=2) as pool:
        closings = pool.map(lambda angle: _masked_closing(lowered, invalid, line_segment_footprint(length_um, angle, spacing)), angles_deg)
        for number, closed in enumerate(closings):
            if lowest is None:
                lowest, highest = closed, closed.copy()
                index = np.zeros(closed.shape, np.int16) if return_lowest_index else None
            else:
                if return_lowest_index:
                    index[closed < lowest] = number
                np.minimum(lowest, closed, out=lowest)
                np.maximum(highest, closed, out=highest)
    # back in double precision; masked points keep their heights (valid ones are finite in every closing)
    lowest, highest = (_exact_where_unchanged(closed, lowered, z, valid, offset) for closed in (lowest, highest))
    if return_lowest_index:
        index[invalid] = 0
    return (lowest, highest, index) if return_lowest_index else (lowest, highest)


def level(height: HeightMap, order=1):
    """The height map with its least-squares polynomial form (default: plane) removed."""
    return HeightMap(height.z - polynomial_form(height.z, height.spacing, order, height.mask), height.spacing, height.mask)


def extract_profile(height: HeightMap, start_um, end_um, width_um=0.0):
    """Heights along a straight line, averaged across a band of ``width_um``.

    Parameters
    ----------
    height : HeightMap
    start_um, end_um : (x, y)
        End points in micrometres from the top-left pixel centre, x along columns (right)
        and y along rows (down, as image coordinates).
    width_um : float
        Width of the band averaged across the line (0 = the line itself).

    Returns
    -------
    distance_um, z_um : ndarray
        Positions along the line (one per pixel spacing) and the heights there (bilinear
        interpolation; NaN where the line meets missing data).
    """
    dy, dx = height.spacing
    start = np.asarray(start_um, dtype=float)
    end = np.asarray(end_um, dtype=float)
    rows, columns = height.shape
    for point in (start, end):
        if not (0 <= point[0] <= (columns - 1) * dx and 0 <= point[1] <= (rows - 1) * dy):
            raise SkinTopoError(
                f"profile end point ({point[0]:g}, {point[1]:g}) um lies outside the map (0..{(columns - 1) * dx:g} x 0..{(rows - 1) * dy:g} um)"
            )
    length = float(np.hypot(*(end - start)))
    step = min(dx, dy)
    count = max(2, int(round(length / step)) + 1)
    t = np.linspace(0, 1, count)
    direction = (end - start) / length if length > 0 else np.array([1.0, 0.0])
    across = np.array([-direction[1], direction[0]])
    across_count = int(round(width_um / step)) + 1 if width_um > 0 else 1  # one sample per pixel spacing across
    offsets = np.linspace(-width_um / 2, width_um / 2, across_count) if across_count > 1 else np.zeros(1)  # one: the line itself
    x = start[0] + t[:, None] * (end - start)[0] + offsets[None, :] * across[0]
    y = start[1] + t[:, None] * (end - start)[1] + offsets[None, :] * across[1]
    z = np.where(height.mask, height.z, np.nan)
    sampled = scipy.ndimage.map_coordinates(z, [y.ravel() / dy, x.ravel() / dx], order=1, mode="nearest").reshape(x.shape)
    return t * length, sampled.mean(axis=1)


def profile_gaussian_filter(z, spacing_um, cutoff_um):
    """Low-pass of the ISO 16610-21 Gaussian profile filter, first-order regression at the ends.

    Same weighting function and transmission as :func:`areal_gaussian_filter`, in one
    dimension: at every point a weighted least-squares line (Gaussian weights over the valid
    points) gives the mean line, so a straight profile passes unchanged up to its ends.
    NaN points are left out.
    """
    z = np.asarray(z, dtype=np.float64)
    if z.ndim != 1:
        raise ValueError(f"expected a 1-D profile, got shape {z.shape}")
    if not (cutoff_um > 0):
        raise SkinTopoError(f"cut-off must be positive, got {cutoff_um} um")
    valid = np.isfinite(z)
    sigma = gaussian_sigma_px(cutoff_um, spacing_um)

    def smooth(values):
        return scipy.ndimage.gaussian_filter1d(values, sigma, mode="constant", truncate=_TRUNCATE)

    weight = valid.astype(float)
    values = np.where(valid, z, 0.0)
    x = np.arange(z.size) - z.size / 2
    s0, sx, sxx = smooth(weight), smooth(weight * x), smooth(weight * x * x)
    sz, sxz = smooth(values), smooth(values * x)
    mx, mxx, mxz = sx - x * s0, sxx - 2 * x * sx + x * x * s0, sxz - x * sz
    det = s0 * mxx - mx * mx
    with np.errstate(invalid="ignore", divide="ignore"):
        first = (sz * mxx - mx * mxz) / det
        zeroth = sz / s0
        low = np.where(det > 1e-3 * s0**2 * sigma**2, first, zeroth)
    return np.where(s0 > 1e-6 * s0.max(), low, np.nan)
