"""Compiled loop of the line-segment closings (:func:`skintopo.filters.line_segment_closing`).

Hand-written with Numba: ``scipy.ndimage.grey_dilation`` / ``grey_erosion`` with a footprint
visit every footprint offset for every pixel through a generic N-d iterator; the maximum over
a few offsets is, row by row, a maximum of shifted contiguous rows, which the compiler turns
into vector instructions. A closing of a 1024 x 1024 map with a 31-pixel segment: 37-124 ms in
SciPy depending on the angle, 14-28 ms here. No library offers a grey filter with an
arbitrary digital line that fast (van Herk / Gil-Werman running extrema need a segment that
is the same line through every pixel, which a rounded digital line at most angles is not).
The result is bitwise that of SciPy: a maximum or minimum involves no rounding.
"""

import numba
import numpy as np


@numba.njit(nogil=True, cache=True, error_model="numpy")
def extreme_over_offsets(image, row_offsets, column_offsets, maximum, out):
    """out[r, c] = max (or min) over k of image[r + row_offsets[k], c + column_offsets[k]],
    offsets reaching outside the image left out (SciPy's ``mode="constant"`` with cval -inf
    for the maximum, +inf for the minimum); -inf / +inf where every offset is outside. Equal
    to ``grey_dilation`` / ``grey_erosion`` with the footprint of these offsets when the
    footprint is centrally symmetric (SciPy reflects it for the dilation)."""
    rows, columns = image.shape
    fill = -np.inf if maximum else np.inf
    for r in range(rows):
        out[r, :] = fill
        for k in range(row_offsets.size):
            source_row = r + row_offsets[k]
            if source_row < 0 or source_row >= rows:
                continue
            shift = column_offsets[k]
            start, stop = max(0, -shift), min(columns, columns - shift)
            target = out[r, start:stop]  # views: the loops below index from 0, which the compiler vectorises
            source = image[source_row, start + shift : stop + shift]
            if maximum:
                for c in range(target.size):
                    v = source[c]
                    target[c] = v if v > target[c] else target[c]
            else:
                for c in range(target.size):
                    v = source[c]
                    target[c] = v if v < target[c] else target[c]
