"""The simulator: exact ground truth, closed-form radiosity checks, the paper's effect."""

import dataclasses

import numpy as np
import pytest

from skintopo.height import dct_poisson, integrate_normals
from skintopo.normals import angular_error_degrees, photometric_stereo
from skintopo.synth import Effects, SurfaceSpec, Wrinkle, default_settings, make_surface, optics_profile, preset_spec, simulate_acquisition
from skintopo.synth.render import cast_shadow, interreflection_operator, solve_radiosity
from tests.helpers.analytic import rms_error_after_offset


def wrinkle_depth_ratio(z, surface):
    """Least-squares factor k in z = plane + (truth without wrinkles) - k * (wrinkle relief):
    1 is the true depth, below 1 shallower."""
    relief = surface.wrinkle_depth
    rest = surface.height.z + relief
    rows, columns = np.indices(relief.shape)
    ok = np.isfinite(z)
    design = np.column_stack([np.ones(ok.sum()), rows[ok], columns[ok], -relief[ok]])
    coefficients, *_ = np.linalg.lstsq(design, z[ok] - rest[ok], rcond=None)
    return float(coefficients[3])


def v_groove(slope_degrees, size=257):
    slope = np.tan(np.radians(slope_degrees))
    x = np.arange(size) - (size - 1) / 2
    z = np.broadcast_to(slope * np.abs(x)[None, :], (size, size)).copy()
    p = np.broadcast_to(slope * np.sign(x)[None, :], (size, size))
    normals = np.dstack([-p, np.zeros_like(p), np.ones_like(p)])
    return z, normals / np.linalg.norm(normals, axis=2, keepdims=True)


def test_surface_slopes_are_exact():
    spec = SurfaceSpec(
        size_px=(160, 200), pixel_um=5.0, roughness_cutoff_px=8.0, furrow_width_um=150.0, plate_um=500.0,
        wrinkles=(Wrinkle(100, 500, 700, 20, (30, 20), 0.8, "U"), Wrinkle(60, 300, 600, -70, (-250, -50), -1.0, "U")),
    )
    surface = make_surface(spec, seed=3)
    z = surface.height.z
    # Integrating the exact slopes gives back the exact height.
    assert rms_error_after_offset(dct_poisson(surface.p, surface.q, 5.0), z) < 1e-3 * np.ptp(z)
    assert surface.wrinkle_labels.max() == 2 and (surface.wrinkle_labels == 1).sum() > 100
    np.testing.assert_allclose(np.linalg.norm(surface.normals, axis=2), 1.0)


@pytest.mark.parametrize("opening_degrees", [90.0, 120.0])
@pytest.mark.parametrize("albedo", [0.3, 0.6])
def test_radiosity_gain_in_a_v_groove_matches_the_two_facet_closed_form(opening_degrees, albedo):
    """Long V-groove, uniform irradiance: each facet sees the other with form factor
    F = (1 + cos a) / 2, so B = rho E / (1 - rho F) (field notes)."""
    z, normals = v_groove(90.0 - opening_degrees / 2)
    size = z.shape[0]
    operator = interreflection_operator(z, normals, 1.0, radius_um=size / 2)
    radiosity, iterations, _ = solve_radiosity(np.ones(z.shape), albedo, operator)
    form_factor = (1 + np.cos(np.radians(opening_degrees))) / 2
    expected = 1 / (1 - albedo * form_factor)
    gain = radiosity[size // 2, size // 2 + 1] / albedo  # beside the groove's centre line (the kink has no normal)
    print(f"a = {opening_degrees:.0f} deg, rho = {albedo}: gain {gain:.4f}, closed form {expected:.4f}, {iterations} iterations")
    assert gain == pytest.approx(expected, rel=0.02)


def test_radiosity_converges_and_conserves_energy():
    surface = make_surface(preset_spec("forehead-high", size_px=96, pixel_um=20.0), seed=0)
    z, normals = surface.height.z, surface.normals
    operator = interreflection_operator(z, normals, 20.0, radius_um=600.0)
    row_sums = np.asarray(operator.sum(axis=1)).ravel()
    assert row_sums.max() <= 1.0 + 1e-9
    light = np.array([0.5, 0.0, np.sqrt(0.75)])
    direct = np.maximum(normals @ light, 0)
    gains = []
    for albedo in (0.3, 0.6, 0.9):
        radiosity, iterations, changes = solve_radiosity(direct, albedo, operator)
        assert changes[-1] < 1e-7 and all(b <= a * 1.000001 for a, b in zip(changes, changes[1:]))
        escaping = (radiosity.ravel() * (1 - row_sums)).sum()
        assert escaping <= direct.sum()  # never more power out than in
        gains.append(radiosity.sum() / (albedo * direct.sum()))
    print("mean interreflection gain for albedo 0.3, 0.6, 0.9:", np.round(gains, 4))
    assert gains[0] < gains[1] < gains[2]  # higher albedo, more interreflection


def test_flat_surface_has_no_interreflection_and_no_shadow():
    z = np.zeros((30, 30))
    normals = np.dstack([np.zeros((30, 30)), np.zeros((30, 30)), np.ones((30, 30))])
    assert interreflection_operator(z, normals, 10.0, radius_um=200.0).nnz == 0
    assert not cast_shadow(z, 10.0, [0.7071, 0, 0.7071]).any()


def test_cast_shadow_behind_a_wall_has_the_expected_length():
    z = np.zeros((10, 60))
    z[:, 20:22] = 100.0  # a 100 um wall, 10 um pixels
    light = np.array([np.sin(np.radians(45)), 0.0, np.cos(np.radians(45))])  # from +x
    shadow = cast_shadow(z, 10.0, light)
    # Light from +x: the shadow falls on the -x side, 100 um / tan(45) = 10 pixels long
    # (column 10 sees the wall top exactly at the light elevation: lit).
    assert shadow[5, 11:20].all() and not shadow[5, :10].any() and not shadow[5, 22:].any()


@pytest.mark.parametrize("optics", ["default-v1", "literature", "paper-calibrated"])
def test_same_seed_same_images(optics):
    surface = make_surface(preset_spec("forehead-low", size_px=48, pixel_um=30.0), seed=5)
    settings = default_settings(optics=optics_profile(optics))
    first, _ = simulate_acquisition(surface, settings, seed=9)
    second, _ = simulate_acquisition(surface, settings, seed=9)
    other, _ = simulate_acquisition(surface, settings, seed=10)
    np.testing.assert_array_equal(first["red"][0], second["red"][0])
    assert not np.array_equal(first["red"][0], other["red"][0])  # another capture seed, other images


def test_a_repeat_capture_sees_the_same_skin_with_new_noise():
    """Another capture seed is another sensor noise on the same skin: its albedo variation is
    the skin's (it was the capture's, so repeats of one skin had different albedo maps), and
    the first capture of a skin renders as it always did."""
    surface = make_surface(preset_spec("forehead-low", size_px=48, pixel_um=30.0), seed=5)
    quiet = default_settings(noise=0.0)
    first, _ = simulate_acquisition(surface, quiet, seed=5)
    same, _ = simulate_acquisition(surface, quiet, seed=5, skin_seed=5)
    repeat, _ = simulate_acquisition(surface, quiet, seed=9, skin_seed=5)
    other_skin, _ = simulate_acquisition(surface, quiet, seed=9)
    np.testing.assert_array_equal(first["red"][0], same["red"][0])
    np.testing.assert_allclose(repeat["red"][0], first["red"][0], rtol=1e-6)
    assert np.abs(other_skin["red"][0] / first["red"][0] - 1).max() > 0.01  # another albedo map
    noisy, _ = simulate_acquisition(surface, default_settings(), seed=9, skin_seed=5)
    assert 0 < np.std(noisy["red"][0] - repeat["red"][0]) < 0.02
    # a later visit of the field moved on the skin: the albedo map moves with it, in a first capture as in a repeat
    moved = make_surface(dataclasses.replace(preset_spec("forehead-low", size_px=48, pixel_um=30.0), shift_um=(60.0, -30.0)), seed=5)
    moved_first, _ = simulate_acquisition(moved, quiet, seed=5)
    moved_repeat, _ = simulate_acquisition(moved, quiet, seed=9, skin_seed=5)
    np.testing.assert_allclose(moved_repeat["red"][0], moved_first["red"][0], rtol=1e-6)


@pytest.mark.slow
def test_the_papers_effect_red_shallow_blue_deep():
    surface = make_surface(preset_spec("forehead-moderate", size_px=192, pixel_um=20.0), seed=1)
    ratios = {}
    for label, effects in (
        ("all effects", Effects()),
        ("interreflection off", Effects(interreflection=False)),
        ("interreflection only", Effects(shadows=False, specular=False, translucency=False, albedo_variation=False)),
        ("none", Effects.none()),
    ):
        bands, _ = simulate_acquisition(surface, default_settings(effects=effects, noise=0.0), seed=2)
        for band in ("red", "blue"):
            images, lights = bands[band]
            stereo = photometric_stereo(images, lights)
            height = integrate_normals(stereo.normals, 20.0, mask=stereo.valid)
            ratios[label, band] = wrinkle_depth_ratio(height.z, surface)
    for (label, band), ratio in ratios.items():
        print(f"{label:>22} {band:>5}: recovered / true wrinkle depth {ratio:.3f}")
    assert ratios["all effects", "red"] < 0.95  # red: shallower than the truth
    assert ratios["all effects", "red"] < ratios["all effects", "blue"] - 0.1  # and than blue
    assert ratios["interreflection off", "red"] > ratios["all effects", "red"]  # interreflection makes red shallower
    assert ratios["interreflection only", "red"] < ratios["interreflection only", "blue"] < 1.0  # more in red (higher albedo)
    assert ratios["none", "red"] == pytest.approx(1.0, abs=0.01)


@pytest.mark.slow
def test_robust_solver_on_a_simulated_forehead_with_highlights_and_shadows():
    surface = make_surface(preset_spec("forehead-moderate", size_px=160, pixel_um=20.0), seed=1)
    effects = Effects(interreflection=False, translucency=False)  # specular highlights and cast shadows on
    bands, _ = simulate_acquisition(surface, default_settings(effects=effects, saturate=True), seed=2)
    errors = {}
    for band in ("red", "green", "blue", "white"):
        images, lights = bands[band]
        for solver in ("least-squares", "robust"):
            errors[band, solver] = float(np.nanmean(angular_error_degrees(photometric_stereo(images, lights, solver=solver).normals, surface.normals)))
        print(f"{band:>5}: least squares {errors[band, 'least-squares']:.3f} deg, robust {errors[band, 'robust']:.3f} deg")
    # Skin-level highlights clipped by saturation leave only the lobe's shoulders (under 0.3 albedo
    # above the other lights' fit): with 4 lights the robust solver leaves them in, as it must
    # on translucent skin, whose departures from Lambert's law look the same to one band
    # (test_normals.py::test_robust_solver_on_translucent_skin_stays_with_least_squares). It
    # must not do worse than least squares.
    for band in ("red", "green", "blue", "white"):
        assert errors[band, "robust"] <= errors[band, "least-squares"] + 0.01
