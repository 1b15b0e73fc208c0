"""Integration of normals and slopes to heights on analytic surfaces."""

import numpy as np
import pytest
import scipy.ndimage

from skintopo import height as height_module
from skintopo.errors import SkinTopoError
from skintopo.height import (
    INTEGRATORS,
    dct_poisson,
    edge_differences,
    fill_from_nearest,
    nearest_valid_index,
    frankot_chellappa,
    height_normals,
    integrate_normals,
    integrate_slopes,
    masked_least_squares,
    normals_to_gradients,
)
from skintopo.heightmap import HeightMap
from tests.helpers.analytic import SURFACES, nonperiodic_sinusoid, normals_from_slopes, paraboloid_with_wrinkles, rms_error_after_offset

SPACING = 10.0


@pytest.mark.parametrize("surface", sorted(SURFACES))
@pytest.mark.parametrize("method", sorted(INTEGRATORS))
def test_integrator_rms_error_on_analytic_surfaces(surface, method):
    z, p, q = SURFACES[surface]()
    estimate = INTEGRATORS[method](p, q, SPACING)
    relative = rms_error_after_offset(estimate, z) / np.ptp(z)
    print(f"{method:>18} on {surface:<22}: RMS error {relative:.2e} of the height range ({np.ptp(z):.0f} um)")
    if method == "frankot-chellappa":
        assert relative < 0.1  # see the boundary test below: periodic assumption
    else:
        assert relative <= 1e-4


@pytest.mark.parametrize("surface", sorted(SURFACES))
def test_default_integration_from_normals_within_1e_4_of_range(surface):
    z, p, q = SURFACES[surface]()
    height = integrate_normals(normals_from_slopes(p, q), SPACING)
    assert isinstance(height, HeightMap) and height.spacing == (SPACING, SPACING)
    assert rms_error_after_offset(height.z, z) <= 1e-4 * np.ptp(z)


def test_frankot_chellappa_boundary_error_is_its_known_weakness():
    """Periodic Fourier basis on a non-periodic field: the error sits at the border."""
    z, p, q = nonperiodic_sinusoid()
    fc = frankot_chellappa(p, q, SPACING)
    dct = dct_poisson(p, q, SPACING)
    fc_error = np.abs(fc - fc.mean() - (z - z.mean()))
    border = np.zeros(z.shape, bool)
    border[:5], border[-5:], border[:, :5], border[:, -5:] = True, True, True, True
    rms_fc = rms_error_after_offset(fc, z)
    rms_dct = rms_error_after_offset(dct, z)
    print(f"non-periodic sinusoid RMS error: Frankot-Chellappa {rms_fc:.3g} um, DCT-Poisson {rms_dct:.3g} um")
    assert rms_fc > 1000 * rms_dct
    assert fc_error[border].mean() > 3 * fc_error[~border].mean()


def test_frankot_chellappa_keeps_the_mean_tilt():
    rows, columns = 40, 60
    p = np.full((rows, columns), 0.25)
    q = np.full((rows, columns), -0.1)
    z = frankot_chellappa(p, q, (2.0, 3.0))
    x = np.arange(columns) * 3.0
    y = -np.arange(rows)[:, None] * 2.0
    np.testing.assert_allclose(z - z.mean(), (0.25 * x - 0.1 * y) - (0.25 * x - 0.1 * y).mean(), atol=1e-9)


def test_edge_differences_are_fourth_order():
    errors = []
    for n in (20, 40):
        x = np.linspace(0, 2, n)
        h = x[1] - x[0]
        slope = np.cos(3 * x) * 3  # d/dx sin(3x)
        exact = np.diff(np.sin(3 * x))
        errors.append(np.abs(edge_differences(slope * h, axis=0) - exact).max())
    order = np.log2(errors[0] / errors[1])
    assert order > 4.5  # local error O(h^5), global O(h^4)


@pytest.mark.parametrize("solver", ["dct-preconditioned-cg", "multigrid"])
def test_masked_least_squares_on_a_disc_with_two_regions(solver, monkeypatch):
    import pyamg

    if solver == "multigrid":  # the fallback, as if CG had not converged
        monkeypatch.setattr(height_module, "_dct_preconditioned_cg", lambda *args: None)
    else:  # the fast path must not need multigrid on a disc
        monkeypatch.setattr(pyamg, "smoothed_aggregation_solver", None)
    z, p, q = paraboloid_with_wrinkles()
    rows, columns = z.shape
    r, c = np.mgrid[:rows, :columns]
    disc = (r - 60) ** 2 + (c - 50) ** 2 < 40**2
    island = (r - 60) ** 2 + (c - 125) ** 2 < 15**2
    mask = disc | island
    mask[5, 5] = True  # a region of one pixel: its height is its mean, 0
    estimate = masked_least_squares(p, q, SPACING, mask)
    assert np.isnan(estimate[~mask]).all() and np.isfinite(estimate[mask]).all()
    assert estimate[5, 5] == 0.0
    for region in (disc, island):
        assert rms_error_after_offset(estimate, z, region) <= 1e-4 * np.ptp(z[region])
        assert abs(estimate[region].mean()) < 1e-9  # each region: mean zero (offset unknowable)


def test_masked_least_squares_falls_back_to_multigrid_on_thin_strips(monkeypatch):
    """A comb of 1-pixel columns joined by rows: the rectangle's DCT solve is a poor
    preconditioner there, CG does not converge in DCT_CG_MAX_ITERATIONS, multigrid solves it."""
    import pyamg

    calls = []
    solver = pyamg.smoothed_aggregation_solver
    monkeypatch.setattr(pyamg, "smoothed_aggregation_solver", lambda *args, **kwargs: calls.append(1) or solver(*args, **kwargs))
    z, p, q = paraboloid_with_wrinkles()
    comb = np.zeros(z.shape, bool)
    comb[:, ::3] = True
    comb[::40, :] = True
    estimate = masked_least_squares(p, q, SPACING, comb)
    assert calls == [1]
    assert np.isnan(estimate[~comb]).all()
    assert rms_error_after_offset(estimate, z, comb) <= 1e-3 * np.ptp(z[comb])


def test_auto_integrator_uses_the_mask():
    z, p, q = paraboloid_with_wrinkles()
    normals = normals_from_slopes(p, q)
    normals[:10, :10] = np.nan  # a hole: DCT would fill it with zero slope
    height = integrate_normals(normals, SPACING)
    assert not height.mask[:10, :10].any()
    assert rms_error_after_offset(height.z, z, height.mask) <= 1e-4 * np.ptp(z)


def test_auto_integrator_bridges_holes_in_fields_too_big_for_least_squares():
    """Above 2048 x 2048 pixels a hole of 40 x 40 pixels no longer sends auto to the
    multigrid least squares (70 s at 4 MP): it is bridged and integrated by DCT, stays
    masked, and the valid pixels keep the analytic surface (measured: 1.0e-5 of its range)."""
    n = 2050
    y, x = np.mgrid[0:n, 0:n] * (2 * np.pi / n)
    z = 50 * np.sin(3 * x + 0.4) * np.cos(2 * y)  # um on 1 um pixels
    p = 150 * np.cos(3 * x + 0.4) * np.cos(2 * y) * (2 * np.pi / n)
    q = 100 * np.sin(3 * x + 0.4) * np.sin(2 * y) * (2 * np.pi / n)  # dz/dy with y up = -dz/drow
    p[800:840, 1200:1240] = np.nan
    height = integrate_slopes(p, q, 1.0)
    assert not height.mask[800:840, 1200:1240].any() and height.mask.sum() == n * n - 1600
    assert rms_error_after_offset(height.z, z, height.mask) <= 1e-3 * np.ptp(z)


def test_normals_to_gradients_sign_convention():
    # A surface rising to the right (+x) and up (+y) tilts its normal to -x and -y.
    normals = normals_from_slopes(np.full((2, 2), 0.5), np.full((2, 2), 0.25))
    assert (normals[..., 0] < 0).all() and (normals[..., 1] < 0).all()
    p, q = normals_to_gradients(normals)
    np.testing.assert_allclose(p, 0.5)
    np.testing.assert_allclose(q, 0.25)
    # and the height grows to the right and toward the top row
    z = integrate_normals(normals_from_slopes(np.full((5, 5), 0.5), np.full((5, 5), 0.25)), 1.0).z
    assert z[0, -1] > z[-1, 0] and z[2, 4] > z[2, 0] and z[0, 2] > z[4, 2]


def test_unknown_integrator_is_refused():
    with pytest.raises(SkinTopoError, match="unknown integrator"):
        integrate_normals(np.dstack([np.zeros((3, 3)), np.zeros((3, 3)), np.ones((3, 3))]), 1.0, method="magic")


def test_frankot_chellappa_is_exact_on_periodic_surfaces_and_has_mean_zero():
    """On a field-periodic surface the Fourier basis is exact: one period down the rows and two
    across the columns come back to 1e-9 from their analytic slopes (the spectral derivative of
    a sampled sinusoid is its derivative), with the documented mean zero; with a tilt added, the
    plane too, still with mean zero."""
    rows, columns, dy, dx = 48, 64, 2.0, 3.0
    r, c = np.mgrid[:rows, :columns]
    ky, kx = 2 * np.pi / (rows * dy), 2 * 2 * np.pi / (columns * dx)
    y, x = -r * dy, c * dx  # y up
    z = 5.0 * np.cos(ky * y) + 3.0 * np.sin(kx * x)
    p, q = 3.0 * kx * np.cos(kx * x), -5.0 * ky * np.sin(ky * y)
    found = frankot_chellappa(p, q, (dy, dx))
    np.testing.assert_allclose(found, z - z.mean(), atol=1e-9)
    tilted = frankot_chellappa(p + 0.2, q - 0.1, (dy, dx))
    plane = 0.2 * x - 0.1 * y
    assert abs(tilted.mean()) < 1e-9
    np.testing.assert_allclose(tilted - found, plane - plane.mean(), atol=1e-9)


def test_edge_differences_at_field_ends_and_mask_borders_are_exact_for_quadratic_slopes():
    """Quadratic slopes: the one-sided rules (field ends, both sides of a NaN gap) and the
    centred rule are all exact; an edge touching the gap is NaN; two samples take the
    trapezoid rule."""
    x = np.arange(12.0)
    slope = 0.3 * x**2 - x + 2  # z = 0.1 x^3 - x^2 / 2 + 2 x
    height = 0.1 * x**3 - x**2 / 2 + 2 * x
    gapped = slope.copy()
    gapped[5] = np.nan
    exact = np.diff(height)
    found = edge_differences(gapped, axis=0)
    assert np.isnan(found[4]) and np.isnan(found[5])
    np.testing.assert_allclose(np.delete(found, [4, 5]), np.delete(exact, [4, 5]), atol=1e-12)
    np.testing.assert_allclose(edge_differences(np.array([[1.0, 2.0], [3.0, 6.0]]), axis=0), [[2.0, 4.0]])
    np.testing.assert_allclose(edge_differences(slope[:3], axis=0), exact[:2], atol=1e-12)  # three samples: one-sided rules
    np.testing.assert_allclose(edge_differences(np.stack([slope, slope]), axis=1), np.stack([exact, exact]), atol=1e-12)


def test_height_normals_of_a_plane():
    """z = 0.3 x + 0.2 y (x right, y up; rows run down): n = (-0.3, -0.2, 1) / |.| everywhere,
    edges included, on rectangular pixels."""
    rows, columns, dy, dx = 10, 14, 2.0, 5.0
    r, c = np.mgrid[:rows, :columns]
    z = 0.3 * c * dx + 0.2 * (-r * dy)
    expected = np.array([-0.3, -0.2, 1.0]) / np.linalg.norm([-0.3, -0.2, 1.0])
    np.testing.assert_allclose(height_normals(z, (dy, dx)), np.broadcast_to(expected, (rows, columns, 3)), atol=1e-12)


@pytest.mark.parametrize("share", [0.0005, 0.01])
def test_nearest_valid_index_finds_pixels_as_near_as_the_distance_transform(share):
    """Sparse holes (the k-d tree among the valid pixels touching a hole) and denser ones
    (the distance transform): every hole pixel's chosen pixel is valid and exactly as near
    as the Euclidean distance transform's (ties may differ); valid pixels point to
    themselves."""
    rng = np.random.default_rng(5)
    valid = rng.random((300, 400)) > share
    valid[100:112, 50:90] = False  # a larger hole too
    valid[0:4, 0:4] = False  # in a corner
    rows, columns = nearest_valid_index(valid)
    reference = scipy.ndimage.distance_transform_edt(~valid, return_distances=True)
    r, c = np.indices(valid.shape)
    np.testing.assert_allclose(np.hypot(rows - r, columns - c), reference, atol=1e-12)
    assert valid[rows, columns].all()
    assert (rows[valid] == r[valid]).all() and (columns[valid] == c[valid]).all()


def test_fill_from_nearest_bridges_holes_with_the_nearest_valid_value():
    valid = np.ones((5, 6), bool)
    a, b = np.arange(30.0).reshape(5, 6), -np.arange(30.0).reshape(5, 6)
    same = fill_from_nearest(valid, a, b)
    assert same[0] is a and same[1] is b  # nothing missing: the arrays themselves
    valid[2, 2:4] = False
    filled, = fill_from_nearest(valid, a)
    assert filled[2, 2] in (a[1, 2], a[3, 2], a[2, 1]) and filled[2, 3] in (a[1, 3], a[3, 3], a[2, 4])  # a nearest one
    assert np.array_equal(filled[valid], a[valid])


@pytest.mark.parametrize("method", ["dct-poisson", "frankot-chellappa"])
def test_whole_field_integrators_leave_missing_slopes_missing(method):
    """A missing slope (NaN) in either component is a missing height there, and the rest of the
    field is still integrated (the missing slopes count as 0)."""
    z, p, q = paraboloid_with_wrinkles()
    p, q = p.copy(), q.copy()
    p[10, 12] = np.nan
    q[30, 40] = np.nan
    found = integrate_slopes(p, q, SPACING, method=method).z
    assert np.isnan(found[10, 12]) and np.isnan(found[30, 40]) and np.isfinite(found).sum() == found.size - 2
