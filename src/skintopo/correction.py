"""The paper's spectral interreflection correction (§5) and documented variants.

Red light suffers most from interreflection in wrinkles (highest skin albedo) and
underestimates their depth; green and blue overestimate it (non-Lambertian reflectance).
The paper's algorithm, ``method="paper"``:

1. gradients per band p_c, q_c (c = red, green, blue);
2. T1 = (p_red + (p_green + p_blue) / 2) / 2,  T2 = (q_red + (q_green + q_blue) / 2) / 2;
3. G = (p_red, q_red) with (T1, T2) substituted at the wrinkle pixels;
4. z_a = integral of G,  z_red = integral of (p_red, q_red);
5. Z = z_red, with min(z_a, z_red) at the wrinkle pixels.

"Wrinkle pixels" are the whole wrinkle, walls included (the segmentation's ``extent``):
the paper substitutes gradients on the segmented region of interest, and the depth of a
wrinkle is the integral of the slopes of its walls, so correcting only the inner half-depth
core would leave most of the underestimate in place.

Step 5 compares two integrations whose constant offsets are arbitrary; the paper does not
say how they are referenced. Here z_a is shifted so that its median difference from z_red
outside the wrinkles is zero, before the minimum is taken.

Variant ``method="feathered"`` (a suggestion of the paper's §5 that it does not implement:
no hard switch at the wrinkle border): the substitution weight w goes smoothly from 1 inside
the wrinkle to 0 over ``feather_um`` outside it (a Gaussian-blurred mask), G = (1 - w) red +
w T, and Z = z_red + w (min(z_a, z_red) - z_red). The hard switch of the paper leaves a step
in the gradient field at the border that the integrator spreads around the wrinkle.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.ndimage

from skintopo.defaults import CORRECTION_METHODS, DEFAULT_CORRECTION_METHOD
from skintopo.errors import SkinTopoError
from skintopo.height import DEFAULT_INTEGRATOR, integrate_slopes, normals_to_gradients
from skintopo.heightmap import HeightMap, pixel_spacing
from skintopo.segmentation import WrinkleSegmentation, segment_wrinkles

DEFAULT_FEATHER_UM = 150.0
REQUIRED_BANDS = ("red", "green", "blue")


@dataclass(frozen=True, eq=False)
class CorrectionResult:
    """Output of :func:`spectral_correction`: the corrected height, the red height, the
    interim height z_a and the wrinkle segmentation used."""

    height: HeightMap
    red_height: HeightMap
    interim_height: HeightMap
    segmentation: WrinkleSegmentation
    method: str


def combined_slopes(slopes):
    """T = (s_red + (s_green + s_blue) / 2) / 2 for one slope component (paper §5, step 2)."""
    return (slopes["red"] + (slopes["green"] + slopes["blue"]) / 2) / 2


def substitution_weight(wrinkle_mask, spacing, *, method=DEFAULT_CORRECTION_METHOD, feather_um=DEFAULT_FEATHER_UM):
    """Weight w of the combined slopes T: G = (1 - w) red + w T.

    ``paper``: w = 1 on the wrinkle pixels, 0 elsewhere. ``feathered``: w = 1 on the wrinkle,
    and outside it w = min(1, 2 (G_sigma * mask)), sigma = ``feather_um`` / 2, which is 1 at
    the border and falls smoothly to 0 (for a straight border at distance d, w = 2 Phi(-d /
    sigma), Phi the standard normal distribution function).
    """
    wrinkle_mask = np.asarray(wrinkle_mask, dtype=bool)
    if method == "paper":
        return wrinkle_mask.astype(float)
    dy, dx = pixel_spacing(spacing)
    sigma = (feather_um / 2 / dy, feather_um / 2 / dx)
    weight = np.maximum(wrinkle_mask, scipy.ndimage.gaussian_filter(wrinkle_mask.astype(float), sigma) * 2).clip(0, 1)
    weight[wrinkle_mask] = 1.0
    return weight


def correct_slopes(red, green, blue, wrinkle_mask, spacing, *, method=DEFAULT_CORRECTION_METHOD, feather_um=DEFAULT_FEATHER_UM,
                   integrator=DEFAULT_INTEGRATOR, mask=None):
    """The correction on slope fields.

    Parameters
    ----------
    red, green, blue : (p, q)
        Slopes dz/dx, dz/dy of each band (x right, y up).
    wrinkle_mask : ndarray of bool
        Wrinkle pixels (from :func:`skintopo.segmentation.segment_wrinkles`).
    spacing : float or (dy, dx)
        Micrometres.
    method : ``"paper"`` or ``"feathered"``
    mask : ndarray of bool, optional
        Valid pixels.

    Returns
    -------
    corrected, z_red, z_a : HeightMap
    """
    if method not in CORRECTION_METHODS:
        raise SkinTopoError(f"unknown correction method {method!r}; choose from {list(CORRECTION_METHODS)}")
    wrinkle_mask = np.asarray(wrinkle_mask, dtype=bool)
    p = {"red": red[0], "green": green[0], "blue": blue[0]}
    q = {"red": red[1], "green": green[1], "blue": blue[1]}
    t1, t2 = combined_slopes(p), combined_slopes(q)
    weight = substitution_weight(wrinkle_mask, spacing, method=method, feather_um=feather_um)
    g1 = (1 - weight) * p["red"] + weight * t1
    g2 = (1 - weight) * q["red"] + weight * t2
    valid = np.isfinite(g1) & np.isfinite(g2) & np.isfinite(p["red"]) & np.isfinite(q["red"])
    if mask is not None:
        valid &= np.asarray(mask, dtype=bool)
    z_red = integrate_slopes(p["red"], q["red"], spacing, mask=valid, method=integrator)
    z_a = integrate_slopes(g1, g2, spacing, mask=valid, method=integrator)
    outside = valid & (weight == 0)
    reference = outside if outside.any() else valid
    z_a_values = z_a.z - np.median((z_a.z - z_red.z)[reference])
    corrected = z_red.z + weight * (np.minimum(z_a_values, z_red.z) - z_red.z)
    return HeightMap(corrected, spacing, valid), z_red, HeightMap(z_a_values, spacing, valid)


def spectral_correction(normals_by_band, spacing, *, segmentation: WrinkleSegmentation | None = None, method=DEFAULT_CORRECTION_METHOD,
                        integrator=DEFAULT_INTEGRATOR, mask=None, **segmentation_options) -> CorrectionResult:
    """Run the paper's method on per-band normals.

    Parameters
    ----------
    normals_by_band : dict
        Unit normals (rows, columns, 3) for at least red, green and blue.
    spacing : float or (dy, dx)
        Pixel spacing in micrometres.
    segmentation : WrinkleSegmentation, optional
        Default: :func:`segment_wrinkles` (with ``segmentation_options``) on the height
        integrated from the combined slopes T everywhere. The paper segments "the height map
        calculated by photometric stereo" without naming the band; red, the shallowest, can
        lose shallow wrinkles below the depth threshold (seen on the simulator's dark-skin
        forehead-low subject), the combined height does not.
    """
    missing = [b for b in REQUIRED_BANDS if b not in normals_by_band]
    if missing:
        raise SkinTopoError(
            f"the spectral correction needs red, green and blue bands; missing {missing} (have {sorted(normals_by_band)})"
        )
    slopes = {band: normals_to_gradients(normals_by_band[band]) for band in REQUIRED_BANDS}
    if segmentation is None:
        combined = tuple(combined_slopes({band: slopes[band][axis] for band in REQUIRED_BANDS}) for axis in (0, 1))
        combined_height = integrate_slopes(*combined, spacing, mask=mask, method=integrator)
        segmentation = segment_wrinkles(combined_height, **segmentation_options)
        del combined, combined_height  # 25 bytes a pixel not needed by the correction itself
    corrected, z_red, z_a = correct_slopes(
        slopes["red"], slopes["green"], slopes["blue"], segmentation.extent, spacing, method=method, integrator=integrator, mask=mask
    )
    return CorrectionResult(corrected, z_red, z_a, segmentation, method)
