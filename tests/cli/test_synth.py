"""``skintopo synth``: the skin-optics profile recorded, bad arguments refused."""

import json

import pytest

from skintopo.cli import main
from skintopo.errors import SkinTopoError
from skintopo.optics import (
    LITERATURE,
    PROFILES,
    optics_profile,
)
from skintopo.synth import SurfaceSpec, Wrinkle, make_surface, preset_spec


def test_synth_records_the_profile_and_refuses_an_unknown_one(tmp_path, capsys):
    out = tmp_path / "acq"
    assert main(["synth", "-o", str(out), "--size", "64", "--optics", "literature", "-q"]) == 0
    recorded = json.loads((out / "ground_truth" / "surface.json").read_text())["render"]["optics"]
    assert recorded["name"] == "literature" and recorded["albedo"]["light"] == LITERATURE.albedo["light"]
    assert any("d'Eon" in source for source in recorded["sources"])
    assert main(["synth", "-o", str(tmp_path / "x"), "--optics", "marble"]) == 2
    assert "unknown skin-optics profile 'marble'" in capsys.readouterr().err
    assert not (tmp_path / "x").exists()
    assert optics_profile(LITERATURE) is LITERATURE and set(PROFILES) == {"default-v1", "literature", "paper-calibrated"}


def test_bad_arguments_are_refused(tmp_path, capsys):
    with pytest.raises(SkinTopoError, match="depth must be positive"):
        make_surface(SurfaceSpec(size_px=(64, 64), wrinkles=(Wrinkle(-50, 400, 800),)))
    with pytest.raises(SkinTopoError, match="not smaller than the field"):
        make_surface(SurfaceSpec(size_px=(64, 64), pixel_um=10, wrinkles=(Wrinkle(50, 900, 500),)))
    with pytest.raises(SkinTopoError, match="pixel size must be positive"):
        preset_spec("forehead-low", pixel_um=0)
    with pytest.raises(SkinTopoError, match="unknown preset"):
        preset_spec("cheek")
    assert main(["synth", "-o", str(tmp_path / "x"), "--preset", "cheek"]) == 2
    assert "unknown preset 'cheek'" in capsys.readouterr().err
    assert not (tmp_path / "x").exists()
