"""``skintopo wrinkles``: outputs, and one wrinkle with one true depth in synth, wrinkles and evaluate."""

import dataclasses
import json

import pytest

from skintopo.cli import main
from skintopo.evaluation import match_wrinkle
from skintopo.segmentation import segment_wrinkles
from skintopo.synth import make_surface, preset_spec
from skintopo.wrinkles import measure_wrinkles


def test_wrinkles_command(tmp_path, capsys):
    surface = make_surface(preset_spec("forehead-moderate", size_px=192), seed=2)
    surface.height.save(tmp_path / "h.x3p")
    assert main(["wrinkles", str(tmp_path / "h.x3p"), "-o", str(tmp_path / "w")]) == 0
    data = json.loads((tmp_path / "w" / "wrinkles.json").read_text())
    assert data["totals"]["count"] == 3 and [w["id"] for w in data["wrinkles"]] == [1, 2, 3]
    assert (tmp_path / "w" / "wrinkles_overlay.png").stat().st_size > 10_000
    assert "wrinkle 1:" in capsys.readouterr().out
    flat = make_surface(preset_spec("flat-microrelief", size_px=128), seed=0)
    flat.height.save(tmp_path / "flat.x3p")
    assert main(["wrinkles", str(tmp_path / "flat.x3p"), "-o", str(tmp_path / "none")]) == 0
    assert "no wrinkles found" in capsys.readouterr().out
    assert json.loads((tmp_path / "none" / "wrinkles.json").read_text())["totals"]["count"] == 0


def test_one_wrinkle_has_one_true_depth_in_synth_wrinkles_and_evaluate(tmp_path):
    """Once a 120 um wrinkle had three 'true depths': 120 in surface.json, 152 from evaluate (ring
    median minus the lowest point, a furrow counted), 112 from wrinkles. Now surface.json holds
    the geometric measures, and evaluate and wrinkles read the same definition from the truth."""
    from skintopo.evaluation import evaluate_height

    spec = dataclasses.replace(preset_spec("forehead-moderate", size_px=256), microrelief=False)
    surface = make_surface(spec, seed=1)
    assert main(["synth", "-o", str(tmp_path / "acq"), "--preset", "forehead-moderate", "--size", "64", "-q"]) == 0
    written = json.loads((tmp_path / "acq" / "ground_truth" / "surface.json").read_text())
    assert [m["max_depth_um"] for m in written["wrinkle_measures"]] == [w["depth_um"] for w in written["surface"]["wrinkles"]]
    report = evaluate_height(surface.height, surface.height, wrinkle_labels=surface.wrinkle_labels, register=False)
    measures = measure_wrinkles(surface.height, segment_wrinkles(surface.height))
    for index, wrinkle in enumerate(spec.wrinkles):
        from_wrinkles = match_wrinkle(measures, surface.wrinkle_labels == index + 1).max_depth_um
        assert report["wrinkle_max_depth_true_um"][index] == pytest.approx(from_wrinkles, rel=0.01)
        assert report["wrinkle_max_depth_true_um"][index] == pytest.approx(wrinkle.depth_um, rel=0.02)
