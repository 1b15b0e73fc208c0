"""Skin's diffusion profile from a black mask's edge (``skintopo calibrate skin``), against
the profile that made the image: an exact one on uniformly lit skin, the simulator's
skin-edge target (microrelief, noise) of a published profile, bad input, and the file."""

import json

import numpy as np
import pytest
import scipy.fft

from skintopo.calibration import (
    diffusion_profile_from_edge,
    read_diffusion_profiles,
    write_diffusion_profiles,
)
from skintopo.cli import main
from skintopo.errors import SkinTopoError
from skintopo.optics import ScatteringProfile, optics_profile
from skintopo.physics import ScatteringKernel
from skintopo.synth.render import default_lights
from skintopo.synth.targets import skin_edge_images

CYCLES_PER_MM = np.array([0.25, 0.5, 1.0, 2.0, 4.0])


def uniform_edge(profile, shape=(200, 400), pixel_um=20.0, edge_column=120, tilt=0.03):
    """Uniformly lit skin scattering by ``profile`` (anything with ``transfer``) right of a
    straight edge (the pixels it crosses lit and seen in proportion to their uncovered
    area), a dark mask left of it. The scattering is a convolution written here (DCT-II with
    the transfer at its frequencies: symmetric borders), not the simulator's."""
    rows, columns = np.indices(shape, dtype=float)
    uncovered = np.clip(columns + 1.0 - (edge_column + tilt * (rows + 0.5)), 0.0, 1.0)
    f = np.hypot(*np.meshgrid(np.arange(shape[0]) / (2 * shape[0] * pixel_um), np.arange(shape[1]) / (2 * shape[1] * pixel_um),
                              indexing="ij"))
    radiance = scipy.fft.idctn(scipy.fft.dctn(0.5 * uncovered, norm="ortho") * profile.transfer(f), norm="ortho")
    return uncovered * radiance + (1 - uncovered) * 0.01


@pytest.mark.parametrize("profile", [ScatteringProfile((0.6, 0.4), (0.0, 150.0)), ScatteringProfile((0.5, 0.3, 0.2), (40.0, 120.0, 500.0)),
                                     ScatteringKernel(0.7, 150.0, 1.5), ScatteringKernel(1.0, 60.0, 0.8)])
def test_edge_gives_the_transfer_of_a_known_profile(profile):
    """Profiles with light re-emerging where it entered and without, heavy-tailed ones, and
    ones that are not sums of Gaussians (the exponential profile exp(-sqrt(3) r / l), and a
    Matern shape heavier still): the transfer within 0.02 at 0.25-4 cycles/mm."""
    found, record = diffusion_profile_from_edge(uniform_edge(profile), 20.0)
    print(np.round(found.transfer(CYCLES_PER_MM / 1000), 4), np.round(profile.transfer(CYCLES_PER_MM / 1000), 4))
    assert found.transfer(CYCLES_PER_MM / 1000) == pytest.approx(profile.transfer(CYCLES_PER_MM / 1000), abs=0.02)
    assert record["edge_angle_deg"] == pytest.approx(np.degrees(np.arctan(0.03)), abs=0.1)
    assert record["level"] == pytest.approx(0.5, rel=0.01)


def test_the_mask_may_lie_on_any_side():
    profile = ScatteringProfile((0.6, 0.4), (0.0, 150.0))
    image = uniform_edge(profile)
    expected = diffusion_profile_from_edge(image, 20.0)[0].transfer(CYCLES_PER_MM / 1000)
    for turned in (image[:, ::-1], image.T, image.T[::-1]):
        assert diffusion_profile_from_edge(turned, 20.0)[0].transfer(CYCLES_PER_MM / 1000) == pytest.approx(expected, abs=1e-9)


@pytest.mark.parametrize("skin", ["light", "dark"])
def test_simulated_edge_capture_of_the_published_skin_profile(skin):
    """The simulator's skin-edge target (microrelief, sensor noise, a tilted edge) of the
    ``literature`` profile (d'Eon & Luebke's six Gaussians, heavy-tailed in red): every band's
    transfer within 0.05 of the published profile's at 0.25-4 cycles/mm."""
    optics = optics_profile("literature")
    images, _ = skin_edge_images(optics, skin, default_lights(), shape=(256, 512), pixel_um=20.0, seed=4)
    for band, image in images.items():
        found, record = diffusion_profile_from_edge(image, 20.0, name=band)
        truth = optics.scattering[band].transfer(CYCLES_PER_MM / 1000)
        print(band, np.round(found.transfer(CYCLES_PER_MM / 1000), 3), np.round(truth, 3))
        assert found.transfer(CYCLES_PER_MM / 1000) == pytest.approx(truth, abs=0.05), band
        assert record["rms_misfit_relative"] < 0.02


def test_bad_edge_images_are_refused_with_the_reason():
    profile = ScatteringProfile((0.6, 0.4), (0.0, 150.0))
    with pytest.raises(SkinTopoError, match="flat.png: no dark mask found"):
        diffusion_profile_from_edge(np.full((100, 200), 0.5), 20.0, name="flat.png")
    jagged = uniform_edge(profile)
    jagged[::2] = uniform_edge(profile, edge_column=160)[::2]
    with pytest.raises(SkinTopoError, match="not straight"):
        diffusion_profile_from_edge(jagged, 20.0)
    with pytest.raises(SkinTopoError, match="only 20 px of skin"):
        diffusion_profile_from_edge(uniform_edge(profile, shape=(100, 150), edge_column=130, tilt=0.0), 20.0)
    with pytest.raises(SkinTopoError, match="one finite grey image"):
        diffusion_profile_from_edge(np.full((10, 10, 3), np.nan), 20.0)


def test_profile_file_round_trip_and_bad_files(tmp_path):
    profiles = {"red": ScatteringProfile((0.5, 0.5), (0.0, 250.0)), "green": ScatteringProfile((1.0,), (0.0,)),
                "blue": ScatteringProfile((0.75, 0.25), (0.0, 90.0))}
    write_diffusion_profiles(tmp_path / "k.json", profiles, pixel_um=20.0)
    assert read_diffusion_profiles(tmp_path / "k.json") == profiles
    (tmp_path / "other.json").write_text(json.dumps({"format": "skintopo-device"}))
    with pytest.raises(SkinTopoError, match="other.json: not a diffusion-profile file"):
        read_diffusion_profiles(tmp_path / "other.json")
    data = json.loads((tmp_path / "k.json").read_text())
    del data["bands"]["blue"]
    (tmp_path / "nob.json").write_text(json.dumps(data))
    with pytest.raises(SkinTopoError, match=r"nob.json: no diffusion profile for \['blue'\]"):
        read_diffusion_profiles(tmp_path / "nob.json")
    data["bands"]["blue"] = {"weights": [0.5], "sigmas_um": [0.0]}
    (tmp_path / "sum.json").write_text(json.dumps(data))
    with pytest.raises(SkinTopoError, match="sum to 1"):
        read_diffusion_profiles(tmp_path / "sum.json")


def test_cli_synth_edge_target_then_calibrate_skin(tmp_path, capsys):
    """synth --target skin-edge -> calibrate skin -> a file that measure/correct take as
    --physics-kernels; an existing output is not overwritten."""
    assert main(["synth", "--target", "skin-edge", "--optics", "literature", "--size", "256", "-o", str(tmp_path / "edge"), "-q"]) == 0
    assert sorted(p.name for p in (tmp_path / "edge").iterdir()) == ["edge_blue.png", "edge_green.png", "edge_red.png", "ground_truth.json"]
    out = tmp_path / "skin.json"
    assert main(["calibrate", "skin", str(tmp_path / "edge"), "--pixel-um", "20", "-o", str(out)]) == 0
    assert "wrote" in capsys.readouterr().out
    found = read_diffusion_profiles(out)
    truth = optics_profile("literature").scattering
    assert found["red"].transfer(0.001) == pytest.approx(truth["red"].transfer(0.001), abs=0.06)
    assert main(["calibrate", "skin", str(tmp_path / "edge"), "--pixel-um", "20", "-o", str(out), "-q"]) != 0
