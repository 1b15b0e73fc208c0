"""Melanin and haemoglobin from the per-band albedo (a measurement, beside the topography).

Photometric stereo gives, with the normals, each band's albedo: the skin's diffuse
reflectance at 625, 523 and 462 nm with the shading divided out. Clinical 3-D skin cameras
report from such colour a melanin and a haemoglobin map; this module does the same with a
two-chromophore linear model on optical densities.

Model
-----
The optical density of band b, OD_b = -log10 R_b (R the diffuse reflectance), is

    OD_b = M m_b + H h_b + B,

with m_b and h_b the spectral shapes of melanin and haemoglobin absorption at the band's
LED wavelength, each 1 at the reference wavelength 523 nm, and B a baseline the same in
every band (the scattering loss and anything that scales all bands alike: left-over shading,
the exposure). Three bands give three equations for the three unknowns, solved exactly per
pixel. So M and H are the optical densities (log10 units) that melanin and haemoglobin add
at 523 nm: the **melanin index** and the **haemoglobin index** of the maps.

- Melanin: mu_a proportional to lambda^-3.5 (Jacques, "Optical properties of biological
  tissues: a review", Phys. Med. Biol. 58 (2013) R37: mu_a.mel = 519 (lambda / 500 nm)^-3.5
  cm^-1); only the shape is used.
- Haemoglobin: total haemoglobin at an oxygen saturation of 75% (mixed arterial and venous
  dermal blood; a choice, stated in the output), from the molar extinction coefficients
  compiled by S. Prahl from W. B. Gratzer and N. Kollias (Oregon Medical Laser Center,
  omlc.org/spectra/hemoglobin), linearly interpolated between the table's 2 nm rows around
  each LED wavelength.

Limits (stated with every result): three bands determine two chromophores and one baseline
exactly, so nothing is left to check the model per pixel; a band's photons travel different
depths and path lengths in skin (red the deepest), which the linear model folds into
effective spectra: the indices are linear in optical density and comparable between regions,
subjects measured alike and visits, not absolute concentrations. Shading that is the same in
every band goes into B and not into the maps; what is not (interreflection inside wrinkles
scales with each band's albedo, translucency blurs each band by its own kernel) can leak, and
is measured in the tests and in ``docs/method.md``.

Reflectance
-----------
The albedo is an absolute reflectance only if the lights' intensities are known in the same
units. With a white reference target of known reflectance in the field (manifest field
``white_reference``: a box of the images and the target's reflectance), each band's albedo is
scaled so that the target's median albedo equals its reflectance; without one the albedo is
taken as it is and the result is marked **relative** (the lights' recorded intensities set the
scale; an error of a factor k in one band shifts M and H by constants, so maps and changes
keep their meaning, absolute levels do not).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from skintopo.defaults import DEFAULT_COLOUR_SMOOTHING_UM, DEFAULT_SHADOW_FRACTION
from skintopo.errors import SkinTopoError

LED_WAVELENGTHS_NM = {"red": 625.0, "green": 523.0, "blue": 462.0}
RGB = ("red", "green", "blue")
REFERENCE_WAVELENGTH_NM = 523.0
MELANIN_EXPONENT = 3.5  # Jacques 2013, mu_a.mel = 519 (lambda / 500 nm)^-3.5 cm^-1
OXYGEN_SATURATION = 0.75
# Prahl's compilation (Gratzer; Kollias): wavelength nm -> molar extinction (HbO2, Hb) in
# cm^-1 / (mol / L); the rows around the three LED wavelengths.
PRAHL_HAEMOGLOBIN = {
    460: (44480.0, 23388.8), 462: (41320.0, 20891.2), 464: (39807.2, 19260.8),
    522: (26450.4, 32851.2), 524: (29269.2, 34397.6),
    624: (774.0, 5906.8), 626: (707.6, 5620.0),
}
OUT_OF_RANGE_LIMIT = 0.01  # more than this fraction of the valid pixels outside (0, 1] in a band: refused


def haemoglobin_extinction(wavelength_nm, saturation=OXYGEN_SATURATION):
    """Molar extinction of haemoglobin at oxygen saturation ``saturation`` (cm^-1 / M):
    S eps_HbO2 + (1 - S) eps_Hb, linear between the rows of :data:`PRAHL_HAEMOGLOBIN`."""
    rows = sorted(PRAHL_HAEMOGLOBIN)
    below = max((w for w in rows if w <= wavelength_nm), default=None)
    above = min((w for w in rows if w >= wavelength_nm), default=None)
    if below is None or above is None or above - below > 2:
        raise SkinTopoError(f"no haemoglobin extinction tabulated around {wavelength_nm} nm (rows: {rows})")
    t = 0.0 if above == below else (wavelength_nm - below) / (above - below)
    oxy, deoxy = ((1 - t) * np.array(PRAHL_HAEMOGLOBIN[below]) + t * np.array(PRAHL_HAEMOGLOBIN[above]))
    return float(saturation * oxy + (1 - saturation) * deoxy)


def melanin_absorption(wavelength_nm):
    """Melanin's absorption coefficient, cm^-1 (Jacques 2013: 519 (lambda / 500 nm)^-3.5)."""
    return 519.0 * (wavelength_nm / 500.0) ** -MELANIN_EXPONENT


def spectra_matrix(wavelengths_nm=None, saturation=OXYGEN_SATURATION):
    """The model's matrix: one row (m_b, h_b, 1) per band of ``wavelengths_nm`` (default the
    LED wavelengths in the order red, green, blue), each spectrum 1 at 523 nm."""
    wavelengths_nm = wavelengths_nm or LED_WAVELENGTHS_NM
    reference_m = melanin_absorption(REFERENCE_WAVELENGTH_NM)
    reference_h = haemoglobin_extinction(REFERENCE_WAVELENGTH_NM, saturation)
    return np.array([[melanin_absorption(wavelengths_nm[b]) / reference_m, haemoglobin_extinction(wavelengths_nm[b], saturation) / reference_h, 1.0]
                     for b in RGB])


def forward_reflectance(melanin, haemoglobin, baseline, saturation=OXYGEN_SATURATION):
    """R_b = 10^-(M m_b + H h_b + B) per band (the model of the module notes): dict band ->
    array. The simulator makes its albedo maps with this."""
    matrix = spectra_matrix(saturation=saturation)
    return {band: 10.0 ** -(matrix[i, 0] * np.asarray(melanin) + matrix[i, 1] * np.asarray(haemoglobin) + np.asarray(baseline))
            for i, band in enumerate(RGB)}


def chromophore_indices(reflectance, saturation=OXYGEN_SATURATION):
    """(melanin, haemoglobin, baseline) per pixel from ``reflectance`` (dict band -> array,
    red, green and blue, values in (0, 1]): the exact solution of the 3 x 3 model of the
    module notes, in the reflectance's floating type (float32 stays float32); NaN where a
    band is not finite or not positive."""
    missing = [b for b in RGB if b not in reflectance]
    if missing:
        raise SkinTopoError(f"melanin and haemoglobin need red, green and blue reflectance; missing {missing}")
    inverse = np.linalg.inv(spectra_matrix(saturation=saturation))
    density = []
    for band in RGB:
        values = np.asarray(reflectance[band])
        values = values if values.dtype.kind == "f" else values.astype(np.float64)
        with np.errstate(divide="ignore", invalid="ignore"):
            density.append(np.where(values > 0, -np.log10(values), np.nan).astype(values.dtype, copy=False))
    return tuple(sum(values.dtype.type(inverse[k, i]) * values for i, values in enumerate(density)) for k in range(3))


STATISTICS = ("mean", "standard_deviation", "relative_variation")  # of a region, by region_statistics


def region_statistics(values, mask=None):
    """Mean, standard deviation and relative variation (standard deviation / |mean|) of the
    finite ``values`` inside ``mask``, as clinical skin cameras report a region's level and
    its variation; and the number of pixels."""
    values = np.asarray(values, dtype=np.float64)
    inside = np.isfinite(values) if mask is None else (np.isfinite(values) & np.asarray(mask, dtype=bool))
    if not inside.any():
        return {"mean": None, "standard_deviation": None, "relative_variation": None, "pixels": 0}
    chosen = values[inside]
    mean, deviation = float(chosen.mean()), float(chosen.std())
    return {"mean": mean, "standard_deviation": deviation, "relative_variation": deviation / abs(mean) if mean != 0 else None,
            "pixels": int(inside.sum())}


@dataclass(frozen=True, eq=False)
class ChromophoreMaps:
    """Melanin and haemoglobin indices per pixel (module notes), with how the reflectance
    was obtained.

    Attributes
    ----------
    melanin, haemoglobin, baseline : ndarray
        Optical densities (log10) at 523 nm; NaN where not measured.
    reflectance : str
        ``"absolute"`` (scaled by a white reference) or ``"relative"`` (the albedo as the
        lights' recorded intensities give it).
    scale : dict
        The factor each band's albedo was multiplied by (1 without a reference).
    out_of_range : dict
        Per band, the fraction of valid pixels whose reflectance fell outside (0, 1] (left
        out of the maps).
    smoothing_um : float
        Sigma of the Gaussian the optical densities were smoothed with (0: none).
    """

    melanin: np.ndarray
    haemoglobin: np.ndarray
    baseline: np.ndarray
    reflectance: str
    scale: dict
    out_of_range: dict
    smoothing_um: float = 0.0

    def statistics(self, regions=None):
        """{region: {"melanin": stats, "haemoglobin": stats}} for the whole field and each
        of ``regions`` (name -> boolean mask), by :func:`region_statistics`."""
        regions = {"field": None, **(regions or {})}
        return {name: {"melanin": region_statistics(self.melanin, mask), "haemoglobin": region_statistics(self.haemoglobin, mask)}
                for name, mask in regions.items()}

    def as_dict(self, regions=None, statistics=None):
        """JSON-ready: the model, its sources and limits, the reflectance scale and the
        statistics per region (``statistics``: those of :meth:`statistics` when the caller
        has them already)."""
        return {
            "model": "OD_b = M m_b + H h_b + B per pixel, OD = -log10 reflectance; M, H: optical density at 523 nm",
            "wavelengths_nm": dict(LED_WAVELENGTHS_NM),
            "oxygen_saturation": OXYGEN_SATURATION,
            "sources": {"melanin": "Jacques 2013, Phys. Med. Biol. 58 R37: mu_a proportional to lambda^-3.5",
                        "haemoglobin": "Prahl, omlc.org/spectra/hemoglobin (Gratzer; Kollias), molar extinction"},
            "limits": "three bands: two chromophores and a baseline, exactly determined; effective spectra (path lengths differ by "
                      "band): indices comparable between regions, subjects measured alike and visits, not absolute concentrations",
            "reflectance": self.reflectance,
            "scale": self.scale,
            "out_of_range_fraction": self.out_of_range,
            "smoothing_um": self.smoothing_um,
            "units": "optical density (log10) at 523 nm",
            "regions": self.statistics(regions) if statistics is None else statistics,
        }


def _smoothed(values, sigma_px):
    """Gaussian smoothing that ignores NaN (normalised convolution); NaN stays NaN."""
    import scipy.ndimage

    valid = np.isfinite(values)
    if sigma_px <= 0:
        return values
    total = scipy.ndimage.gaussian_filter(np.where(valid, values, values.dtype.type(0)), sigma_px, mode="nearest")
    weight = scipy.ndimage.gaussian_filter(valid.astype(values.dtype), sigma_px, mode="nearest")
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(valid, total / weight, np.nan)


def chromophore_maps(albedo, *, pixel_um=None, smoothing_um=DEFAULT_COLOUR_SMOOTHING_UM, reference_albedo=None, reference_reflectance=None,
                     source="the acquisition"):
    """:class:`ChromophoreMaps` from per-band albedo maps (dict band -> array, red, green,
    blue).

    With ``reference_albedo`` (dict band -> the white reference's median albedo) and
    ``reference_reflectance`` (dict band -> its known reflectance), each band is scaled by
    reflectance / albedo of the reference (absolute reflectance); else the albedo is used as
    it is (relative). Pixels whose reflectance falls outside (0, 1] are left out; when more
    than 1% of a band's valid pixels do, the reference (or the lights' intensities) cannot be
    right and a :class:`SkinTopoError` names ``source``, the band and the fraction.

    The optical densities are smoothed by a Gaussian of ``smoothing_um`` (sigma; needs
    ``pixel_um``; 0: per pixel) before the inversion: the inversion amplifies each band's
    noise about 15-fold (the condition number of the model's matrix), and a single pixel's
    sensor noise would otherwise dominate the maps (measured on the simulator: correlation
    with the true melanin map 0.95 per pixel, 0.985 with 30 um at 20 um pixels).
    """
    missing = [b for b in RGB if b not in albedo]
    if missing:
        raise SkinTopoError(f"{source}: melanin and haemoglobin need red, green and blue albedo; missing {missing}")
    if reference_albedo is not None:
        scale = {b: float(reference_reflectance[b] / reference_albedo[b]) for b in RGB}
    else:
        scale = {b: 1.0 for b in RGB}
    reflectance, out_of_range, problems = {}, {}, []
    for band in RGB:  # float32 (a 20-megapixel field: 80 MB a map)
        values = np.asarray(albedo[band], dtype=np.float32) * np.float32(scale[band])
        valid = np.isfinite(values)
        outside = valid & ~((values > 0) & (values <= 1))
        fraction = float(outside.sum() / max(int(valid.sum()), 1))
        out_of_range[band] = fraction
        if fraction > OUT_OF_RANGE_LIMIT:
            low, high = int((valid & (values <= 0)).sum()), int((valid & (values > 1)).sum())
            how = f"scaled by the white reference (x{scale[band]:.4g})" if reference_albedo is not None else "as the lights' intensities give it"
            problems.append(f"{band}: {100 * fraction:.1f}% of the pixels have a reflectance outside (0, 1] ({high} above 1, {low} at or "
                            f"below 0) {how}")
        reflectance[band] = np.where(outside, np.nan, values)
        if smoothing_um and pixel_um:
            reflectance[band] = np.float32(10.0) ** -_smoothed(-np.log10(reflectance[band]), smoothing_um / pixel_um)
    if problems:
        hint = ("check the reference's reflectance and box" if reference_albedo is not None
                else "give a white reference (manifest field 'white_reference') or check the lights' intensities")
        raise SkinTopoError(f"{source}: the reflectance is not physical ({'; '.join(problems)}): {hint}")
    melanin, haemoglobin, baseline = chromophore_indices(reflectance)
    return ChromophoreMaps(melanin, haemoglobin, baseline,
                           "absolute" if reference_albedo is not None else "relative", scale, out_of_range,
                           smoothing_um if (smoothing_um and pixel_um) else 0.0)


def reference_albedo(acquisition, *, shadow_fraction=None):
    """Each band's median albedo over the acquisition's white reference box
    (:class:`~skintopo.acquisition.WhiteReference`), by photometric stereo of the box alone
    (the target is outside the skin mask). A :class:`SkinTopoError` when the box gives no
    valid albedo in a band."""
    from skintopo.normals import photometric_stereo

    reference = acquisition.white_reference
    rows, columns = reference.slices
    values = {}
    for band in RGB:
        images = acquisition.bands[band]
        stereo = photometric_stereo(images.images[:, rows, columns], images.lights,
                                    shadow_fraction=DEFAULT_SHADOW_FRACTION if shadow_fraction is None else shadow_fraction)
        albedo = stereo.albedo[np.isfinite(stereo.albedo)]
        if albedo.size == 0 or not np.median(albedo) > 0:
            raise SkinTopoError(f"{acquisition.source}: the white reference box {list(reference.box_px)} gives no valid albedo in the "
                                f"{band} band (is the target in the box and lit by every light?)")
        values[band] = float(np.median(albedo))
    return values
