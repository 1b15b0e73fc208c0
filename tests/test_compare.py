"""Visit registration and before/after comparison on simulated visits."""

import dataclasses
import json

import numpy as np
import pytest
import scipy.ndimage

from skintopo.cli import main
from skintopo.compare import Comparison, compare_visits, detection_limits
from skintopo.registration import register_height_maps, residual_misalignment
from skintopo.errors import SkinTopoError
from skintopo.height import integrate_normals
from skintopo.heightmap import HeightMap
from skintopo.normals import photometric_stereo
from skintopo.results import comparison_rows
from skintopo.synth import default_settings, make_surface, preset_spec, simulate_acquisition


def transformed_view(big, size, offset, angle_deg, shift):
    """The view x_f = R (x_b - c) + c - t of a larger map (the registration's convention)."""
    rows, columns = np.mgrid[:size, :size].astype(float)
    centre = (size - 1) / 2
    theta = np.radians(angle_deg)
    rotation = np.array([[np.cos(theta), np.sin(theta)], [-np.sin(theta), np.cos(theta)]])
    points = np.stack([rows - centre + shift[0], columns - centre + shift[1]])
    source = np.tensordot(np.linalg.inv(rotation), points, axes=1) + centre + offset
    return scipy.ndimage.map_coordinates(big, source, order=3, mode="nearest")


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


def visit(spec, noise_seed):
    surface = make_surface(spec, seed=5)
    bands, _ = simulate_acquisition(surface, default_settings(), seed=noise_seed)
    stereo = photometric_stereo(*bands["white"])
    return integrate_normals(stereo.normals, spec.pixel_um, mask=stereo.valid)


@pytest.mark.slow
def test_treatment_of_one_wrinkle_is_detected_and_repeats_are_near_zero():
    spec = preset_spec("forehead-moderate", size_px=256)
    baseline = visit(spec, 1)
    repeat = visit(dataclasses.replace(spec, shift_um=(30.0, -25.0)), 2)  # same skin, new noise, moved
    wrinkles = list(spec.wrinkles)
    wrinkles[1] = dataclasses.replace(wrinkles[1], depth_um=0.7 * wrinkles[1].depth_um)  # treated: 30% shallower
    treated = visit(dataclasses.replace(spec, wrinkles=tuple(wrinkles), shift_um=(-20.0, 35.0)), 3)
    second_repeat = visit(dataclasses.replace(spec, shift_um=(-35.0, 10.0)), 4)
    repeat_comparisons = [compare_visits(baseline, r) for r in (repeat, second_repeat)]
    limits = detection_limits(repeat_comparisons)
    comparison = compare_visits(baseline, treated)
    for label, c in (("repeat", repeat_comparisons[0]), ("treated", comparison)):
        for wrinkle_id, record in c.wrinkles.items():
            print(label, wrinkle_id, "->", record["follow_up_id"], {k: f"{v['change_percent']:+.1f}%" for k, v in record.items() if isinstance(v, dict)})
    # repeats: every wrinkle found again, depth changes near zero
    for record in repeat_comparisons[0].wrinkles.values():
        assert record["follow_up_id"] is not None and abs(record["max_depth_um"]["change_percent"]) < 3
    # treatment: the second wrinkle (baseline id 2, top to bottom) -30% +- 5% and detectable; the
    # untouched ones not flagged (once, with a single repeat, one was: +2.7% against 0.19 um)
    assert comparison.wrinkles[2]["max_depth_um"]["change_percent"] == pytest.approx(-30, abs=5)
    rows = {row["parameter"]: row for row in comparison_rows(comparison, limits.limits)}
    assert rows["wrinkle2.max_depth_um"]["detectable"] and rows["wrinkle2.mean_depth_um"]["detectable"]
    for wrinkle_id in (1, 3):
        assert not any(rows[f"wrinkle{wrinkle_id}.{name}"]["detectable"] for name in ("max_depth_um", "mean_depth_um", "length_mm"))
    # 2 repeats x 3 wrinkles pooled: 6 degrees of freedom per wrinkle measure, 2 per texture parameter (warned)
    assert limits.degrees_of_freedom["wrinkle1.max_depth_um"] == 6 and limits.degrees_of_freedom["Sa"] == 2 and limits.warnings
    print("smallest detectable change of max depth (um):", {k: round(v, 2) for k, v in limits.limits.items() if k.endswith("max_depth_um")})


def test_detection_limits_are_student_prediction_limits_of_repeat_differences():
    """The formula against numbers worked by hand. Texture differences 1 and -2 (nu = 2):
    s_r^2 = (1 + 4) / 4, limit = t_(0.975, 2) sqrt(2) s_r. Two wrinkles of 100 and 50 um max
    depth, changed by +2%, -2% in one repeat and -2%, +2% in the other: relative differences
    pooled (nu = 4), s_rel^2 = 4 x 0.02^2 / 8, limit = t_(0.975, 4) sqrt(2) s_rel x baseline."""
    def record(before, after):
        return {"baseline": before, "follow_up": after, "change": after - before, "change_percent": 100 * (after - before) / before}

    def repeat(sa_change, depths):
        wrinkles = {i + 1: {"follow_up_id": i + 1, "max_depth_um": record(b, a)} for i, (b, a) in enumerate(depths)}
        return Comparison(None, None, {"Sa": record(10.0, 10.0 + sa_change)}, wrinkles, {}, None, None)

    limits = detection_limits([repeat(1.0, [(100.0, 102.0), (50.0, 49.0)]), repeat(-2.0, [(100.0, 98.0), (50.0, 51.0)])],
                              confidence=0.95)
    assert limits.limits["Sa"] == pytest.approx(4.302653 * np.sqrt(2) * np.sqrt(5 / 4), rel=1e-6)
    s_rel = np.sqrt(4 * 0.02**2 / 8)
    assert limits.limits["wrinkle1.max_depth_um"] == pytest.approx(2.776445 * np.sqrt(2) * s_rel * 100, rel=1e-6)
    assert limits.limits["wrinkle2.max_depth_um"] == pytest.approx(2.776445 * np.sqrt(2) * s_rel * 50, rel=1e-6)
    assert limits.degrees_of_freedom == {"Sa": 2, "wrinkle1.max_depth_um": 4, "wrinkle2.max_depth_um": 4}
    assert "2 repeat pair(s)" in limits.warnings[0]
    with pytest.raises(SkinTopoError, match="at least one repeat"):
        detection_limits([])


def test_compare_command_and_bad_inputs(tmp_path, capsys):
    spec = preset_spec("forehead-moderate", size_px=160)
    make_surface(spec, seed=2).height.save(tmp_path / "a.x3p")
    make_surface(dataclasses.replace(spec, shift_um=(25.0, 10.0)), seed=2).height.save(tmp_path / "b.x3p")
    assert main(["compare", str(tmp_path / "a.x3p"), str(tmp_path / "b.x3p"), "-o", str(tmp_path / "c")]) == 0
    data = json.loads((tmp_path / "c" / "changes.json").read_text())
    matches = data["summary"]["wrinkle_matches"]
    assert len(matches) >= 2 and all(int(k) == v for k, v in matches.items())  # the same skin, moved: every wrinkle matched
    assert data["summary"]["registration"]["shift_px"] == pytest.approx([-0.5, 1.25], abs=0.1)
    assert (tmp_path / "c" / "difference.x3p").exists() and "registration:" in capsys.readouterr().out
    # different pixel sizes: refused
    make_surface(dataclasses.replace(spec, pixel_um=25.0), seed=2).height.save(tmp_path / "coarse.x3p")
    assert main(["compare", str(tmp_path / "a.x3p"), str(tmp_path / "coarse.x3p"), "-o", str(tmp_path / "d")]) == 2
    assert "different pixel sizes (20 and 25 um): refusing" in capsys.readouterr().err
    # no overlap (another person's skin): refused
    make_surface(spec, seed=99).height.save(tmp_path / "other.x3p")
    with pytest.raises(SkinTopoError, match="do not overlap"):
        register_height_maps(HeightMap.load(tmp_path / "a.x3p"), HeightMap(np.random.default_rng(0).normal(size=(160, 160)), 20.0))
    # no wrinkles: texture only, clear message
    flat = preset_spec("flat-microrelief", size_px=160)
    make_surface(flat, seed=1).height.save(tmp_path / "f1.x3p")
    make_surface(dataclasses.replace(flat, shift_um=(15.0, 0.0)), seed=1).height.save(tmp_path / "f2.x3p")
    assert main(["compare", str(tmp_path / "f1.x3p"), str(tmp_path / "f2.x3p"), "-o", str(tmp_path / "e")]) == 0
    assert "no wrinkles in the baseline" in capsys.readouterr().out
    assert not (tmp_path / "d").exists()


def test_albedo_is_carried_by_the_height_registration(tmp_path, capsys):
    big = make_surface(preset_spec("forehead-moderate", size_px=384), seed=3).height.z
    rng = np.random.default_rng(7)
    pigment = 0.45 + 0.1 * scipy.ndimage.gaussian_filter(rng.normal(size=big.shape), 3) / 0.03  # freckle-like albedo texture
    angle, shift = 2.4, (1.7, -0.6)
    heights = [HeightMap(transformed_view(big, 256, 64, a, t), 20.0) for a, t in ((0.0, (0, 0)), (angle, shift))]
    albedos = [transformed_view(pigment, 256, 64, a, t) for a, t in ((0.0, (0, 0)), (angle, shift))]
    comparison = compare_visits(*heights, baseline_albedo=albedos[0], follow_up_albedo=albedos[1])
    inner = (slice(40, -40), slice(40, -40))
    error = comparison.aligned_albedo[inner] - albedos[0][inner]
    print(f"albedo after registration: RMS difference {np.sqrt(np.mean(error**2)):.4f} (albedo std {albedos[0].std():.4f}), "
          f"residual misalignment {comparison.albedo_residual_px:.3f} px")
    assert np.sqrt(np.mean(error**2)) < 0.05 * albedos[0].std()
    assert comparison.albedo_residual_px < 0.1
    # and the check can fail: half a pixel of misalignment is seen as such
    assert residual_misalignment(albedos[0], scipy.ndimage.shift(albedos[0], (0.5, 0.0), mode="nearest")) == pytest.approx(0.5, abs=0.06)
    # the command finds albedo.npy beside height.x3p (the output of measure) and writes the registered one
    for name, height, albedo in zip("ab", heights, albedos):
        (tmp_path / name).mkdir()
        height.save(tmp_path / name / "height.x3p")
        np.save(tmp_path / name / "albedo.npy", albedo.astype(np.float32))
    assert main(["compare", str(tmp_path / "a"), str(tmp_path / "b"), "-o", str(tmp_path / "c"), "-q"]) == 0
    summary = json.loads((tmp_path / "c" / "changes.json").read_text())["summary"]
    assert summary["registration"]["albedo_residual_misalignment_px"] < 0.1
    assert np.load(tmp_path / "c" / "follow_up_albedo_registered.npy").shape == (256, 256)
    with pytest.raises(SkinTopoError, match="albedo image is"):
        compare_visits(*heights, baseline_albedo=albedos[0][:100], follow_up_albedo=albedos[1])


@pytest.mark.slow
def test_a_visit_pair_rehearsed_from_the_command_line(tmp_path, capsys):
    """synth makes the same skin displaced and with one wrinkle treated (no Python needed);
    measure and compare find the treatment where it was made."""
    common = ["--preset", "forehead-moderate", "--size", "192", "--seed", "5", "-q"]
    assert main(["synth", "-o", str(tmp_path / "v1"), *common]) == 0
    assert main(["synth", "-o", str(tmp_path / "v2"), *common, "--capture-seed", "6", "--shift-um", "60,-40", "--treat", "1=0.7"]) == 0
    surface = json.loads((tmp_path / "v2" / "ground_truth" / "surface.json").read_text())
    assert surface["surface"]["shift_um"] == [60.0, -40.0] and surface["surface"]["wrinkles"][0]["depth_um"] == pytest.approx(0.7 * 120.0)
    assert surface["seed"] == 5 and surface["capture_seed"] == 6
    for visit in ("v1", "v2"):
        assert main(["measure", str(tmp_path / visit), "-o", str(tmp_path / f"m{visit}"), "-q"]) == 0
    assert main(["compare", str(tmp_path / "mv1"), str(tmp_path / "mv2"), "-o", str(tmp_path / "change"), "-q"]) == 0
    rows = {r["parameter"]: r for r in json.loads((tmp_path / "change" / "changes.json").read_text())["changes"]}
    assert rows["wrinkle1.max_depth_um"]["change_percent"] == pytest.approx(-30, abs=6)
    for other in ("wrinkle2.max_depth_um", "wrinkle3.max_depth_um"):
        assert abs(rows[other]["change_percent"]) < 6
    with pytest.raises(SystemExit):
        main(["synth", "-o", str(tmp_path / "bad"), "--treat", "1=-2"])
    assert "depth factor must be positive" in capsys.readouterr().err
    assert main(["synth", "-o", str(tmp_path / "bad"), "--treat", "7=0.5", "-q"]) == 2
    assert "has wrinkles 1..3, not [7]" in capsys.readouterr().err and not (tmp_path / "bad").exists()
