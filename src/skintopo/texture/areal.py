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

import functools

import numpy as np
import scipy.fft
import scipy.ndimage

from skintopo.defaults import DEFAULT_P, DEFAULT_Q
from skintopo.errors import SkinTopoError
from skintopo.filters import block_mean
from skintopo.heightmap import HeightMap

EQUIVALENT_LINE_WIDTH = 40.0  # % of the material ratio
FLAT_SQ_UM = 1e-9  # below this Sq the map is flat: Ssk and Sku are undefined


def valid_heights(height: HeightMap):
    """The valid heights as a flat array (a view when nothing is masked)."""
    if height.mask.all():
        return height.z.ravel()
    values = height.z[height.mask]
    if values.size == 0:
        raise SkinTopoError("the height map has no valid points")
    return values


def _mean_removed(height: HeightMap):
    """Heights about the mean of the valid points, 0 at masked points (which then add nothing
    to the sums and FFTs of the spatial parameters)."""
    if height.mask.all():
        return height.z - height.z.mean()
    return np.where(height.mask, height.z - height.z[height.mask].mean(), 0.0)


ROW_BLOCK = 64  # rows per block of the elementwise passes: their temporaries stay in cache


def row_blocks(rows, block=ROW_BLOCK):
    """(start, stop) of consecutive row blocks covering range(rows). Chains of elementwise
    NumPy passes over a 1024 x 1024 map are limited by memory bandwidth, which two threads
    share; run block by block their temporaries stay in the CPU cache (about 1.5x faster
    alone, 1.4x beside another thread, measured on the 2-core benchmark machine)."""
    return [(start, min(start + block, rows)) for start in range(0, rows, block)]


def height_parameters(height: HeightMap):
    """Sa, Sq, Ssk, Sku, Sp, Sv, Sz (ISO 25178-2 §4.1), heights about the mean plane.

    Sa = mean |z|, Sq = sqrt(mean z^2), Ssk = mean z^3 / Sq^3, Sku = mean z^4 / Sq^4 (not
    excess kurtosis: a Gaussian surface has Sku = 3), Sp = max z, Sv = -min z (a positive
    depth), Sz = Sp + Sv. Ssk and Sku are dimensionless, and NaN (undefined: 0/0) for a flat
    map, Sq below 1e-9 um (levelling round-off leaves about 1e-14 um on a plane).
    """
    values = valid_heights(height)
    mean = values.mean()
    sums = np.zeros(4)  # sum |z|, z^2, z^3, z^4
    for start, stop in row_blocks(values.size, ROW_BLOCK * 1024):
        z = values[start:stop] - mean
        squared = z * z
        sums += (np.abs(z).sum(), squared.sum(), np.dot(squared, z), np.dot(squared, squared))
    sa, mean_square, mean_cube, mean_fourth = sums / values.size
    sq = float(np.sqrt(mean_square))
    flat = sq < FLAT_SQ_UM
    ssk = float("nan") if flat else float(mean_cube / sq**3)
    sku = float("nan") if flat else float(mean_fourth / sq**4)
    sp, sv = float(values.max() - mean), float(mean - values.min())
    return {"Sa": float(sa), "Sq": sq, "Ssk": ssk, "Sku": sku, "Sp": sp, "Sv": sv, "Sz": sp + sv}


def hybrid_parameters(height: HeightMap):
    """Sdq (root mean square gradient) and Sdr (developed interfacial area ratio, %).

    Sdq = sqrt(mean (dz/dx)^2 + mean (dz/dy)^2) with forward differences.
    Sdr = (A_surface / A_projected - 1) * 100, A_surface from the two triangulations of each
    cell averaged (ISO 25178-2:2021 eq. D.15). Cells or differences touching a masked point
    are left out.
    """
    dy, dx = height.spacing
    z = height.z
    rows = z.shape[0]
    complete = bool(height.mask.all())

    def total(a):  # (sum, count) over the finite values (NaN next to a masked point)
        if complete:
            return np.array([a.sum(), a.size])
        finite = np.isfinite(a)
        return np.array([a[finite].sum(), np.count_nonzero(finite)])

    sums = np.zeros((3, 2))  # (sum, count) of dz_x^2, dz_y^2 and the cells' corner-area sums
    for start, stop in row_blocks(rows - 1):  # cells start..stop-1 use rows start..stop
        block = z[start : stop + 1]
        slope_x2 = np.square(np.diff(block, axis=1))
        slope_y2 = np.square(np.diff(block, axis=0))
        sums[0] += total(slope_x2 if stop == rows - 1 else slope_x2[:-1])  # the last row is the next block's first
        sums[1] += total(slope_y2)
        # the four corner triangles of each cell: sqrt((dy dzx)^2 + (dx dzy)^2 + (dx dy)^2) is
        # twice the area of the right triangle spanned by the two edge vectors at that corner;
        # summed as dy sqrt(dzx^2 + (dx/dy)^2 dzy^2 + dx^2), the factor dy applied at the end
        if dx != dy:
            slope_y2 *= (dx / dy) ** 2
        slope_y2 += dx * dx
        # horizontal edges: bottom [:-1], top [1:]; vertical edges: left [:, :-1], right [:, 1:]
        corners = [(edge_x, edge_y) for edge_x in (slope_x2[:-1], slope_x2[1:]) for edge_y in (slope_y2[:, :-1], slope_y2[:, 1:])]
        cell_sum = np.sqrt(np.add(*corners[0]))
        for edges in corners[1:]:
            corner = np.add(*edges)
            cell_sum += np.sqrt(corner, out=corner)
        sums[2] += total(cell_sum)
    if rows < 2 or z.shape[1] < 2 or not sums[:, 1].all():
        raise SkinTopoError("Sdq and Sdr need at least 2 x 2 valid points")
    (sum_x2, count_x), (sum_y2, count_y), (area, cells) = sums
    sdq = float(np.sqrt(sum_x2 / count_x / dx**2 + sum_y2 / count_y / dy**2))
    sdr = float((0.25 * dy * area / (cells * dx * dy) - 1) * 100)
    return {"Sdq": sdq, "Sdr": sdr}


def autocorrelation(height: HeightMap, max_lag=None):
    """Unbiased linear autocorrelation of the mean-removed heights.

    Lags run over |t_y| <= max_lag[0], |t_x| <= max_lag[1] pixels (default: every lag, i.e.
    rows - 1 and columns - 1); the zero lag is at index (max_lag[0], max_lag[1]). Each lag is
    divided by its number of overlapping valid points; lags without overlap are NaN. The
    zero-padding is only as large as the lags asked for need (size + max lag), so a small
    window costs a small FFT and has no wrap-around."""
    return _autocorrelation(_mean_removed(height), height.mask, max_lag)


def _autocorrelation(z, mask, max_lag):
    rows, columns = z.shape
    lag_y, lag_x = (rows - 1, columns - 1) if max_lag is None else (min(max_lag[0], rows - 1), min(max_lag[1], columns - 1))
    raw = _linear_correlation(z, lag_y, lag_x)
    if mask.all():  # overlap of a full field: (rows - |lag_y|) (columns - |lag_x|), at least 1 at every lag asked for
        raw /= np.outer(rows - np.abs(np.arange(-lag_y, lag_y + 1.0)), columns - np.abs(np.arange(-lag_x, lag_x + 1.0)))
        return raw
    overlap = np.round(_linear_correlation(mask.astype(float), lag_y, lag_x))
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(overlap > 0, raw / overlap, np.nan)


def _linear_correlation(a, lag_y, lag_x):
    """sum_ij a[i, j] a[i + t_y, j + t_x] for |t_y| <= lag_y, |t_x| <= lag_x (zero lag in the
    middle), by FFT with zero-padding to size + lag. The 2-D transforms are written as their
    two 1-D passes so that no work is spent on what is known or not wanted: the forward row
    pass skips the padding rows (zeros), the inverse column pass is a real transform, and
    the inverse row pass runs only on the non-negative row lags asked for, the others
    following by symmetry (scipy.fft.rfft2/irfft2 would transform every padded row, and the
    power spectrum as complex)."""
    rows, columns = a.shape
    size_y = scipy.fft.next_fast_len(rows + lag_y, real=True)
    size_x = scipy.fft.next_fast_len(columns + lag_x, real=True)
    spectrum = scipy.fft.rfft(a, n=size_x, axis=1)
    spectrum = scipy.fft.fft(spectrum, n=size_y, axis=0, overwrite_x=True)
    power = spectrum.real**2
    power += spectrum.imag**2
    del spectrum
    # Inverse along the columns: the power is real, so G = ifft(power, axis=0) has
    # G[-t] = conj(G[t]) = rfft(power, axis=0)[t] / size_y: a real transform of half the work.
    half = scipy.fft.rfft(power, axis=0, n=size_y)[: lag_y + 1]
    np.conj(half, out=half)
    half /= size_y  # row lags 0 .. lag_y
    circular = scipy.fft.irfft(half, n=size_x, axis=1, overwrite_x=True)
    out = np.empty((2 * lag_y + 1, 2 * lag_x + 1))
    upper = out[lag_y:]  # row lags 0 .. lag_y
    upper[:, :lag_x] = circular[:, size_x - lag_x :]
    upper[:, lag_x:] = circular[:, : lag_x + 1]
    # the correlation is point-symmetric, c(-t) = c(t): the negative row lags are the
    # positive ones turned by 180 degrees
    out[:lag_y] = upper[:0:-1, ::-1]
    return out


def _centred_lags(circular, lag_y, lag_x):
    """Lags -lag..lag of a circular correlation (lag 0 at index 0) as one array with the zero
    lag in the middle (slices, not fancy indexing: this is a large copy)."""
    rows, columns = circular.shape
    out = np.empty((2 * lag_y + 1, 2 * lag_x + 1))
    for target_rows, source_rows in ((slice(0, lag_y), slice(rows - lag_y, rows)), (slice(lag_y, None), slice(0, lag_y + 1))):
        out[target_rows, :lag_x] = circular[source_rows, columns - lag_x :]
        out[target_rows, lag_x:] = circular[source_rows, : lag_x + 1]
    return out


def _touches_border(region):
    """Whether a boolean region reaches the first or last row or column."""
    return bool(region[0].any() or region[-1].any() or region[:, 0].any() or region[:, -1].any())


def _decay_window(z, s):
    """Lags (rows, columns) that the central region of the autocorrelation above s probably
    needs: estimated from the circular (unpadded) autocorrelation of the map block-averaged
    to about 256 pixels across, with a 50% margin (the circular estimate decays sooner than
    the unbiased one). Only a guess: the caller checks it and falls back to every lag. None
    when the circular estimate's region already reaches its own border: the window then
    mostly does too (on 9 of 9 simulated 1024 x 1024 foreheads), and computing it first was wasted
    (spatial parameters of those 0.18-0.30 s with it, 0.16-0.22 s without; same values)."""
    factor = max(1, min(z.shape) // 256)
    z = block_mean(z, factor)
    rows, columns = z.shape
    spectrum = scipy.fft.rfft2(z)
    circular = scipy.fft.irfft2(spectrum.real**2 + spectrum.imag**2, z.shape)
    half_y, half_x = (rows - 1) // 2, (columns - 1) // 2
    acf = _centred_lags(circular, half_y, half_x)
    labels, _ = scipy.ndimage.label(acf > s * acf[half_y, half_x])
    region = labels == labels[half_y, half_x]
    if _touches_border(region):
        return None
    region_rows, region_cols = np.nonzero(region)
    extent_y = (np.abs(region_rows - half_y).max() + 1) * factor
    extent_x = (np.abs(region_cols - half_x).max() + 1) * factor
    return int(1.5 * extent_y) + 4, int(1.5 * extent_x) + 4


def spatial_parameters(height: HeightMap, *, s=0.2, directions=720):
    """Sal (autocorrelation length, um), Str (texture aspect ratio) and Std (texture
    direction, degrees) per ISO 25178-2 §4.3, threshold s = 0.2 (ISO 25178-3).

    Sal = the shortest distance at which the autocorrelation decays to s times its zero-lag
    value; Str = shortest / longest such distance (NaN when the central region above s
    reaches the border: the slowest decay is not inside the field). The autocorrelation is
    first computed only for the lags the circular estimate says the central region needs;
    when the region reaches that window, or the estimate reaches its own border, it is
    computed for every lag (the values are the same, only the FFT is larger).
    """
    dy, dx = height.spacing
    rows, columns = height.shape
    z = _mean_removed(height)
    window = _decay_window(z, s)
    for max_lag in ([window] if window is not None else []) + [(rows - 1, columns - 1)]:
        acf = _autocorrelation(z, height.mask, max_lag)
        centre = np.array([(acf.shape[0] - 1) // 2, (acf.shape[1] - 1) // 2])
        threshold = s * acf[centre[0], centre[1]]
        labels, _ = scipy.ndimage.label(acf > threshold)  # NaN lags compare False
        region = labels == labels[centre[0], centre[1]]
        touches = _touches_border(region)
        if not touches:
            break
    region_rows, region_cols = np.nonzero(region)
    reach = np.hypot((region_rows - centre[0]) * dy, (region_cols - centre[1]) * dx).max() + 2 * max(dx, dy)
    lengths = _decay_lengths(acf, centre, threshold, (dy, dx), directions, reach, shortest_only=touches)
    sal = float(np.nanmin(lengths)) if np.isfinite(lengths).any() else float("nan")
    str_ = float(sal / np.nanmax(lengths)) if np.isfinite(lengths).any() and not touches else float("nan")
    return {"Sal": sal, "Str": str_, "Std": _texture_direction(z, height.spacing)}


_DECAY_BLOCK = 32  # coarse steps per block of the decay-length search


def _decay_lengths(acf, centre, threshold, spacing, directions, reach, shortest_only=False):
    """Distance (um) along each of ``directions`` rays from the centre, over [0, 180) degrees
    (the ACF is point-symmetric), at which the ACF first falls to the threshold; NaN where a
    ray leaves the field first. The first crossing is found on 1-pixel steps and then located
    within that step on quarter-pixel samples, with linear interpolation between samples.
    Rays only need to reach across the central region (``reach``, um). The steps are taken
    in blocks of ``_DECAY_BLOCK`` outward, each only on the rays that have not crossed yet.
    ``shortest_only``: only the shortest length is wanted (Str is undefined): the search
    stops after the first block in which a ray crosses (a ray crossing in a later block is
    longer than the end of this one); the other rays stay NaN."""
    dy, dx = spacing
    filled = np.where(np.isnan(acf), threshold, acf)
    angles = np.linspace(0, np.pi, directions, endpoint=False)
    sin, cos = np.sin(angles)[:, None], np.cos(angles)[:, None]

    def sample(radius, sin, cos):
        rows = centre[0] - sin * radius / dy  # y up: rows go the other way
        cols = centre[1] + cos * radius / dx
        inside = (rows >= 0) & (rows <= acf.shape[0] - 1) & (cols >= 0) & (cols <= acf.shape[1] - 1)
        return _bilinear(filled, rows.clip(0, acf.shape[0] - 1), cols.clip(0, acf.shape[1] - 1)), inside

    step = min(dx, dy)
    coarse = np.arange(int(reach / step) + 2) * step
    first = np.full(directions, -1, np.intp)  # index of the first coarse sample at or below the threshold; -1: none yet
    for start in range(0, coarse.size, _DECAY_BLOCK):
        open_rays = np.flatnonzero(first < 0)
        if open_rays.size == 0 or (shortest_only and (first > 0).any()):
            break
        values, inside = sample(coarse[None, start : start + _DECAY_BLOCK], sin[open_rays], cos[open_rays])
        below = (values <= threshold) & inside
        hit = below.any(axis=1)
        first[open_rays[hit]] = start + below[hit].argmax(axis=1)
    crossed = np.flatnonzero(first > 0)
    lengths = np.full(directions, np.nan)
    fine = coarse[first[crossed] - 1][:, None] + np.arange(5)[None, :] * (step / 4)
    values, _ = sample(fine, sin[crossed], cos[crossed])
    k = (values <= threshold).argmax(axis=1)  # >= 1: the step starts above and ends below
    ray = np.arange(crossed.size)
    before, after = values[ray, k - 1], values[ray, k]
    lengths[crossed] = fine[ray, k - 1] + (before - threshold) / (before - after) * (step / 4)
    return lengths


def _bilinear(image, rows, cols):
    """Bilinear interpolation at (rows, cols) inside the image (the numbers of
    ``scipy.ndimage.map_coordinates(order=1)``, several times faster for many points)."""
    columns = image.shape[1]
    r0 = np.minimum(rows.astype(np.intp), image.shape[0] - 2)
    c0 = np.minimum(cols.astype(np.intp), columns - 2)
    fr, fc = rows - r0, cols - c0
    flat = image.ravel()
    index = r0 * columns + c0
    top = flat.take(index)
    top += fc * (flat.take(index + 1) - top)
    bottom = flat.take(index + columns)
    bottom += fc * (flat.take(index + columns + 1) - bottom)
    return top + fr * (bottom - top)


@functools.lru_cache(maxsize=8)
def _angle_bins(shape, spacing, angle_step):
    """Angular bin (centred on multiples of ``angle_step`` degrees, counter-clockwise from
    +x, y up, modulo 180) of every term of a ``scipy.fft.rfft2`` spectrum, and each term's
    weight in the full spectrum: 2 for the columns whose mirror image the real FFT leaves
    out (|F| is point-symmetric for real input, and so is the angle modulo 180), 1 for the
    zero and Nyquist columns, 0 for the DC term."""
    (rows, columns), (dy, dx) = shape, spacing
    fy = scipy.fft.fftfreq(rows, dy)
    fx = scipy.fft.rfftfreq(columns, dx)
    if columns % 2 == 0:
        fx[-1] = -fx[-1]  # the Nyquist column: numpy's full-spectrum convention puts it at -f
    angle = np.degrees(np.arctan2(-fy[:, None], fx[None, :])) % 180.0  # rows run down: y up is -fy
    count = int(round(180 / angle_step))
    bins = np.round(angle / angle_step).astype(np.intp) % count
    weight = np.full(fx.size, 2.0)
    weight[0] = 1.0
    if columns % 2 == 0:
        weight[-1] = 1.0
    weights = np.broadcast_to(weight, bins.shape).copy()
    weights[0, 0] = 0.0
    return bins.ravel(), weights.ravel(), count


def _texture_direction(z, spacing, angle_step=0.5):
    bins, weights, count = _angle_bins(z.shape, tuple(spacing), angle_step)
    amplitude = np.abs(scipy.fft.rfft2(z)).ravel()
    density = np.bincount(bins, weights=amplitude * weights, minlength=count)
    return float(np.argmax(density) * angle_step)


class MaterialRatio:
    """The areal material ratio curve of a height map, exact (no binning).

    Heights are about the mean plane. ``smr(c)`` is the percentage of valid points at or above
    height c; ``smc(mr)`` the height at which the material ratio is mr percent, the
    (1 - mr/100) quantile with linear interpolation.
    """

    def __init__(self, height: HeightMap):
        z = valid_heights(height)
        self._ascending = np.sort(z)
        self._ascending -= z.mean()  # sorting commutes with subtracting the mean, exactly
        self.heights = self._ascending[::-1]  # descending: index i has material ratio 100 i / (n - 1) %
        self.count = self.heights.size

    @property
    def ratios(self):
        """Material ratio (%) of each entry of ``heights``: 100 i / (n - 1)."""
        return np.linspace(0.0, 100.0, self.count)

    def _sum_highest(self, k):
        return self._ascending[self.count - k :].sum()

    def _sum_lowest(self, k):
        return self._ascending[:k].sum()

    def _at_or_above(self, c):
        return self.count - int(np.searchsorted(self._ascending, c, side="left"))

    def _above(self, c):
        return self.count - int(np.searchsorted(self._ascending, c, side="right"))

    def smr(self, c):
        """Areal material ratio Smr(c) in %: share of the points at or above height c (um)."""
        return 100.0 * self._at_or_above(c) / self.count

    def smc(self, mr):
        """Inverse areal material ratio Smc(mr) in um: the height where the ratio is mr %."""
        if not 0 <= mr <= 100:
            raise SkinTopoError(f"material ratio must be within 0-100 %, got {mr}")
        position = mr / 100.0 * (self.count - 1)
        i = min(int(position), self.count - 2) if self.count > 1 else 0
        if self.count == 1:
            return float(self.heights[0])
        fraction = position - i
        return float(self.heights[i] + fraction * (self.heights[i + 1] - self.heights[i]))

    def material_volume(self, mr):
        """Vm(mr) in um^3/um^2 (= ml/m^2): volume of material above the height Smc(mr), per
        unit area, Vm = (1/N) sum over z > c of (z - c)."""
        c = self.smc(mr)
        above = self._above(c)
        return float((self._sum_highest(above) - above * c) / self.count)

    def void_volume(self, mr):
        """Vv(mr) in um^3/um^2: void volume below Smc(mr) per unit area, (1/N) sum over z < c of (c - z)."""
        c = self.smc(mr)
        above = self._at_or_above(c)
        below = self.count - above
        return float((below * c - self._sum_lowest(below)) / self.count)

    def core(self):
        """Sk, Spk, Svk, Smr1, Smr2 (ISO 25178-2:2021 Annex B.1, after ISO 13565-2).

        Point i of the curve has material ratio 100 i / (n - 1) %, so the 40% window spans
        w = 0.4 (n - 1) index steps (an integer part and a fraction; integer arithmetic keeps
        the window's ends exact)."""
        heights, n = self.heights, self.count
        if n < 3:
            raise SkinTopoError("Sk and its companions need at least 3 valid points")
        steps, remainder = divmod(2 * (n - 1), 5)  # 40% of the n - 1 steps
        fraction = remainder / 5
        starts = 3 * (n - 1) // 5 + 1  # points with ratio <= 60 %
        # Least steep 40% secant: heights at mr and mr + 40 (interpolated), over all start points.
        ends = heights[steps : steps + starts]
        if fraction:
            ends = ends + fraction * (heights[steps + 1 : steps + 1 + starts] - ends)
        drops = heights[:starts] - ends
        first = int(np.argmin(drops))  # smallest drop = least steep; first occurrence
        # Equivalent straight line: least squares over the points of the window, in closed form
        # (u = index - first, uniform steps): slope per index step, then per % of material ratio.
        window = heights[first : first + steps + 1]
        u = np.arange(window.size, dtype=float)
        u_mean, y_mean = u.mean(), window.mean()
        slope_per_step = float(np.dot(u - u_mean, window - y_mean) / np.dot(u - u_mean, u - u_mean))
        per_percent = (n - 1) / 100.0
        slope = slope_per_step * per_percent
        intercept = y_mean - slope_per_step * (first + u_mean)
        upper, lower = intercept, slope * 100 + intercept
        smr1, smr2 = self.smr(upper), self.smr(lower)
        # Peak area A1 = integral over 0..Smr1 of (curve - upper); valley area A2 likewise,
        # each point standing for one step of 100 / (n - 1) %.
        step = 100.0 / (n - 1)
        peaks = self._above(upper)
        valleys = n - self._at_or_above(lower)
        a1 = float((self._sum_highest(peaks) - peaks * upper) * step)
        a2 = float((valleys * lower - self._sum_lowest(valleys)) * step)
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
