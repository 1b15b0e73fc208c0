"""Surface texture parameters against closed forms, surfalize, and Gwyddion."""

import numpy as np
import pytest
import scipy.ndimage
import scipy.special
import scipy.stats

from skintopo.errors import SkinTopoError
from skintopo.heightmap import HeightMap
from skintopo.texture import Parameter, measure_texture, parameter_note, parameters_by_name
from skintopo.texture.areal import (
    MaterialRatio,
    autocorrelation,
    functional_parameters,
    height_parameters,
    hybrid_parameters,
    spatial_parameters,
)
from skintopo.texture.fractal import ESTIMATORS, fractal_dimension, power_spectrum
from skintopo.texture.profile import line_profile_parameters, profile_parameters
from tests.helpers.analytic import fbm
from tests.helpers.gwyddion_oracle import available as gwyddion_available
from tests.helpers.gwyddion_oracle import fractal as gwyddion_fractal
from tests.helpers.gwyddion_oracle import row_psdf as gwyddion_row_psdf

A = 3.0  # amplitude, um


def sinusoid_map(period_px=32, periods=8, pixel=2.0, rows=16):
    x = np.arange(period_px * periods) * pixel
    k = 2 * np.pi / (period_px * pixel)
    return HeightMap(A * np.sin(k * x)[None, :] * np.ones((rows, 1)), pixel), k


SURFALIZE_PARAMETERS_EXACT = ("Sa", "Sq", "Ssk", "Sku", "Sp", "Sv", "Sz", "Sdq", "Sdr")


def comparison_surfaces():
    rng = np.random.default_rng(11)
    y, x = np.mgrid[:200, :240].astype(float)
    from skintopo.synth import make_surface, preset_spec

    return {
        "gaussian-noise": rng.normal(size=(200, 240)),
        "fbm-H0.7": fbm(256, 0.7, 2)[:200, :240] * 40,
        "sinusoid-grid": 4 * np.sin(2 * np.pi * x / 30) * np.cos(2 * np.pi * y / 45) + 0.2 * rng.normal(size=x.shape),
        "grooves-30deg": 5 * np.sin(2 * np.pi * (x * np.cos(0.5) + y * np.sin(0.5)) / 25) + 0.1 * rng.normal(size=x.shape),
        "forehead-moderate": make_surface(preset_spec("forehead-moderate", size_px=(200, 240)), seed=3).height.z,
    }


def _reference_fractal_points(z, method):
    """The definitions of shared/reference/fractal-methods.md written out directly (one
    level at a time, whole arrays, scipy's bilinear resampling, Heron's formula): an
    independent check of the blocked, pooled implementation when Gwyddion is absent."""
    rows, columns = z.shape
    k = int(round(np.log2(columns)))
    n = 2**k + 1
    coords = [((np.arange(n) + 0.5) * size / n - 0.5).clip(0, size - 1) for size in (rows, columns)]
    z = scipy.ndimage.map_coordinates(z, np.meshgrid(*coords, indexing="ij"), order=1, mode="nearest")
    size, h = 2**k, z.max() - z.min()
    xs, ys = [], []
    if method == "partitioning":
        for level in range(1, k):
            r = 2**level
            c = size // r - 1
            tiles = z[: c * r, : c * r].reshape(c, r, c, r)
            xs.append(np.log(r))
            ys.append(np.log(tiles.var(axis=(1, 3)).mean()))
    elif method == "cube-counting":
        shifted = z - z.min()
        for level in range(k):
            m = 2 ** (level + 1)
            s, eps = size // m, h / m
            count = 0.0
            for i in range(m):
                for j in range(m):
                    column = shifted[i * s : (i + 1) * s + 1, j * s : (j + 1) * s + 1]
                    count += m - np.floor(column.min() / eps) - np.floor((h - column.max()) / eps)
            xs.append((level + 1 - k) * np.log(2))
            ys.append(np.log(count))
    else:  # triangulation
        scaled = z * (size / h)

        def heron(p, q, r):
            a, b, c = np.linalg.norm(q - p, axis=-1), np.linalg.norm(r - q, axis=-1), np.linalg.norm(p - r, axis=-1)
            half = (a + b + c) / 2
            return np.sqrt(np.maximum(half * (half - a) * (half - b) * (half - c), 0.0))

        for level in range(k + 1):
            s = size // 2**level
            i, j = np.meshgrid(np.arange(0, size, s), np.arange(0, size, s), indexing="ij")
            point = lambda di, dj: np.stack([(i + di) * 1.0, (j + dj) * 1.0, scaled[i + di, j + dj]], axis=-1)
            area = heron(point(0, 0), point(s, 0), point(0, s)) + heron(point(s, s), point(s, 0), point(0, s))
            xs.append((level - k) * np.log(2))
            ys.append(np.log(area.sum()))
    return np.array(xs), np.array(ys)


def test_height_parameters_of_a_sinusoid_are_exact():
    period = 32
    height, _ = sinusoid_map(period_px=period)
    p = height_parameters(height)
    # N samples per period: mean |sin| = (2/N) cot(pi/N) exactly (-> 2/pi as N grows); mean sin^2 = 1/2
    expected = {"Sa": A * 2 / period / np.tan(np.pi / period), "Sq": A / np.sqrt(2), "Sku": 1.5, "Sp": A, "Sv": A, "Sz": 2 * A}
    for name, value in expected.items():
        assert p[name] == pytest.approx(value, rel=1e-9), name
    assert abs(p["Ssk"]) < 1e-9


def test_step_and_plane():
    z = np.where(np.arange(40)[None, :] < 20, -5.0, 5.0) * np.ones((10, 1))
    p = height_parameters(HeightMap(z, 1.0))
    assert (p["Sa"], p["Sq"], p["Ssk"], p["Sku"], p["Sp"], p["Sv"]) == pytest.approx((5, 5, 0, 1, 5, 5), rel=1e-12, abs=1e-12)
    rows, columns = np.mgrid[:20, :30]
    plane = measure_texture(HeightMap(0.3 * rows - 0.1 * columns + 7, 1.0), fractal_methods=())
    values = parameters_by_name(plane)
    assert abs(values["Sq"]) < 1e-9 and np.isnan(values["Ssk"]) and np.isnan(values["Sku"])  # documented: undefined at Sq = 0


def test_gaussian_random_surface_moments_match_an_independent_computation():
    z = np.random.default_rng(7).normal(2.0, 1.5, size=(300, 200)) ** 3  # skewed, heavy-tailed
    p = height_parameters(HeightMap(z, 1.0))
    centred = z - z.mean()
    assert p["Sa"] == pytest.approx(np.mean(np.abs(centred)), rel=1e-9)
    assert p["Sq"] == pytest.approx(np.std(z), rel=1e-9)
    assert p["Ssk"] == pytest.approx(scipy.stats.skew(z, axis=None), rel=1e-9)
    assert p["Sku"] == pytest.approx(scipy.stats.kurtosis(z, axis=None, fisher=False), rel=1e-9)


def test_sdq_and_sdr_of_a_sinusoid_against_closed_forms():
    period, pixel = 128, 1.0
    height, k = sinusoid_map(period_px=period, periods=6, pixel=pixel, rows=8)
    p = hybrid_parameters(height)
    # forward differences of A sin(kx): RMS (2A/dx) sin(k dx/2) / sqrt(2) exactly; continuous A k / sqrt(2)
    # forward differences over whole periods would give (2A/dx) sin(k dx/2) / sqrt(2); the n - 1
    # differences of a finite map miss one, hence the small tolerance
    assert p["Sdq"] == pytest.approx(2 * A / pixel * np.sin(k * pixel / 2) / np.sqrt(2), rel=3e-3)
    assert p["Sdq"] == pytest.approx(A * k / np.sqrt(2), rel=3e-3)
    a = A * k
    sdr = (2 / np.pi * np.sqrt(1 + a * a) * scipy.special.ellipe(a * a / (1 + a * a)) - 1) * 100
    assert p["Sdr"] == pytest.approx(sdr, rel=2e-3)  # triangulated area: O(h^2) below the true area


def test_material_ratio_and_volumes_of_a_uniform_height_distribution():
    n = 1000
    z = np.linspace(-1.0, 1.0, n * n)
    np.random.default_rng(0).shuffle(z)
    height = HeightMap(z.reshape(n, n), 1.0)
    curve = MaterialRatio(height)
    for mr in (2.5, 10, 50, 80):
        assert curve.smc(mr) == pytest.approx(1 - 2 * mr / 100, abs=1e-6)
        assert curve.smr(1 - 2 * mr / 100) == pytest.approx(mr, abs=1e-3)
    f = functional_parameters(height)
    # Vm(p) = (p/100)^2 and Vv(q) = (1 - q/100)^2 for heights uniform on [-1, 1]
    assert f["Vmp"] == pytest.approx(0.01, rel=1e-5)
    assert f["Vmc"] == pytest.approx(0.64 - 0.01, rel=1e-5)
    assert f["Vvc"] == pytest.approx(0.81 - 0.04, rel=1e-5)
    assert f["Vvv"] == pytest.approx(0.04, rel=1e-5)
    assert f["Sxp"] == pytest.approx(0.95, abs=1e-5)
    assert f["Sk"] == pytest.approx(2.0, rel=1e-5)
    assert f["Spk"] == pytest.approx(0, abs=1e-5) and f["Svk"] == pytest.approx(0, abs=1e-5)


def test_profile_parameters_of_a_sinusoid():
    period, pixel = 40, 0.5
    n = period * 10
    x = (np.arange(n) - (n - 1) / 2) * pixel  # symmetric samples: the least-squares line is exactly zero
    k = 2 * np.pi / (period * pixel)
    z = A * np.cos(k * x)
    p = profile_parameters(z, pixel)
    # exact: the sample statistics of the analytic profile (nothing may be removed from it)
    exact = {"Ra": np.mean(np.abs(z)), "Rq": np.sqrt(np.mean(z**2)), "Rku": np.mean(z**4) / np.mean(z**2) ** 2, "Rp": z.max(), "Rv": -z.min()}
    for name, value in exact.items():
        assert p[name] == pytest.approx(value, rel=1e-9), name
    # and the continuous closed forms: 2A/pi, A/sqrt(2), 1.5, A, A, 2A, 2A, A k / sqrt(2)
    closed = {"Ra": 2 * A / np.pi, "Rq": A / np.sqrt(2), "Rku": 1.5, "Rp": A, "Rv": A, "Rz": 2 * A, "Rt": 2 * A}
    for name, value in closed.items():  # samples fall half a step beside the crests: cos(pi/40) of A
        assert p[name] == pytest.approx(value, rel=5e-3), name
    # Rdq: the 7-point slopes exist only 3 samples in from each end, so compare with the RMS
    # of the analytic slope -A k sin(k x) over those samples (the formula is O(h^6) accurate)
    assert p["Rdq"] == pytest.approx(np.sqrt(np.mean((A * k * np.sin(k * x[3:-3])) ** 2)), rel=1e-6)
    assert abs(p["Rsk"]) < 1e-9


def test_profile_filter_transmission_and_line_extraction():
    pixel, cutoff = 1.0, 200.0
    x = np.arange(4000) * pixel
    wavelength = 200.0
    z = A * np.sin(2 * np.pi * x / wavelength)
    # roughness keeps 1 - 0.5 = 50% at lambda = lambda_c (away from the ends, where the
    # regression filter's end correction changes the response slightly)
    from skintopo.texture.profile import roughness_profile

    interior = roughness_profile(z, pixel, lambda_c=cutoff)[1000:3000]
    assert np.sqrt(np.mean(interior**2)) == pytest.approx(0.5 * A / np.sqrt(2), rel=5e-3)
    assert profile_parameters(z, pixel, lambda_c=cutoff)["Rq"] == pytest.approx(0.5 * A / np.sqrt(2), rel=2e-2)
    height, _ = sinusoid_map(period_px=32, periods=8, pixel=2.0, rows=16)
    along = line_profile_parameters(height, (0.0, 10.0), (2.0 * 255, 10.0), width_um=6.0)
    assert along["Rq"] == pytest.approx(A / np.sqrt(2), rel=1e-2)


@pytest.mark.parametrize("name", sorted(comparison_surfaces()))
def test_agrees_with_surfalize(name):
    surfalize = pytest.importorskip("surfalize", reason="surfalize (GPL, test-only) is not installed")
    z = comparison_surfaces()[name]
    ours = parameters_by_name(measure_texture(HeightMap(z, 1.0), level_order=None, fractal_methods=()))
    surface = surfalize.Surface(z.copy(), 1.0, 1.0)
    gaps = {}
    for parameter, value in ours.items():
        with np.errstate(all="ignore"):
            theirs = float(getattr(surface, parameter)())
        gaps[parameter] = (value, theirs, abs(value - theirs) / max(abs(theirs), 1e-12))
    print(name, {p: f"{g[2]:.1e}" for p, g in gaps.items()})
    for parameter in SURFALIZE_PARAMETERS_EXACT:
        assert gaps[parameter][2] < 1e-6, parameter
    # Documented definitional differences (see skintopo.texture.areal):
    #  - Sal: surfalize takes the crossing as the nearest of 1000 cubic samples on rays to the
    #    edge pixels of the thresholded region; we interpolate linearly along 720 rays. On white
    #    noise Sal is about one pixel and the interpolation rule shows most (3%).
    assert gaps["Sal"][2] < (0.05 if name == "gaussian-noise" else 0.02)
    #  - Std: both take the angular amplitude maximum in 0.5 degree bins; bin placement may differ
    #    by one bin. Isotropic noise has no texture direction: not compared.
    if name != "gaussian-noise":
        assert min(abs(gaps["Std"][0] - gaps["Std"][1]), 180 - abs(gaps["Std"][0] - gaps["Std"][1])) <= 1.0
    #  - material ratio curve: surfalize bins it (argclosest on a sampled curve), ours is exact;
    #    the gap is a few per cent at most on Spk/Svk, below 0.5% on the rest.
    for parameter in ("Sk", "Smr1", "Smr2", "Sxp", "Vmc", "Vvc"):
        assert gaps[parameter][2] < 5e-3, parameter
    for parameter in ("Spk", "Svk", "Vmp", "Vvv"):
        assert gaps[parameter][2] < 5e-2, parameter


@pytest.mark.skipif(not gwyddion_available(), reason="Debian's gwyddion (libgwyprocess2) is not installed: no oracle")
@pytest.mark.parametrize("method", ["partitioning", "cube-counting", "triangulation"])
@pytest.mark.parametrize("shape", [(257, 257), (200, 300), (130, 64)])
def test_fractal_estimators_match_gwyddion_exactly(method, shape):
    z = fbm(max(shape), 0.5, 1)[: shape[0], : shape[1]]
    d, x, y = gwyddion_fractal(z, method)
    ours = fractal_dimension(HeightMap(z, 1.0), method)
    np.testing.assert_allclose(ours.x, x, atol=1e-9)
    np.testing.assert_allclose(ours.y, y, atol=1e-9)
    assert ours.dimension == pytest.approx(d, abs=1e-9)


@pytest.mark.parametrize("method", ["partitioning", "cube-counting", "triangulation"])
@pytest.mark.parametrize("shape", [(257, 257), (200, 300), (130, 64)])
def test_fractal_estimators_follow_the_written_definitions(method, shape):
    z = fbm(max(shape), 0.5, 1)[: shape[0], : shape[1]]
    x, y = _reference_fractal_points(z, method)
    ours = fractal_dimension(HeightMap(z, 1.0), method)
    np.testing.assert_allclose(ours.x, x, atol=1e-12)
    np.testing.assert_allclose(ours.y, y, atol=1e-9)


def test_autocorrelation_matches_direct_sums_on_a_masked_map():
    rng = np.random.default_rng(5)
    z = rng.normal(size=(23, 31))
    mask = rng.random(z.shape) > 0.15
    values = np.where(mask, z - z[mask].mean(), 0.0)
    for max_lag in ((5, 7), None):
        acf = autocorrelation(HeightMap(z, 1.0, mask), max_lag)
        lag_y, lag_x = (22, 30) if max_lag is None else max_lag
        assert acf.shape == (2 * lag_y + 1, 2 * lag_x + 1)
        for t_y in range(-lag_y, lag_y + 1):
            for t_x in range(-lag_x, lag_x + 1):
                a = values[max(0, -t_y) : 23 - max(0, t_y), max(0, -t_x) : 31 - max(0, t_x)]
                b = values[max(0, t_y) : 23 - max(0, -t_y), max(0, t_x) : 31 - max(0, -t_x)]
                pairs = (mask[max(0, -t_y) : 23 - max(0, t_y), max(0, -t_x) : 31 - max(0, t_x)]
                         & mask[max(0, t_y) : 23 - max(0, -t_y), max(0, t_x) : 31 - max(0, -t_x)]).sum()
                expected = (a * b).sum() / pairs if pairs else np.nan
                np.testing.assert_allclose(acf[t_y + lag_y, t_x + lag_x], expected, atol=1e-12)


def test_hybrid_parameters_on_a_masked_map_match_a_direct_computation():
    """More rows than one processing block (64), rectangular pixels, holes."""
    rng = np.random.default_rng(6)
    z = rng.normal(size=(150, 40))
    mask = rng.random(z.shape) > 0.05
    dy, dx = 2.0, 1.5
    ours = hybrid_parameters(HeightMap(z, (dy, dx), mask))
    w = np.where(mask, z, np.nan)
    gx, gy = np.diff(w, axis=1) / dx, np.diff(w, axis=0) / dy
    assert ours["Sdq"] == pytest.approx(np.sqrt(np.nanmean(gx**2) + np.nanmean(gy**2)), rel=1e-12)
    # each cell: the mean of its four corner triangles, 1/2 |edge_x x edge_y| (ISO 25178-2 D.15)
    ex = [np.stack([np.full_like(g, dx), np.zeros_like(g), g * dx], -1) for g in (gx[:-1], gx[1:])]
    ey = [np.stack([np.zeros_like(g), np.full_like(g, dy), g * dy], -1) for g in (gy[:, :-1], gy[:, 1:])]
    cells = sum(0.5 * np.linalg.norm(np.cross(a, b), axis=-1) for a in ex for b in ey) / 2  # two triangulations averaged
    valid = np.isfinite(cells)
    assert ours["Sdr"] == pytest.approx((cells[valid].sum() / (valid.sum() * dx * dy) - 1) * 100, rel=1e-12)


@pytest.mark.slow
def test_fractal_bias_on_fractional_brownian_surfaces():
    table = {}
    for hurst in (0.3, 0.5, 0.7, 0.9):
        estimates = {m: np.mean([ESTIMATORS[m](HeightMap(fbm(257, hurst, s), 1.0)).dimension for s in range(6)]) for m in ESTIMATORS}
        table[hurst] = estimates
        print(f"H = {hurst}: true D = {3 - hurst:.2f}; " + ", ".join(f"{m} {d:.3f} (bias {d - 3 + hurst:+.3f})" for m, d in estimates.items()))
    # Gwyddion's behaviour on 257 x 257, H = 0.5 (field notes): 2.504, 2.353, 2.403, 2.525
    for method, quoted in (("partitioning", 2.504), ("cube-counting", 2.353), ("triangulation", 2.403), ("power-spectrum", 2.525)):
        assert table[0.5][method] == pytest.approx(quoted, abs=0.02), method
    # every estimator orders the surfaces correctly: rougher (lower H) means higher D
    for method in ESTIMATORS:
        assert table[0.3][method] > table[0.5][method] > table[0.7][method] > table[0.9][method]


@pytest.mark.skipif(not gwyddion_available(), reason="Debian's gwyddion (libgwyprocess2) is not installed: no oracle")
@pytest.mark.parametrize("shape", [(257, 257), (200, 300), (130, 64), (64, 129)])
def test_power_spectrum_matches_gwyddion_exactly(shape):
    z = fbm(max(shape), 0.5, 2)[: shape[0], : shape[1]]
    surface = HeightMap(z, 1.0)
    # Gwyddion <= 2.65 (Debian 12 ships 2.62): the curve is resampled to N points first
    d, x, y = gwyddion_fractal(z, "power-spectrum")
    legacy = power_spectrum(surface, legacy_resampling=True)
    np.testing.assert_allclose(legacy.x, x, atol=1e-9)
    np.testing.assert_allclose(legacy.y, y, atol=1e-9)
    assert legacy.dimension == pytest.approx(d, abs=1e-9)
    # Gwyddion >= 2.66 (our default): the same PSDF, not resampled, x_i = ln i against P_{i+1}
    curve = gwyddion_row_psdf(z)
    ours = power_spectrum(surface)
    np.testing.assert_allclose(ours.x, np.log(np.arange(1, curve.size)), atol=1e-12)
    np.testing.assert_allclose(ours.y, np.log(curve[1:]), atol=1e-9)
    slope = np.polyfit(np.log(np.arange(1, curve.size)), np.log(curve[1:]), 1)[0]
    assert ours.dimension == pytest.approx(3.5 + slope / 2, abs=1e-9)


def test_power_spectrum_reproduces_the_quoted_gwyddion_figure():
    """Field notes: Gwyddion gives 2.525 on a 257 x 257 fBm surface with H = 0.5."""
    mean = np.mean([ESTIMATORS["power-spectrum"](HeightMap(fbm(257, 0.5, s), 1.0)).dimension for s in range(6)])
    assert mean == pytest.approx(2.525, abs=0.02)


def test_bad_inputs():
    with pytest.raises(SkinTopoError, match="no valid points"):
        measure_texture(HeightMap(np.full((20, 20), np.nan), 1.0))
    with pytest.raises(SkinTopoError, match="at least 8 columns"):
        fractal_dimension(HeightMap(np.random.default_rng(0).normal(size=(5, 5)), 1.0), "partitioning")
    with pytest.raises(SkinTopoError, match="flat"):
        fractal_dimension(HeightMap(np.zeros((32, 32)), 1.0), "cube-counting")
    with pytest.raises(SkinTopoError, match="outside the map"):
        line_profile_parameters(HeightMap(np.zeros((10, 10)), 1.0), (0, 0), (50, 0))
    with pytest.raises(SkinTopoError, match="shorter than the cut-off"):
        profile_parameters(np.zeros(100), 1.0, lambda_c=800.0)
    with pytest.raises(SkinTopoError, match="unknown fractal method"):
        fractal_dimension(HeightMap(np.zeros((32, 32)), 1.0), "box")
    with pytest.raises(SkinTopoError, match="cannot be fitted.*1 x 50"):
        measure_texture(HeightMap(np.arange(50.0)[None, :], 1.0))
    # a constant map: Sq = 0, so Ssk and Sku (0/0) and the fractal dimensions are NaN, the rest is defined
    flat = parameters_by_name(measure_texture(HeightMap(np.full((32, 32), 7.0), 1.0)))
    assert flat["Sq"] < 1e-12 and flat["Sz"] < 1e-12 and abs(flat["Sdr"]) < 1e-12  # levelling round-off only
    assert np.isnan(flat["Ssk"]) and np.isnan(flat["Sku"]) and np.isnan(flat["D_cube-counting"])


def test_measure_texture_returns_the_estimators_results_on_request():
    height = HeightMap(np.random.default_rng(5).normal(size=(64, 64)), 2.0)
    parameters, fractal = measure_texture(height, return_fractal=True)
    assert parameters_by_name(parameters) == parameters_by_name(measure_texture(height))
    by_name = parameters_by_name(parameters)
    assert [r.method for r in fractal] == [name[2:] for name in by_name if name.startswith("D_")]
    assert all(by_name[f"D_{r.method}"] == r.dimension and r.x.size > 2 for r in fractal)


def test_masked_points_are_left_out():
    z = np.random.default_rng(3).normal(size=(60, 60))
    holey = z.copy()
    holey[10:20, 10:20] = 1e6  # garbage under the mask
    mask = np.ones(z.shape, bool)
    mask[10:20, 10:20] = False
    ours = height_parameters(HeightMap(holey, 1.0, mask))
    reference = height_parameters(HeightMap(np.where(mask, z, np.nan), 1.0))
    assert ours == pytest.approx(reference)
    assert ours["Sp"] < 10


def test_every_missing_or_impossible_value_has_its_reason():
    """Parallel grooves: the autocorrelation never decays along them, so Str has no value and
    says why; a flat map has no skewness; a fractal dimension outside [2, 3] is flagged and one
    inside is not."""
    grooves = {p.name: p for p in measure_texture(sinusoid_map(rows=64)[0], fractal_methods=())}
    assert np.isnan(grooves["Str"].value) and "dominant direction" in parameter_note(grooves["Str"])
    assert parameter_note(grooves["Sa"]) == ""
    flat = {p.name: p for p in measure_texture(HeightMap(np.zeros((32, 32)), 1.0), fractal_methods=())}
    assert np.isnan(flat["Ssk"].value) and "flat" in parameter_note(flat["Ssk"])
    assert "outside [2, 3]" in parameter_note(Parameter("D_power-spectrum", 1.716, "", "power spectrum"))
    assert parameter_note(Parameter("D_power-spectrum", 2.3, "", "power spectrum")) == ""
    assert parameter_note(Parameter("D_cube-counting", 3.2, "", "cube counting")).endswith(
        "(the surface is not self-affine there), so this is not a dimension of this surface")
    for bound in (2.0, 3.0):  # the closed range [2, 3]
        assert parameter_note(Parameter("D_cube-counting", bound, "", "cube counting")) == ""
    assert parameter_note(Parameter("D_triangulation", float("nan"), "", "triangulation")) == "undefined on a flat map"
    assert parameter_note(Parameter("Sxx", float("nan"), "", "")) == "undefined for this map"


def test_values_for_json_are_none_where_not_finite():
    from skintopo.texture import finite_or_none

    assert [finite_or_none(v) for v in (None, float("nan"), float("inf"), np.float64("nan"), 1.5, np.float64(2.5), 3)] == [
        None, None, None, None, 1.5, 2.5, 3]


def test_areal_power_spectrum_dimension_of_fractional_brownian_surfaces():
    """The radially averaged 2-D spectrum of an fBm surface falls as f^-(2H + 2), so
    D = (8 + slope) / 2 = 3 - H: within 0.06 on the mean of three 256 x 256 fields (their random
    amplitudes scatter single fields by about 0.07); the pixel size scales the frequencies, not
    the slope; fewer than 64 points are refused."""
    from skintopo.texture.fractal import power_spectrum_areal

    for hurst in (0.3, 0.8):
        found = [power_spectrum_areal(HeightMap(fbm(256, hurst, seed), 2.0)).dimension for seed in range(3)]
        assert np.mean(found) == pytest.approx(3 - hurst, abs=0.06)
    z = fbm(256, 0.5, 0)
    assert power_spectrum_areal(HeightMap(z, 10.0)).dimension == pytest.approx(power_spectrum_areal(HeightMap(z, 2.0)).dimension, abs=1e-9)
    with pytest.raises(SkinTopoError, match="too few valid points"):
        power_spectrum_areal(HeightMap(np.zeros((7, 9)), 1.0))


def test_fractal_results_carry_their_method_and_flat_or_empty_maps_are_named():
    """Each estimator's result names its method (the column D_<method>); on a flat map the
    estimators that need relief say so; a map with no valid point is refused by name."""
    z = fbm(64, 0.5, 1)
    for method in ESTIMATORS:
        result = fractal_dimension(HeightMap(z, 1.0), method)
        assert result.method == method and np.isfinite(result.dimension) and np.isfinite(result.intercept)
    flat = HeightMap(np.zeros((64, 64)), 1.0)
    with pytest.raises(SkinTopoError, match="^cube counting: the map is flat$"):
        ESTIMATORS["cube-counting"](flat)
    with pytest.raises(SkinTopoError, match="^triangulation: the map is flat$"):
        ESTIMATORS["triangulation"](flat)
    empty = HeightMap(np.full((64, 64), np.nan), 1.0)
    with pytest.raises(SkinTopoError, match="^the height map has no valid points$"):
        ESTIMATORS["partitioning"](empty)
    with pytest.raises(SkinTopoError, match="^the height map has no valid points$"):
        height_parameters(empty)


def test_measure_texture_passes_the_volume_ratios_on():
    """Vmp at p = 5% and Vvc/Vvv at q = 60% of heights uniform on [-1, 1] (no form to remove):
    Vm(p) = (p/100)^2, Vv(q) = (1 - q/100)^2, Vvc = Vv(p) - Vv(q)."""
    z = np.linspace(-1.0, 1.0, 400 * 400)
    np.random.default_rng(2).shuffle(z)
    values = parameters_by_name(measure_texture(HeightMap(z.reshape(400, 400), 1.0), level_order=None, p=5.0, q=60.0, fractal_methods=()))
    assert values["Vmp"] == pytest.approx(0.05**2, rel=1e-3)
    assert values["Vvv"] == pytest.approx(0.4**2, rel=1e-3)
    assert values["Vvc"] == pytest.approx(0.95**2 - 0.4**2, rel=1e-3)


@pytest.mark.parametrize("phi", [30.0, 120.0])
def test_spatial_parameters_of_an_oblique_sinusoid(phi):
    """z = sin(2 pi (x cos phi + y sin phi) / L), x right and y up: the autocorrelation is
    cos(2 pi d / L) along phi, so Sal = L acos(0.2) / (2 pi) (its fastest decay to 0.2); it never
    decays along the crests, so Str is undefined (NaN); Std = phi (within the 0.5 degree bins)."""
    rows, columns = np.mgrid[:256, :256]
    x, y = columns * 1.0, -rows * 1.0
    angle = np.radians(phi)
    z = np.sin(2 * np.pi * (x * np.cos(angle) + y * np.sin(angle)) / 16.0)
    values = spatial_parameters(HeightMap(z, 1.0))
    assert values["Sal"] == pytest.approx(16.0 * np.arccos(0.2) / (2 * np.pi), rel=0.01)
    assert np.isnan(values["Str"]) and abs(values["Std"] - phi) <= 0.5


def _relief_with_oblique_stripes(stripes):
    """Short-correlated relief (300 x 260, 2 um pixels, unit rms) plus oblique stripes of
    amplitude ``stripes`` and 150-pixel period, whose autocorrelation never decays along them."""
    rows, columns = np.mgrid[:300, :260]
    z = scipy.ndimage.gaussian_filter(np.random.default_rng(5).normal(size=(300, 260)), (3.0, 1.5))
    return HeightMap(z / z.std() + stripes * np.sin(2 * np.pi * (columns * 0.8 + rows * 0.6) / 150.0), 2.0)


@pytest.mark.parametrize("stripes", [0.0, 3.0])
def test_spatial_parameters_do_not_depend_on_the_lag_window(monkeypatch, stripes):
    """The lag window is only a speed-up: short-correlated relief (its region well inside the
    window) and the same with long oblique stripes (the circular estimate reaching its border:
    every lag at once) give the Sal, Str and Std of the autocorrelation over every lag."""
    from skintopo.texture import areal

    height = _relief_with_oblique_stripes(stripes)
    window = areal._decay_window(areal._mean_removed(height), 0.2)
    assert (window is None) == (stripes > 0)  # both paths are taken
    windowed = spatial_parameters(height)
    monkeypatch.setattr(areal, "_decay_window", lambda z, s: None)
    every_lag = spatial_parameters(height)
    assert windowed["Sal"] == pytest.approx(every_lag["Sal"], rel=1e-9)
    assert windowed["Std"] == every_lag["Std"]
    assert windowed["Str"] == pytest.approx(every_lag["Str"], rel=1e-9, nan_ok=True)


def test_fractal_estimators_fill_missing_points_from_their_nearest_neighbour():
    """Gwyddion's estimators work on complete fields: a map with missing points gives the
    dimension of the same map with each missing point set to its nearest valid neighbour's
    height (nearest found here by SciPy's exact Euclidean distance transform; the areal
    spectrum, not Gwyddion's, uses the valid points alone); two usable scales are enough for
    the log-log line."""
    from skintopo.texture.fractal import _fit

    z = fbm(64, 0.6, 3)
    mask = np.ones_like(z, dtype=bool)
    mask[10:14, 20:23] = False
    mask[40, 5] = False
    _, (rows, columns) = scipy.ndimage.distance_transform_edt(~mask, return_indices=True)
    filled = z[rows, columns]
    for method in set(ESTIMATORS) - {"power-spectrum-areal"}:
        measured = fractal_dimension(HeightMap(np.where(mask, z, np.nan), 1.0, mask), method).dimension
        assert measured == pytest.approx(fractal_dimension(HeightMap(filled, 1.0), method).dimension, abs=1e-12), method
    line = _fit("test", [0.0, 1.0, np.nan], [1.0, 3.0, 5.0], lambda slope: slope)
    assert line.dimension == pytest.approx(2.0) and line.intercept == pytest.approx(1.0)


def test_the_shortest_decay_length_alone_is_the_shortest_of_all():
    """When Str is undefined only Sal is wanted, and the decay-length search stops at the first
    block of steps in which a ray crosses: its shortest length is the one of the search over
    every ray to its end (long oblique stripes: the rays across them cross at different
    distances, those along them never), and it looked at fewer rays' ends."""
    from skintopo.texture import areal

    acf = areal.autocorrelation(_relief_with_oblique_stripes(3.0))
    centre = np.array([(acf.shape[0] - 1) // 2, (acf.shape[1] - 1) // 2])
    threshold = 0.2 * acf[centre[0], centre[1]]
    reach = np.hypot(*acf.shape) * 2.0
    every = areal._decay_lengths(acf, centre, threshold, (2.0, 2.0), 720, reach)
    shortest = areal._decay_lengths(acf, centre, threshold, (2.0, 2.0), 720, reach, shortest_only=True)
    assert np.isnan(every).any() and np.nanmax(every) > 2 * np.nanmin(every)  # a case where stopping early matters
    assert np.nanmin(shortest) == np.nanmin(every)
    assert np.isfinite(shortest).sum() < np.isfinite(every).sum()
