"""The :class:`HeightMap` type: heights in micrometres with the pixel spacing and mask that
give them meaning; storage through :mod:`skintopo.formats`.

It is a plain data type shared by every stage from height integration onward; it holds no
processing code.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from skintopo.errors import SkinTopoError



def pixel_spacing(spacing):
    """(dy, dx) in micrometres from one value (square pixels) or a pair; both finite and
    positive, else a clear error. Every function that takes a spacing goes through here."""
    pair = (spacing, spacing) if np.isscalar(spacing) else tuple(spacing)
    try:
        pair = tuple(float(value) for value in pair)
    except (TypeError, ValueError):
        pair = ()
    if len(pair) != 2 or not all(np.isfinite(value) and value > 0 for value in pair):
        raise SkinTopoError(f"pixel spacing must be one or two positive micrometre values, got {spacing!r}")
    return pair


def _frozen(array):
    """The array, made read-only (callers pass arrays they have just created, never the
    caller's own: the inputs are copied, not locked)."""
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
        spacing = pixel_spacing(self.spacing)
        mask = np.isfinite(z) if self.mask is None else np.asarray(self.mask, dtype=bool)
        if mask.shape != z.shape:
            raise SkinTopoError(f"mask shape {mask.shape} differs from height map shape {z.shape}")
        mask = mask & np.isfinite(z)  # new arrays: copies of the inputs
        z = np.where(mask, z, np.nan)
        object.__setattr__(self, "z", _frozen(z))
        object.__setattr__(self, "spacing", spacing)
        object.__setattr__(self, "mask", _frozen(mask))

    @property
    def shape(self):
        """Shape of the grid, (rows, columns)."""
        return self.z.shape

    @property
    def extent_um(self):
        """Field size in micrometres, (height, width) = (rows * dy, columns * dx)."""
        return (self.shape[0] * self.spacing[0], self.shape[1] * self.spacing[1])

    def save(self, path):
        """Write the height map; the format follows the extension (``.x3p``, ``.sdf``,
        ``.gwy``, ``.tif``, ``.npy``, and meshes ``.ply`` / ``.stl``): see
        :mod:`skintopo.formats`. Written to a temporary name and renamed into place, so a
        failed write never leaves a half-written file."""
        from skintopo.formats import write_height

        write_height(path, self.z, self.spacing)

    @classmethod
    def load(cls, path, *, pixel_um=None):
        """Read a height map (``.x3p``, ``.sdf``, ``.gwy``, ``.tif``, ``.npy``).

        Parameters
        ----------
        path : str or Path
        pixel_um : float, optional
            Pixel size in micrometres; required for ``.npy`` and float TIFF (which store
            none), and for the others it must agree with the file if given.
        """
        from skintopo.formats import read_height

        z, spacing = read_height(path, pixel_um)
        return cls(z, spacing)
