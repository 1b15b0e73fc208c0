"""Shared ending of the benchmark scripts: the machine they ran on, then
bench/results/NAME.json (written) and the same JSON on standard output."""

import json
import os
import platform
from pathlib import Path


def write_result(name, result):
    """Add the machine description to ``result`` and write bench/results/``name``.json."""
    result["machine"] = f"{platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}"
    text = json.dumps(result, indent=2)
    (Path(__file__).parent / "results" / f"{name}.json").write_text(text + "\n")
    print(text)
