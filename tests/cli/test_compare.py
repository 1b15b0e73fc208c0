"""``skintopo compare``: outputs, bad inputs, the albedo carried by the registration, and a visit pair rehearsed from the command line."""

import dataclasses
import json

import numpy as np
import pytest
import scipy.ndimage

from skintopo.cli import main
from skintopo.compare import compare_visits
from skintopo.errors import SkinTopoError
from skintopo.height import integrate_normals
from skintopo.heightmap import HeightMap
from skintopo.normals import photometric_stereo
from skintopo.registration import register_height_maps, residual_misalignment
from skintopo.synth import default_settings, make_surface, preset_spec, simulate_acquisition
from tests.helpers.transforms import transformed_view


def visit(spec, noise_seed):
    surface = make_surface(spec, seed=5)
    bands, _ = simulate_acquisition(surface, default_settings(), seed=noise_seed)
    stereo = photometric_stereo(*bands["white"])
    return integrate_normals(stereo.normals, spec.pixel_um, mask=stereo.valid)


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


def test_colour_maps_and_pores_are_compared_over_the_registered_overlap():
    """The same skin (wrinkles, 8 pores, 20 um pixels) seen again rotated 2.4 degrees and
    moved, its melanin made 10% darker everywhere and its haemoglobin unchanged: the pore
    count does not change, melanin.mean changes by +10% (within 0.5%), haemoglobin.mean by
    0 (within 0.5%); maps of another size than their height are refused."""
    from skintopo.synth.surfaces import place_pores

    spec = place_pores(dataclasses.replace(preset_spec("forehead-moderate", size_px=384), plate_um=700.0), 3, 8, radius_um=(50.0, 120.0),
                       depth_um=(40.0, 120.0))
    big = make_surface(spec, seed=3).height.z
    rng = np.random.default_rng(4)
    melanin = 0.12 * (1 + 0.2 * scipy.ndimage.gaussian_filter(rng.normal(size=big.shape), 8) / 0.035)
    haemoglobin = 0.1 * (1 + 0.2 * scipy.ndimage.gaussian_filter(rng.normal(size=big.shape), 8) / 0.035)
    views = [(0.0, (0, 0)), (2.4, (1.7, -0.6))]
    heights = [HeightMap(transformed_view(big, 256, 64, a, t), 20.0) for a, t in views]
    colours = [{"melanin": transformed_view(melanin, 256, 64, a, t) * factor, "haemoglobin": transformed_view(haemoglobin, 256, 64, a, t)}
               for (a, t), factor in zip(views, (1.0, 1.1))]
    comparison = compare_visits(*heights, baseline_colour=colours[0], follow_up_colour=colours[1])
    assert comparison.pores["count"]["baseline"] >= 3 and comparison.pores["count"]["change"] == 0
    assert comparison.colour["melanin.mean"]["change_percent"] == pytest.approx(10.0, abs=0.5)
    assert comparison.colour["haemoglobin.mean"]["change_percent"] == pytest.approx(0.0, abs=0.5)
    with pytest.raises(SkinTopoError, match="do not match their height maps"):
        compare_visits(*heights, baseline_colour=colours[0], follow_up_colour={k: v[:-1] for k, v in colours[1].items()})
