"""Registration of height maps: sub-pixel shifts and rotations recovered."""

import numpy as np
import pytest
import scipy.ndimage

from skintopo.evaluation import evaluate_height
from skintopo.heightmap import HeightMap
from skintopo.registration import register_height_maps
from skintopo.synth import make_surface, preset_spec
from tests.helpers.transforms import transformed_view


@pytest.mark.parametrize("angle, shift", [(3.7, (1.3, -2.6)), (-5.0, (0.4, 0.7)), (0.8, (-3.25, 2.1))])
def test_registration_recovers_subpixel_shift_and_rotation(angle, shift):
    big = make_surface(preset_spec("forehead-moderate", size_px=384), seed=3).height.z
    baseline = HeightMap(transformed_view(big, 256, 64, 0.0, (0, 0)), 20.0)
    follow_up = HeightMap(transformed_view(big, 256, 64, angle, shift), 20.0)
    _, registration = register_height_maps(baseline, follow_up)
    print(f"true ({shift[0]}, {shift[1]}) px, {angle} deg -> ({registration.shift_px[0]:.3f}, {registration.shift_px[1]:.3f}) px, "
          f"{registration.rotation_deg:.4f} deg, residual {registration.residual_px:.3f} px")
    assert np.allclose(registration.shift_px, shift, atol=0.1)
    assert registration.rotation_deg == pytest.approx(angle, abs=0.05)


def test_registration_recovers_a_subpixel_shift():
    surface = make_surface(preset_spec("forehead-moderate", size_px=128, pixel_um=20.0), seed=4)
    import scipy.ndimage

    shifted = HeightMap(scipy.ndimage.shift(surface.height.z, (1.3, -2.6), order=3, mode="nearest"), 20.0)
    aligned, registration = register_height_maps(surface.height, shifted, rotation=False)
    assert registration.shift_px == pytest.approx((-1.3, 2.6), abs=0.02)
    assert registration.rotation_deg == 0.0 and registration.scale == 1.0
    report = evaluate_height(shifted, surface.height)
    assert report["rms_height_error_um"] < 1.0


def test_the_registered_map_keeps_a_wrinkle_floor_and_its_missing_data():
    """An analytic Gaussian-profile groove (100 um deep, sigma 0.1 mm, 20 um pixels) on a relief
    of plane waves (for the registration), sampled on a grid moved by (0.5, -0.5) px: the
    registered map must be the same function on the reference grid. Bilinear resampling (the
    former one) averages two samples at a half-pixel shift and loses 0.55 um of the floor; the
    cubic spline is within 0.05 um (0.017 measured). A hole in the moving map stays missing
    where its nearest samples are (as with bilinear resampling)."""
    waves = np.random.default_rng(2).uniform([0.004, 0.0, 0.0], [0.02, np.pi, 2 * np.pi], (8, 3))  # per um, direction, phase

    def surface(rows, columns):  # um: a groove along the rows on a relief of 8 plane waves
        x, y = columns * 20.0, rows * 20.0
        relief = sum(4.0 * np.sin(k * (x * np.cos(a) + y * np.sin(a)) + phase) for k, a, phase in waves)
        return relief - 100.0 * np.exp(-0.5 * ((x - 1600.0) / 100.0) ** 2)

    rows, columns = np.mgrid[:128, :160].astype(float)
    reference = HeightMap(surface(rows, columns), 20.0)
    moved = surface(rows + 0.5, columns - 0.5)
    moved[60:64, 30:34] = np.nan  # a hole
    aligned, registration = register_height_maps(reference, HeightMap(moved, 20.0), rotation=False)
    assert registration.shift_px == pytest.approx((0.5, -0.5), abs=0.01)
    groove = (slice(20, 100), slice(74, 87))
    assert aligned.mask[groove].all() and np.abs(reference.z[groove] - aligned.z[groove]).max() < 0.05
    bilinear = scipy.ndimage.shift(np.nan_to_num(moved), (0.5, -0.5), order=1)  # output(x) = moved(x - shift)
    assert np.abs(reference.z[groove] - bilinear[groove]).max() > 0.4  # what the spline avoids
    # missing: every point whose 2 x 2 nearest samples include the hole, nothing else inside
    hole = np.zeros(moved.shape, bool)
    hole[60:64, 30:34] = True
    reads_hole = scipy.ndimage.shift(hole.astype(float), (0.5, -0.5), order=1) > 1e-9
    assert reads_hole.sum() == 25 and not aligned.mask[reads_hole].any()
    assert aligned.mask[5:-5, 5:-5][~reads_hole[5:-5, 5:-5]].all()
    assert np.isnan(aligned.z[~aligned.mask]).all()
