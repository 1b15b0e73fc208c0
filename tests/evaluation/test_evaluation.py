"""Accuracy evaluation against a reference: every figure on differences with a closed form; incomparable maps refused."""

import numpy as np
import pytest

from skintopo.errors import SkinTopoError
from skintopo.evaluation import evaluate_height
from skintopo.heightmap import HeightMap


def test_evaluation_refuses_incomparable_maps():
    a = HeightMap(np.random.default_rng(0).normal(size=(64, 64)), 10.0)
    with pytest.raises(SkinTopoError, match="different pixel sizes"):
        evaluate_height(a, HeightMap(a.z, 20.0))
    with pytest.raises(SkinTopoError, match="do not overlap"):
        evaluate_height(a, HeightMap(np.random.default_rng(1).normal(size=(64, 64)), 10.0))


def test_accuracy_figures_of_known_differences():
    """Every figure of evaluation.json on differences with a closed form (no registration, so
    the numbers are the formulas'): a tilted plane alone is no height error (the plane of the
    difference is removed) but every normal turns by atan(slope): L2 = 2 sin(angle / 2); a
    cosine of amplitude A over whole periods, even about the centre (so it has no plane
    component), is an RMS error of A / sqrt(2); a quarter of
    the field missing is a valid fraction of 0.75."""
    rows, columns, pixel = 120, 160, 10.0
    y, x = np.mgrid[:rows, :columns] * pixel
    reference = HeightMap(np.zeros((rows, columns)), pixel)
    slope = 0.05
    tilted = evaluate_height(HeightMap(slope * x + 3.0, pixel), reference, register=False)
    angle = np.arctan(slope)
    assert tilted["rms_height_error_um"] == pytest.approx(0, abs=1e-9)
    assert tilted["mean_angular_error_deg"] == pytest.approx(np.degrees(angle), rel=1e-9)
    assert tilted["l2_normal_error"] == pytest.approx(2 * np.sin(angle / 2), rel=1e-9)
    assert tilted["valid_fraction"] == 1.0 and tilted["shift_px"] == [0.0, 0.0]
    amplitude, period = 2.0, columns * pixel / 4  # 4 whole periods across
    wave = amplitude * np.cos(2 * np.pi * (x - (columns - 1) * pixel / 2) / period)
    wavy = evaluate_height(HeightMap(wave, pixel), reference, register=False)
    assert wavy["rms_height_error_um"] == pytest.approx(amplitude / np.sqrt(2), rel=1e-9)
    z = np.where(y < rows * pixel * 0.75, wave, np.nan)
    assert evaluate_height(HeightMap(z, pixel), reference, register=False)["valid_fraction"] == pytest.approx(0.75)


def test_wrinkle_figures_of_a_known_wrinkle():
    """A reconstruction whose wrinkle is 20% shallower everywhere (a scaled copy of the truth):
    the max depth read where the reference's wrinkle is, 0.8 of the true one (relative
    error 0.2), the true depth the wrinkle's geometry, and the RMS error inside the wrinkle
    larger than over the field."""
    from skintopo.synth import make_surface
    from skintopo.synth.surfaces import SurfaceSpec, Wrinkle, geometric_measures

    wrinkle = Wrinkle(depth_um=100.0, width_um=500.0, length_um=3500.0, orientation_deg=20.0, shape="U")
    surface = make_surface(SurfaceSpec(size_px=(200, 200), pixel_um=20.0, wrinkles=(wrinkle,), microrelief=False,
                                       roughness_rms_um=0.0, form_radius_mm=None), seed=0)
    shallower = HeightMap(0.8 * surface.height.z, surface.height.spacing)
    report = evaluate_height(shallower, surface.height, wrinkle_labels=surface.wrinkle_labels, register=False)
    true_depth = geometric_measures(wrinkle)["max_depth_um"]
    assert report["wrinkle_max_depth_true_um"][0] == pytest.approx(true_depth, rel=0.03)
    assert report["wrinkle_max_depth_um"][0] == pytest.approx(0.8 * true_depth, rel=0.03)
    assert report["wrinkle_depth_error_relative"][0] == pytest.approx(0.2, abs=0.01)
    assert report["rms_height_error_in_wrinkles_um"] > 2 * report["rms_height_error_um"]


def test_each_measured_wrinkle_matches_one_true_wrinkle_at_most():
    """Two true wrinkles crossing; the measured wrinkle 1 covers all of the first and a third
    of the second (a shallow wrinkle merged into the deep one it crosses): the first is found
    as 1, the second is not found (before, it was "found" as 1 too). With a measured wrinkle 2
    on the rest of the second, each is found as its own; an id in the labels that has no
    measures (4) belongs to nobody."""
    from types import SimpleNamespace

    from skintopo.evaluation import match_wrinkles_to_truth

    truth = np.zeros((20, 30), int)
    truth[8:12, :] = 1
    truth[:, 14:16] = 2
    truth[8:12, 14:16] = 1  # the crossing belongs to the first
    measured = np.where(truth == 1, 1, 0)
    measured[:6, 14:16] = 1  # a third of the second wrinkle's region outside the crossing
    wrinkles = [SimpleNamespace(id=1), SimpleNamespace(id=3)]
    first, second = match_wrinkles_to_truth(SimpleNamespace(labels=measured, wrinkles=wrinkles), truth)
    assert first.id == 1 and second is None
    measured[12:, 14:16] = 3
    measured[0, 0] = 4
    first, second = match_wrinkles_to_truth(SimpleNamespace(labels=measured, wrinkles=wrinkles), truth)
    assert first.id == 1 and second.id == 3
