"""``skintopo batch``: bad studies refused with clear messages and nothing written; measure options reach the items."""

import json

import pytest

from skintopo.batch import run_study
from skintopo.cli import main
from skintopo.errors import SkinTopoError
from tests.helpers.study import write_study


def test_bad_batch_inputs_give_clear_errors_and_write_nothing(tmp_path, capsys):
    study_path = tmp_path / "study" / "study.csv"
    (tmp_path / "study" / "a").mkdir(parents=True)
    study_path.write_text("subject,visit,region,acquisition\nS1,V1,fh,a\n")
    before = sorted(p.name for p in (tmp_path / "study").rglob("*"))
    with pytest.raises(SkinTopoError, match="holds the study file"):
        run_study(study_path, tmp_path / "study")
    with pytest.raises(SkinTopoError, match="overlaps the acquisition folder a"):
        run_study(study_path, tmp_path / "study" / "a" / "out")
    with pytest.raises(SkinTopoError, match="holds the study file"):
        run_study(study_path, tmp_path)
    with pytest.raises(SkinTopoError, match="--workers must be 1 or more"):
        run_study(study_path, tmp_path / "new", workers=0)
    with pytest.raises(SystemExit):
        main(["batch", str(study_path), "-o", str(tmp_path / "new2"), "--workers", "0"])
    assert "must be 1 or more" in capsys.readouterr().err
    assert sorted(p.name for p in (tmp_path / "study").rglob("*")) == before
    assert not (tmp_path / "new").exists() and not (tmp_path / "new2").exists()


def test_batch_passes_measure_options_to_its_items(tmp_path):
    study_path = write_study(tmp_path / "study", ["S"], size_px=80, depth_factors=(1.0,))
    out = tmp_path / "out"
    assert main(["batch", str(study_path), "-o", str(out), "-q", "--workers", "1", "--method", "blue", "--min-depth-um", "40"]) == 0
    summary = json.loads((out / "items" / "S" / "forehead" / "V1" / "summary.json").read_text())
    assert summary["source"]["height"] == "blue band"
    assert summary["options"]["segmentation"]["min_depth_um"] == 40.0 and summary["options"]["height"]["method"] == "blue"
    assert json.loads((out / "summary.json").read_text())["options"]["height"]["method"] == "blue"
