"""Profile (R) parameters, ISO 21920-2 with the ISO 4287 names: Ra, Rq, Rsk, Rku, Rp, Rv,
Rz, Rt, Rdq.

The profile is the height along a line of the map (:func:`skintopo.filters.extract_profile`,
optionally averaged across a band). Filtering (ISO 16610-21 Gaussian, first-order regression
at the ends so the whole length stays usable): ``lambda_s`` removes wavelengths shorter than
it (the primary profile), ``lambda_c`` separates roughness from waviness (R = primary - mean
line). Without ``lambda_c`` the least-squares line is removed instead. The evaluation length
is the whole profile, divided into ``sections`` sampling lengths (default 5).

Definitions (heights z about the mean line, over the evaluation length unless noted):

    Ra = mean |z|                 Rq = sqrt(mean z^2)
    Rsk = mean z^3 / Rq^3         Rku = mean z^4 / Rq^4     (dimensionless; not excess)
    Rp = max z                    Rv = -min z               Rt = Rp + Rv
    Rz = mean over the sections of (max z - min z) in each section
    Rdq = sqrt(mean (dz/dx)^2), dz/dx from the 7-point formula of ISO 4287:
          (z[i+3] - 9 z[i+2] + 45 z[i+1] - 45 z[i-1] + 9 z[i-2] - z[i-3]) / (60 dx)
"""

from __future__ import annotations

import numpy as np

from skintopo.errors import SkinTopoError
from skintopo.filters import extract_profile, profile_gaussian_filter
from skintopo.heightmap import HeightMap

PROFILE_UNITS = {"Ra": "um", "Rq": "um", "Rsk": "", "Rku": "", "Rp": "um", "Rv": "um", "Rz": "um", "Rt": "um", "Rdq": ""}


def roughness_profile(z, spacing_um, *, lambda_s=None, lambda_c=None):
    """The scale-limited profile: low-pass at ``lambda_s``, minus the mean line at
    ``lambda_c`` (or minus the least-squares line without ``lambda_c``)."""
    z = np.asarray(z, dtype=float)
    if lambda_s is not None:
        z = profile_gaussian_filter(z, spacing_um, lambda_s)
    if lambda_c is not None:
        if lambda_s is not None and not lambda_s < lambda_c:
            raise SkinTopoError(f"lambda_s ({lambda_s} um) must be shorter than lambda_c ({lambda_c} um)")
        return z - profile_gaussian_filter(z, spacing_um, lambda_c)
    valid = np.isfinite(z)
    x = np.arange(z.size)
    slope, intercept = np.polyfit(x[valid], z[valid], 1)
    return z - (slope * x + intercept)


def profile_parameters(z, spacing_um, *, lambda_s=None, lambda_c=None, sections=5):
    """Ra, Rq, Rsk, Rku, Rp, Rv, Rz, Rt, Rdq of a profile (see the module notes).

    Parameters
    ----------
    z : array_like
        Heights in micrometres, equally spaced by ``spacing_um``; NaN = missing.
    lambda_s, lambda_c : float, optional
        Filter cut-offs in micrometres.
    sections : int
        Number of sampling lengths for Rz.
    """
    z = np.asarray(z, dtype=float)
    if z.ndim != 1 or np.isfinite(z).sum() < max(7, sections * 2):
        raise SkinTopoError(f"a profile needs at least {max(7, sections * 2)} valid points, got {int(np.isfinite(z).sum())}")
    if lambda_c is not None and z.size * spacing_um < lambda_c:
        raise SkinTopoError(f"the profile ({z.size * spacing_um:g} um) is shorter than the cut-off lambda_c = {lambda_c:g} um")
    r = roughness_profile(z, spacing_um, lambda_s=lambda_s, lambda_c=lambda_c)
    values = r[np.isfinite(r)]
    values = values - values.mean() if lambda_c is None else values
    rq = float(np.sqrt(np.mean(values**2)))
    with np.errstate(invalid="ignore", divide="ignore"):
        rsk = float(np.mean(values**3) / rq**3) if rq > 0 else float("nan")
        rku = float(np.mean(values**4) / rq**4) if rq > 0 else float("nan")
    parts = [p[np.isfinite(p)] for p in np.array_split(r, sections)]
    rz = float(np.mean([p.max() - p.min() for p in parts if p.size]))
    slope = (r[6:] - 9 * r[5:-1] + 45 * r[4:-2] - 45 * r[2:-4] + 9 * r[1:-5] - r[:-6]) / (60 * spacing_um)
    rp, rv = float(values.max()), float(-values.min())
    return {
        "Ra": float(np.mean(np.abs(values))),
        "Rq": rq,
        "Rsk": rsk,
        "Rku": rku,
        "Rp": rp,
        "Rv": rv,
        "Rz": rz,
        "Rt": rp + rv,
        "Rdq": float(np.sqrt(np.nanmean(slope**2))),
    }


def line_profile_parameters(height: HeightMap, start_um, end_um, *, width_um=0.0, **options):
    """Profile parameters along a line of a height map (end points in um, image axes: x right,
    y down from the top-left pixel centre), averaged across ``width_um``."""
    distance, z = extract_profile(height, start_um, end_um, width_um)
    spacing = distance[1] - distance[0]
    return profile_parameters(z, spacing, **options)
