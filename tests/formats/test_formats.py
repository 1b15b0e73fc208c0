"""Height map formats: round trips and files readable by the other packages."""

from pathlib import Path

import numpy as np
import pytest

from skintopo.acquisition import read_image
from skintopo.errors import SkinTopoError
from skintopo.formats import read_png, write_png
from skintopo.heightmap import HeightMap


def sample():
    rng = np.random.default_rng(0)
    z = rng.normal(size=(30, 40)).cumsum(axis=1) * 3.0
    z[4, 5] = np.nan
    return HeightMap(z, (12.5, 10.0))


# x3p is written as binary32: rounded to 24 significant bits (2^-24 relative)
@pytest.mark.parametrize("suffix, tolerance", [(".x3p", 2.0**-24 * (1 + 1e-6)), (".sdf", 1e-12), (".gwy", 1e-12), (".npy", 0.0), (".tif", None), (".tiff", None)])
def test_round_trip(tmp_path, suffix, tolerance):
    height = sample()
    path = tmp_path / f"h{suffix}"
    height.save(path)
    back = HeightMap.load(path, pixel_um=10.0 if suffix == ".npy" else None)
    np.testing.assert_array_equal(back.mask, height.mask)
    if tolerance is None:  # 16-bit TIFF: within half a quantisation step of (max - min) / 65534
        step = np.nanmax(height.z) - np.nanmin(height.z)
        assert np.nanmax(np.abs(back.z - height.z)) <= 0.5 * step / 65534 + 1e-9
    else:
        np.testing.assert_allclose(back.z, height.z, rtol=tolerance, atol=tolerance, equal_nan=True)
    if suffix != ".npy":
        assert back.spacing == pytest.approx(height.spacing)


def test_files_are_readable_by_the_other_packages(tmp_path):
    import gwyfile
    import sdfio
    import x3pio

    height = sample()
    for suffix in (".x3p", ".sdf", ".gwy"):
        height.save(tmp_path / f"h{suffix}")
    np.testing.assert_allclose(x3pio.read(tmp_path / "h.x3p").layers[0].z, height.z * 1e-6, equal_nan=True)
    sdf = sdfio.read(tmp_path / "h.sdf")
    np.testing.assert_allclose(sdf.data, height.z * 1e-6, equal_nan=True)
    assert sdf.header.x_scale == pytest.approx(10e-6) and sdf.header.y_scale == pytest.approx(12.5e-6)
    container = gwyfile.load(str(tmp_path / "h.gwy"))
    field = container["/0/data"]
    assert field.data.shape == (30, 40) and field["xreal"] == pytest.approx(40 * 10e-6) and field["yreal"] == pytest.approx(30 * 12.5e-6)
    assert field["si_unit_xy"].unitstr == "m" and field["si_unit_z"].unitstr == "m" and container["/0/data/title"] == "height"


def test_meshes(tmp_path):
    import trimesh

    height = sample()
    for suffix in (".ply", ".stl"):
        height.save(tmp_path / f"h{suffix}")
        mesh = trimesh.load(tmp_path / f"h{suffix}")
        assert len(mesh.faces) == 2 * (29 * 39 - 4)  # the missing point removes the 4 cells around it
        assert mesh.bounds[1][0] == pytest.approx(39 * 10e-3)  # millimetres


def test_bad_formats(tmp_path):
    with pytest.raises(SkinTopoError, match="unknown height map format '.bmp'"):
        sample().save(tmp_path / "h.bmp")
    (tmp_path / "h.sdf").write_bytes(b"garbage")
    with pytest.raises(SkinTopoError, match="h.sdf: not a readable .sdf height map"):
        HeightMap.load(tmp_path / "h.sdf")
    assert not list(tmp_path.glob("*.part"))


@pytest.mark.parametrize("channels", [None, 2, 3, 4])
@pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
def test_png_round_trip_is_exact_in_every_depth_and_channel_count(tmp_path, dtype, channels):
    rng = np.random.default_rng(5)
    shape = (13, 17) if channels is None else (13, 17, channels)
    image = rng.integers(0, np.iinfo(dtype).max + 1, size=shape, dtype=dtype)
    write_png(tmp_path / "a.png", image)
    back = read_png(tmp_path / "a.png")
    assert back.dtype == dtype and back.shape == shape
    np.testing.assert_array_equal(back, image)


def test_png_channels_are_in_rgb_order_and_read_image_drops_alpha(tmp_path):
    import zlib

    # A 1 x 1 16-bit RGBA PNG written byte by byte (PNG spec: IHDR, IDAT, IEND; channels R, G, B, A)
    def chunk(kind, data):
        return len(data).to_bytes(4, "big") + kind + data + zlib.crc32(kind + data).to_bytes(4, "big")

    pixel = b"\x00" + (1000).to_bytes(2, "big") + (2000).to_bytes(2, "big") + (3000).to_bytes(2, "big") + (65535).to_bytes(2, "big")
    png = (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", (1).to_bytes(4, "big") * 2 + bytes([16, 6, 0, 0, 0]))
           + chunk(b"IDAT", zlib.compress(pixel)) + chunk(b"IEND", b""))
    (tmp_path / "rgba.png").write_bytes(png)
    np.testing.assert_array_equal(read_png(tmp_path / "rgba.png")[0, 0], [1000, 2000, 3000, 65535])
    np.testing.assert_array_equal(read_image(tmp_path / "rgba.png")[0, 0], [1000, 2000, 3000])
    (tmp_path / "broken.png").write_bytes(png[:30])
    with pytest.raises(SkinTopoError, match="broken.png: not a readable PNG"):
        read_image(tmp_path / "broken.png")


def test_mesh_keeps_the_map_upright_in_millimetres(tmp_path):
    """Row 0 is the top of the map, y up: a peak at row 5, column 30 lies at x = 30 dx,
    y = -5 dy (mm), and the mesh spans y from -(rows - 1) dy to 0."""
    import trimesh

    z = np.zeros((30, 40))
    z[5, 30] = 50.0
    HeightMap(z, (12.5, 10.0)).save(tmp_path / "peak.ply")
    mesh = trimesh.load(tmp_path / "peak.ply")
    top = mesh.vertices[np.argmax(mesh.vertices[:, 2])]
    np.testing.assert_allclose(top, [30 * 10.0e-3, -5 * 12.5e-3, 50.0e-3], atol=1e-9)
    np.testing.assert_allclose(mesh.bounds, [[0, -29 * 12.5e-3, 0], [39 * 10.0e-3, 0, 50.0e-3]], atol=1e-9)


def test_height_file_errors_name_the_file_and_the_problem(tmp_path):
    height = sample()
    (tmp_path / "h.bmp").write_bytes(b"x")
    with pytest.raises(SkinTopoError, match=r"h.bmp: unknown height map format '.bmp' \(readable: .x3p, "):
        HeightMap.load(tmp_path / "h.bmp")
    np.save(tmp_path / "h.npy", height.z)
    with pytest.raises(SkinTopoError, match=r"h.npy: a .npy height map carries no pixel size; give it \(pixel_um / --pixel-um\)"):
        HeightMap.load(tmp_path / "h.npy")
    np.save(tmp_path / "cube.npy", np.zeros((2, 2, 2)))
    with pytest.raises(SkinTopoError, match=r"cube.npy: expected a 2-D numeric array, got float64 of shape \(2, 2, 2\)"):
        HeightMap.load(tmp_path / "cube.npy", pixel_um=1.0)
    height.save(tmp_path / "h.x3p")
    with pytest.raises(SkinTopoError, match="h.x3p: pixel size in the file is 10 um, not 20 um as given"):
        HeightMap.load(tmp_path / "h.x3p", pixel_um=20.0)
    assert HeightMap.load(tmp_path / "h.x3p", pixel_um=10.0).spacing == pytest.approx((12.5, 10.0))


def test_writes_are_atomic_and_create_folders(tmp_path):
    """A height saved into folders that do not exist yet creates them; a write that fails leaves
    neither the file nor its temporary part."""
    from skintopo.formats import atomic_write

    sample().save(tmp_path / "a" / "b" / "h.x3p")
    assert (tmp_path / "a" / "b" / "h.x3p").is_file() and not list((tmp_path / "a" / "b").glob("*.part"))

    def failing(tmp):
        Path(tmp).write_bytes(b"half")
        raise OSError("disk full")
    with pytest.raises(OSError, match="disk full"):
        atomic_write(tmp_path / "c" / "x.bin", failing)
    assert list((tmp_path / "c").iterdir()) == []


def test_a_flat_map_survives_the_16_bit_tiff(tmp_path):
    z = np.full((6, 7), 42.0)
    z[0, 0] = np.nan
    HeightMap(z, 5.0).save(tmp_path / "h.tif")
    back = HeightMap.load(tmp_path / "h.tif")
    np.testing.assert_array_equal(np.isnan(back.z), np.isnan(z))
    np.testing.assert_allclose(back.z[1:], 42.0)


def test_a_gwy_file_in_other_units_is_refused_and_readers_return_floats(tmp_path):
    """A .gwy field whose heights are not in metres (here nm) is refused by name; every reader
    returns float64 heights with NaN where data are missing."""
    from gwyfile.objects import GwyContainer, GwyDataField, GwySIUnit

    from skintopo.formats import read_height

    field = GwyDataField(np.zeros((4, 5)), xreal=5e-5, yreal=4e-5, si_unit_xy=GwySIUnit(unitstr="m"), si_unit_z=GwySIUnit(unitstr="nm"))
    GwyContainer({"/0/data": field}).tofile(str(tmp_path / "nm.gwy"))
    with pytest.raises(SkinTopoError, match="nm.gwy: heights in 'nm', expected metres"):
        read_height(tmp_path / "nm.gwy")
    for suffix in (".tif", ".gwy", ".x3p"):
        sample().save(tmp_path / f"h{suffix}")
        z, _ = read_height(tmp_path / f"h{suffix}")
        assert z.dtype == np.float64 and np.isnan(z[4, 5]) and np.isfinite(z).sum() == z.size - 1
