"""Headless Chromium (Debian's ``chromium``) for the report tests: screenshots, and the
3-D view driven by injected mouse, wheel and touch events (``view3d_probe.js``)."""

import json
import re
import shutil
import subprocess
from pathlib import Path

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
QUIET = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run", "--disable-background-networking",
         "--disable-component-update", "--disable-sync"]


def screenshot(page: Path, out: Path, width, height, profile: Path):
    """A screenshot of ``page`` in a window of ``width`` x ``height`` pixels; Chromium's stderr."""
    run = subprocess.run([CHROMIUM, *QUIET, "--hide-scrollbars", "--enable-logging=stderr", "--v=0", f"--user-data-dir={profile}",
                          f"--screenshot={out}", f"--window-size={width},{height}", page.as_uri()],
                         capture_output=True, text=True, timeout=120)
    return run.stderr


def probe_3d_view(page: Path, tmp: Path):
    """Open a copy of the report with ``view3d_probe.js`` appended: it drags with the mouse,
    turns the wheel, pinches with two fingers, swipes with one and presses Reset view, and
    records the view's state and pixels after each (``snapshot`` of the page's view3d)."""
    probe = (Path(__file__).with_name("view3d_probe.js")).read_text()
    copy = tmp / "probe.html"
    copy.write_text(page.read_text().replace("</body>", f"<script>{probe}</script></body>"))
    run = subprocess.run([CHROMIUM, *QUIET, f"--user-data-dir={tmp / 'probe-profile'}", "--virtual-time-budget=10000", "--dump-dom",
                          copy.as_uri()], capture_output=True, text=True, timeout=120)
    found = re.search(r'data-probe="([^"]*)"', run.stdout)
    assert found, f"the probe did not run: {run.stderr[-2000:]}"
    return json.loads(found.group(1).replace("&quot;", '"'))
