"""Before/after comparison on simulated visits: a treated wrinkle detected, repeats near zero, detection limits."""

import dataclasses

import numpy as np
import pytest

from skintopo.compare import Comparison, compare_visits, detection_limits
from skintopo.errors import SkinTopoError
from skintopo.height import integrate_normals
from skintopo.heightmap import HeightMap
from skintopo.normals import photometric_stereo
from skintopo.registration import register_height_maps
from skintopo.results import comparison_rows
from skintopo.synth import default_settings, make_surface, preset_spec, simulate_acquisition
from skintopo.texture import measure_texture, parameters_by_name


def visit(spec, noise_seed):
    surface = make_surface(spec, seed=5)
    bands, _ = simulate_acquisition(surface, default_settings(), seed=noise_seed, skin_seed=5)  # the same skin, its noise
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
    # 2 repeats: 2 degrees of freedom per parameter, wrinkle measures too (warned)
    assert limits.degrees_of_freedom["wrinkle1.max_depth_um"] == 2 and limits.degrees_of_freedom["Sa"] == 2 and limits.warnings
    print("smallest detectable change of max depth (um):", {k: round(v, 2) for k, v in limits.limits.items() if k.endswith("max_depth_um")})


def test_detection_limits_are_student_prediction_limits_of_repeat_differences():
    """The formula against numbers worked by hand. Texture differences 1 and -2 (nu = 2):
    s_r^2 = (1 + 4) / 4, limit = t_(0.975, 2) sqrt(2) s_r. Two wrinkles of 100 and 50 um max
    depth, changed by +2, -1 um in one repeat and -2, +1 um in the other: each wrinkle on its
    own (nu = 2), s_r^2 = (4 + 4) / 4 and (1 + 1) / 4."""
    def record(before, after):
        return {"baseline": before, "follow_up": after, "change": after - before, "change_percent": 100 * (after - before) / before}

    def repeat(sa_change, depths):
        wrinkles = {i + 1: {"follow_up_id": i + 1, "max_depth_um": record(b, a)} for i, (b, a) in enumerate(depths)}
        return Comparison(None, None, {"Sa": record(10.0, 10.0 + sa_change)}, wrinkles, {}, None, None)

    limits = detection_limits([repeat(1.0, [(100.0, 102.0), (50.0, 49.0)]), repeat(-2.0, [(100.0, 98.0), (50.0, 51.0)])],
                              confidence=0.95)
    assert limits.limits["Sa"] == pytest.approx(4.302653 * np.sqrt(2) * np.sqrt(5 / 4), rel=1e-6)
    assert limits.limits["wrinkle1.max_depth_um"] == pytest.approx(4.302653 * np.sqrt(2) * np.sqrt(8 / 4), rel=1e-6)
    assert limits.limits["wrinkle2.max_depth_um"] == pytest.approx(4.302653 * np.sqrt(2) * np.sqrt(2 / 4), rel=1e-6)
    assert limits.degrees_of_freedom == {"Sa": 2, "wrinkle1.max_depth_um": 2, "wrinkle2.max_depth_um": 2}
    assert "2 repeat pair(s): 2 degree(s) of freedom for some parameters" in limits.warnings[0]
    assert "(t factor 4.3 instead of 1.96)" in limits.warnings[0]  # t_(0.975, 2) = 4.303, the normal quantile 1.960
    assert limits.as_dict() == {"confidence": 0.95, "repeat_pairs": 2, "warnings": list(limits.warnings),
                                "degrees_of_freedom": limits.degrees_of_freedom}
    with pytest.raises(SkinTopoError, match="at least one repeat"):
        detection_limits([])


def test_compare_visits_on_exact_heights_of_a_treated_wrinkle():
    """Two visits of the same simulated skin, exact heights (no rendering): the follow-up moved
    by (40, -30) um and its second wrinkle made 30% shallower. The registration finds the move
    (50 um, no turn), the treated wrinkle's max depth reads -30% +- 3%, the
    others within 2%, every wrinkle is matched to its own; each change record is follow-up -
    baseline and its per cent of the baseline; an albedo carried by the same transform lands
    where the baseline's is (residual under 0.1 px); a follow-up that does not overlap is refused."""
    spec = dataclasses.replace(preset_spec("forehead-moderate", size_px=200), microrelief=False)
    baseline = make_surface(spec, seed=5)
    wrinkles = list(spec.wrinkles)
    wrinkles[1] = dataclasses.replace(wrinkles[1], depth_um=0.7 * wrinkles[1].depth_um)
    follow_up = make_surface(dataclasses.replace(spec, wrinkles=tuple(wrinkles), shift_um=(40.0, -30.0)), seed=5)
    y, x = ((199 / 2 - np.mgrid[:200, :200][0]) * 20.0, (np.mgrid[:200, :200][1] - 199 / 2) * 20.0)  # um, y up

    def pattern(x, y):  # a skin colour pattern fixed to the skin, seen through each visit's field
        return 0.5 + 0.1 * np.sin(2 * np.pi * x / 700.0) * np.cos(2 * np.pi * y / 900.0)

    albedo = [pattern(x, y), pattern(x + 40.0, y - 30.0)]
    comparison = compare_visits(baseline.height, follow_up.height, baseline_albedo=albedo[0], follow_up_albedo=albedo[1])
    assert np.hypot(*comparison.registration.shift_px) * 20.0 == pytest.approx(50.0, abs=2.0)  # |(40, -30)| um
    assert abs(comparison.registration.rotation_deg) < 0.1 and comparison.registration.scale == 1.0
    changes = {wrinkle_id: record["max_depth_um"]["change_percent"] for wrinkle_id, record in comparison.wrinkles.items()}
    assert len(changes) == 3 and all(record["follow_up_id"] == wrinkle_id for wrinkle_id, record in comparison.wrinkles.items())
    assert changes[2] == pytest.approx(-30.0, abs=3.0) and abs(changes[1]) < 2 and abs(changes[3]) < 2
    for record in [*comparison.texture.values(), *comparison.totals.values()]:
        if np.isfinite(record["baseline"]) and record["baseline"] != 0:
            assert record["change"] == pytest.approx(record["follow_up"] - record["baseline"], abs=1e-12)
            assert record["change_percent"] == pytest.approx(100 * record["change"] / abs(record["baseline"]), rel=1e-12)
    assert comparison.totals["count"]["change"] == 0
    assert comparison.albedo_residual_px < 0.1 and comparison.aligned_albedo.shape == albedo[0].shape
    assert comparison.baseline_wrinkles.totals["count"] == 3 and comparison.follow_up_wrinkles.totals["count"] == 3
    # texture on the overlap alone: the baseline's Sa over the points the registered follow-up covers
    aligned, _ = register_height_maps(baseline.height, follow_up.height)
    overlap = HeightMap(baseline.height.z, baseline.height.spacing, aligned.mask)
    assert comparison.texture["Sa"]["baseline"] == pytest.approx(parameters_by_name(measure_texture(overlap))["Sa"], rel=1e-9)
    assert np.isnan(comparison.difference[~aligned.mask]).all()
    strict = compare_visits(baseline.height, follow_up.height, segmentation_options={"min_depth_um": 500.0})
    assert strict.wrinkles == {} and strict.totals["count"]["baseline"] == 0
    with pytest.raises(SkinTopoError, match="the baseline albedo image is \\(10, 10\\), its height map \\(200, 200\\): they must match"):
        compare_visits(baseline.height, follow_up.height, baseline_albedo=np.ones((10, 10)), follow_up_albedo=albedo[1])
    far = make_surface(dataclasses.replace(spec, shift_um=(3000.0, 0.0)), seed=5)
    with pytest.raises(SkinTopoError, match="overlap"):
        compare_visits(baseline.height, far.height)


def test_change_records_and_wrinkle_matching():
    """A change in per cent of the baseline's magnitude (NaN from a zero baseline); wrinkles
    matched by the largest overlap, at least 20% of the smaller region, else None."""
    from skintopo.compare import _change, match_wrinkles

    assert _change(1.0, 1.5) == {"baseline": 1.0, "follow_up": 1.5, "change": 0.5, "change_percent": 50.0}
    assert _change(-2.0, -1.0)["change_percent"] == 50.0 and np.isnan(_change(0.0, 2.0)["change_percent"])
    baseline, follow_up = np.zeros((20, 30), int), np.zeros((20, 30), int)
    baseline[2:6, 2:20], baseline[12:16, 2:20] = 1, 2
    follow_up[3:7, 4:22] = 5  # most of wrinkle 1
    follow_up[15:18, 2:4] = 6  # 2 of wrinkle 2's 72 pixels: 2 / min(72, 6) = 33%
    follow_up[15:16, 10:11] = 7  # a one-pixel region also in wrinkle 2: fewer pixels, not its match
    assert match_wrinkles(baseline, follow_up) == {1: 5, 2: 6}
    assert match_wrinkles(baseline, np.zeros_like(follow_up)) == {1: None, 2: None}


def test_wrinkle_matching_is_one_to_one():
    """Two baseline wrinkles that the follow-up segmented as one (a crossing pair merged): only
    the one covering most of the merged region is compared with it; the other is unmatched,
    not reported with its partner's measures. A baseline wrinkle split in two in the
    follow-up is matched with its larger piece."""
    from skintopo.compare import match_wrinkles

    baseline = np.zeros((40, 40), int)
    baseline[18:22, 2:38] = 1  # a long horizontal wrinkle
    baseline[10:30, 19:21] = 2  # a shorter vertical one crossing it
    merged = np.where(baseline > 0, 4, 0)  # one region in the follow-up
    assert match_wrinkles(baseline, merged) == {1: 4, 2: None}
    split = np.zeros_like(baseline)
    split[18:22, 2:15], split[18:22, 15:38] = 1, 2
    assert match_wrinkles(baseline, np.where(baseline == 1, split, 0)) == {1: 2, 2: None}
