"""Height map file formats, in and out, by extension (micrometres in the API, metres where
the format's standard says so).

=========  =====  ==========================================================================
format     dir    how
=========  =====  ==========================================================================
``.x3p``   r/w    ISO 25178-72 via x3pio; metres, written as binary32 (type F: 24 significant
                  bits, 0.03 nm at 500 um; any type read). Record2 names only the software
                  and time.
``.sdf``   r/w    ISO 25178-71 via sdfio; metres, binary64.
``.gwy``   r/w    Gwyddion via gwyfile; metres, missing points as Gwyddion's mask (/0/mask).
``.tif``   r/w    16-bit TIFF via tifffile: heights quantised between the map's minimum and
                  maximum; offset, step and pixel size in the ImageDescription (JSON), 0 =
                  missing. A float TIFF is read as heights in micrometres.
``.npy``   r/w    heights in micrometres, NaN missing; no pixel size (give it when reading).
``.ply``   w      triangle mesh (trimesh), vertices in millimetres, for 3D printing / CAD.
``.stl``   w      the same mesh as binary STL (trimesh), millimetres.
=========  =====  ==========================================================================

Every write goes to a temporary file in the target folder, renamed into place when complete.
"""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path

import numpy as np

from skintopo.defaults import HEIGHT_MAP_SUFFIXES
from skintopo.errors import SkinTopoError

METRES_PER_MICROMETRE = 1e-6
READABLE = HEIGHT_MAP_SUFFIXES
WRITABLE = (".x3p", ".sdf", ".gwy", ".tif", ".tiff", ".npy", ".ply", ".stl")
TIFF_LEVELS = 65534  # codes 1..65535 hold heights; 0 marks a missing point


def current_umask():
    """The process umask (read by setting and restoring it), for files made via tempfile."""
    mask = os.umask(0)
    os.umask(mask)
    return mask


def fsync_path(path):
    """Flush a file's (or a folder's entries') data to the disk: a rename is durable only
    once both the file and its folder are synced (POSIX; a power cut otherwise can leave a
    "complete" name over an empty file)."""
    descriptor = os.open(path, os.O_RDONLY)
    try:
        os.fsync(descriptor)
    finally:
        os.close(descriptor)


def atomic_write(path, write):
    """Call ``write(tmp)`` on a temporary file beside ``path``, sync it, rename it into place
    and sync the folder."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    handle, tmp = tempfile.mkstemp(prefix=path.name + ".", suffix=".part", dir=path.parent)
    os.close(handle)
    try:
        write(tmp)
        os.chmod(tmp, 0o666 & ~current_umask())
        fsync_path(tmp)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    fsync_path(path.parent)


def read_png(path):
    """A PNG image in its own bit depth (8 or 16) and channel order (grey, grey + alpha, RGB,
    RGBA), through imagecodecs (libpng). Pillow would reduce 16-bit RGB to 8 bits."""
    import imagecodecs

    try:
        return imagecodecs.png_decode(Path(path).read_bytes())
    except (imagecodecs.PngError, ValueError) as exc:
        raise SkinTopoError(f"{path}: not a readable PNG image ({exc})") from None


def write_png(path, image):
    """Write a uint8 or uint16 grey / RGB / RGBA array as a lossless PNG (RGB order)."""
    import imagecodecs

    Path(path).write_bytes(imagecodecs.png_encode(np.ascontiguousarray(image)))


def write_height(path, z_um, spacing_um):
    """Write heights (um, NaN missing) with pixel spacing (dy, dx) in um; format by extension."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in WRITABLE:
        raise SkinTopoError(f"{path}: unknown height map format {suffix!r} (writable: {', '.join(WRITABLE)})")
    dy, dx = spacing_um
    z = np.asarray(z_um, dtype=np.float64)
    metres = z * METRES_PER_MICROMETRE

    def write(tmp):
        if suffix == ".npy":
            with open(tmp, "wb") as stream:
                np.save(stream, z)
        elif suffix == ".x3p":
            import x3pio

            # binary32, not binary64: the low 29 bits of a measured height are noise, and zlib
            # (x3pio compresses at its default level) takes half the time on half the bytes
            # (1024 x 1024: 0.29 -> 0.14 s, 8.0 -> 3.8 MB; heights change by at most 6e-8 relative)
            x3pio.write(tmp, metres, x_scale=dx * METRES_PER_MICROMETRE, y_scale=dy * METRES_PER_MICROMETRE, z_type=x3pio.DataType.FLOAT32)
        elif suffix == ".sdf":
            import sdfio

            sdfio.write(tmp, metres, x_scale=dx * METRES_PER_MICROMETRE, y_scale=dy * METRES_PER_MICROMETRE)
        elif suffix == ".gwy":
            _write_gwy(tmp, metres, dx, dy)
        elif suffix in (".tif", ".tiff"):
            _write_tiff(tmp, z, dx, dy)
        else:
            _write_mesh(tmp, z, dx, dy, suffix)

    atomic_write(path, write)


def read_height(path, pixel_um=None):
    """Read heights (um) and spacing (dy, dx) (um) from a file; returns (z, spacing)."""
    path = Path(path)
    if not path.is_file():
        raise SkinTopoError(f"{path}: no such file")
    suffix = path.suffix.lower()
    if suffix not in READABLE:
        raise SkinTopoError(f"{path}: unknown height map format {suffix!r} (readable: {', '.join(READABLE)})")
    try:
        if suffix == ".npy":
            if pixel_um is None:
                raise SkinTopoError(f"{path}: a .npy height map carries no pixel size; give it (pixel_um / --pixel-um)")
            z = np.load(path, allow_pickle=False)
            if z.ndim != 2 or not np.issubdtype(z.dtype, np.number):
                raise SkinTopoError(f"{path}: expected a 2-D numeric array, got {z.dtype} of shape {z.shape}")
            return np.asarray(z, dtype=np.float64), (float(pixel_um), float(pixel_um))
        if suffix == ".x3p":
            z, spacing = _read_x3p(path)
        elif suffix == ".sdf":
            import sdfio

            surface = sdfio.read(path)
            if surface.is_profile:
                raise SkinTopoError(f"{path}: the SDF file holds a profile, not a surface")
            header = surface.header
            z, spacing = np.asarray(surface.data, float) / METRES_PER_MICROMETRE, (header.y_scale / METRES_PER_MICROMETRE, header.x_scale / METRES_PER_MICROMETRE)
        elif suffix == ".gwy":
            z, spacing = _read_gwy(path)
        else:
            z, spacing = _read_tiff(path, pixel_um)
    except SkinTopoError:
        raise
    except Exception as exc:  # each reader raises its own types for damaged files
        raise SkinTopoError(f"{path}: not a readable {suffix} height map ({exc.__class__.__name__}: {exc})") from None
    if pixel_um is not None and not np.isclose(pixel_um, spacing[1], rtol=1e-6):
        raise SkinTopoError(f"{path}: pixel size in the file is {spacing[1]:g} um, not {pixel_um:g} um as given")
    return z, spacing


def _read_x3p(path):
    import x3pio

    surface = x3pio.read(path)
    if not isinstance(surface, x3pio.Surface) or not surface.is_regular_grid:
        raise SkinTopoError(f"{path}: the x3p file is not a surface on a regular grid")
    layer = surface.layers[0]
    dx, dy = (float(s) / METRES_PER_MICROMETRE for s in layer.spacing[:2])
    return np.asarray(layer.z, dtype=np.float64) / METRES_PER_MICROMETRE, (dy, dx)


def _write_gwy(tmp, metres, dx, dy):
    from gwyfile.objects import GwyContainer, GwyDataField, GwySIUnit

    rows, columns = metres.shape
    missing = ~np.isfinite(metres)
    filled = np.where(missing, np.nanmean(metres) if (~missing).any() else 0.0, metres)

    def field(data, z_unit):
        return GwyDataField(
            np.ascontiguousarray(data, dtype=np.float64), xreal=columns * dx * METRES_PER_MICROMETRE,
            yreal=rows * dy * METRES_PER_MICROMETRE, si_unit_xy=GwySIUnit(unitstr="m"), si_unit_z=GwySIUnit(unitstr=z_unit),
        )

    container = GwyContainer()
    container["/0/data"] = field(filled, "m")
    container["/0/data/title"] = "height"
    if missing.any():
        container["/0/mask"] = field(missing.astype(np.float64), "")
    container.tofile(tmp)


def _read_gwy(path):
    import gwyfile

    container = gwyfile.load(str(path))
    if "/0/data" not in container:
        raise SkinTopoError(f"{path}: the .gwy file has no data field /0/data")
    field = container["/0/data"]
    z = np.asarray(field.data, dtype=np.float64)
    rows, columns = z.shape
    unit = getattr(field.get("si_unit_z"), "unitstr", "m") if hasattr(field, "get") else "m"
    if unit not in ("m", ""):
        raise SkinTopoError(f"{path}: heights in {unit!r}, expected metres")
    if "/0/mask" in container:
        z = np.where(np.asarray(container["/0/mask"].data) > 0.5, np.nan, z)
    dx = field["xreal"] / columns / METRES_PER_MICROMETRE
    dy = field["yreal"] / rows / METRES_PER_MICROMETRE
    return z / METRES_PER_MICROMETRE, (dy, dx)


def _write_tiff(tmp, z, dx, dy):
    import tifffile

    valid = np.isfinite(z)
    low = float(np.min(z[valid])) if valid.any() else 0.0
    high = float(np.max(z[valid])) if valid.any() else 0.0
    step = (high - low) / TIFF_LEVELS if high > low else 1.0
    codes = np.where(valid, np.round((np.nan_to_num(z, nan=low) - low) / step) + 1, 0).astype(np.uint16)
    description = json.dumps({"skintopo_height": 1, "z_offset_um": low - step, "z_step_um": step, "pixel_um": [dy, dx], "missing_code": 0})
    tifffile.imwrite(tmp, codes, description=description, metadata=None)


def _read_tiff(path, pixel_um):
    import tifffile

    with tifffile.TiffFile(path) as tif:
        codes = tif.asarray()
        description = tif.pages[0].description
    try:
        meta = json.loads(description) if description else {}
    except json.JSONDecodeError:
        meta = {}
    if codes.ndim != 2:
        raise SkinTopoError(f"{path}: expected a single-channel TIFF height map, got shape {codes.shape}")
    if meta.get("skintopo_height") == 1:
        z = np.where(codes == meta["missing_code"], np.nan, meta["z_offset_um"] + codes.astype(np.float64) * meta["z_step_um"])
        return z, tuple(float(v) for v in meta["pixel_um"])
    if not np.issubdtype(codes.dtype, np.floating):
        raise SkinTopoError(f"{path}: an integer TIFF without skintopo's height metadata has no height scale; use a float TIFF in micrometres")
    if pixel_um is None:
        raise SkinTopoError(f"{path}: a float TIFF height map carries no pixel size; give it (--pixel-um)")
    return codes.astype(np.float64), (float(pixel_um), float(pixel_um))


def _write_mesh(tmp, z, dx, dy, suffix):
    import trimesh

    rows, columns = z.shape
    r, c = np.mgrid[:rows, :columns]
    vertices = np.column_stack([c.ravel() * dx, -r.ravel() * dy, np.nan_to_num(z).ravel()]) / 1000.0  # mm, y up
    index = np.arange(rows * columns).reshape(rows, columns)
    valid = np.isfinite(z)
    corners = [index[:-1, :-1], index[1:, :-1], index[:-1, 1:], index[1:, 1:]]
    cell_ok = valid[:-1, :-1] & valid[1:, :-1] & valid[:-1, 1:] & valid[1:, 1:]
    a, b, c2, d = (corner[cell_ok] for corner in corners)
    faces = np.concatenate([np.column_stack([a, b, c2]), np.column_stack([c2, b, d])])
    mesh = trimesh.Trimesh(vertices=vertices, faces=faces, process=False)
    mesh.remove_unreferenced_vertices()
    mesh.export(tmp, file_type=suffix[1:])
