"""Filters: ISO Gaussian transmission, form removal, line-segment closings, profiles, block means, coarse regression."""

import numpy as np
import pytest
import scipy.ndimage
import scipy.special
import scipy.stats

from skintopo.errors import SkinTopoError
from skintopo.filters import (
    areal_gaussian_filter,
    block_mean,
    extract_profile,
    gaussian_smooth,
    gaussian_transmission,
    level,
    line_segment_closing,
    line_segment_footprint,
    polynomial_form,
)
from skintopo.heightmap import HeightMap
from skintopo.synth import make_surface, preset_spec


def sinusoid_amplitude(values, x, wavelength):
    design = np.column_stack([np.sin(2 * np.pi * x / wavelength), np.cos(2 * np.pi * x / wavelength), np.ones_like(x)])
    coefficients, *_ = np.linalg.lstsq(design, values, rcond=None)
    return np.hypot(coefficients[0], coefficients[1])


@pytest.mark.parametrize("sigmas", [(3.0, 1.5), (12.0, 20.0), (25.0, 9.0)])  # direct path, then the FFT path (>= 8 px)
def test_gaussian_smooth_matches_scipy_with_different_row_and_column_widths(sigmas):
    rng = np.random.default_rng(2)
    image = np.zeros((90, 130))
    image[20:70, 30:100] = rng.normal(size=(50, 70))  # zero margins: the same as zero outside the field
    expected = scipy.ndimage.gaussian_filter(image, sigmas, mode="constant", truncate=6.0)
    np.testing.assert_allclose(gaussian_smooth(image[None], sigmas)[0], expected, atol=1e-4 * np.abs(expected).max())  # the direct path truncates at 4 sigma


def test_coarse_gaussian_regression_matches_the_full_filter_where_wrinkles_are_masked():
    """The 2.5 mm regression under a wrinkle's masked band, on block means 2 x coarser: within
    0.3 um of the full filter on a levelled simulated forehead (relief about 8 um RMS)."""
    from skintopo.filters import areal_gaussian_filter, coarse_areal_gaussian_filter, polynomial_form

    surface = make_surface(preset_spec("forehead-moderate", size_px=400), seed=1)
    mask = np.ones(surface.height.shape, bool)
    mask[150:190, 40:360] = False
    z = surface.height.z - polynomial_form(surface.height.z, 20.0, 2, mask)
    full = areal_gaussian_filter(z, 20.0, 2500.0, mask)
    coarse = coarse_areal_gaussian_filter(z, 20.0, 2500.0, mask)
    assert np.abs(coarse - full).max() < 0.3 and np.abs(coarse - full)[~mask].max() < 0.3


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


def test_polynomial_form_removal():
    rows, columns = np.mgrid[:40, :50]
    form = 0.01 * (rows - 20) ** 2 + 0.3 * columns
    np.testing.assert_allclose(polynomial_form(form, 1.0, 2), form, atol=1e-9)
    levelled = level(HeightMap(form + 5, 1.0), order=2)
    assert np.abs(levelled.z).max() < 1e-9
    with pytest.raises(SkinTopoError, match="needs at least"):
        polynomial_form(np.full((1, 2), 1.0), 1.0, 2)


@pytest.mark.parametrize("order", [1, 2, 3])
def test_polynomial_form_is_the_least_squares_fit_over_the_valid_points(order):
    rng = np.random.default_rng(order)
    z = rng.standard_normal((30, 45)) + np.mgrid[:30, :45][0] * 0.1
    mask = rng.random(z.shape) > 0.3
    z[~mask] = np.nan
    v, u = np.meshgrid(np.linspace(-1, 1, 30), np.linspace(-1, 1, 45), indexing="ij")
    basis = np.stack([u**i * v**j for i in range(order + 1) for j in range(order + 1 - i)], axis=-1)
    coefficients, *_ = np.linalg.lstsq(basis[mask], z[mask], rcond=None)  # independent: QR-based lstsq
    np.testing.assert_allclose(polynomial_form(z, 1.0, order, mask), basis @ coefficients, atol=1e-10)


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
    with pytest.raises(SkinTopoError, match="outside the map"):
        extract_profile(height, (0.0, 0.0), (1000.0, 0.0))


def test_gaussian_highpass_keeps_roughness_and_removes_form():
    from skintopo.filters import gaussian_highpass

    rows, columns = np.mgrid[:80, :400]
    roughness = 2.0 * np.sin(2 * np.pi * columns / 20)  # 40 um wavelength at 2 um pixels, lambda_c = 800 um
    form = 0.05 * columns + 0.02 * rows  # a plane: first-order regression removes it exactly (curvature c leaves c sigma^2)
    high = gaussian_highpass(HeightMap(form + roughness, 2.0), 800.0)
    interior = (slice(10, -10), slice(100, 300))
    assert np.abs(high.z[interior] - roughness[interior]).max() < 0.05


def test_block_mean_against_a_padded_reshape():
    rng = np.random.default_rng(7)
    for shape, factor in (((64, 48), 4), ((67, 45), 4), ((10, 9), 3), ((5, 5), 1)):
        image = rng.normal(size=shape)
        rows, columns = -(-shape[0] // factor), -(-shape[1] // factor)
        padded = np.zeros((rows * factor, columns * factor))
        padded[: shape[0], : shape[1]] = image
        expected = padded.reshape(rows, factor, columns, factor).mean(axis=(1, 3))
        np.testing.assert_allclose(block_mean(image, factor), expected, rtol=1e-14, atol=1e-15)
