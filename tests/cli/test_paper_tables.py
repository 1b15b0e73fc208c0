"""``skintopo paper-tables``: the paper's Tables 1-2 on simulated subjects, default and paper-calibrated optics."""

import json

import numpy as np
import pytest

from skintopo.cli import main
from skintopo.optics import (
    PROFILES,
)


@pytest.mark.slow
def test_paper_tables_command(tmp_path, capsys):
    """Deterministic tables and figures; the claims that hold in the simulator are asserted,
    and the paper's full claim (algorithm better than every band) is printed for the note."""
    out = tmp_path / "tables"
    assert main(["paper-tables", "-o", str(out)]) == 0
    printed = capsys.readouterr().out
    print(printed)
    for name in ("table1_rms_height_error", "table2_l2_normal_error", "table_wrinkle_depth_error"):
        assert (out / f"{name}.csv").exists() and (out / f"{name}.md").exists()
    for figure in ("figure3_cross_section_per_band.png", "figure5_algorithm_vs_truth.png"):
        assert (out / figure).stat().st_size > 10_000

    def read(name):
        lines = (out / f"{name}.csv").read_text().splitlines()
        header = lines[0].split(",")
        return [dict(zip(header, line.split(","))) for line in lines[1:]]

    table1, depth = read("table1_rms_height_error"), read("table_wrinkle_depth_error")
    for row in table1:
        assert float(row["algorithm"]) < float(row["red"])  # the algorithm improves on red, every subject
    improvements = [1 - float(row["algorithm"]) / float(row["red"]) for row in depth]
    print("wrinkle depth error improvement over red per subject:", np.round(improvements, 3))
    assert np.mean(improvements) >= 0.30  # the bar, at the default size
    # Determinism: the same command gives the same table.
    assert main(["paper-tables", "-o", str(tmp_path / "again"), "-q"]) == 0
    assert (tmp_path / "again" / "table1_rms_height_error.csv").read_text() == (out / "table1_rms_height_error.csv").read_text()


@pytest.mark.slow
def test_paper_calibrated_reproduces_table_1_order_and_ratios(tmp_path):
    """The paper's Table 1 on four foreheads: red < green < blue on RMS height error, blue/red
    1.7-3.2 (we require [1.5, 3]) and white between red and blue; on ratios, not absolute values."""
    out = tmp_path / "tables"
    assert main(["paper-tables", "-o", str(out), "--optics", "paper-calibrated", "-q"]) == 0
    assert json.loads((out / "optics.json").read_text())["specular_scale"] == PROFILES["paper-calibrated"].specular_scale
    lines = (out / "table1_rms_height_error.csv").read_text().splitlines()
    header = lines[0].split(",")
    for line in lines[1:]:
        row = dict(zip(header, line.split(",")))
        red, green, blue, white = (float(row[b]) for b in ("red", "green", "blue", "white"))
        print(f"{row['']}: red {red:.2f} green {green:.2f} blue {blue:.2f} white {white:.2f} um")
        assert red < green < blue
        assert 1.5 <= blue / red <= 3.0
        assert red <= white <= blue
