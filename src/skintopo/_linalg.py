"""Small vectorised linear algebra shared by several stages."""

import numpy as np


def solve_symmetric_3x3(a, b):
    """Solve a[k] x[k] = b[k] for many symmetric 3 x 3 systems by the adjugate (vectorised).

    ``a`` has shape (k, 6) holding (a00, a01, a02, a11, a12, a22); ``b`` (k, 3).
    Returns x (k, 3) and the determinant (k,). NumPy's batched solver raises on the first
    singular matrix, so the closed form is used to let degenerate pixels be flagged instead.
    """
    a00, a01, a02, a11, a12, a22 = a.T
    c00 = a11 * a22 - a12 * a12
    c01 = a02 * a12 - a01 * a22
    c02 = a01 * a12 - a02 * a11
    c11 = a00 * a22 - a02 * a02
    c12 = a01 * a02 - a00 * a12
    c22 = a00 * a11 - a01 * a01
    det = a00 * c00 + a01 * c01 + a02 * c02
    with np.errstate(divide="ignore", invalid="ignore"):
        x = np.stack(
            [
                c00 * b[:, 0] + c01 * b[:, 1] + c02 * b[:, 2],
                c01 * b[:, 0] + c11 * b[:, 1] + c12 * b[:, 2],
                c02 * b[:, 0] + c12 * b[:, 1] + c22 * b[:, 2],
            ],
            axis=1,
        ) / det[:, None]
    return x, det

