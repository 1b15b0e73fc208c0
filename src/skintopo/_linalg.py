"""Small vectorised linear algebra shared by several stages."""

import numpy as np


def solve_symmetric_3x3(a, b, components=3):
    """Solve a[k] x[k] = b[k] for many symmetric 3 x 3 systems by the adjugate (vectorised).

    ``a`` holds the upper entries (a00, a01, a02, a11, a12, a22) as 6 arrays of k values
    (any sequence; an array of shape (6, k)); ``b`` the right-hand sides as 3 arrays (3, k).
    Returns the first ``components`` entries of x (components, k) and the determinant (k,).
    NumPy's batched solver raises on the first singular matrix, so the closed form is used
    to let degenerate pixels be flagged instead.
    """
    a00, a01, a02, a11, a12, a22 = a
    b0, b1, b2 = b
    c00 = a11 * a22 - a12 * a12
    c01 = a02 * a12 - a01 * a22
    c02 = a01 * a12 - a02 * a11
    det = a00 * c00 + a01 * c01 + a02 * c02
    rows = [(c00, c01, c02)]  # rows of the adjugate, as many as asked for
    if components > 1:
        c11 = a00 * a22 - a02 * a02
        c12 = a01 * a02 - a00 * a12
        rows.append((c01, c11, c12))
        if components > 2:
            rows.append((c02, c12, a00 * a11 - a01 * a01))
    with np.errstate(divide="ignore", invalid="ignore"):
        inverse = 1 / det
        x = np.stack([(r0 * b0 + r1 * b1 + r2 * b2) * inverse for r0, r1, r2 in rows])
    return x, det
