"""Wrinkle segmentation on the simulator's presets, and straight valleys the band-pass misses."""

import numpy as np
import pytest

from skintopo.segmentation import segment_wrinkles, segmentation_quality
from skintopo.synth import make_surface, preset_spec


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


def test_segmentation_quality_of_overlapping_rectangles():
    """demo's precision, recall and IoU on two rectangles counted by hand: predicted 10 x 20 =
    200 pixels, true 10 x 30 = 300, overlap 10 x 10 = 100: precision 1/2, recall 1/3, IoU
    100 / 400; nothing predicted: precision NaN (undefined), recall 0."""
    predicted, truth = np.zeros((40, 60), bool), np.zeros((40, 60), bool)
    predicted[5:15, 10:30] = True
    truth[5:15, 20:50] = True
    assert segmentation_quality(predicted, truth) == {"precision": 0.5, "recall": pytest.approx(1 / 3), "iou": 0.25}
    empty = segmentation_quality(np.zeros_like(truth), truth)
    assert np.isnan(empty["precision"]) and empty["recall"] == 0.0 and empty["iou"] == 0.0
