"""Views of a larger map under a known rigid transform (the registration's convention)."""

import numpy as np
import scipy.ndimage


def transformed_view(big, size, offset, angle_deg, shift):
    """The view x_f = R (x_b - c) + c - t of a larger map (the registration's convention)."""
    rows, columns = np.mgrid[:size, :size].astype(float)
    centre = (size - 1) / 2
    theta = np.radians(angle_deg)
    rotation = np.array([[np.cos(theta), np.sin(theta)], [-np.sin(theta), np.cos(theta)]])
    points = np.stack([rows - centre + shift[0], columns - centre + shift[1]])
    source = np.tensordot(np.linalg.inv(rotation), points, axes=1) + centre + offset
    return scipy.ndimage.map_coordinates(big, source, order=3, mode="nearest")
