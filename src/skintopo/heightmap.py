"""The :class:`HeightMap` type: heights in micrometres with the pixel spacing and mask that
give them meaning, and its storage in ISO 25178-72 (x3p) and NumPy files.

It is a plain data type shared by every stage from height integration onward; it holds no
processing code.
"""

from __future__ import annotations

import os
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from skintopo.errors import SkinTopoError
from skintopo.outputs import current_umask

METRES_PER_MICROMETRE = 1e-6


def _read_only(array):
    array = np.array(array, copy=True)
    array.setflags(write=False)
    return array


@dataclass(frozen=True, eq=False)
class HeightMap:
    """An immutable height map.

    Parameters
    ----------
    z : array_like, shape (rows, columns)
        Heights in micrometres, positive toward the camera. ``NaN`` marks a point with no
        measurement. Row 0 is the top row of the image (the camera's +y side).
    spacing : float or (float, float)
        Pixel spacing in micrometres, as ``(row spacing, column spacing)`` = ``(dy, dx)``;
        a single number means square pixels.
    mask : array_like of bool, optional
        True where the height is valid. Points where ``z`` is NaN are invalid whatever the
        mask says. Default: every finite point.

    Notes
    -----
    The arrays are copied and made read-only, so a HeightMap never changes after creation.
    """

    z: np.ndarray
    spacing: tuple[float, float]
    mask: np.ndarray = field(default=None)

    def __post_init__(self):
        z = np.asarray(self.z, dtype=np.float64)
        if z.ndim != 2 or min(z.shape) < 1:
            raise SkinTopoError(f"a height map must be a 2-D array, got shape {z.shape}")
        spacing = self.spacing
        if np.isscalar(spacing):
            spacing = (spacing, spacing)
        spacing = tuple(float(s) for s in spacing)
        if len(spacing) != 2 or not all(np.isfinite(s) and s > 0 for s in spacing):
            raise SkinTopoError(f"pixel spacing must be two positive micrometre values, got {self.spacing!r}")
        mask = np.isfinite(z) if self.mask is None else np.asarray(self.mask, dtype=bool)
        if mask.shape != z.shape:
            raise SkinTopoError(f"mask shape {mask.shape} differs from height map shape {z.shape}")
        mask = mask & np.isfinite(z)
        z = np.where(mask, z, np.nan)
        object.__setattr__(self, "z", _read_only(z))
        object.__setattr__(self, "spacing", spacing)
        object.__setattr__(self, "mask", _read_only(mask))

    @property
    def shape(self):
        """Shape of the grid, (rows, columns)."""
        return self.z.shape

    @property
    def extent_um(self):
        """Field size in micrometres, (height, width) = (rows * dy, columns * dx)."""
        return (self.shape[0] * self.spacing[0], self.shape[1] * self.spacing[1])

    def save(self, path):
        """Write the height map to ``.x3p`` (ISO 25178-72, metres inside the file) or ``.npy``.

        A ``.npy`` file holds only the heights in micrometres (NaN where invalid); the pixel
        spacing must be given again when it is loaded. The file is written to a temporary name
        and renamed into place, so a failed write never leaves a half-written file.
        """
        path = Path(path)
        suffix = path.suffix.lower()
        if suffix not in (".x3p", ".npy"):
            raise SkinTopoError(f"{path}: unknown height map format {suffix!r} (use .x3p or .npy)")
        path.parent.mkdir(parents=True, exist_ok=True)
        handle, tmp = tempfile.mkstemp(prefix=path.name + ".", suffix=".part", dir=path.parent)
        try:
            with os.fdopen(handle, "wb") as stream:
                if suffix == ".npy":
                    np.save(stream, self.z)
                else:
                    import x3pio

                    # Record2 holds only the software and the UTC time: nothing about the subject.
                    x3pio.write(
                        stream,
                        self.z * METRES_PER_MICROMETRE,
                        x_scale=self.spacing[1] * METRES_PER_MICROMETRE,
                        y_scale=self.spacing[0] * METRES_PER_MICROMETRE,
                    )
            os.chmod(tmp, 0o666 & ~current_umask())
            os.replace(tmp, path)
        except BaseException:
            Path(tmp).unlink(missing_ok=True)
            raise

    @classmethod
    def load(cls, path, *, pixel_um=None):
        """Read a height map from ``.x3p`` or ``.npy``.

        Parameters
        ----------
        path : str or Path
        pixel_um : float, optional
            Pixel size in micrometres; required for ``.npy`` (which stores none), and for
            ``.x3p`` it must agree with the file if given.
        """
        path = Path(path)
        if not path.is_file():
            raise SkinTopoError(f"{path}: no such file")
        suffix = path.suffix.lower()
        if suffix == ".npy":
            if pixel_um is None:
                raise SkinTopoError(f"{path}: a .npy height map carries no pixel size; give it (pixel_um / --pixel-um)")
            try:
                z = np.load(path, allow_pickle=False)
            except ValueError as exc:
                raise SkinTopoError(f"{path}: not a readable .npy array ({exc})") from None
            if z.ndim != 2 or not np.issubdtype(z.dtype, np.number):
                raise SkinTopoError(f"{path}: expected a 2-D numeric array, got {z.dtype} of shape {z.shape}")
            return cls(z, pixel_um)
        if suffix == ".x3p":
            import x3pio

            try:
                surface = x3pio.read(path)
            except (x3pio.X3pError, OSError, ValueError) as exc:
                raise SkinTopoError(f"{path}: not a readable x3p file ({exc})") from None
            if not isinstance(surface, x3pio.Surface) or not surface.is_regular_grid:
                raise SkinTopoError(f"{path}: the x3p file is not a surface on a regular grid")
            layer = surface.layers[0]
            dx, dy = (float(s) / METRES_PER_MICROMETRE for s in layer.spacing[:2])
            if pixel_um is not None and not np.isclose(pixel_um, dx, rtol=1e-6):
                raise SkinTopoError(f"{path}: pixel size in the file is {dx:g} um, not {pixel_um:g} um as given")
            return cls(np.asarray(layer.z, dtype=np.float64) / METRES_PER_MICROMETRE, (dy, dx))
        raise SkinTopoError(f"{path}: unknown height map format {suffix!r} (use .x3p or .npy)")
