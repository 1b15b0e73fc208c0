import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parent))

from analytic import normals_from_slopes, paraboloid_with_wrinkles  # noqa: E402

from skintopo.acquisition import write_acquisition  # noqa: E402
from skintopo.normals import render_lambertian  # noqa: E402

SHARED = Path(__file__).resolve().parents[1].parent / "shared"
DILIGENT_BALL = SHARED / "data" / "diligent-ball"


def four_lights(slant_degrees=45.0, first_tilt_degrees=0.0):
    """The paper's geometry: 4 lights at one slant, 90 degrees apart in tilt."""
    slant = np.radians(slant_degrees)
    tilt = np.radians(first_tilt_degrees + 90.0 * np.arange(4))
    return np.stack([np.sin(slant) * np.cos(tilt), np.sin(slant) * np.sin(tilt), np.full(4, np.cos(slant))], axis=1)


@pytest.fixture
def diligent_ball():
    if not (DILIGENT_BALL / "filenames.txt").is_file():
        pytest.skip(f"DiLiGenT ball data not found at {DILIGENT_BALL} (../shared is absent in a user's clone)")
    return DILIGENT_BALL


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
