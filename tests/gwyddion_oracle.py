"""Debian's Gwyddion (libgwyprocess2) called through ctypes, as a test oracle for the
fractal estimators. ``available()`` is False when the library is not installed."""

import ctypes

import numpy as np

LINEAR = 2  # GwyInterpolationType GWY_INTERPOLATION_LINEAR
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


def fractal(z, method):
    """(D, x, y) from Gwyddion for a 2-D array z (rows, columns)."""
    lib = _LIB
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
    rows, columns = z.shape
    field = lib.gwy_data_field_new(columns, rows, float(columns), float(rows), 0)
    buffer = np.ctypeslib.as_array(lib.gwy_data_field_get_data(field), shape=(rows * columns,))
    buffer[:] = np.ascontiguousarray(z, dtype=np.float64).ravel()
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
    n = lib.gwy_data_line_get_res(xline)
    x = np.ctypeslib.as_array(lib.gwy_data_line_get_data(xline), shape=(n,)).copy()
    y = np.ctypeslib.as_array(lib.gwy_data_line_get_data(yline), shape=(n,)).copy()
    return float(d), x, y
