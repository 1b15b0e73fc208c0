"""ISO 25178-2 areal surface texture parameters.

All heights are taken from the mean plane of the valid points (z - mean(z)); the caller
chooses the S-F (form removal) and S-L (filtering) operators first, as the standard says
(``skintopo measure`` levels with a least-squares plane by default). Masked (NaN) points are
left out of every sum. Heights and lengths in micrometres; ratios in percent.

Discretisation choices, where the standard leaves one:

* gradients (Sdq) use forward differences along x and y, each averaged over its own
  differences; the developed area (Sdr) averages the two triangulations of every grid cell
  (ISO 25178-2:2021, D.3, eq. D.15) over the (nx-1)(ny-1) cells, whose projected area is
  (nx-1) dx (ny-1) dy;
* the areal material ratio curve is exact: Smr(c) is the fraction of valid points at or
  above c, its inverse Smc(mr) the (1 - mr) quantile with linear interpolation, and the
  volumes are exact sums over the points (no binning of the curve);
* Sk, Spk, Svk, Smr1, Smr2 follow ISO 25178-2:2021 Annex B.1 (after ISO 13565-2): the 40%
  window of the material ratio curve whose secant is least steep, the equivalent straight
  line fitted to the curve in that window by least squares, Sk its height difference
  between 0% and 100%, Spk and Svk the heights of the triangles of equal area to the peak
  and valley areas;
* the autocorrelation function is the unbiased linear one (zero-padded FFT, each lag divided
  by its number of overlapping points); Sal and Str come from the decay distances to
  s = 0.2 of its central value along 720 directions (first crossing, linear interpolation);
* Std is the direction of the largest angular amplitude density of the Fourier transform
  (0.5 degree bins centred on multiples of 0.5 degree), in degrees counter-clockwise from
  +x (y up), in [0, 180).
"""

from __future__ import annotations

import numpy as np
import scipy.fft
import scipy.ndimage

from skintopo.errors import SkinTopoError
from skintopo.heightmap import HeightMap

DEFAULT_P = 10.0  # % (ISO 25178-2 default for Vmp, Vmc, Vvc)
DEFAULT_Q = 80.0  # %
EQUIVALENT_LINE_WIDTH = 40.0  # % of the material ratio
FLAT_SQ_UM = 1e-9  # below this Sq the map is flat: Ssk and Sku are undefined


def _values(height: HeightMap):
    values = height.z[height.mask]
    if values.size == 0:
        raise SkinTopoError("the height map has no valid points")
    return values


def height_parameters(height: HeightMap):
    """Sa, Sq, Ssk, Sku, Sp, Sv, Sz (ISO 25178-2 §4.1), heights about the mean plane.

    Sa = mean |z|, Sq = sqrt(mean z^2), Ssk = mean z^3 / Sq^3, Sku = mean z^4 / Sq^4 (not
    excess kurtosis: a Gaussian surface has Sku = 3), Sp = max z, Sv = -min z (a positive
    depth), Sz = Sp + Sv. Ssk and Sku are dimensionless, and NaN (undefined: 0/0) for a flat
    map, Sq below 1e-9 um (levelling round-off leaves about 1e-14 um on a plane).
    """
    z = _values(height)
    z = z - z.mean()
    squared = z * z
    sq = float(np.sqrt(squared.mean()))
    flat = sq < FLAT_SQ_UM
    ssk = float("nan") if flat else float((squared * z).mean() / sq**3)
    sku = float("nan") if flat else float((squared * squared).mean() / sq**4)
    sp, sv = float(z.max()), float(-z.min())
    return {"Sa": float(np.abs(z).mean()), "Sq": sq, "Ssk": ssk, "Sku": sku, "Sp": sp, "Sv": sv, "Sz": sp + sv}


def hybrid_parameters(height: HeightMap):
    """Sdq (root mean square gradient) and Sdr (developed interfacial area ratio, %).

    Sdq = sqrt(mean (dz/dx)^2 + mean (dz/dy)^2) with forward differences.
    Sdr = (A_surface / A_projected - 1) * 100, A_surface from the two triangulations of each
    cell averaged (ISO 25178-2:2021 eq. D.15). Cells or differences touching a masked point
    are left out.
    """
    dy, dx = height.spacing
    z = height.z
    diff_x = np.diff(z, axis=1)
    diff_y = np.diff(z, axis=0)
    if not (np.isfinite(diff_x).any() and np.isfinite(diff_y).any()):
        raise SkinTopoError("Sdq and Sdr need at least 2 x 2 valid points")
    sdq = float(np.sqrt(np.nanmean((diff_x / dx) ** 2) + np.nanmean((diff_y / dy) ** 2)))
    bottom, top = (dy * diff_x[:-1, :]) ** 2, (dy * diff_x[1:, :]) ** 2
    left, right = (dx * diff_y[:, :-1]) ** 2, (dx * diff_y[:, 1:]) ** 2
    flat = (dx * dy) ** 2
    corners = (
        np.sqrt(bottom + left + flat) + np.sqrt(bottom + right + flat) + np.sqrt(top + right + flat) + np.sqrt(top + left + flat)
    )
    cells = np.isfinite(corners)
    sdr = float((0.25 * corners[cells].sum() / (cells.sum() * dx * dy) - 1) * 100)
    return {"Sdq": sdq, "Sdr": sdr}


def autocorrelation(height: HeightMap):
    """Unbiased linear autocorrelation of the mean-removed heights, zero lag at the centre
    index (rows - 1, columns - 1); lags without any valid overlap are NaN."""
    z = np.where(height.mask, height.z - height.z[height.mask].mean(), 0.0)
    weight = height.mask.astype(float)
    shape = (2 * z.shape[0] - 1, 2 * z.shape[1] - 1)
    fast = [scipy.fft.next_fast_len(n) for n in shape]

    def correlate(a):
        spectrum = scipy.fft.rfft2(a, fast, workers=-1)
        full = scipy.fft.irfft2(spectrum * np.conj(spectrum), fast, workers=-1)
        return np.roll(full, (z.shape[0] - 1, z.shape[1] - 1), axis=(0, 1))[: shape[0], : shape[1]]

    raw = correlate(z)
    if height.mask.all():  # overlap of a full field: (rows - |lag_y|) (columns - |lag_x|)
        lag_rows = z.shape[0] - np.abs(np.arange(-(z.shape[0] - 1), z.shape[0]))
        lag_columns = z.shape[1] - np.abs(np.arange(-(z.shape[1] - 1), z.shape[1]))
        overlap = np.outer(lag_rows, lag_columns).astype(float)
    else:
        overlap = np.round(correlate(weight))
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(overlap > 0, raw / overlap, np.nan)


def spatial_parameters(height: HeightMap, *, s=0.2, directions=720):
    """Sal (autocorrelation length, um), Str (texture aspect ratio) and Std (texture
    direction, degrees) per ISO 25178-2 §4.3, threshold s = 0.2 (ISO 25178-3).

    Sal = the shortest distance at which the autocorrelation decays to s times its zero-lag
    value; Str = shortest / longest such distance (NaN when the central region above s
    reaches the border: the slowest decay is not inside the field).
    """
    acf = autocorrelation(height)
    dy, dx = height.spacing
    centre = np.array([height.shape[0] - 1, height.shape[1] - 1])
    threshold = s * acf[centre[0], centre[1]]
    above = np.nan_to_num(acf, nan=-np.inf) > threshold
    labels, _ = scipy.ndimage.label(above)
    region = labels == labels[centre[0], centre[1]]
    touches = region[0].any() or region[-1].any() or region[:, 0].any() or region[:, -1].any()
    angles = np.linspace(0, np.pi, directions, endpoint=False)  # the ACF is point-symmetric
    step = min(dx, dy) / 4  # um along each ray
    region_rows, region_cols = np.nonzero(region)
    reach = np.hypot((region_rows - centre[0]) * dy, (region_cols - centre[1]) * dx).max() + 2 * max(dx, dy)
    radius = np.arange(int(reach / step) + 2) * step  # rays need only cross the central region
    rows = centre[0] - np.sin(angles)[:, None] * radius[None, :] / dy  # y up: rows go the other way
    cols = centre[1] + np.cos(angles)[:, None] * radius[None, :] / dx
    inside = (rows >= 0) & (rows <= acf.shape[0] - 1) & (cols >= 0) & (cols <= acf.shape[1] - 1)
    filled = np.nan_to_num(acf, nan=threshold)
    samples = scipy.ndimage.map_coordinates(filled, [rows.clip(0, acf.shape[0] - 1), cols.clip(0, acf.shape[1] - 1)], order=1)
    below = (samples <= threshold) & inside
    first = below.argmax(axis=1)
    crossed = below.any(axis=1) & (first > 0)
    lengths = np.full(directions, np.nan)
    i = np.flatnonzero(crossed)
    before, after = samples[i, first[i] - 1], samples[i, first[i]]
    lengths[i] = radius[first[i] - 1] + (before - threshold) / (before - after) * step
    sal = float(np.nanmin(lengths)) if np.isfinite(lengths).any() else float("nan")
    str_ = float(sal / np.nanmax(lengths)) if np.isfinite(lengths).any() and not touches else float("nan")
    return {"Sal": sal, "Str": str_, "Std": texture_direction(height)}


def texture_direction(height: HeightMap, *, angle_step=0.5):
    """Std: the angle (degrees, counter-clockwise from +x, y up, in [0, 180)) of the largest
    angular amplitude density of the 2-D Fourier transform of the mean-removed heights.
    A lay of parallel grooves along direction theta has its spectrum along theta + 90 degrees;
    Std reports the direction of that spectral maximum, as ISO 25178-2 §4.3.4 defines it."""
    z = np.where(height.mask, height.z - height.z[height.mask].mean(), 0.0)
    dy, dx = height.spacing
    amplitude = np.abs(scipy.fft.fftshift(scipy.fft.fft2(z)))
    fy = scipy.fft.fftshift(scipy.fft.fftfreq(z.shape[0], dy))
    fx = scipy.fft.fftshift(scipy.fft.fftfreq(z.shape[1], dx))
    angle = np.degrees(np.arctan2(-fy[:, None], fx[None, :])) % 180.0  # rows run down: y up is -fy
    radius = np.hypot(fy[:, None], fx[None, :])
    keep = radius > 0
    count = int(round(180 / angle_step))
    bins = np.round(angle[keep] / angle_step).astype(int) % count  # bins centred on multiples of the step
    density = np.bincount(bins, weights=amplitude[keep], minlength=count)
    return float(np.argmax(density) * angle_step)


class MaterialRatio:
    """The areal material ratio curve of a height map, exact (no binning).

    Heights are about the mean plane. ``smr(c)`` is the percentage of valid points at or above
    height c; ``smc(mr)`` the height at which the material ratio is mr percent, the
    (1 - mr/100) quantile with linear interpolation.
    """

    def __init__(self, height: HeightMap):
        z = _values(height)
        self.heights = np.sort(z - z.mean())[::-1]  # descending: index i has material ratio i / (n - 1)
        self.count = self.heights.size
        self.ratios = np.linspace(0.0, 100.0, self.count)
        self._cumulative = np.concatenate([[0.0], np.cumsum(self.heights)])

    def smr(self, c):
        """Areal material ratio Smr(c) in %: share of the points at or above height c (um)."""
        return 100.0 * float(np.count_nonzero(self.heights >= c)) / self.count

    def smc(self, mr):
        """Inverse areal material ratio Smc(mr) in um: the height where the ratio is mr %."""
        if not 0 <= mr <= 100:
            raise SkinTopoError(f"material ratio must be within 0-100 %, got {mr}")
        return float(np.interp(mr, self.ratios, self.heights))

    def material_volume(self, mr):
        """Vm(mr) in um^3/um^2 (= ml/m^2): volume of material above the height Smc(mr), per
        unit area, Vm = (1/N) sum over z > c of (z - c)."""
        c = self.smc(mr)
        above = int(np.count_nonzero(self.heights > c))
        return float((self._cumulative[above] - above * c) / self.count)

    def void_volume(self, mr):
        """Vv(mr) in um^3/um^2: void volume below Smc(mr) per unit area, (1/N) sum over z < c of (c - z)."""
        c = self.smc(mr)
        above = int(np.count_nonzero(self.heights >= c))
        below = self.count - above
        return float((below * c - (self._cumulative[-1] - self._cumulative[above])) / self.count)

    def core(self):
        """Sk, Spk, Svk, Smr1, Smr2 (ISO 25178-2:2021 Annex B.1, after ISO 13565-2)."""
        ratios, heights = self.ratios, self.heights
        # Least steep 40% secant: heights at mr and mr + 40 (interpolated), over all start points.
        starts = ratios[ratios <= 100 - EQUIVALENT_LINE_WIDTH]
        ends = np.interp(starts + EQUIVALENT_LINE_WIDTH, ratios, heights)
        drops = heights[: starts.size] - ends
        first = int(np.argmin(drops))  # smallest drop = least steep; first occurrence
        window = (ratios >= starts[first]) & (ratios <= starts[first] + EQUIVALENT_LINE_WIDTH)
        slope, intercept = np.polyfit(ratios[window], heights[window], 1)
        upper, lower = intercept, slope * 100 + intercept
        smr1, smr2 = self.smr(upper), self.smr(lower)
        # Peak area A1 = integral over 0..Smr1 of (curve - upper); valley area A2 likewise.
        peak = heights > upper
        valley = heights < lower
        step = 100.0 / (self.count - 1)
        a1 = float(np.sum(heights[peak] - upper) * step)
        a2 = float(np.sum(lower - heights[valley]) * step)
        return {
            "Sk": float(upper - lower),
            "Spk": 2 * a1 / smr1 if a1 > 0 and smr1 > 0 else 0.0,
            "Svk": 2 * a2 / (100 - smr2) if a2 > 0 and smr2 < 100 else 0.0,
            "Smr1": smr1,
            "Smr2": smr2,
        }


def functional_parameters(height: HeightMap, *, p=DEFAULT_P, q=DEFAULT_Q, sxp=(2.5, 50.0)):
    """Material-ratio (functional) and volume parameters (ISO 25178-2 §4.4-4.5).

    Sxp = Smc(2.5 %) - Smc(50 %); Vmp = Vm(p); Vmc = Vm(q) - Vm(p); Vvc = Vv(p) - Vv(q);
    Vvv = Vv(q); with p = 10 %, q = 80 % by default. Volumes in um^3/um^2 (= ml/m^2).
    """
    if not 0 <= p < q <= 100:
        raise SkinTopoError(f"volume parameters need 0 <= p < q <= 100 %, got p = {p}, q = {q}")
    curve = MaterialRatio(height)
    result = curve.core()
    result["Sxp"] = curve.smc(sxp[0]) - curve.smc(sxp[1])
    vm_p, vm_q = curve.material_volume(p), curve.material_volume(q)
    vv_p, vv_q = curve.void_volume(p), curve.void_volume(q)
    result.update({"Vmp": vm_p, "Vmc": vm_q - vm_p, "Vvc": vv_p - vv_q, "Vvv": vv_q})
    return result
