"""``skintopo demo`` at a small size."""

import json

from skintopo.cli import main


def test_demo_command_runs_at_a_small_size(tmp_path, capsys):
    assert main(["demo", "-o", str(tmp_path / "demo"), "--size", "128"]) == 0
    printed = capsys.readouterr().out
    assert "algorithm" in printed and "report:" in printed
    assert (tmp_path / "demo" / "result" / "report.html").stat().st_size > 50_000
    summary = json.loads((tmp_path / "demo" / "summary.json").read_text())
    assert set(summary["evaluation"]) == {"red", "green", "blue", "white", "algorithm"}
