"""Filters against independent computations (scipy.ndimage, closed forms)."""

import numpy as np
import pytest
import scipy.ndimage

from skintopo.filters import gaussian_smooth


@pytest.mark.parametrize("sigmas", [(3.0, 1.5), (12.0, 20.0), (25.0, 9.0)])  # direct path, then the FFT path (>= 8 px)
def test_gaussian_smooth_matches_scipy_with_different_row_and_column_widths(sigmas):
    rng = np.random.default_rng(2)
    image = np.zeros((90, 130))
    image[20:70, 30:100] = rng.normal(size=(50, 70))  # zero margins: the same as zero outside the field
    expected = scipy.ndimage.gaussian_filter(image, sigmas, mode="constant", truncate=6.0)
    np.testing.assert_allclose(gaussian_smooth(image[None], sigmas)[0], expected, atol=1e-4 * np.abs(expected).max())  # the direct path truncates at 4 sigma
