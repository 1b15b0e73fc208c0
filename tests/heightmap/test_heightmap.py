"""The immutable height map: units, mask, and its files (x3p in metres, npy with a pixel size)."""

import numpy as np
import pytest
import x3pio

from skintopo.errors import SkinTopoError
from skintopo.heightmap import HeightMap


class TestHeightMap:
    def make(self):
        z = np.arange(12.0).reshape(3, 4) * 7.5
        z[1, 2] = np.nan
        return HeightMap(z, (2.0, 3.0))

    def test_immutable(self):
        height = self.make()
        with pytest.raises(ValueError):
            height.z[0, 0] = 1
        with pytest.raises(AttributeError):
            height.spacing = (1.0, 1.0)
        assert not height.mask[1, 2] and height.mask.sum() == 11
        assert height.extent_um == (6.0, 12.0)

    def test_x3p_round_trip_in_metres(self, tmp_path):
        height = self.make()
        height.save(tmp_path / "h.x3p")
        raw = x3pio.read(tmp_path / "h.x3p").layers[0]
        np.testing.assert_allclose(raw.z, height.z * 1e-6, equal_nan=True)  # metres in the file
        np.testing.assert_allclose(raw.spacing[:2], (3e-6, 2e-6))  # (dx, dy)
        back = HeightMap.load(tmp_path / "h.x3p")
        np.testing.assert_allclose(back.z, height.z, rtol=2.0**-24 * (1 + 1e-6), atol=0, equal_nan=True)  # stored as binary32
        assert back.spacing == pytest.approx(height.spacing)
        np.testing.assert_array_equal(back.mask, height.mask)

    def test_npy_round_trip_needs_pixel_size(self, tmp_path):
        height = HeightMap(np.ones((3, 3)), 5.0)
        height.save(tmp_path / "h.npy")
        with pytest.raises(SkinTopoError, match="no pixel size"):
            HeightMap.load(tmp_path / "h.npy")
        back = HeightMap.load(tmp_path / "h.npy", pixel_um=5.0)
        np.testing.assert_array_equal(back.z, height.z)

    def test_bad_inputs(self, tmp_path):
        with pytest.raises(SkinTopoError, match="spacing"):
            HeightMap(np.ones((2, 2)), -1.0)
        with pytest.raises(SkinTopoError, match="2-D"):
            HeightMap(np.ones(3), 1.0)
        with pytest.raises(SkinTopoError, match="unknown height map format"):
            HeightMap(np.ones((2, 2)), 1.0).save(tmp_path / "h.bmp")
        (tmp_path / "bad.x3p").write_bytes(b"not a zip")
        with pytest.raises(SkinTopoError, match="bad.x3p: not a readable .x3p height map"):
            HeightMap.load(tmp_path / "bad.x3p")
        assert not list(tmp_path.glob("*.part"))
