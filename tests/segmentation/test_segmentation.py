"""Wrinkle segmentation on the simulator's presets, and straight valleys the band-pass misses."""

import numpy as np
import pytest
import scipy.ndimage

from skintopo.errors import SkinTopoError
from skintopo.heightmap import HeightMap
from skintopo.segmentation import (
    margin_pixels,
    segment_wrinkles,
    segmentation_from_labels,
    segmentation_quality,
    skin_around,
    split_crossing_wrinkles,
)
from skintopo.synth import make_surface, preset_spec


@pytest.mark.slow
def test_segmentation_defaults_work_on_the_presets():
    """Seeds 1-6 of each preset chose the defaults (all counts exact); seeds 7-14 are held
    out (two failures allowed of 32 fields). Over seeds 1-60 (240 fields) the count is wrong
    in 5 fields with 48 straight-valley directions (4 with 16): a chain of furrows straight
    over 1.6-2.4 mm taken for a wrinkle (seed 13 of the low state and of the flat
    microrelief, 24 and 56 of the flat microrelief), and one extra wrinkle at seed 37 of the
    high state. With the band-pass alone a 50 um wrinkle was missed (seed 10 of the low
    state: its band-passed floor stays under the 25 um seed depth); the straight valleys
    find it."""
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
    assert len(held_out_failures) <= 2
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


def _band(shape, centre, angle_deg, length_px, width_px):
    """Pixels within width/2 of a segment (x right, rows down; angle counter-clockwise from +x)."""
    rows, columns = np.mgrid[: shape[0], : shape[1]]
    theta = np.radians(angle_deg)
    along = (columns - centre[1]) * np.cos(theta) - (rows - centre[0]) * np.sin(theta)
    across = (columns - centre[1]) * np.sin(theta) + (rows - centre[0]) * np.cos(theta)
    return (np.abs(along) <= length_px / 2) & (np.abs(across) <= width_px / 2)


@pytest.mark.parametrize("angle", [90.0, 60.0])
def test_crossing_wrinkles_sharing_a_label_are_split_along_their_lines(angle):
    """Two 3 mm bands crossing (20 um pixels) as one label beside another wrinkle: the crossing
    label becomes two (the new one numbered after the last), each band's far parts wholly one
    label; the other wrinkle keeps its label."""
    shape = (220, 220)
    first, second = _band(shape, (110, 110), 0.0, 150, 10), _band(shape, (110, 110), angle, 150, 10)
    other = _band(shape, (20, 110), 0.0, 120, 8)
    labels = np.where(other, 1, np.where(first | second, 2, 0))
    split = split_crossing_wrinkles(labels, 20.0, 1500.0)
    assert set(np.unique(split)) == {0, 1, 2, 3}
    np.testing.assert_array_equal(split[other], 1)
    far = np.hypot(*(np.mgrid[:220, :220] - 110)) > 20
    first_labels, second_labels = np.unique(split[first & ~second & far]), np.unique(split[second & ~first & far])
    assert len(first_labels) == 1 and len(second_labels) == 1 and first_labels[0] != second_labels[0]
    assert set(first_labels) | set(second_labels) == {2, 3}


def test_an_arm_ending_in_a_fork_of_spurs_still_continues_through_the_crossing():
    """bench_wrinkles' field 169 (simulated: a 167 um deep, 0.66 mm wide wrinkle crossing a
    158 um, 0.97 mm one): one arm of the wider wrinkle, shorter than two widths, ends in a
    fork of spurs of its skeleton, which made it look like a bridge between two crossings and
    left it out of its wrinkle (measured 2.2 mm long instead of 4.2). Each wrinkle is now
    found whole: length within 5% of the geometry's, the other wrinkle's label covering
    little of it."""
    from skintopo.evaluation import match_wrinkle
    from skintopo.synth.surfaces import geometric_measures, random_wrinkle_spec
    from skintopo.wrinkles import measure_wrinkles

    surface = make_surface(random_wrinkle_spec(np.random.default_rng(169), microrelief=False, crossing=True), seed=169)
    measures = measure_wrinkles(surface.height, segment_wrinkles(surface.height))
    matched = [match_wrinkle(measures, surface.wrinkle_labels == index + 1) for index in range(2)]
    assert len(measures.wrinkles) == 2 and matched[0].id != matched[1].id
    for wrinkle, found in zip(surface.spec.wrinkles, matched):
        assert found.length_mm == pytest.approx(geometric_measures(wrinkle)["length_mm"], rel=0.05)


def test_a_narrow_shallow_wrinkle_crossing_a_deeper_one_is_found_whole():
    """bench_wrinkles' field 179 (simulated, no microrelief): a 29 um deep, 0.29 mm wide U
    wrinkle crossing a 102 um deep V wrinkle. On the band-pass it reads about 11 um, below the
    25 um minimum depth, so its half-depth reference was the deep wrinkle's floor within 0.75 mm
    of the crossing, and only one side of it was kept (1.78 mm of 3.99). It runs straight, so
    it is now held against its own floor: each wrinkle found whole, length within 5%."""
    from skintopo.evaluation import match_wrinkle
    from skintopo.synth.surfaces import geometric_measures, random_wrinkle_spec
    from skintopo.wrinkles import measure_wrinkles

    surface = make_surface(random_wrinkle_spec(np.random.default_rng(179), microrelief=False, crossing=True), seed=179)
    measures = measure_wrinkles(surface.height, segment_wrinkles(surface.height))
    matched = [match_wrinkle(measures, surface.wrinkle_labels == index + 1) for index in range(2)]
    assert matched[0] is not None and matched[1] is not None and matched[0].id != matched[1].id
    for wrinkle, found in zip(surface.spec.wrinkles, matched):
        assert found.length_mm == pytest.approx(geometric_measures(wrinkle)["length_mm"], rel=0.05)


@pytest.mark.parametrize("seed", [309, 319, 324])
def test_a_wrinkle_cut_in_two_by_a_deeper_one_is_found_whole(seed):
    """bench_wrinkles' fields 309, 319 and 324 (simulated crossing pairs): a wrinkle cut in two
    by another it crosses was left inside the other's label. In field 309 (81 um deep G crossing
    a 109 um V at 74 degrees) the skeleton of one piece was all spurs (a short arm ending in a
    fork), so the piece had no arm to continue across the gap. In field 319 (a 110 um deep,
    0.21 mm wide G crossing a 122 um V at 88 degrees) the G's longer piece was measured on its
    skeleton, 0.97 mm, under the 1.05 mm a piece meeting a crossing needs (its region: 1.24 mm),
    and its stub on the other side, 2 skeleton pixels, had no direction to be chained by. In
    field 324 (92 um V crossing a 193 um G at 49 degrees) the pieces' ends were 2.59 mm apart,
    beyond the former 2.5 mm gap. Each wrinkle is now its own and whole: length and max depth
    within 5% of the geometry's."""
    from skintopo.evaluation import match_wrinkle
    from skintopo.synth.surfaces import geometric_measures, random_wrinkle_spec
    from skintopo.wrinkles import measure_wrinkles

    surface = make_surface(random_wrinkle_spec(np.random.default_rng(seed), microrelief=seed % 2 == 0, crossing=True), seed=seed)
    measures = measure_wrinkles(surface.height, segment_wrinkles(surface.height))
    matched = [match_wrinkle(measures, surface.wrinkle_labels == index + 1) for index in range(2)]
    assert matched[0] is not None and matched[1] is not None and matched[0].id != matched[1].id
    for wrinkle, found in zip(surface.spec.wrinkles, matched):
        truth = geometric_measures(wrinkle)
        assert found.length_mm == pytest.approx(truth["length_mm"], rel=0.05)
        assert found.max_depth_um == pytest.approx(truth["max_depth_um"], rel=0.05)


def test_short_spurs_and_a_single_wrinkle_are_left_alone():
    """A 3 mm band with a 0.12 mm stub (shorter than its width) and a T whose stem is shorter
    than the minimum length: one label each, unchanged."""
    shape = (220, 220)
    band = _band(shape, (60, 110), 0.0, 150, 10) | _band(shape, (52, 110), 90.0, 16, 6)
    tee = _band(shape, (160, 110), 0.0, 150, 10) | _band(shape, (185, 110), 90.0, 50, 8)
    labels = np.where(band, 1, np.where(tee, 2, 0))
    np.testing.assert_array_equal(split_crossing_wrinkles(labels, 20.0, 1500.0), labels)


def test_pieces_of_a_wrinkle_cut_by_a_deeper_one_are_chained_across_the_gap():
    """A deep band with the two pieces of a shallower wrinkle above and below it, stopping short of
    it on each side (about 0.25 mm; one label, as a basin group gives): the pieces, collinear, become one wrinkle
    across the band; a piece pointing elsewhere (off by 60 degrees) is not joined to them."""
    shape = (240, 240)
    deep = _band(shape, (120, 120), 0.0, 200, 12)
    above, below = _band(shape, (72, 120), 90.0, 60, 8), _band(shape, (168, 120), 90.0, 60, 8)
    labels = np.where(deep | above | below, 1, 0)
    split = split_crossing_wrinkles(labels, 20.0, 1500.0)
    assert set(np.unique(split)) == {0, 1, 2}
    assert len(np.unique(split[above | below])) == 1 and np.unique(split[above])[0] != np.unique(split[deep & (np.abs(np.mgrid[:240, :240][1] - 120) > 30)])[0]
    slanted = _band(shape, (168, 134), 30.0, 60, 8)  # points 60 degrees away from the upper piece
    labels = np.where(deep | above | slanted, 1, 0)
    split = split_crossing_wrinkles(labels, 20.0, 1500.0)
    # the upper piece (1.2 mm, at least 0.7 of the minimum length) meets the deep band from the
    # side: a wrinkle of its own, not joined to the slanted piece
    assert len(np.unique(split[above])) == 1 and np.unique(split[above])[0] != np.unique(split[deep & (np.abs(np.mgrid[:240, :240][1] - 120) > 30)])[0]
    assert not set(np.unique(split[slanted & ~deep])) & set(np.unique(split[above]))


def test_a_short_piece_off_a_wrinkles_end_is_not_split_off():
    """A 1.4 mm piece (under the 1.5 mm minimum length, over 0.7 of it) in a 4 mm band's label,
    leaving it at an end (a furrow running on from the wrinkle's end, as in forehead-high seed
    10) stays in the band's label; the same piece meeting the band in its middle is a wrinkle
    of its own."""
    shape = (240, 240)
    deep = _band(shape, (120, 120), 0.0, 200, 12)
    off_end = _band(shape, (160, 232), 80.0, 70, 8)  # beyond the band's right end, running down
    labels = np.where(deep | off_end, 1, 0)
    np.testing.assert_array_equal(split_crossing_wrinkles(labels, 20.0, 1500.0), labels)
    middle = _band(shape, (155, 120), 80.0, 70, 8)
    labels = np.where(deep | middle, 1, 0)
    assert len(np.unique(split_crossing_wrinkles(labels, 20.0, 1500.0)[labels > 0])) == 2


def test_segmentation_of_a_simulated_forehead_against_its_truth():
    """One moderate forehead (3 wrinkles, 256 x 256): the three found, IoU with the simulator's
    half-depth regions above 0.7; extent contains the half-depth regions; centre lines inside
    them; the depth map NaN only outside the valid points; the parameters are those asked."""
    surface = make_surface(preset_spec("forehead-moderate", size_px=256), seed=1)
    z = surface.height.z.copy()
    z[:, :6] = np.nan
    height = HeightMap(z, surface.height.spacing)
    found = segment_wrinkles(height, min_depth_um=25.0, min_length_um=1500.0, width_window_um=1500.0)
    assert found.count == 3
    assert segmentation_quality(found.mask, surface.wrinkle_labels > 0)["iou"] > 0.7
    assert found.extent[found.mask].all() and found.extent.sum() > 1.5 * found.mask.sum()
    assert not (found.lines & ~found.mask).any() and set(np.unique(found.labels[found.lines])) == {1, 2, 3}
    assert np.isnan(found.depth[:, :6]).all() and np.isfinite(found.depth[:, 6:]).all()
    assert not found.extent[:, :6].any() and (found.depth[found.extent] > 0.25 * 25.0).all()  # walls end at a quarter of the min depth
    paper = segment_wrinkles(height, min_depth_um=25.0, straight_valley_um=0)  # the paper's band-pass alone finds them too
    assert paper.count == 3 and segmentation_quality(paper.mask, surface.wrinkle_labels > 0)["iou"] > 0.7
    assert segment_wrinkles(height, min_length_um=0.0).count >= 3
    assert {k: found.parameters[k] for k in ("min_depth_um", "min_length_um", "width_window_um")} == {
        "min_depth_um": 25.0, "min_length_um": 1500.0, "width_window_um": 1500.0}
    assert set(found.parameters) >= {"cutoff_um", "short_cutoff_um", "straight_valley_um"}
    assert segment_wrinkles(height, min_depth_um=200.0).count == 0  # deeper than every wrinkle
    with pytest.raises(SkinTopoError, match="minimum depth must be positive and minimum length >= 0, got 0.0, 1500.0"):
        segment_wrinkles(height, min_depth_um=0.0)
    with pytest.raises(SkinTopoError, match=r"the short cut-off \(9000.0 um\) must be below the long one \(8000.0 um\)"):
        segment_wrinkles(height, short_cutoff_um=9000.0)


def test_skin_around_wrinkles_is_the_valid_skin_beyond_the_margin():
    """The margin in whole pixels of the finer side (150 um at 20 x 30 um: 8), grown from the
    wrinkles' extent step by step (city-block distance); None when under 5% of the field."""
    assert margin_pixels(150.0, (20.0, 30.0)) == 8 and margin_pixels(5.0, 20.0) == 1
    valid = np.ones((60, 80), bool)
    valid[:, :4] = False
    wrinkles = np.zeros_like(valid)
    wrinkles[28:32, 10:70] = True
    skin = skin_around(valid, wrinkles, (20.0, 30.0), margin_um=150.0)
    expected = valid & (scipy.ndimage.distance_transform_cdt(~wrinkles, metric="taxicab") > 8)
    np.testing.assert_array_equal(skin, expected)
    everywhere = np.ones_like(valid)
    everywhere[0, 0] = False
    assert skin_around(valid, everywhere, 20.0) is None
    field, wrinkles = np.ones_like(valid), np.zeros_like(valid)
    wrinkles[3:] = True  # one pixel of margin (the least) leaves 2 of 60 rows: 3% of the field, too little
    assert margin_pixels(10.0, 20.0) == 1 and skin_around(field, wrinkles, 20.0, margin_um=10.0) is None
    wrinkles[:5] = False  # 4 rows: 7%
    assert skin_around(field, wrinkles, 20.0, margin_um=10.0).sum() == 4 * 80


def test_segmentation_from_known_labels_widens_each_wrinkle_by_its_width():
    """A 10 x 100 pixel rectangle (20 um pixels): its width is area / major axis length, the
    major axis of the inertia ellipse of n = 100 pixels in a row being 4 sqrt((n^2 - 1) / 12) =
    115.5 pixels, so 1000 x 400 / (115.5 x 20) = 173 um; the extent reaches that far beyond it.
    A 4-pixel-wide one beside it: 69 um."""
    labels = np.zeros((80, 160), np.int32)
    labels[20:30, 30:130] = 1
    labels[60:64, 30:130] = 2
    segmentation = segmentation_from_labels(labels, 20.0)
    assert segmentation.count == 2 and segmentation.parameters == {"from": "labels"}
    distance_1 = scipy.ndimage.distance_transform_edt(labels != 1) * 20.0
    distance_2 = scipy.ndimage.distance_transform_edt(labels != 2) * 20.0
    major_px = 4 * np.sqrt((100**2 - 1) / 12)
    width_1, width_2 = 1000 * 400 / (major_px * 20), 400 * 400 / (major_px * 20)
    np.testing.assert_array_equal(segmentation.extent, (distance_1 <= width_1) | (distance_2 <= width_2))
    assert segmentation.lines[24:26, 40:120].any(axis=0).all() and not segmentation.lines[labels == 0].any()


def test_one_straight_groove_beside_a_masked_area_is_one_wrinkle_along_its_floor():
    """A Gaussian groove (60 um deep, sigma 120 um) along x on a plane, its centre at row
    100.3, the left 30 columns and the bottom 50 rows masked out, the band-pass alone (no
    straight valleys): one wrinkle, its half-depth region symmetric about the groove's axis,
    its centre line on the axis and along the whole valid length, nothing (region, walls or
    line) outside the mask. Label images given as masks are read as "label > 0"."""
    rows, columns, pixel = 200, 240, 20.0
    y = (np.arange(rows)[:, None] - 100.3) * pixel
    mask = np.ones((rows, columns), bool)
    mask[:, :30] = False
    mask[150:] = False
    z = np.where(mask, -60.0 * np.exp(-0.5 * (y / 120.0) ** 2) * np.ones((1, columns)), np.nan)
    found = segment_wrinkles(HeightMap(z, (pixel, pixel), mask), straight_valley_um=0)
    assert found.count == 1 and found.labels.max() == 1
    assert not found.labels[~mask].any() and not found.extent[~mask].any() and not found.lines[~mask].any()
    label_rows = np.flatnonzero(found.labels.any(axis=1))
    assert abs((label_rows.min() + label_rows.max()) / 2 - 100.3) <= 1.0
    line_rows = np.flatnonzero(found.lines.any(axis=1))
    assert set(line_rows) <= {100, 101} and found.lines[:, 30:].any(axis=0).mean() > 0.9
    assert found.extent[found.mask].all() and found.extent.sum() > found.mask.sum()
    as_labels = np.where(found.labels > 0, 2, 0).astype(np.int64)  # a label image, not a boolean mask
    assert segmentation_quality(as_labels, found.labels > 0) == segmentation_quality(found.labels > 0, found.labels > 0)
    assert segmentation_quality(found.labels > 0, as_labels) == {"precision": 1.0, "recall": 1.0, "iou": 1.0}
    empty = np.zeros((4, 4), bool)
    assert all(np.isnan(v) for v in segmentation_quality(empty, empty).values())
    assert segmentation_from_labels(found.labels.astype(np.uint8), pixel).labels.dtype == np.int32


def test_half_depth_reference_follows_the_valley_direction():
    """A 200 um deep valley along x crossed by a 50 um one along y (Gaussian profiles of 6
    px, 20 um pixels, 2 mm window): on the shallow valley's floor 0.8-0.9 mm from the deep one
    the reference is its own 50 um, where the square window's maximum is the deep floor (which
    would cut the shallow valley there); nearer, where the deep valley's walls set the
    direction, it is the deep floor as before; on the deep floor it stays 200 um; a shallow
    branch beside the deep valley, with no valley of the minimum depth running its way, keeps
    the square window's reference."""
    from skintopo.segmentation import local_maximum_along_valley

    rows, columns = np.mgrid[:200, :200].astype(float)
    depth = 200 * np.exp(-0.5 * ((rows - 100) / 6) ** 2) + 50 * np.exp(-0.5 * ((columns - 100) / 6) ** 2)
    region = depth > 10
    reference = local_maximum_along_valley(depth, region, 101, 20.0, 25.0)
    square = scipy.ndimage.maximum_filter(np.where(region, depth, 0.0), size=101)
    for row in (55, 60):
        assert reference[row, 100] == pytest.approx(50.0, rel=0.02) and square[row, 100] > 150
    assert reference[85, 100] == pytest.approx(square[85, 100]) and reference[100, 30] == pytest.approx(200.0, rel=0.01)
    branch = 200 * np.exp(-0.5 * ((rows - 100) / 6) ** 2) + 15 * np.exp(-0.5 * ((columns - 100) / 4) ** 2) * (rows < 120)
    reference = local_maximum_along_valley(branch, branch > 10, 101, 20.0, 25.0)
    assert reference[70, 100] > 150
