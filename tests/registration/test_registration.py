"""Registration of height maps: sub-pixel shifts and rotations recovered."""

import numpy as np
import pytest

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
