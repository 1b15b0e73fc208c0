"""Per-wrinkle measures against the simulator's exact wrinkles."""

import dataclasses

import numpy as np
import pytest

from skintopo.errors import SkinTopoError
from skintopo.heightmap import HeightMap
from skintopo.evaluation import match_wrinkle
from skintopo.segmentation import segment_wrinkles, segmentation_from_labels
from skintopo.synth import make_surface, preset_spec
from skintopo.synth.surfaces import SurfaceSpec, Wrinkle, geometric_measures, random_wrinkle_spec
from skintopo.wrinkles import centre_lines, measure_wrinkles, quadratic_savitzky_golay, wrinkle_field, wrinkle_frame

TOLERANCES = {"max_depth_um": 0.05, "mean_depth_um": 0.05, "mean_width_mm": 0.10, "length_mm": 0.05, "volume_mm3": 0.10,
              "cross_section_mm2": 0.10}


def relative_errors(surface, *, require_all=True):
    """Each simulated wrinkle's measures against its geometry (synth.geometric_measures: the
    wrinkle alone, exact, never filtered), matched by overlap of the half-depth regions; None
    for a wrinkle not found (an error unless ``require_all`` is false)."""
    measures = measure_wrinkles(surface.height, segment_wrinkles(surface.height))
    errors = []
    for index, wrinkle in enumerate(surface.spec.wrinkles):
        measured = match_wrinkle(measures, surface.wrinkle_labels == index + 1)
        assert measured is not None or not require_all, f"wrinkle {index} not found"
        if measured is None:
            errors.append(None)
            continue
        expected = geometric_measures(wrinkle)
        errors.append({name: getattr(measured, name) / expected[name] - 1 for name in TOLERANCES})
    return measures, errors


@pytest.mark.parametrize("preset", ["forehead-low", "forehead-moderate", "forehead-high"])
def test_measures_of_known_wrinkles_on_smooth_skin(preset):
    spec = dataclasses.replace(preset_spec(preset, size_px=256), microrelief=False)
    surface = make_surface(spec, seed=1)
    measures, errors = relative_errors(surface)
    for e in errors:
        print(preset, {k: f"{100 * v:+.1f}%" for k, v in e.items()})
    assert len(measures.wrinkles) == len(spec.wrinkles)
    for e in errors:
        assert all(abs(e[name]) <= tolerance for name, tolerance in TOLERANCES.items()), e


@pytest.mark.parametrize("shape", ["V", "U", "G"])
@pytest.mark.parametrize("width_um", [150.0, 1000.0])
def test_depth_width_length_and_volume_of_narrow_and_wide_profiles(shape, width_um):
    """The S-filter once filled the floor of narrow wrinkles (-10 to -25% in depth): with none,
    a 0.15 mm wrinkle (7.5 pixels; a V is sampled off its cusp) keeps its depth to 3%, and a curved
    (5 mm radius) wide one its length and width."""
    wrinkle = Wrinkle(depth_um=200.0, width_um=width_um, length_um=4000.0, orientation_deg=7.0, shape=shape,
                      curvature_per_mm=0.2 if width_um > 500 else 0.0)
    surface = make_surface(SurfaceSpec(size_px=(320, 320), wrinkles=(wrinkle,), microrelief=False, form_radius_mm=None), seed=0)
    measures, errors = relative_errors(surface)
    print(shape, width_um, {k: f"{100 * v:+.2f}%" for k, v in errors[0].items()})
    assert abs(errors[0]["max_depth_um"]) < 0.03 and abs(errors[0]["length_mm"]) < 0.01
    assert abs(errors[0]["mean_width_mm"]) < 0.03 and abs(errors[0]["volume_mm3"]) < 0.05
    assert measures.wrinkles[0].mean_depth_um <= measures.wrinkles[0].max_depth_um


@pytest.mark.parametrize("shape", ["V", "U", "G"])
@pytest.mark.parametrize("depth_um, furrow_depth_um", [(40.0, 30.0), (100.0, 60.0)])
def test_a_furrow_running_on_from_an_end_does_not_lengthen_the_wrinkle(shape, depth_um, furrow_depth_um):
    """A microrelief furrow (Gaussian, sigma 25 um) on the wrinkle's axis from 0.5 mm inside
    its end to 1 mm past it is deeper than half the wrinkle on the centre line: read on the
    centre line alone the ends moved out along it (+11 to +36% in length, mean depth -2 to
    -9%). The ends are found where the depth a quarter of the half-depth width beside the line
    is also gone: length and mean depth within 1% of the geometry."""
    wrinkle = Wrinkle(depth_um=depth_um, width_um=600.0, length_um=4000.0, shape=shape)
    surface = make_surface(SurfaceSpec(size_px=(320, 320), wrinkles=(wrinkle,), microrelief=False, form_radius_mm=None), seed=0)
    height = surface.height
    rows, columns = height.shape
    x = (np.arange(columns) - (columns - 1) / 2) * height.spacing[1]  # um from the centre; the wrinkle runs along x
    y = ((rows - 1) / 2 - np.arange(rows)) * height.spacing[0]
    furrow = -furrow_depth_um * np.exp(-0.5 * (y[:, None] / 25.0) ** 2) * ((x >= 1500) & (x <= 3000))[None, :]
    furrowed = HeightMap(height.z + furrow, height.spacing, height.mask)
    measured = match_wrinkle(measure_wrinkles(furrowed, segment_wrinkles(furrowed)), surface.wrinkle_labels == 1)
    truth = geometric_measures(wrinkle)
    assert measured.length_mm == pytest.approx(truth["length_mm"], rel=0.01)
    assert measured.mean_depth_um == pytest.approx(truth["mean_depth_um"], rel=0.01)


@pytest.mark.slow
def test_random_fields_on_smooth_skin_within_the_issue_tolerances():
    """Random fields (synth.random_wrinkle_spec: V/U/G, 0.15-1.2 mm wide, 20-300 um deep,
    straight or arcs down to 5 mm radius), smooth skin, no crossings: all 16 wrinkles found;
    every measure of every wrinkle at least 30 um deep (the issue's detection bar) within the
    tolerances of issue 17 (5% depths and length, 10% width and volume), among them a 57 um
    deep, 0.19 mm wide V and a 31 um, 0.42 mm U found only as straight valleys. Shallower
    wrinkles: max depth within 5%. Their half-depth region is kept within 0.75 mm of the
    points deeper than the 25 um minimum, so a curved one is measured short: the 28 um deep,
    0.48 mm wide U of radius 6.7 mm (seed 4) reads 2.35 of 2.71 mm (-13%), its volume -11%
    (bench/bench_wrinkles.py: on smooth skin 3 of 327 wrinkles outside a tolerance)."""
    failures, measured = [], 0
    for seed in range(8):
        surface = make_surface(random_wrinkle_spec(np.random.default_rng(1000 + seed), microrelief=False), seed=seed)
        for wrinkle, e in zip(surface.spec.wrinkles, relative_errors(surface, require_all=False)[1]):
            if e is None:
                continue
            measured += 1
            checked = TOLERANCES if wrinkle.depth_um >= 30 else {"max_depth_um": TOLERANCES["max_depth_um"]}
            failures += [(seed, wrinkle.depth_um, name, round(e[name], 3)) for name, tolerance in checked.items() if abs(e[name]) > tolerance]
    assert measured == 16 and not failures


def test_mean_depth_never_exceeds_max_depth():
    """A property of the definitions (both read from one centre-line profile), on wrinkles
    with furrows, roughness and noise, where a separate robust maximum once gave 77.49 um
    mean against 76.65 um max."""
    rng = np.random.default_rng(7)
    for seed in range(3):
        surface = make_surface(random_wrinkle_spec(rng, microrelief=True), seed=seed)
        for w in measure_wrinkles(surface.height, segment_wrinkles(surface.height)).wrinkles:
            assert w.mean_depth_um <= w.max_depth_um


def test_centre_line_is_the_longest_path_without_side_branches():
    skeleton = np.zeros((40, 80), bool)
    skeleton[20, 10:70] = True  # 60 pixels along x
    skeleton[21:30, 40] = True  # a side branch of 9 pixels
    skeleton[5, 5:8] = True  # a second piece, 3 pixels
    paths = centre_lines(skeleton, (2.0, 1.5))
    assert sorted(len(path) for path in paths) == [3, 60]
    main_path = max(paths, key=len)
    frame = wrinkle_frame(main_path, (2.0, 1.5), smoothing_um=100.0, extension_um=0.0, half_span_um=3.0, step_um=0.5)
    assert frame.s[-1] == pytest.approx(59 * 1.5, abs=0.5)
    np.testing.assert_allclose((frame.direction_deg() + 90) % 180 - 90, 0.0, atol=1e-6)  # axial: 180 is 0


@pytest.mark.parametrize("points, window", [(5, 5), (6, 5), (40, 11), (101, 21)])
def test_savitzky_golay_smoothing_matches_scipy(points, window):
    """The path smoother against scipy.signal.savgol_filter (quadratic, ends fitted by the end
    windows' quadratic), on 2-D paths and 1-D profiles; and a parabola passes unchanged."""
    import scipy.signal

    path = np.random.default_rng(points).normal(size=(points, 2)).cumsum(axis=0)
    np.testing.assert_allclose(quadratic_savitzky_golay(path, window), scipy.signal.savgol_filter(path, window, 2, axis=0, mode="interp"),
                               atol=1e-12)
    np.testing.assert_allclose(quadratic_savitzky_golay(path[:, 0], window), scipy.signal.savgol_filter(path[:, 0], window, 2, mode="interp"),
                               atol=1e-12)
    t = np.arange(points, dtype=float)
    np.testing.assert_allclose(quadratic_savitzky_golay(3 - 2 * t + 0.5 * t**2, window), 3 - 2 * t + 0.5 * t**2, atol=1e-9)


def test_frame_of_a_staircase_line_has_its_true_length_and_direction():
    """An 8-connected digital line at 22.5 degrees: counting steps of 1 and sqrt(2) pixels
    overstates its length by 8%; the smoothed frame is within 0.5%, and its direction
    within 0.5 degrees."""
    angle = np.radians(22.5)
    columns = np.arange(200)
    path = np.stack([np.rint(100 - columns * np.tan(angle)).astype(int), columns], axis=-1)  # rows run down: y up
    frame = wrinkle_frame(path, (1.0, 1.0), smoothing_um=25.0, extension_um=0.0, half_span_um=2.0, step_um=0.5)
    assert frame.s[-1] == pytest.approx(199 / np.cos(angle), rel=0.005)
    np.testing.assert_allclose(np.median(frame.direction_deg()), 22.5, atol=0.5)


@pytest.mark.parametrize("angle", [0.0, 30.0, 90.0, 135.0])
def test_orientation_centroid_and_severity_of_a_known_straight_wrinkle(angle):
    """One straight wrinkle at a known angle (counter-clockwise from +x, y up) and position on
    smooth skin: orientation within 2 degrees (as an axial angle), centroid within 0.1 mm,
    severity = mean depth x length / 100 by definition."""
    wrinkle = Wrinkle(depth_um=120.0, width_um=500.0, length_um=3500.0, orientation_deg=angle, centre_um=(300.0, -200.0), shape="U")
    spec = SurfaceSpec(size_px=(256, 256), pixel_um=20.0, wrinkles=(wrinkle,), microrelief=False, roughness_rms_um=0.2, form_radius_mm=None)
    surface = make_surface(spec, seed=0)
    measures = measure_wrinkles(surface.height, segment_wrinkles(surface.height))
    assert len(measures.wrinkles) == 1
    w = measures.wrinkles[0]
    difference = (w.orientation_deg - angle + 90) % 180 - 90
    assert abs(difference) < 2.0 and 0 <= w.orientation_deg < 180
    centre_x_mm, centre_y_mm = (2560 + 300) / 1000, (2560 + 200) / 1000  # image coordinates: x right, rows down from the top
    assert w.centroid_x_mm == pytest.approx(centre_x_mm, abs=0.1) and w.centroid_y_mm == pytest.approx(centre_y_mm, abs=0.1)
    assert w.severity == pytest.approx(w.mean_depth_um * w.length_mm / 100, rel=1e-12)


@pytest.mark.parametrize("angle, depths", [(90.0, (150.0, 80.0)), (60.0, (120.0, 100.0)), (35.0, (100.0, 100.0))])
def test_crossing_wrinkles_are_measured_each_on_its_own(angle, depths):
    """Two wrinkles that cross (one basin group, so one label before the split) are split
    into two, each measured by its own geometry: depth, width and length within the issue's
    tolerances; the volume of the part inside the other is interpolated along the line, within
    25% (measured 3-20%)."""
    wrinkles = (Wrinkle(depth_um=depths[0], width_um=500.0, length_um=4500.0, orientation_deg=5.0, shape="U"),
                Wrinkle(depth_um=depths[1], width_um=400.0, length_um=4000.0, orientation_deg=5.0 + angle, centre_um=(200.0, -100.0),
                        shape="V"))
    surface = make_surface(SurfaceSpec(size_px=(320, 320), pixel_um=20.0, wrinkles=wrinkles, microrelief=False), seed=1)
    segmentation = segment_wrinkles(surface.height)
    assert segmentation.count == 2
    _, errors = relative_errors(surface)
    for measure, tolerance in TOLERANCES.items():
        allowed = 0.25 if measure in ("volume_mm3", "cross_section_mm2") else tolerance
        assert all(abs(e[measure]) <= allowed for e in errors), (measure, [e[measure] for e in errors])


def test_field_totals_of_two_known_wrinkles():
    """Ids from the top down, and the totals of wrinkles.json against the two wrinkles' geometry: count, total length (sum of
    the exact lengths), length-weighted mean depth, the axial mean orientation (175 and 30
    degrees: 8.3 weighted by length, 12.5 unweighted, 102.5 as a plain mean), and the
    area fraction of the half-depth regions (the simulator's exact labels)."""
    wrinkles = (Wrinkle(depth_um=150.0, width_um=500.0, length_um=4000.0, orientation_deg=175.0, centre_um=(0.0, -1200.0), shape="U"),
                Wrinkle(depth_um=90.0, width_um=400.0, length_um=2600.0, orientation_deg=30.0, centre_um=(0.0, 1200.0), shape="G"))
    spec = SurfaceSpec(size_px=(300, 300), pixel_um=20.0, wrinkles=wrinkles, microrelief=False, roughness_rms_um=0.2, form_radius_mm=None)
    surface = make_surface(spec, seed=0)
    measures = measure_wrinkles(surface.height, segment_wrinkles(surface.height))
    totals = measures.totals
    top, bottom = measures.wrinkles  # ids 1, 2 from the top: the 90 um wrinkle (y = +1.2 mm, up) first
    assert (top.id, bottom.id) == (1, 2) and top.centroid_y_mm < bottom.centroid_y_mm
    assert top.max_depth_um == pytest.approx(90.0, rel=0.05) and bottom.max_depth_um == pytest.approx(150.0, rel=0.05)
    truth = [geometric_measures(w) for w in wrinkles]
    lengths = np.array([t["length_mm"] for t in truth])
    assert totals["count"] == 2
    assert totals["total_length_mm"] == pytest.approx(lengths.sum(), rel=0.05)
    assert totals["mean_depth_um"] == pytest.approx((lengths * [t["mean_depth_um"] for t in truth]).sum() / lengths.sum(), rel=0.05)
    doubled = np.radians(2 * np.array([175.0, 30.0]))
    weighted = np.degrees(np.arctan2((lengths * np.sin(doubled)).sum(), (lengths * np.cos(doubled)).sum())) / 2
    assert (totals["mean_orientation_deg"] - weighted + 90) % 180 - 90 == pytest.approx(0, abs=1.5)
    assert totals["area_fraction"] == pytest.approx((surface.wrinkle_labels > 0).mean(), rel=0.10)


def test_centre_lines_lie_on_the_true_centre_line():
    """The centre-line pixels of wrinkles.json's line image (the report's overlay) of a straight
    wrinkle at 30 degrees: within 1.5 pixels of the true line, spanning its measured length."""
    wrinkle = Wrinkle(depth_um=120.0, width_um=500.0, length_um=3500.0, orientation_deg=30.0, centre_um=(300.0, -200.0), shape="U")
    spec = SurfaceSpec(size_px=(256, 256), pixel_um=20.0, wrinkles=(wrinkle,), microrelief=False, roughness_rms_um=0.2, form_radius_mm=None)
    surface = make_surface(spec, seed=0)
    measures = measure_wrinkles(surface.height, segment_wrinkles(surface.height))
    rows, columns = np.nonzero(measures.lines)
    x, y = (columns - 127.5) * 20.0 - 300.0, (127.5 - rows) * 20.0 + 200.0  # um from the wrinkle's centre, y up
    theta = np.radians(30.0)
    across = -x * np.sin(theta) + y * np.cos(theta)
    along = x * np.cos(theta) + y * np.sin(theta)
    assert np.abs(across).max() < 1.5 * 20.0
    assert (along.max() - along.min()) / 1000 == pytest.approx(measures.wrinkles[0].length_mm, rel=0.05)
    assert measures.lines[measures.labels == 1].sum() > 0.8 * measures.lines.sum()  # mostly on the wrinkle's own core
    assert measures.as_dict()["totals"] == measures.totals and len(measures.as_dict()["wrinkles"]) == 1


def test_depth_s_filter_option_and_settings_errors():
    """short_cutoff_um S-filters the height before the depth is read, as measuring the filtered
    map does, and a narrow wrinkle then reads shallower (the bias the default avoids); settings
    that cannot be are refused by name."""
    from skintopo.filters import areal_gaussian_filter
    from skintopo.wrinkles import WrinkleSettings, wrinkle_table

    wrinkle = Wrinkle(depth_um=150.0, width_um=200.0, length_um=3500.0, orientation_deg=5.0, shape="V")
    surface = make_surface(SurfaceSpec(size_px=(200, 200), wrinkles=(wrinkle,), microrelief=False, form_radius_mm=None), seed=0)
    segmentation = segment_wrinkles(surface.height)
    filtered = wrinkle_table(surface.height, segmentation, properties=("label", "max_depth_um"), short_cutoff_um=250.0)
    plain = wrinkle_table(surface.height, segmentation, properties=("label", "max_depth_um"))
    height = surface.height
    prefiltered = HeightMap(areal_gaussian_filter(height.z, height.spacing, 250.0, height.mask), height.spacing, height.mask)
    again = wrinkle_table(prefiltered, segmentation, properties=("max_depth_um",))
    assert list(filtered["label"]) == [1]
    assert filtered["max_depth_um"][0] == pytest.approx(again["max_depth_um"][0], rel=1e-4)  # the field levels first: rounding
    assert filtered["max_depth_um"][0] < 0.9 * plain["max_depth_um"][0]
    with pytest.raises(ValueError, match="unknown wrinkle properties \\['depth'\\]; the measures are id, centroid_x_mm"):
        wrinkle_table(height, segmentation, properties=("depth",))
    with pytest.raises(SkinTopoError, match="the margin length must be positive, got 0.0 um"):
        WrinkleSettings(margin_um=0.0)
    with pytest.raises(SkinTopoError, match="the depth's S-filter cut-off must be 0 \\(none\\) or positive, got -1.0 um"):
        WrinkleSettings(short_cutoff_um=-1.0)


def test_no_wrinkles_and_a_segmentation_of_another_map():
    """A field without wrinkles has no measures and zero totals; a segmentation made on a map of
    another size is refused, also when it found nothing."""
    flat = HeightMap(np.zeros((60, 80)), 20.0)
    measures = measure_wrinkles(flat, segmentation_from_labels(np.zeros((60, 80), np.int32), 20.0))
    assert measures.wrinkles == [] and measures.totals["count"] == 0 and measures.totals["total_length_mm"] == 0
    with pytest.raises(ValueError, match="shape"):
        measure_wrinkles(flat, segmentation_from_labels(np.zeros((50, 80), np.int32), 20.0))


def test_any_labelled_region_is_measured_or_left_out_never_an_error():
    """Regions that are no wrinkle's (boxes of 3-30 pixels on the skin beside a 80 um wrinkle,
    across it, at the map's edge) are measured when their floor reaches half depth somewhere
    and left out otherwise; never an IndexError from an empty floor profile (the former code
    raised on 265 of 576 such boxes: the profile's NaN made its maximum NaN, and a floor above
    the surrounding skin had no sample at half depth)."""

    spec = SurfaceSpec(size_px=(128, 128), pixel_um=20.0, microrelief=False,
                       wrinkles=(Wrinkle(depth_um=80.0, width_um=400.0, length_um=1500.0, shape="V"),))
    height = make_surface(spec, seed=1).height
    for top, left, rows, columns in ((0, 0, 3, 3), (0, 32, 30, 30), (16, 64, 3, 8), (60, 40, 8, 30), (56, 120, 30, 8), (100, 100, 30, 30)):
        labels = np.zeros(height.shape, np.int32)
        labels[top:top + rows, left:left + columns] = 1
        measures = measure_wrinkles(height, segmentation_from_labels(labels, height.spacing))
        for wrinkle in measures.wrinkles:
            assert np.isfinite(wrinkle.max_depth_um) and wrinkle.mean_depth_um <= wrinkle.max_depth_um


def test_a_valley_shallower_than_the_minimum_depth_is_not_a_wrinkle():
    """The segmentation only proposes candidates; a wrinkle is one whose max depth (from the
    geometry, this module's) reaches the segmentation's minimum depth. A 60 um deep wrinkle
    reads about 60 um: kept at a minimum of 55 um, left out at 65 um. Labels given by hand
    (no minimum depth) are measured whatever their depth."""
    wrinkle = Wrinkle(depth_um=60.0, width_um=500.0, length_um=4000.0, orientation_deg=5.0, shape="U")
    surface = make_surface(SurfaceSpec(size_px=(256, 256), wrinkles=(wrinkle,), microrelief=False, form_radius_mm=None), seed=0)
    segmentation = segment_wrinkles(surface.height)
    depth = measure_wrinkles(surface.height, segmentation).wrinkles[0].max_depth_um
    assert depth == pytest.approx(60.0, rel=0.03)
    for minimum, count in ((55.0, 1), (65.0, 0)):
        stricter = dataclasses.replace(segmentation, parameters={**segmentation.parameters, "min_depth_um": minimum})
        measures = measure_wrinkles(surface.height, stricter)
        assert len(measures.wrinkles) == count and measures.totals["count"] == count
        assert (measures.labels > 0).any() == bool(count)
    assert len(measure_wrinkles(surface.height, segmentation_from_labels(segmentation.labels, surface.height.spacing)).wrinkles) == 1


def test_a_skin_level_is_set_even_far_inside_a_wide_wrinkled_area():
    """Where no skin lies within the skin level's regression (the middle of a 6 mm wrinkled
    area), the regression has no value: the level is carried on from the nearest point that
    has one, and the wrinkle is measured instead of failing deep inside NumPy."""
    wrinkle = Wrinkle(depth_um=100.0, width_um=600.0, length_um=4000.0, orientation_deg=0.0, shape="U")
    surface = make_surface(SurfaceSpec(size_px=(500, 500), wrinkles=(wrinkle,), microrelief=False, form_radius_mm=None), seed=0)
    segmentation = segment_wrinkles(surface.height)
    extent = np.zeros(surface.height.shape, bool)
    extent[100:400, 100:400] = True  # 6 mm x 6 mm around the wrinkle, at 20 um pixels
    wide = dataclasses.replace(segmentation, extent=segmentation.extent | extent)
    field = wrinkle_field(surface.height, wide)
    assert np.isfinite(field.reference).all()
    measured = match_wrinkle(measure_wrinkles(surface.height, wide), surface.wrinkle_labels == 1)
    assert measured.max_depth_um == pytest.approx(geometric_measures(wrinkle)["max_depth_um"], rel=0.05)
