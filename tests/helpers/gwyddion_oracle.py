"""Debian's Gwyddion (libgwyprocess2) called through ctypes, as a test oracle for the
fractal estimators. ``available()`` is False when the library is not installed."""

import ctypes

import numpy as np

LINEAR = 2  # GwyInterpolationType GWY_INTERPOLATION_LINEAR
NO_INTERPOLATION = 0  # GWY_INTERPOLATION_NONE
HORIZONTAL = 0  # GwyOrientation GWY_ORIENTATION_HORIZONTAL
HANN = 1  # GwyWindowingType GWY_WINDOWING_HANN
_NAMES = {"partitioning": "partitioning", "cube-counting": "cubecounting", "triangulation": "triangulation", "power-spectrum": "psdf"}


def _load():
    try:
        # libgwyprocess2 needs libgwyddion2's symbols loaded globally first.
        ctypes.CDLL("libgwyddion2.so.0", mode=ctypes.RTLD_GLOBAL)
        return ctypes.CDLL("libgwyprocess2.so.0")
    except OSError:
        return None


_LIB = _load()


def available():
    return _LIB is not None


def version_note():
    return "Debian gwyddion (libgwyprocess2)"


def _declare(lib):
    """ctypes signatures of the libgwyprocess2 functions used here."""
    lib.gwy_data_field_new.restype = ctypes.c_void_p
    lib.gwy_data_field_new.argtypes = [ctypes.c_int, ctypes.c_int, ctypes.c_double, ctypes.c_double, ctypes.c_int]
    lib.gwy_data_field_get_data.restype = ctypes.POINTER(ctypes.c_double)
    lib.gwy_data_field_get_data.argtypes = [ctypes.c_void_p]
    lib.gwy_data_line_new.restype = ctypes.c_void_p
    lib.gwy_data_line_new.argtypes = [ctypes.c_int, ctypes.c_double, ctypes.c_int]
    lib.gwy_data_line_get_res.restype = ctypes.c_int
    lib.gwy_data_line_get_res.argtypes = [ctypes.c_void_p]
    lib.gwy_data_line_get_data.restype = ctypes.POINTER(ctypes.c_double)
    lib.gwy_data_line_get_data.argtypes = [ctypes.c_void_p]
    lib.gwy_data_field_psdf.argtypes = [ctypes.c_void_p, ctypes.c_void_p, ctypes.c_int, ctypes.c_int, ctypes.c_int, ctypes.c_int]


def _field(lib, z):
    rows, columns = z.shape
    field = lib.gwy_data_field_new(columns, rows, float(columns), float(rows), 0)
    buffer = np.ctypeslib.as_array(lib.gwy_data_field_get_data(field), shape=(rows * columns,))
    buffer[:] = np.ascontiguousarray(z, dtype=np.float64).ravel()
    return field


def _line(lib, line):
    n = lib.gwy_data_line_get_res(line)
    return np.ctypeslib.as_array(lib.gwy_data_line_get_data(line), shape=(n,)).copy()


def fractal(z, method):
    """(D, x, y) from Gwyddion for a 2-D array z (rows, columns); for the power spectrum this
    is the installed version's definition (Debian 12: 2.62, which resamples the curve)."""
    lib = _LIB
    _declare(lib)
    field = _field(lib, z)
    xline, yline = lib.gwy_data_line_new(1, 1.0, 0), lib.gwy_data_line_new(1, 1.0, 0)
    name = _NAMES[method]
    compute = getattr(lib, f"gwy_data_field_fractal_{name}")
    compute.argtypes = [ctypes.c_void_p, ctypes.c_void_p, ctypes.c_void_p, ctypes.c_int]
    compute(field, xline, yline, LINEAR)
    dimension = getattr(lib, f"gwy_data_field_fractal_{name}_dim")
    dimension.restype = ctypes.c_double
    dimension.argtypes = [ctypes.c_void_p, ctypes.c_void_p, ctypes.POINTER(ctypes.c_double), ctypes.POINTER(ctypes.c_double)]
    a, b = ctypes.c_double(), ctypes.c_double()
    d = dimension(xline, yline, ctypes.byref(a), ctypes.byref(b))
    return float(d), _line(lib, xline), _line(lib, yline)


def row_psdf(z):
    """Gwyddion's row PSDF as the power-spectrum estimator of 2.66 and later uses it
    (``gwy_data_field_psdf``, horizontal, no curve resampling, Hann window), pixel units,
    without the DC term."""
    lib = _LIB
    _declare(lib)
    line = lib.gwy_data_line_new(1, 1.0, 0)
    lib.gwy_data_field_psdf(_field(lib, z), line, HORIZONTAL, NO_INTERPOLATION, HANN, -1)
    return _line(lib, line)
