"""``skintopo demo`` at a small size."""

import json

import pandas as pd

from skintopo.cli import main
from skintopo.synth import preset_spec


def test_demo_command_runs_at_a_small_size(tmp_path, capsys):
    assert main(["demo", "-o", str(tmp_path / "demo"), "--size", "128"]) == 0
    printed = capsys.readouterr().out
    assert "algorithm" in printed and "report:" in printed
    assert (tmp_path / "demo" / "result" / "report.html").stat().st_size > 50_000
    summary = json.loads((tmp_path / "demo" / "summary.json").read_text())
    assert set(summary["evaluation"]) == {"red", "green", "blue", "white", "algorithm"}
    assert summary["segmentation"]["wrinkles_true"] == len(preset_spec("forehead-moderate", size_px=128).wrinkles) == 3
    measured = pd.read_csv(tmp_path / "demo" / "result" / "wrinkles.csv")
    assert summary["segmentation"]["wrinkles_found"] == len(measured) and summary["acquisition"]["shape"] == [128, 128]
