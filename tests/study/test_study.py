"""Study files and trial statistics: validation reports every problem; statistics against SciPy."""


import numpy as np
import pandas as pd
import pytest

from skintopo.batch import read_study
from skintopo.errors import SkinTopoError
from skintopo.study import study_statistics


def test_study_statistics_against_scipy():
    from scipy import stats

    before = {"S1": 10.0, "S2": 12.5, "S3": 9.0, "S4": 14.0, "S5": 11.0}
    after = {"S1": 8.9, "S2": 12.9, "S3": 7.1, "S4": 12.2, "S5": 10.1}
    changes = pd.DataFrame([{"subject": s, "region": "fh", "baseline_visit": "V1", "visit": "V2", "parameter": "Sa",
                             "baseline": before[s], "follow_up": after[s], "change": after[s] - before[s]} for s in before]
                           + [{"subject": "S1", "region": "fh", "baseline_visit": "V1", "visit": "V2", "parameter": "wrinkle1.max_depth_um",
                               "baseline": 1.0, "follow_up": 2.0, "change": 1.0}])
    repeats = pd.DataFrame([{"subject": s, "region": "fh", "baseline_visit": "V1", "visit": "V1", "parameter": "Sa", "change": e}
                            for s, e in (("S1", 0.3), ("S2", -0.5), ("S3", 0.2))])
    visits = {("fh", "V1"): set(before) | {"S6"}, ("fh", "V2"): set(after)}
    table = study_statistics(changes, repeats, {"Sa": "um"}, visits)
    assert list(table.parameter) == ["Sa"]  # per-wrinkle rows are not pooled across subjects
    row = table.iloc[0]
    x, y = np.array(list(before.values())), np.array(list(after.values()))
    d = y - x
    t = stats.ttest_rel(y, x)
    w = stats.wilcoxon(y - x)
    half = stats.t.ppf(0.975, 4) * d.std(ddof=1) / np.sqrt(5)
    s_r = np.sqrt((0.3**2 + 0.5**2 + 0.2**2) / 6)
    expected = {"subjects": 5, "mean_change": d.mean(), "ci95_low": d.mean() - half, "ci95_high": d.mean() + half,
                "t_statistic": t.statistic, "t_p_value": t.pvalue, "wilcoxon_statistic": w.statistic, "wilcoxon_p_value": w.pvalue,
                "detection_limit": 2.8 * s_r, "repeat_pairs": 3, "fraction_beyond_limit": np.mean(np.abs(d) > 2.8 * s_r),
                "mean_change_percent": 100 * d.mean() / x.mean(), "unpaired_subjects": 1}
    for name, value in expected.items():
        assert row[name] == pytest.approx(value, rel=1e-12, abs=1e-12), name
    assert row.unit == "um"


def test_mean_change_percent_of_a_negative_parameter_and_a_missing_change():
    """Ssk from -0.8 to -0.6 on average is an increase: +25% (per cent of the baseline's
    magnitude, as change_percent of changes.csv); a subject whose change is missing (NaN) is
    left out of the mean baseline too."""
    rows = [("S1", -1.0, -0.7), ("S2", -0.6, -0.5), ("S3", -3.0, np.nan)]
    changes = pd.DataFrame([{"subject": s, "region": "fh", "baseline_visit": "V1", "visit": "V2", "parameter": "Ssk",
                             "baseline": b, "follow_up": f, "change": f - b} for s, b, f in rows])
    row = study_statistics(changes, pd.DataFrame(), {"Ssk": ""}, {("fh", "V1"): {"S1", "S2", "S3"}, ("fh", "V2"): {"S1", "S2", "S3"}}).iloc[0]
    assert row.subjects == 2 and row.mean_change == pytest.approx(0.2)
    assert row.mean_change_percent == pytest.approx(100 * 0.2 / 0.8)


def test_study_validation_reports_every_problem(tmp_path):
    (tmp_path / "a").mkdir()
    (tmp_path / "study.csv").write_text("subject,visit,region,acquisition,baseline\nS1,V1,fh,a,\nS1,V1,fh,a,\nS2,V2,fh,missing,V1\n,V3,fh,a,\n")
    with pytest.raises(SkinTopoError) as error:
        read_study(tmp_path / "study.csv")
    message = str(error.value)
    assert "4 problem(s)" in message and "listed twice" in message and "'missing' not found" in message
    assert "empty subject" in message and "baseline visit 'V1' of subject S2" in message


def test_study_files_without_rows_or_columns_and_what_a_valid_one_gives(tmp_path):
    (tmp_path / "a").mkdir()
    (tmp_path / "a again").mkdir()
    header_only = tmp_path / "header.csv"
    header_only.write_text("subject,visit,region,acquisition\n")
    with pytest.raises(SkinTopoError, match=r"header.csv: the study lists no acquisition \(a header line only\)"):
        read_study(header_only)
    no_region = tmp_path / "no-region.csv"
    no_region.write_text("subject,visit,acquisition\nS1,V1,a\n")
    with pytest.raises(SkinTopoError, match=r"needs the columns \['subject', 'visit', 'region', 'acquisition'\] \(missing \['region'\]\)"):
        read_study(no_region)
    not_text = tmp_path / "binary.csv"
    not_text.write_bytes(b"subject,visit\n\xff\xfe\x00\x81\n")
    with pytest.raises(SkinTopoError, match=r"binary.csv: not a readable CSV file \('utf-8' codec can't decode"):
        read_study(not_text)
    problems = tmp_path / "problems.csv"
    problems.write_text("subject,visit,region,acquisition\nS1,,,a\nAnna,V1,cheek,a\nAnna,V1,cheek,a\n")
    with pytest.raises(SkinTopoError) as error:
        read_study(problems)
    assert "problems.csv: line 2: empty visit, region" in str(error.value)
    assert "problems.csv: line 4: subject Anna region cheek visit V1 listed twice" in str(error.value)
    study_path = tmp_path / "study.csv"
    study_path.write_text("subject,visit,region,acquisition,baseline,repeat\n"
                          "Zoë,V1,cheek,a,,a again\nZoë,V2,cheek, a ,V1,\nZoë,V3,cheek,a,,\n", encoding="utf-8")
    study = read_study(study_path)
    assert [(i.subject, i.visit, i.region, i.baseline) for i in study] == [("Zoë", "V1", "cheek", None), ("Zoë", "V2", "cheek", "V1"),
                                                                           ("Zoë", "V3", "cheek", "V1")]
    assert [i.acquisition for i in study] == [(tmp_path / "a").resolve()] * 3
    assert [i.repeat for i in study] == [(tmp_path / "a again").resolve(), None, None]
    assert study[0].key == ("Zo_", "cheek", "V1") and study[0].repeat_key == ("Zo_", "cheek", "V1~repeat")
