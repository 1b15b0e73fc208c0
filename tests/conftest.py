import os
from pathlib import Path

import pytest

from skintopo.acquisition import write_acquisition
from skintopo.normals import render_lambertian
from tests.helpers.analytic import four_lights, normals_from_slopes, paraboloid_with_wrinkles

SHARED = Path(__file__).resolve().parents[1].parent / "shared"
DILIGENT_BALL = SHARED / "data" / "diligent-ball"


@pytest.fixture
def diligent_ball():
    if not (DILIGENT_BALL / "filenames.txt").is_file():
        pytest.skip(f"DiLiGenT ball data not found at {DILIGENT_BALL} (../shared is absent in a user's clone)")
    return DILIGENT_BALL


@pytest.fixture
def mitsuba_renderer():
    """tests/helpers/mitsuba_render.py, the second renderer (Mitsuba 3); skips when mitsuba is absent."""
    try:
        import mitsuba  # noqa: F401

        from tests.helpers import mitsuba_render
    except ImportError as error:
        pytest.skip(f"mitsuba (the second renderer) is not installed: {error}")
    return mitsuba_render


@pytest.fixture
def lambertian_acquisition(tmp_path):
    """A 12-image (4 lights x red/green/blue) 16-bit acquisition of an analytic surface."""
    z, p, q = paraboloid_with_wrinkles(shape=(48, 64), spacing=10.0)
    normals = normals_from_slopes(p, q)
    lights = four_lights()
    albedo = {"red": 0.6, "green": 0.41, "blue": 0.33}
    bands = {band: (render_lambertian(normals, a, lights), lights) for band, a in albedo.items()}
    folder = tmp_path / "acq"
    write_acquisition(folder, bands, 10.0)
    return folder, z, normals


# CI sets SKINTOPO_REQUIRE=gwyddion,chromium,diligent after installing the tools (.ci/run): a test
# skipped for want of one of them then fails the run, so the oracle and browser tests cannot
# silently stop running. On a user's machine they skip with their reason.
_REQUIRED = [word for word in os.environ.get("SKINTOPO_REQUIRE", "").lower().split(",") if word]
_required_skips = []


def pytest_runtest_logreport(report):
    if report.skipped and _REQUIRED:
        reason = str(report.longrepr).lower()
        if any(word in reason for word in _REQUIRED):
            _required_skips.append(f"{report.nodeid}: {report.longrepr}")


def pytest_sessionfinish(session, exitstatus):
    if _required_skips:
        print(f"\n{len(_required_skips)} test(s) skipped although SKINTOPO_REQUIRE asks for their tools:")
        for line in _required_skips:
            print("  " + line)
        session.exitstatus = 1
