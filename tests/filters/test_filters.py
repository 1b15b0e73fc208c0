"""Filters: ISO Gaussian transmission, form removal, line-segment closings, profiles, block means, coarse regression."""

import numpy as np
import pytest
import scipy.ndimage
import scipy.special
import scipy.stats

from skintopo import filters
from skintopo.errors import SkinTopoError
from skintopo.filters import (
    areal_gaussian_filter,
    block_mean,
    extract_profile,
    gaussian_bandpass,
    gaussian_moments,
    gaussian_transmission,
    level,
    line_segment_closing,
    line_segment_footprint,
    polynomial_form,
    profile_gaussian_filter,
    sphere_fit,
)
from skintopo.heightmap import HeightMap
from skintopo.synth import make_surface, preset_spec


def sinusoid_amplitude(values, x, wavelength):
    design = np.column_stack([np.sin(2 * np.pi * x / wavelength), np.cos(2 * np.pi * x / wavelength), np.ones_like(x)])
    coefficients, *_ = np.linalg.lstsq(design, values, rcond=None)
    return np.hypot(coefficients[0], coefficients[1])


@pytest.mark.parametrize("sigmas", [(1.5, 1.0), (3.0, 1.5), (12.0, 20.0), (25.0, 9.0)])  # direct path, then the FFT path (>= 2 px)
def test_gaussian_smoothing_matches_scipy_with_different_row_and_column_widths(sigmas):
    """Zero outside the field (scipy's mode "constant"), data up to the border; 150 columns
    padded by 4 x 9 px on each side make an odd FFT length (225)."""
    image = np.random.default_rng(2).normal(size=(90, 150))
    (smoothed,) = gaussian_moments(image, sigmas, ((0, 0),))
    expected = scipy.ndimage.gaussian_filter(image, sigmas, mode="constant", truncate=6.0)
    np.testing.assert_allclose(smoothed, expected, atol=1e-4 * np.abs(expected).max())  # the direct path truncates at 4 sigma


@pytest.mark.parametrize("sigmas", [(1.5, 1.2), (6.0, 4.0)])  # direct path, FFT path
def test_gaussian_moments_about_each_point_match_explicit_sums(sigmas):
    """M_pq(y, x) = sum (y' - y)^p (x' - x)^q g g f, summed explicitly over every pair of
    points with the continuous Gaussian's weights (no truncation), at points in the middle,
    at an edge and at a corner."""
    image = np.random.default_rng(3).normal(size=(40, 50))
    orders = ((0, 0), (0, 1), (1, 0), (0, 2), (1, 1), (2, 0))
    moments = gaussian_moments(image, sigmas, orders)
    rows, columns = np.mgrid[:40, :50]
    for r, c in ((20, 25), (0, 30), (39, 0)):
        dy, dx = rows - r, columns - c
        weight = np.exp(-0.5 * (dy / sigmas[0]) ** 2 - 0.5 * (dx / sigmas[1]) ** 2) / (2 * np.pi * sigmas[0] * sigmas[1])
        for (p, q), moment in zip(orders, moments):
            expected = np.sum(dy**p * dx**q * weight * image)
            scale = np.sum(np.abs(dy) ** p * np.abs(dx) ** q * weight * np.abs(image))
            assert abs(moment[r, c] - expected) < 2e-3 * scale, ((p, q), (r, c), moment[r, c], expected)


def test_coarse_gaussian_regression_matches_the_full_filter_where_wrinkles_are_masked():
    """The 2.5 mm regression under a wrinkle's masked band, on block means 2 x coarser: within
    0.3 um of the full filter on a levelled simulated forehead (relief about 8 um RMS) when the
    band's edges fall on block edges, within 1.2 um when they fall inside blocks (the
    documented limit), and never the same as the full filter (it is the coarse grid)."""
    from skintopo.filters import (
        areal_gaussian_filter,
        coarse_areal_gaussian_filter,
        polynomial_form,
    )

    surface = make_surface(preset_spec("forehead-moderate", size_px=400), seed=1)
    for first, bound in ((150, 0.3), (151, 1.2)):  # the second: the blocks at the edges are partly valid
        mask = np.ones(surface.height.shape, bool)
        mask[first:190, 40:360] = False
        z = surface.height.z - polynomial_form(surface.height.z, 20.0, 2, mask)
        full = areal_gaussian_filter(z, 20.0, 2500.0, mask)
        coarse = coarse_areal_gaussian_filter(z, 20.0, 2500.0, mask)
        assert 0.01 < np.abs(coarse - full).max() < bound and np.abs(coarse - full)[~mask].max() < bound
    # a filter too narrow for a coarser grid (sigma under 16 samples) is the full filter itself
    np.testing.assert_array_equal(coarse_areal_gaussian_filter(z, 20.0, 1000.0, mask), areal_gaussian_filter(z, 20.0, 1000.0, mask))


@pytest.mark.parametrize("factor", [1 / 3, 1.0, 3.0])
def test_gaussian_filter_transmission(factor):
    pixel, cutoff = 2.0, 400.0
    wavelength = cutoff * factor
    x = np.arange(1500) * pixel
    z = 10 * np.sin(2 * np.pi * x / wavelength)[None, :] * np.ones((8, 1))
    low = areal_gaussian_filter(z, pixel, cutoff)
    interior = slice(500, 1000)
    transmission = sinusoid_amplitude(low[4, interior], x[interior], wavelength) / 10
    expected = gaussian_transmission(wavelength, cutoff)
    print(f"lambda = {factor:.3g} lambda_c: transmission {transmission:.5f}, formula {expected:.5f}")
    if factor == 1.0:
        assert transmission == pytest.approx(0.5, abs=0.005)
    assert transmission == pytest.approx(expected, abs=0.005 * max(expected, 0.01) + 1e-4)


def test_plane_passes_unchanged_including_edges_and_masks():
    rows, columns = np.mgrid[:90, :120]
    z = 0.7 * rows - 0.4 * columns + 12.0
    mask = np.ones(z.shape, bool)
    mask[30:60, 40:70] = False
    for m in (None, mask):
        low = areal_gaussian_filter(z, (3.0, 4.0), 500.0, m)
        assert np.nanmax(np.abs(low - z)) < 1e-9


@pytest.mark.parametrize("sigma_y, masked", [(1.5, False), (1.5, True), (3.0, False), (3.0, True), (10.0, False), (10.0, True)])
def test_regression_equals_a_weighted_plane_fitted_by_direct_sums(sigma_y, masked):
    """ISO 16610-61 as first-order Gaussian regression: at each point, the plane fitted by
    weighted least squares with the Gaussian weights over the valid points, written here as
    direct sums (numpy lstsq per point) on rectangular pixels (sigma_x = 0.8 sigma_y), at
    corners, edges, inside and beside a masked block. The narrow filter (direct path)
    truncates its kernel at 4 sigma along each axis as scipy does, int(4 sigma + 0.5); the wide
    one (FFT path) uses the whole Gaussian. With a full mask the filter's weight moments are
    1-D smoothings, with a partial one 2-D."""
    rng = np.random.default_rng(5)
    z = rng.normal(size=(70, 90)).cumsum(axis=0).cumsum(axis=1)
    dy, dx = 10.0, 12.5
    sigmas = (sigma_y, 0.8 * sigma_y)
    cutoff = sigma_y * dy * np.sqrt(2 * np.pi) / np.sqrt(np.log(2) / np.pi)
    mask = np.ones(z.shape, bool)
    if masked:
        mask[20:35, 30:60] = False
    low = areal_gaussian_filter(np.where(mask, z, np.nan), (dy, dx), cutoff, mask if masked else None)
    rows, columns = np.mgrid[: z.shape[0], : z.shape[1]]
    for r, c in ((0, 0), (69, 89), (0, 45), (35, 0), (40, 50), (19, 45), (27, 62)):
        if not mask[r, c] and not masked:
            continue
        weight = np.exp(-0.5 * (((rows - r) / sigmas[0]) ** 2 + ((columns - c) / sigmas[1]) ** 2)) * mask
        if max(sigmas) < filters._FFT_SIGMA_PX:  # the direct path's truncated kernels
            weight *= (np.abs(rows - r) <= int(4 * sigmas[0] + 0.5)) & (np.abs(columns - c) <= int(4 * sigmas[1] + 0.5))
        design = np.column_stack([np.ones(z.size), (columns - c).ravel(), (rows - r).ravel()]) * np.sqrt(weight.ravel())[:, None]
        plane = np.linalg.lstsq(design, z.ravel() * np.sqrt(weight.ravel()), rcond=None)[0]
        assert low[r, c] == pytest.approx(plane[0], abs=1e-8 * np.ptp(z))


def test_a_single_valid_row_is_filtered_by_the_weighted_mean_and_reaches_five_sigmas():
    """Where the valid points lie on one row, the local plane has no y-slope to fit and the
    filter falls back to the weighted mean (zeroth order): along the row, the 1-D Gaussian,
    whose transmission of a cosine is exp(-pi (alpha lambda_c / lambda)^2); across it, the
    row's value at every row within reach. Reach (the weight above 1e-6 of its largest):
    exp(-d^2 / 2 sigma^2) > 1e-6, i.e. d < 5.26 sigma."""
    cutoff, pixel = 53.36, 1.0  # sigma = 10.0 px: the FFT path
    sigma = cutoff * np.sqrt(np.log(2) / np.pi) / np.sqrt(2 * np.pi) / pixel
    wavelength = 2 * cutoff
    x = np.arange(600) * pixel
    z = np.full((70, 600), np.nan)
    z[5] = 3.0 * np.cos(2 * np.pi * x / wavelength) + 7.0
    low = areal_gaussian_filter(z, pixel, cutoff)
    interior = slice(150, 450)
    expected = 3.0 * gaussian_transmission(wavelength, cutoff) * np.cos(2 * np.pi * x[interior] / wavelength) + 7.0
    reached = [row for row in range(70) if abs(row - 5) < 5.0 * sigma]
    for row in reached:
        np.testing.assert_allclose(low[row, interior], expected, atol=3e-3)
    assert np.isnan(low[[row for row in range(70) if abs(row - 5) > 5.5 * sigma]]).all()


def test_polynomial_form_removal():
    rows, columns = np.mgrid[:40, :50]
    form = 0.01 * (rows - 20) ** 2 + 0.3 * columns
    np.testing.assert_allclose(polynomial_form(form, 1.0, 2), form, atol=1e-9)
    levelled = level(HeightMap(form + 5, 1.0), order=2)
    assert np.abs(levelled.z).max() < 1e-9
    with pytest.raises(SkinTopoError, match="needs at least"):
        polynomial_form(np.full((1, 2), 1.0), 1.0, 2)


@pytest.mark.parametrize("order", [0, 1, 2, 3])
def test_polynomial_form_is_the_least_squares_fit_over_the_valid_points(order):
    """Against NumPy's QR least squares over the valid points: the mask's points that are also
    finite (the mask and the missing points differ), and every point when all are valid."""
    rng = np.random.default_rng(order)
    z = rng.standard_normal((30, 45)) + np.mgrid[:30, :45][0] * 0.1 + 0.02 * np.mgrid[:30, :45][1] ** 2
    mask = rng.random(z.shape) > 0.3
    z_missing = z.copy()
    z_missing[rng.random(z.shape) > 0.9] = np.nan
    v, u = np.meshgrid(np.linspace(-1, 1, 30), np.linspace(-1, 1, 45), indexing="ij")
    basis = np.stack([u**i * v**j for i in range(order + 1) for j in range(order + 1 - i)], axis=-1)
    for values, valid in ((z_missing, mask), (z, np.ones_like(mask))):
        used = valid & np.isfinite(values)
        coefficients, *_ = np.linalg.lstsq(basis[used], values[used], rcond=None)  # independent: QR-based lstsq
        np.testing.assert_allclose(polynomial_form(values, 1.0, order, valid), basis @ coefficients, atol=1e-10)
    if order == 1:  # the default is the plane, with the mask and the missing points taken as they are
        np.testing.assert_allclose(polynomial_form(z_missing, 1.0, mask=mask), polynomial_form(z_missing, 1.0, 1, mask), atol=0)
        used = np.isfinite(z_missing)
        coefficients, *_ = np.linalg.lstsq(basis[used], z_missing[used], rcond=None)
        np.testing.assert_allclose(polynomial_form(z_missing, 1.0), basis @ coefficients, atol=1e-10)


def test_polynomial_form_needs_as_many_points_as_terms():
    """A plane has 3 terms: 3 points not on a line fix it exactly; 2 are refused."""
    z = np.full((4, 5), np.nan)
    z[0, 0], z[3, 0], z[0, 4] = 1.0, 4.0, 9.0
    expected = 1.0 + 1.0 * np.mgrid[:4, :5][0] + 2.0 * np.mgrid[:4, :5][1]
    np.testing.assert_allclose(polynomial_form(z, 1.0), expected, atol=1e-9)
    z[3, 0] = np.nan
    with pytest.raises(SkinTopoError, match="order 1 needs at least 3 valid points, got 2"):
        polynomial_form(z, 1.0)


def test_line_segment_closing_fills_valleys_narrower_than_the_segment_only():
    """On a level surface: a groove 3 pixels wide along y and one 15 pixels wide along x. A
    10-pixel (100 um) segment along x fills the narrow groove back to the surface exactly and
    leaves the wide groove (long along x) as it is; along y the wide groove (15 px across)
    stays, and so does the narrow one (long along y). A tilted plane passes unchanged (away
    from the border, where the segment would reach out of the field)."""
    rows, columns = np.mgrid[0:60, 0:80].astype(float)
    tilted = 0.3 * columns - 0.2 * rows
    for angle in (0.0, 30.0, 90.0, 135.0):
        np.testing.assert_allclose(line_segment_closing(tilted, 10.0, 100.0, angle)[10:-10, 10:-10], tilted[10:-10, 10:-10], atol=1e-12)
    plane = np.full(rows.shape, 7.0)
    narrow = np.abs(columns - 40) <= 1
    wide = np.abs(rows - 30) <= 7
    z = plane - 20.0 * narrow - 30.0 * wide  # flat-bottomed grooves
    along_x = line_segment_closing(z, 10.0, 100.0, 0.0)
    np.testing.assert_allclose(along_x[narrow & ~wide], plane[narrow & ~wide], atol=1e-12)
    np.testing.assert_array_equal(along_x[wide & (np.abs(columns - 40) > 6)], z[wide & (np.abs(columns - 40) > 6)])
    np.testing.assert_allclose(along_x[~narrow & ~wide], plane[~narrow & ~wide], atol=1e-12)
    along_y = line_segment_closing(z, 10.0, 100.0, 90.0)
    far = (np.abs(rows - 30) > 12) | (np.abs(columns - 40) > 6)
    np.testing.assert_array_equal(along_y[far], z[far])
    # A 300 um segment across the wide groove (150 um) fills it to the plane.
    across = line_segment_closing(z, 10.0, 300.0, 90.0)
    inside = wide & ~narrow & (rows > 16) & (rows < 44)
    np.testing.assert_allclose(across[inside], plane[inside], atol=1e-12)


@pytest.mark.parametrize("valley_deg", [0.0, 30.0, 120.0])
def test_the_lowest_closing_is_the_one_laid_along_a_straight_valley(valley_deg):
    """A straight groove 40 um wide at a known angle (counter-clockwise from +x, y up) on a
    level surface: of 12 closings with a 600 um segment, only the ones within a few degrees of
    the groove leave its floor low, so the index of the lowest points at the groove's angle
    (the first of equal ones); the extremes are those of the closings taken one by one."""
    from skintopo.filters import line_segment_closing_extremes

    rows, columns = np.mgrid[0:120, 0:120].astype(float)
    theta = np.radians(valley_deg)
    across = (columns - 60) * np.sin(theta) + (rows - 60) * np.cos(theta)  # distance (px) from the groove's axis, rows down
    z = -10.0 * (np.abs(across) <= 2)
    angles = np.arange(12) * 15.0
    lowest, highest, index = line_segment_closing_extremes(z, 10.0, 600.0, angles, return_lowest_index=True)
    closings = np.stack([line_segment_closing(z, 10.0, 600.0, angle) for angle in angles])
    np.testing.assert_array_equal(lowest, closings.min(axis=0))
    np.testing.assert_array_equal(highest, closings.max(axis=0))
    np.testing.assert_array_equal(index, closings.argmin(axis=0))
    floor = (np.abs(across) <= 1) & (np.hypot(rows - 60, columns - 60) < 20)
    assert (angles[index[floor]] == valley_deg).all()
    np.testing.assert_array_equal(line_segment_closing_extremes(z, 10.0, 600.0, angles)[0], lowest)


def test_line_segment_closing_leaves_masked_points_out():
    """A masked point takes no part: the result is that of the map ending there."""
    rng = np.random.default_rng(3)
    z = rng.normal(size=(30, 40))
    mask = np.ones_like(z, dtype=bool)
    mask[:, 25:] = False
    z[~mask] = -100.0  # whatever is there must not count
    for angle in (0.0, 30.0, 90.0):
        closed = line_segment_closing(z, 1.0, 7.0, angle, mask)
        np.testing.assert_array_equal(closed[:, :25], line_segment_closing(z[:, :25], 1.0, 7.0, angle))
        np.testing.assert_array_equal(closed[~mask], z[~mask])
        assert (closed[mask] >= z[mask]).all()  # a closing only fills
    labels = np.where(mask, np.arange(40)[None, :] % 3 + 1, 0)  # a label image as the mask: non-zero is inside
    np.testing.assert_array_equal(line_segment_closing(z, 1.0, 7.0, 30.0, labels), line_segment_closing(z, 1.0, 7.0, 30.0, mask))


@pytest.mark.parametrize("angle", [0.0, 15.0, 45.0, 75.0, 90.0, 135.0, 165.0])
def test_line_segment_closing_is_scipys_grey_closing_rounded_to_single_precision(angle):
    """The OpenCV closing against SciPy's grey dilation then erosion with the same footprint
    in double precision (masked points -inf, then +inf; mode "constant"), on a rough map with
    scattered masked points and rectangular pixels, segment reaching past the edges: a point
    the closing leaves at its own height keeps it bit for bit, any other is within half an
    ulp of single precision of the half-range (the heights are centred on their mid-range)."""
    rng = np.random.default_rng(11)
    z = rng.normal(size=(60, 70)).cumsum(axis=1)
    mask = rng.random(z.shape) > 0.05
    footprint = line_segment_footprint(300.0, angle, (10.0, 12.0))
    dilated = scipy.ndimage.grey_dilation(np.where(mask, z, -np.inf), footprint=footprint, mode="constant", cval=-np.inf)
    closed = scipy.ndimage.grey_erosion(np.where(mask, dilated, np.inf), footprint=footprint, mode="constant", cval=np.inf)
    expected = np.where(mask & np.isfinite(closed), closed, z)
    result = line_segment_closing(z, (10.0, 12.0), 300.0, angle, mask)
    unchanged = expected == z
    assert 0.05 < unchanged.mean() < 0.95  # both kinds of points are tested
    np.testing.assert_array_equal(result[unchanged], z[unchanged])
    half_range = 0.5 * (z[mask].max() - z[mask].min())
    assert np.abs(result - expected).max() <= 2.0**-24 * half_range


@pytest.mark.parametrize("angle", [0.0, 17.0, 45.0, 90.0, 120.0, 178.0])
def test_line_segment_footprint_is_a_symmetric_digital_line(angle):
    footprint = line_segment_footprint(200.0, angle, (10.0, 20.0))  # rectangular pixels
    np.testing.assert_array_equal(footprint, footprint[::-1, ::-1])
    rows, columns = np.nonzero(footprint)
    centre = np.array(footprint.shape) // 2
    x, y = (columns - centre[1]) * 20.0, -(rows - centre[0]) * 10.0
    # every pixel within half a pixel diagonal of the ideal line, ends within half the length
    distance = np.abs(-np.sin(np.radians(angle)) * x + np.cos(np.radians(angle)) * y)
    assert distance.max() <= 0.5 * np.hypot(10.0, 20.0)
    assert np.hypot(x, y).max() <= 100.0 + 0.5 * np.hypot(10.0, 20.0)


def test_profile_extraction_across_a_ramp():
    rows, columns = np.mgrid[:50, :60]
    height = HeightMap(2.0 * columns * 5.0, 5.0)  # z = 2 x (um)
    distance, z = extract_profile(height, (10.0, 100.0), (200.0, 100.0), width_um=20.0)
    np.testing.assert_allclose(z, 2 * (10.0 + distance), atol=1e-9)
    np.testing.assert_allclose(np.diff(distance), 5.0)
    assert distance[-1] == pytest.approx(190.0)
    with pytest.raises(SkinTopoError, match=r"end point \(1000, 0\) um lies outside the map \(0..295 x 0..245 um\)"):
        extract_profile(height, (0.0, 0.0), (1000.0, 0.0))
    with pytest.raises(SkinTopoError, match=r"\(0, 250\) um lies outside"):
        extract_profile(height, (0.0, 250.0), (0.0, 0.0))
    distance, z = extract_profile(height, (0.0, 0.0), (295.0, 245.0))  # corner to corner: inside
    assert distance[-1] == pytest.approx(np.hypot(295.0, 245.0)) and z[-1] == pytest.approx(590.0)


@pytest.mark.parametrize("vertical", [False, True])
def test_profile_band_averages_across_the_line(vertical):
    """Along the floor of a V valley z = 3 |d| (d the distance from a grid line; bilinear
    interpolation is exact there), the band of width w averages 3 |o| over its offsets o
    (one per pixel spacing across the line, from -w/2 to w/2): the line alone reads 0. A
    profile of zero length reads the band across the x axis."""
    pixel, width = 4.0, 40.0
    r, c = np.mgrid[:60, :70] * pixel
    d = (c - 30 * pixel) if vertical else (r - 25 * pixel)
    height = HeightMap(3.0 * np.abs(d), pixel)
    start, end = ((120.0, 20.0), (120.0, 200.0)) if vertical else ((20.0, 100.0), (240.0, 100.0))
    offsets = np.linspace(-width / 2, width / 2, 11)
    _, floor = extract_profile(height, start, end, width_um=0.0)
    _, band = extract_profile(height, start, end, width_um=width)
    np.testing.assert_allclose(floor, 0.0, atol=1e-9)
    np.testing.assert_allclose(band, 3.0 * np.abs(offsets).mean(), atol=1e-9)
    if not vertical:
        _, point = extract_profile(height, (60.0, 100.0), (60.0, 100.0), width_um=width)
        np.testing.assert_allclose(point, 3.0 * np.abs(offsets).mean(), atol=1e-9)


def test_gaussian_highpass_keeps_roughness_and_removes_form():
    from skintopo.filters import gaussian_highpass

    rows, columns = np.mgrid[:80, :400]
    roughness = 2.0 * np.sin(2 * np.pi * columns / 20)  # 40 um wavelength at 2 um pixels, lambda_c = 800 um
    form = 0.05 * columns + 0.02 * rows  # a plane: first-order regression removes it exactly (curvature c leaves c sigma^2)
    high = gaussian_highpass(HeightMap(form + roughness, 2.0), 800.0)
    interior = (slice(10, -10), slice(100, 300))
    assert np.abs(high.z[interior] - roughness[interior]).max() < 0.05
    mask = np.ones(form.shape, bool)
    mask[30:50, 180:220] = False  # finite garbage under the mask must not count, and stays masked
    garbage = np.where(mask, form + roughness, 500.0)
    masked = gaussian_highpass(HeightMap(garbage, 2.0, mask), 800.0)
    np.testing.assert_array_equal(masked.mask, mask)
    assert np.abs(masked.z[interior][mask[interior]] - roughness[interior][mask[interior]]).max() < 0.05


@pytest.mark.parametrize("factor, offset, shape", [(4, 1.5, (41, 37)), (3, 0.0, (30, 31)), (5, 2.0, (5, 12))])
def test_bilinear_resize_matches_map_coordinates_at_the_same_points(factor, offset, shape):
    """The separable resize against scipy's general bilinear interpolation (mode "nearest")
    at the points (i - offset) / factor, edges included (one coarse row: constant down)."""
    from skintopo.filters import bilinear_resize

    coarse = np.random.default_rng(2).normal(size=(-(-shape[0] // factor) if shape[0] > 5 else 1, -(-shape[1] // factor)))
    rows, columns = np.meshgrid((np.arange(shape[0]) - offset) / factor, (np.arange(shape[1]) - offset) / factor, indexing="ij")
    expected = scipy.ndimage.map_coordinates(coarse, [rows, columns], order=1, mode="nearest")
    np.testing.assert_allclose(bilinear_resize(coarse, shape, factor, offset), expected, rtol=0, atol=1e-12)


def test_ellipse_axes_are_scikit_images_for_every_label():
    """Areas and ellipse axes of all labels at once against regionprops, label by label: a
    random label image (specks, single pixels, lines, blobs) and an absent label."""
    import skimage.measure

    from skintopo.filters import ellipse_axes

    rng = np.random.default_rng(4)
    labels = skimage.measure.label(rng.random((80, 90)) > 0.6)
    labels[5, 5:40] = labels.max() + 2  # a line, and one label number left unused
    area, major, minor = ellipse_axes(labels)
    for region in skimage.measure.regionprops(labels):
        assert area[region.label] == region.area
        assert major[region.label] == pytest.approx(region.axis_major_length, rel=1e-9, abs=1e-9)
        assert minor[region.label] == pytest.approx(region.axis_minor_length, rel=1e-9, abs=1e-9)
    assert area[labels.max() - 1] == 0 and major[labels.max() - 1] == 0


def test_block_mean_against_a_padded_reshape():
    rng = np.random.default_rng(7)
    for shape, factor in (((64, 48), 4), ((67, 45), 4), ((10, 9), 3), ((5, 5), 1)):
        image = rng.normal(size=shape)
        rows, columns = -(-shape[0] // factor), -(-shape[1] // factor)
        padded = np.zeros((rows * factor, columns * factor))
        padded[: shape[0], : shape[1]] = image
        expected = padded.reshape(rows, factor, columns, factor).mean(axis=(1, 3))
        np.testing.assert_allclose(block_mean(image, factor), expected, rtol=1e-14, atol=1e-15)


@pytest.mark.parametrize("factor", [1, 2, 3, 4])
def test_block_mean_of_a_float32_stack_trimmed_to_whole_blocks(factor):
    stack = np.random.default_rng(factor).random((3, 37, 50)).astype(np.float32)
    rows, columns = 37 // factor * factor, 50 // factor * factor
    expected = stack[:, :rows, :columns].reshape(3, rows // factor, factor, columns // factor, factor).mean(axis=(2, 4))
    found = block_mean(stack, factor, "trim")
    assert found.shape == expected.shape and found.dtype == np.float32
    np.testing.assert_allclose(found, expected, rtol=1e-6)


@pytest.mark.parametrize("factor", [0.5, 1.0, 3.0])
def test_profile_filter_transmission_ends_and_gaps(factor):
    """ISO 16610-21 in one dimension: a sinusoid is transmitted by exp(-pi (alpha lambda_c /
    lambda)^2) (50% at lambda_c); a straight line passes unchanged up to both ends and across a
    gap (first-order regression); NaN points are left out and a lone point keeps its value."""
    pixel, cutoff = 2.0, 400.0
    x = np.arange(3000) * pixel
    wavelength = cutoff * factor
    low = profile_gaussian_filter(10 * np.sin(2 * np.pi * x / wavelength), pixel, cutoff)
    interior = slice(1000, 2000)
    assert sinusoid_amplitude(low[interior], x[interior], wavelength) / 10 == pytest.approx(
        gaussian_transmission(wavelength, cutoff), abs=0.005 * max(gaussian_transmission(wavelength, cutoff), 0.01) + 1e-4)
    line = 0.3 * x - 5.0
    line[1200:1300] = np.nan
    np.testing.assert_allclose(profile_gaussian_filter(line, pixel, cutoff), 0.3 * x - 5.0, atol=1e-8)
    lone = np.full(200, np.nan)
    lone[50] = 4.0
    assert profile_gaussian_filter(lone, pixel, cutoff)[50] == pytest.approx(4.0)
    with pytest.raises(SkinTopoError, match="cut-off must be positive, got 0 um"):
        profile_gaussian_filter(line, pixel, 0)


def test_band_pass_transmission_is_the_difference_of_the_two_low_passes():
    """Band-pass (lambda_s, lambda_c) of a sinusoid: T(lambda; lambda_s) - T(lambda; lambda_c),
    about 0.94 - 0.06 at the geometric mean of the cut-offs here; a plane is removed."""
    pixel, short, long = 5.0, 250.0, 2500.0
    wavelength = np.sqrt(short * long)
    x = np.arange(1600) * pixel
    z = 4 * np.sin(2 * np.pi * x / wavelength)[None, :] * np.ones((6, 1)) + 0.01 * x[None, :]
    band = gaussian_bandpass(HeightMap(z, pixel), short, long).z
    interior = slice(500, 1100)
    expected = gaussian_transmission(wavelength, short) - gaussian_transmission(wavelength, long)
    assert sinusoid_amplitude(band[3, interior], x[interior], wavelength) / 4 == pytest.approx(expected, abs=0.005)
    with pytest.raises(SkinTopoError, match="must be below the long one"):
        gaussian_bandpass(HeightMap(z, pixel), long, short)


def test_sphere_fit_of_a_sampled_cap():
    """A cap of a sphere of radius 80 mm centred off the optical axis, sampled on a 60 x 80 grid
    of 50 x 40 um pixels (x right, y up from the map's centre, height toward the camera):
    radius and centre exact to 1e-6 relative; fewer than 4 points refused."""
    radius, centre = 80000.0, np.array([300.0, -200.0, -79000.0])
    rows, columns, dy, dx = 60, 80, 50.0, 40.0
    r, c = np.mgrid[:rows, :columns]
    x, y = (c - (columns - 1) / 2) * dx, ((rows - 1) / 2 - r) * dy
    z = centre[2] + np.sqrt(radius**2 - (x - centre[0]) ** 2 - (y - centre[1]) ** 2)
    found_radius, found_centre = sphere_fit(HeightMap(z, (dy, dx)))
    assert found_radius == pytest.approx(radius, rel=1e-6)
    np.testing.assert_allclose(found_centre, centre, rtol=0, atol=1e-6 * radius)
    sparse = np.full(z.shape, np.nan)
    sparse[0, :3] = z[0, :3]
    with pytest.raises(SkinTopoError, match="at least 4 valid points, got 3"):
        sphere_fit(HeightMap(sparse, (dy, dx)))


def test_filter_and_form_errors_name_the_problem():
    z = np.zeros((20, 20))
    with pytest.raises(SkinTopoError, match="cut-off must be positive, got 0.0 um"):
        areal_gaussian_filter(z, 1.0, 0.0)
    one_row = np.full((20, 20), np.nan)
    one_row[4] = 1.0
    with pytest.raises(SkinTopoError, match="the 20 valid points of the 20 x 20 map lie on too few rows or columns"):
        polynomial_form(one_row, 1.0, 1)


def test_a_profile_band_narrower_than_half_a_pixel_is_the_line_itself():
    pixel = 4.0
    r, c = np.mgrid[:30, :40] * pixel
    height = HeightMap(3.0 * np.abs(r - 15 * pixel), pixel)
    _, narrow = extract_profile(height, (20.0, 60.0), (120.0, 60.0), width_um=1.5)
    np.testing.assert_allclose(narrow, 0.0, atol=1e-9)
