"""Surface texture parameters of height maps: ISO 21920-2 profile (R) parameters, ISO
25178-2 areal height, hybrid, spatial, functional and volume parameters, and fractal
dimension by four classic estimators (Gwyddion's definitions) plus a physically scaled one.

:func:`measure_texture` computes the whole areal set in one call and returns a list of
:class:`Parameter` (name, value, unit, standard reference).
"""

from __future__ import annotations

import functools
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np
from threadpoolctl import ThreadpoolController

from skintopo.defaults import DEFAULT_LEVEL_ORDER
from skintopo.errors import SkinTopoError
from skintopo.filters import level
from skintopo.heightmap import HeightMap
from skintopo.texture.areal import (
    DEFAULT_P, DEFAULT_Q, FLAT_SQ_UM, functional_parameters, height_parameters, hybrid_parameters, spatial_parameters, valid_heights,
)
from skintopo.texture.fractal import METHODS as FRACTAL_METHODS
from skintopo.texture.fractal import RESAMPLED_METHODS, FractalResult, fractal_dimension, resample_for_fractal
from skintopo.texture.profile import PROFILE_UNITS, line_profile_parameters, profile_parameters

__all__ = ["Parameter", "measure_texture", "profile_parameters", "line_profile_parameters", "fractal_dimension", "PROFILE_UNITS"]

_UNITS = {
    "Sa": "um", "Sq": "um", "Ssk": "", "Sku": "", "Sp": "um", "Sv": "um", "Sz": "um",
    "Sdq": "", "Sdr": "%", "Sal": "um", "Str": "", "Std": "deg",
    "Sk": "um", "Spk": "um", "Svk": "um", "Smr1": "%", "Smr2": "%", "Sxp": "um",
    "Vmp": "um3/um2", "Vmc": "um3/um2", "Vvc": "um3/um2", "Vvv": "um3/um2",
}
_REFERENCES = {
    **{n: "ISO 25178-2 4.1 (height)" for n in ("Sa", "Sq", "Ssk", "Sku", "Sp", "Sv", "Sz")},
    **{n: "ISO 25178-2 4.4 (hybrid)" for n in ("Sdq", "Sdr")},
    **{n: "ISO 25178-2 4.3 (spatial), s = 0.2" for n in ("Sal", "Str", "Std")},
    **{n: "ISO 25178-2 Annex B / ISO 13565-2 (functional)" for n in ("Sk", "Spk", "Svk", "Smr1", "Smr2")},
    "Sxp": "ISO 25178-2 4.5 (functional), p = 2.5 %, q = 50 %",
}


@dataclass(frozen=True)
class Parameter:
    """One measured parameter: name, value, unit (um, %, deg, um3/um2 = ml/m2, '' = none),
    and the standard clause or method it follows."""

    name: str
    value: float
    unit: str
    reference: str


def measure_texture(height: HeightMap, *, level_order=DEFAULT_LEVEL_ORDER, p=DEFAULT_P, q=DEFAULT_Q, fractal_methods=FRACTAL_METHODS, return_fractal=False):
    """All areal parameters and fractal dimensions of a height map, in one call.

    Parameters
    ----------
    height : HeightMap
        Micrometres.
    level_order : int or None
        F-operator: the least-squares polynomial form removed first (1 = plane, the
        default; None = none).
    p, q : float
        Material ratios (%) of the volume parameters (ISO defaults 10 and 80).
    fractal_methods : sequence of str
        Estimators to run (default the four Gwyddion ones).
    return_fractal : bool
        Also return each estimator's :class:`~skintopo.texture.fractal.FractalResult` (with
        its log-log points, for plotting).

    Returns
    -------
    parameters : list of Parameter
    fractal : tuple of FractalResult
        Only when ``return_fractal`` is true.

    Notes
    -----
    Runs on two threads (the calling one and one worker) and holds BLAS to one thread while
    it runs; the numbers do not depend on the threading.
    """
    if not height.mask.any():
        raise SkinTopoError("the height map has no valid points")
    # Two threads for two cores: the fractal estimators and the hybrid parameters in a worker,
    # the height, spatial and functional parameters here. Both spend their time inside
    # NumPy/SciPy loops that release the GIL. BLAS is held to one thread meanwhile:
    # OpenBLAS's idle workers spin after each call and would take the other core.
    with blas_threads(1), ThreadPoolExecutor(max_workers=1) as pool:
        surface = level(height, level_order) if level_order is not None else height
        fractal = pool.submit(_fractal_estimates, surface, tuple(fractal_methods))
        hybrid = pool.submit(hybrid_parameters, surface)
        values = height_parameters(surface)
        spatial = spatial_parameters(surface)
        functional = functional_parameters(surface, p=p, q=q)
        for part in (hybrid.result(), spatial, functional):
            values.update(part)
        estimates = fractal.result()
    references = dict(_REFERENCES)
    for name in ("Vmp", "Vmc", "Vvc", "Vvv"):
        references[name] = f"ISO 25178-2 4.5 (volume), p = {p:g} %, q = {q:g} %"
    parameters = [Parameter(name, float(value), _UNITS[name], references[name]) for name, value in values.items()]
    for result in estimates:
        reference = f"fractal dimension, {result.method} (Gwyddion definition)" if result.method in FRACTAL_METHODS else f"fractal dimension, {result.method}"
        parameters.append(Parameter(f"D_{result.method}", result.dimension, "", reference))
    return (parameters, tuple(estimates)) if return_fractal else parameters


@functools.cache
def _thread_pools():
    """The BLAS and OpenMP libraries loaded in this process (found once, on first use, when
    NumPy's and SciPy's are both loaded)."""
    return ThreadpoolController()


def blas_threads(limit):
    """Context manager: BLAS held to ``limit`` threads (process-wide) while it is open."""
    return _thread_pools().limit(limits=limit, user_api="blas")


def _fractal_estimates(surface, methods):
    """Every estimator's result; on a flat map (height range below 1e-9 um, levelling
    round-off) D is undefined: NaN, with no log-log points, instead of an error that would
    hide the other parameters."""
    if not methods:
        return []
    if np.ptp(valid_heights(surface)) < FLAT_SQ_UM:
        return [FractalResult(method, float("nan"), np.array([]), np.array([]), float("nan"), float("nan")) for method in methods]
    resampled = resample_for_fractal(surface) if set(methods) & set(RESAMPLED_METHODS) else None
    return [fractal_dimension(surface, method, resampled) for method in methods]


def parameters_by_name(parameters):
    """{name: value} of a list of :class:`Parameter`."""
    return {p.name: p.value for p in parameters}


_UNDEFINED = {  # why a parameter has no value (NaN)
    "Ssk": "undefined on a flat map (Sq = 0)",
    "Sku": "undefined on a flat map (Sq = 0)",
    "Sal": "the autocorrelation never falls to s = 0.2 in any direction within the field",
    "Str": ("the autocorrelation does not fall to s = 0.2 within the field in every direction (a surface with one dominant "
            "direction, such as parallel wrinkles, or a field smaller than its texture): the ratio is undefined"),
    "Std": "no texture direction (a flat or isotropic map)",
}


def parameter_note(parameter: Parameter) -> str:
    """Why a parameter has no value, or why its value is outside the range the quantity can
    take ('' when neither): a fractal dimension of a surface lies in [2, 3] (ISO 25178-2 and
    the estimators' definitions); a value outside means that the log-log points are not on
    one line over the fitted scales (the surface is not self-affine there, e.g. wrinkles and
    furrows dominate the spectrum), so it is no dimension of this surface."""
    if not np.isfinite(parameter.value):
        if parameter.name.startswith("D_"):
            return "undefined on a flat map"
        return _UNDEFINED.get(parameter.name, "undefined for this map")
    if parameter.name.startswith("D_") and not 2.0 <= parameter.value <= 3.0:
        return ("outside [2, 3], the range of a surface's dimension: the log-log points are not on a line over these scales "
                "(the surface is not self-affine there), so this is not a dimension of this surface")
    return ""


def finite_or_none(value):
    """JSON-friendly value: None for NaN."""
    return None if value is None or (isinstance(value, float) and not np.isfinite(value)) else value
