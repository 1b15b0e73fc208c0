"""Radiometry: full scale, transfer function (gamma, sRGB), saturation, to linear fractions of full scale."""

from __future__ import annotations

import numpy as np


def full_scale_of(dtype, declared):
    """The value of a saturated pixel: the declared full scale, else the integer type's maximum."""
    if declared is not None:
        return float(declared)
    if np.issubdtype(dtype, np.unsignedinteger):
        return float(np.iinfo(dtype).max)
    return None  # float images: taken as already normalised, no saturation test


def linearise(values, gamma):
    """Undo the declared transfer function; ``gamma`` 1.0 (the default) leaves data linear."""
    if gamma == "srgb":
        return np.where(values <= 0.04045, values / 12.92, ((values + 0.055) / 1.055) ** 2.4).astype(np.float32)
    if gamma != 1.0:
        return np.power(values, np.float32(gamma))
    return values


def normalise(image, full_scale, saturation, gamma):
    """Linear intensity as a fraction of full scale, NaN where saturated."""
    values = image.astype(np.float32)
    if full_scale is not None:
        saturated = values >= saturation * full_scale
        values /= np.float32(full_scale)
        values = linearise(values, gamma)
        values[saturated] = np.nan
    return values
