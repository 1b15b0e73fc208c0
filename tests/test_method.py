"""The paper's method: ISO Gaussian filter, segmentation, spectral correction, evaluation, tables."""

import json

import numpy as np
import pytest
from conftest import four_lights

from skintopo.acquisition import write_acquisition
from skintopo.cli import main
from skintopo.correction import correct_slopes, spectral_correction
from skintopo.errors import SkinTopoError
from skintopo.evaluation import evaluate_height
from skintopo.registration import register_height_maps
from skintopo.filters import (
    areal_gaussian_filter,
    extract_profile,
    gaussian_transmission,
    level,
    line_segment_closing,
    line_segment_footprint,
    polynomial_form,
)
from skintopo.heightmap import HeightMap
from skintopo.normals import render_lambertian
from skintopo.segmentation import segment_wrinkles, segmentation_quality
from skintopo.synth import make_surface, preset_spec


def sinusoid_amplitude(values, x, wavelength):
    design = np.column_stack([np.sin(2 * np.pi * x / wavelength), np.cos(2 * np.pi * x / wavelength), np.ones_like(x)])
    coefficients, *_ = np.linalg.lstsq(design, values, rcond=None)
    return np.hypot(coefficients[0], coefficients[1])


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


@pytest.mark.slow
def test_segmentation_defaults_work_on_the_presets():
    """Seeds 1-6 of each preset chose the defaults (all counts exact); seeds 7-14 are held
    out (one failure allowed). With the band-pass alone it was a miss (seed 10 of the low
    state: a 50 um wrinkle whose band-passed floor stays under the 25 um seed depth); with
    the straight valleys that wrinkle is found and the failure is a false wrinkle (seed 13 of
    the low state: a chain of furrows straight at 45 degrees over 1.6 mm)."""
    failures, held_out_failures, ious = [], [], []
    for seed in range(1, 15):
        for preset, expected in (("forehead-low", 2), ("forehead-moderate", 3), ("forehead-high", 4), ("flat-microrelief", 0)):
            surface = make_surface(preset_spec(preset, size_px=256), seed=seed)
            segmentation = segment_wrinkles(surface.height)
            quality = segmentation_quality(segmentation.mask, surface.wrinkle_labels > 0)
            if segmentation.count != expected:
                (failures if seed <= 6 else held_out_failures).append((preset, seed, segmentation.count))
            if expected:
                if segmentation.count == expected:  # the missed wrinkle's field has a low IoU by construction
                    ious.append(quality["iou"])
                assert segmentation.extent[segmentation.mask].all() and segmentation.extent.sum() > segmentation.mask.sum()
    print(f"segmentation: failures {failures} (seeds 1-6), {held_out_failures} (held-out seeds 7-14); IoU min {min(ious):.2f}, mean {np.mean(ious):.2f}")
    assert not failures
    assert len(held_out_failures) <= 1
    assert np.mean(ious) > 0.7 and min(ious) > 0.55


def test_straight_valleys_find_narrow_shallow_wrinkles_the_band_pass_misses():
    """A 54 um deep, 0.27 mm wide U wrinkle reads 22 um after the band-pass (below the 25 um
    minimum): found as a straight valley, not by the band-pass alone; among furrows 20-60 um deep
    (flat microrelief, 3 fields) no straight valley is taken for a wrinkle."""
    from skintopo.synth.surfaces import SurfaceSpec, Wrinkle

    for shape, curvature in (("U", 0.0), ("V", 0.05)):
        wrinkle = Wrinkle(depth_um=54.0, width_um=273.0, length_um=4000.0, orientation_deg=8.0, shape=shape, curvature_per_mm=curvature)
        surface = make_surface(SurfaceSpec(size_px=(320, 320), wrinkles=(wrinkle,), microrelief=False), seed=0)
        assert segment_wrinkles(surface.height, straight_valley_um=0).count == 0
        found = segment_wrinkles(surface.height)
        assert found.count == 1 and segmentation_quality(found.mask, surface.wrinkle_labels > 0)["recall"] > 0.5
    for seed in range(3):
        assert segment_wrinkles(make_surface(preset_spec("flat-microrelief", size_px=320), seed=10 + seed).height).count == 0


def test_correction_is_exactly_the_papers_algorithm_on_known_slopes():
    rng = np.random.default_rng(0)
    shape = (40, 50)
    red, green, blue = ((rng.normal(size=shape) * 0.1, rng.normal(size=shape) * 0.1) for _ in range(3))
    mask = np.zeros(shape, bool)
    mask[15:25, 10:40] = True
    corrected, z_red, z_a = correct_slopes(red, green, blue, mask, 10.0, integrator="dct-poisson")
    t1 = (red[0] + (green[0] + blue[0]) / 2) / 2
    t2 = (red[1] + (green[1] + blue[1]) / 2) / 2
    from skintopo.height import dct_poisson

    expected_red = dct_poisson(*red, 10.0)
    expected_a = dct_poisson(np.where(mask, t1, red[0]), np.where(mask, t2, red[1]), 10.0)
    expected_a -= np.median((expected_a - expected_red)[~mask])
    np.testing.assert_allclose(z_red.z, expected_red)
    np.testing.assert_allclose(corrected.z, np.where(mask, np.minimum(expected_a, expected_red), expected_red))


def test_correction_needs_three_bands():
    with pytest.raises(SkinTopoError, match=r"missing \['blue'\]"):
        spectral_correction({"red": np.zeros((4, 4, 3)), "green": np.zeros((4, 4, 3))}, 1.0)


def test_registration_recovers_a_subpixel_shift():
    surface = make_surface(preset_spec("forehead-moderate", size_px=128, pixel_um=20.0), seed=4)
    import scipy.ndimage

    shifted = HeightMap(scipy.ndimage.shift(surface.height.z, (1.3, -2.6), order=3, mode="nearest"), 20.0)
    aligned, registration = register_height_maps(surface.height, shifted, rotation=False)
    assert registration.shift_px == pytest.approx((-1.3, 2.6), abs=0.02)
    assert registration.rotation_deg == 0.0 and registration.scale == 1.0
    report = evaluate_height(shifted, surface.height)
    assert report["rms_height_error_um"] < 1.0


def test_evaluation_refuses_incomparable_maps():
    a = HeightMap(np.random.default_rng(0).normal(size=(64, 64)), 10.0)
    with pytest.raises(SkinTopoError, match="different pixel sizes"):
        evaluate_height(a, HeightMap(a.z, 20.0))
    with pytest.raises(SkinTopoError, match="do not overlap"):
        evaluate_height(a, HeightMap(np.random.default_rng(1).normal(size=(64, 64)), 10.0))


@pytest.mark.slow
def test_paper_tables_command(tmp_path, capsys):
    """Deterministic tables and figures; the claims that hold in the simulator are asserted,
    and the paper's full claim (algorithm better than every band) is printed for the note."""
    out = tmp_path / "tables"
    assert main(["paper-tables", "-o", str(out)]) == 0
    printed = capsys.readouterr().out
    print(printed)
    for name in ("table1_rms_height_error", "table2_l2_normal_error", "table_wrinkle_depth_error"):
        assert (out / f"{name}.csv").exists() and (out / f"{name}.md").exists()
    for figure in ("figure3_cross_section_per_band.png", "figure5_algorithm_vs_truth.png"):
        assert (out / figure).stat().st_size > 10_000

    def read(name):
        lines = (out / f"{name}.csv").read_text().splitlines()
        header = lines[0].split(",")
        return [dict(zip(header, line.split(","))) for line in lines[1:]]

    table1, depth = read("table1_rms_height_error"), read("table_wrinkle_depth_error")
    for row in table1:
        assert float(row["algorithm"]) < float(row["red"])  # the algorithm improves on red, every subject
    improvements = [1 - float(row["algorithm"]) / float(row["red"]) for row in depth]
    print("wrinkle depth error improvement over red per subject:", np.round(improvements, 3))
    assert np.mean(improvements) >= 0.30  # the bar, at the default size
    # Determinism: the same command gives the same table.
    assert main(["paper-tables", "-o", str(tmp_path / "again"), "-q"]) == 0
    assert (tmp_path / "again" / "table1_rms_height_error.csv").read_text() == (out / "table1_rms_height_error.csv").read_text()


def test_correct_and_evaluate_commands(tmp_path, capsys):
    acquisition = tmp_path / "acq"
    assert main(["synth", "-o", str(acquisition), "--preset", "forehead-moderate", "--size", "128", "-q"]) == 0
    assert main(["correct", str(acquisition), "-o", str(tmp_path / "corr"), "-q"]) == 0
    summary = json.loads((tmp_path / "corr" / "summary.json").read_text())
    assert summary["options"]["height"]["method"] == "paper" and summary["wrinkles_found"] >= 1
    for name in ("height.x3p", "wrinkles.png", "red/height.x3p", "white/height.x3p"):
        assert (tmp_path / "corr" / name).exists()
    report = tmp_path / "evaluation.json"
    args = ["evaluate", str(tmp_path / "corr" / "height.x3p"), str(acquisition / "ground_truth" / "height.x3p"), "-o", str(report)]
    assert main(args + ["--wrinkles", str(acquisition / "ground_truth" / "wrinkles.png")]) == 0
    data = json.loads(report.read_text())
    assert data["rms_height_error_um"] > 0 and len(data["wrinkle_max_depth_um"]) == 3
    assert main(args) == 2 and "exists" in capsys.readouterr().err


def test_correct_refuses_an_acquisition_without_red_green_blue(tmp_path, capsys):
    normals = np.dstack([np.zeros((20, 20)), np.zeros((20, 20)), np.ones((20, 20))])
    lights = four_lights()
    write_acquisition(tmp_path / "white", {"white": (render_lambertian(normals, 0.5, lights), lights)}, 20.0)
    assert main(["correct", str(tmp_path / "white"), "-o", str(tmp_path / "out"), "-q"]) == 2
    err = capsys.readouterr().err
    assert "needs red, green and blue images; missing ['red', 'green', 'blue']" in err
    assert not (tmp_path / "out").exists()


def test_gaussian_highpass_keeps_roughness_and_removes_form():
    from skintopo.filters import gaussian_highpass

    rows, columns = np.mgrid[:80, :400]
    roughness = 2.0 * np.sin(2 * np.pi * columns / 20)  # 40 um wavelength at 2 um pixels, lambda_c = 800 um
    form = 0.05 * columns + 0.02 * rows  # a plane: first-order regression removes it exactly (curvature c leaves c sigma^2)
    high = gaussian_highpass(HeightMap(form + roughness, 2.0), 800.0)
    interior = (slice(10, -10), slice(100, 300))
    assert np.abs(high.z[interior] - roughness[interior]).max() < 0.05
