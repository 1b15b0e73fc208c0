"""``skintopo correct`` and ``evaluate``: the paper's correction and the physically based height from the command line."""

import json
import subprocess
import sys

import numpy as np
import pytest

from skintopo.acquisition import write_acquisition
from skintopo.cli import main
from skintopo.formats import read_height
from skintopo.normals import render_lambertian
from tests.helpers.analytic import four_lights

BANDS = ("red", "green", "blue")


def test_correct_and_evaluate_commands(tmp_path, capsys):
    acquisition = tmp_path / "acq"
    assert main(["synth", "-o", str(acquisition), "--preset", "forehead-moderate", "--size", "128", "-q"]) == 0
    assert main(["correct", str(acquisition), "-o", str(tmp_path / "corr"), "-q"]) == 0
    summary = json.loads((tmp_path / "corr" / "summary.json").read_text())
    assert summary["options"]["height"]["method"] == "paper" and summary["wrinkles_found"] >= 1
    for name in ("height.x3p", "wrinkles.png", "red/height.x3p", "white/height.x3p"):
        assert (tmp_path / "corr" / name).exists()
    report = tmp_path / "evaluation.json"
    args = ["evaluate", str(tmp_path / "corr" / "height.x3p"), str(acquisition / "ground_truth" / "height.x3p"), "-o", str(report)]
    assert main(args + ["--wrinkles", str(acquisition / "ground_truth" / "wrinkles.png")]) == 0
    data = json.loads(report.read_text())
    # the RMS written out from the two files: difference, least-squares plane removed (the
    # command's sub-pixel registration moves it by well under 1%)
    (found, _), (truth, _) = read_height(tmp_path / "corr" / "height.x3p"), read_height(acquisition / "ground_truth" / "height.x3p")
    difference = (found - truth).ravel()
    rows, columns = np.mgrid[: truth.shape[0], : truth.shape[1]]
    design = np.column_stack([np.ones(difference.size), rows.ravel(), columns.ravel()])
    residual = difference - design @ np.linalg.lstsq(design, difference, rcond=None)[0]
    assert data["rms_height_error_um"] == pytest.approx(np.sqrt(np.mean(residual**2)), rel=0.01)
    found_depths, true_depths = np.array(data["wrinkle_max_depth_um"]), np.array(data["wrinkle_max_depth_true_um"])
    assert len(found_depths) == 3 and np.isfinite(found_depths).all()
    np.testing.assert_allclose(data["wrinkle_depth_error_relative"], np.abs(found_depths - true_depths) / true_depths, rtol=1e-12)
    assert main(args) == 2 and "exists" in capsys.readouterr().err


def test_correct_refuses_an_acquisition_without_red_green_blue(tmp_path, capsys):
    normals = np.dstack([np.zeros((20, 20)), np.zeros((20, 20)), np.ones((20, 20))])
    lights = four_lights()
    write_acquisition(tmp_path / "white", {"white": (render_lambertian(normals, 0.5, lights), lights)}, 20.0)
    assert main(["correct", str(tmp_path / "white"), "-o", str(tmp_path / "out"), "-q"]) == 2
    err = capsys.readouterr().err
    assert "needs red, green and blue images; missing ['red', 'green', 'blue']" in err
    assert not (tmp_path / "out").exists()


def test_correct_physics_writes_the_height_and_physics_json(tmp_path):
    acquisition = tmp_path / "acq"
    run = [sys.executable, "-m", "skintopo.cli"]
    subprocess.run([*run, "synth", "-o", str(acquisition), "--size", "128", "--seed", "2", "-q"], check=True)
    done = subprocess.run([*run, "correct", str(acquisition), "-o", str(tmp_path / "out"), "--method", "physics"],
                          capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert "height: physics" in done.stdout
    record = json.loads((tmp_path / "out" / "physics.json").read_text())
    assert set(record["kernels"]) == set(BANDS) and record["iterations"] >= 1 and isinstance(record["converged"], bool)
    assert (tmp_path / "out" / "height.x3p").is_file()
    measured = subprocess.run([*run, "measure", str(acquisition), "-o", str(tmp_path / "measured"), "--method", "physics"],
                              capture_output=True, text=True)
    assert measured.returncode == 0, measured.stderr
    assert "measured height: physics" in measured.stdout
    kept = json.loads((tmp_path / "measured" / "parameters.json").read_text())["summary"]["source"]["physics"]
    assert kept["kernels"] == record["kernels"] and kept["converged"] == record["converged"]
    assert record["components"]["kernels_given"] is False and isinstance(record["plausible"], bool)
    given = subprocess.run([*run, "measure", str(acquisition), "-o", str(tmp_path / "given"), "--method", "physics",
                            "--physics-kernels", "default-v1", "--solver", "robust"], capture_output=True, text=True)
    assert given.returncode == 0, given.stderr
    summary = json.loads((tmp_path / "given" / "parameters.json").read_text())["summary"]
    assert summary["source"]["physics"]["components"]["kernels_given"] is True
    assert summary["source"]["physics"]["components"]["solver"] == "robust" and record["components"]["solver"] == "least-squares"
    assert summary["source"]["physics"]["kernels"]["red"]["transfer_at_cycles_per_mm"]["8"] == pytest.approx(0.5, abs=1e-6)  # 50% spread
    unknown = subprocess.run([*run, "correct", str(acquisition), "-o", str(tmp_path / "unknown"), "--method", "physics",
                              "--physics-kernels", "marble"], capture_output=True, text=True)
    assert unknown.returncode != 0 and "unknown skin-optics profile 'marble'" in unknown.stderr and "Traceback" not in unknown.stderr
    only_two = tmp_path / "two"
    subprocess.run([*run, "synth", "-o", str(only_two), "--size", "32", "-q"], check=True)
    manifest = json.loads((only_two / "acquisition.json").read_text())
    manifest["images"] = [image for image in manifest["images"] if image["band"] != "blue"]
    (only_two / "acquisition.json").write_text(json.dumps(manifest))
    refused = subprocess.run([*run, "correct", str(only_two), "-o", str(tmp_path / "refused"), "--method", "physics"],
                             capture_output=True, text=True)
    assert refused.returncode != 0 and "missing ['blue']" in refused.stderr and "Traceback" not in refused.stderr
    assert not (tmp_path / "refused").exists()
