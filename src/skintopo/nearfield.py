"""Near-field photometric stereo: point LEDs and a perspective camera (:mod:`skintopo.device`).

Under the device's LEDs a Lambertian point P of albedo rho and unit normal n shows
I_i = rho n . s_i(P), with s_i(P) the LED's light vector at P (Quéau et al. 2018, eq. 4;
see :mod:`skintopo.device`). s_i depends on P, hence on the unknown depth, so the solver
alternates (Quéau et al. 2018, section 4; Logothetis et al. 2017 do the same with a joint
variational solver):

1. points P = d (a, b, -1) on each pixel's ray from the current depth d (mm);
2. per pixel, least squares over the LEDs with that pixel's own light matrix S(P):
   g = (S^T W S)^-1 S^T W I, rho = |g|, n = g / |g| (W: the shadow rule of
   :mod:`skintopo.normals`, applied to I_i / |s_i|);
3. normals -> depth by perspective integration: with P = d w, w = (a, b, -1), the
   tangents dP/du = d_u w + d w_u must be normal to n, so

       d(log d)/du = -(n . w_u) / (n . w),    d(log d)/dv = -(n . w_v) / (n . w),

   integrated by the project's integrator (:func:`skintopo.height.integrate_slopes`) on the
   pixel grid; w_u, w_v are differentiated numerically, which includes lens distortion;
4. the constant of integration (a global scale of the shape, which perspective integration
   cannot see) by photometry: the depth scale k that minimises the residual of step 2 over a
   subsample of pixels (the 1/r^2 fall-off and the LEDs' changing directions make a wrong
   distance visible), or by the working distance (``scale="working-distance"``: the median
   depth is the working distance);

until the depth changes by less than ``tolerance_um`` RMS (default 0.1 um), starting from the
plane at the working distance.

The result is resampled to a regular grid in the skin plane (:func:`surface_grid`): the
device's pixel footprint at the working distance, centred on the optical axis, heights in
micrometres toward the camera (h = (D - d) 1000), so every measure of the project applies.

Flat-field images for a device acquisition must correct the camera only (vignetting, pixel
gain), not the LEDs' fall-off: the device model holds that. Cast shadows and highlights
are handled by the shadow rule; interreflection and subsurface scattering are not modelled
here.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace

import numpy as np
import scipy.ndimage

from skintopo._linalg import solve_symmetric_3x3
from skintopo.defaults import DEFAULT_INTEGRATOR, DEFAULT_SHADOW_FRACTION
from skintopo.device import Device
from skintopo.errors import SkinTopoError
from skintopo.filters import block_mean
from skintopo.height import fill_from_nearest, integrate_slopes, nearest_valid_index
from skintopo.heightmap import HeightMap
from skintopo.normals import PhotometricStereoResult

SCALES = ("photometric", "working-distance")
SCALE_SAMPLE_STEP = 2  # the photometric scale is fitted on every 2nd pixel of every 2nd row (of the binned images)
CHUNK = 1 << 15  # pixels per block of the per-pixel solves
COARSE_PIXELS = 256  # the alternation first converges on images binned to about this many pixels across
DEFAULT_TOLERANCE_UM = 0.1
SCALE_SETTLED = 1e-4  # the photometric scale is kept once it changes by less than this between iterations
_UPPER = [(0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2)]


@dataclass(frozen=True, eq=False)
class NearFieldResult:
    """Output of :func:`near_field_photometric_stereo`.

    Attributes
    ----------
    height : HeightMap
        Heights in micrometres (toward the camera, 0 at the working distance) on the regular
        skin-plane grid of :func:`surface_grid`.
    depth_mm : ndarray (rows, columns)
        Depth of each camera pixel's point along the optical axis, mm; NaN where invalid.
    normals, albedo, residual : ndarray
        Per camera pixel (normals in the camera frame; residual relative, as
        :func:`per_pixel_photometric_stereo` gives it); NaN where invalid.
    used : ndarray of bool (m, rows, columns)
        Which LEDs' observations entered each camera pixel's fit.
    valid : ndarray of bool
        Camera pixels with at least 3 usable LEDs.
    sampling : tuple of ndarray
        (row, column) of the camera image at each node of the skin-plane grid.
    changes_um : list of float
        RMS depth change per iteration (micrometres): the convergence record.
    scales : list of float
        The depth scale chosen at each iteration (1 = unchanged).
    seconds : float
    options : dict
    """

    height: HeightMap
    depth_mm: np.ndarray
    normals: np.ndarray
    albedo: np.ndarray
    residual: np.ndarray
    used: np.ndarray
    valid: np.ndarray
    sampling: tuple
    changes_um: list
    scales: list
    seconds: float
    options: dict = field(default_factory=dict)

    @property
    def converged(self):
        """True when the last depth change was below the tolerance."""
        return bool(self.changes_um) and self.changes_um[-1] < self.options["tolerance_um"]

    def stereo_on_surface_grid(self):
        """The normals, albedo and residual resampled to the skin-plane grid of
        :attr:`height` (bilinear; the normals renormalised, the LEDs used taken from the
        nearest pixel), as a :class:`~skintopo.normals.PhotometricStereoResult`: what the
        distant-light pipeline's later stages (spectral correction, report) take."""
        row, column = self.sampling
        inside = self.height.mask
        index = None if self.valid.all() else nearest_valid_index(self.valid)  # one distance transform for every map

        def sample(values, order=1):
            (filled,) = fill_from_nearest(self.valid, values, index=index)
            out = scipy.ndimage.map_coordinates(np.asarray(filled, dtype=np.float64), [row, column], order=order, mode="nearest")
            return np.where(inside, out, np.nan)

        normals = np.stack([sample(self.normals[..., i]) for i in range(3)], axis=-1)
        normals /= np.linalg.norm(normals, axis=-1, keepdims=True)
        used = np.stack([sample(u.astype(np.float64), order=0) > 0.5 for u in self.used]) & inside
        return PhotometricStereoResult(normals.astype(np.float32), sample(self.albedo).astype(np.float32),
                                       sample(self.residual).astype(np.float32), used.sum(axis=0).astype(np.int16), inside.copy(), used)


def _light_matrices(device: Device, points, band):
    """(m, 3, P) float32 light vectors of every LED at points (3, P), times D^2 (so that they
    are about 1 in size: the normal equations stay far from float32's limits)."""
    scale = np.float32(device.working_distance_mm**2)
    return np.stack([led.light_vectors(points, band) * scale for led in device.leds])


def _normals_at(intensity, rays, depth, device, band, shadow_fraction, used=None):
    """:func:`per_pixel_photometric_stereo` with the LEDs' light vectors at the points
    depth x rays (mm): g (3, P), the relative residual (P,) and the observations used
    (m, P). Done in chunks of ``CHUNK`` pixels, so that the temporaries stay in the
    processor's cache (about 3x faster than whole-image temporaries at 1000 x 1000)."""
    count = rays.shape[1]
    g = np.empty((3, count), np.float32)
    residual = np.empty(count, np.float32)
    used_now = np.empty(intensity.shape, bool)
    for start in range(0, count, CHUNK):
        part = slice(start, start + CHUNK)
        points = (depth[part] * rays[:, part]).astype(np.float32)
        g[:, part], residual[part], used_now[:, part] = per_pixel_photometric_stereo(
            intensity[:, part], _light_matrices(device, points, band), shadow_fraction=shadow_fraction,
            used=None if used is None else used[:, part])
    return g, residual, used_now


def _solve(lights, values, weights):
    """g (3, P) from S^T W S g = S^T W I per pixel; NaN where fewer than 3 observations
    remain or the remaining lights do not span 3-D (det below 1e-6 of (trace / 3)^3)."""
    s = [lights[:, i] for i in range(3)]  # (m, P) each
    ws = [weights * c for c in s]
    upper = [np.einsum("mp,mp->p", ws[i], s[j]) for i, j in _UPPER]
    rhs = [np.einsum("mp,mp->p", c, values) for c in ws]
    g, det = solve_symmetric_3x3(upper, rhs)
    trace = (upper[0] + upper[3] + upper[5]) / 3
    g[:, ~((np.einsum("mp->p", weights) >= 3) & (np.abs(det) > 1e-6 * trace**3))] = np.nan
    return g


def per_pixel_photometric_stereo(intensity, lights, *, shadow_fraction=DEFAULT_SHADOW_FRACTION, used=None):
    """Lambertian least squares with a light matrix per pixel.

    Parameters
    ----------
    intensity : ndarray (m, P)
        Observations (NaN: saturated, left out).
    lights : ndarray (m, 3, P)
        Each light's vector s_i at each pixel (direction times irradiance).
    shadow_fraction : float
        An observation is shadowed when I_i / |s_i| < f rho_0, rho_0 the smaller albedo of two
        first fits (all observations; all but the brightest), as in :mod:`skintopo.normals`.
    used : ndarray of bool (m, P), optional
        Which observations to use, decided before (the shadow rule is then not applied: one
        solve instead of three).

    Returns
    -------
    g : ndarray (3, P)
        rho n; NaN where fewer than 3 usable observations remain.
    residual : ndarray (P,)
        Sum of squared residuals over the usable observations divided by the sum of squared
        observations (a relative misfit, independent of the albedo).
    used : ndarray of bool (m, P)
    """
    finite = np.isfinite(intensity)
    values = np.where(finite, intensity, 0).astype(np.float32)
    if used is None:
        strength = np.sqrt(np.sum(lights * lights, axis=1))
        normalised = values / np.maximum(strength, np.float32(1e-30))
        weights = finite.astype(np.float32)
        g_all = _solve(lights, values, weights)
        brightest = np.argmax(np.where(finite, normalised, -np.inf), axis=0)
        without = weights.copy()
        without[brightest, np.arange(values.shape[1])] = 0
        g_without = _solve(lights, values, without)
        rho0 = np.fmin(np.sqrt(np.sum(g_all * g_all, axis=0)), np.sqrt(np.sum(g_without * g_without, axis=0)))
        used = finite & ~(normalised < shadow_fraction * rho0)
    weights = used.astype(np.float32)
    g = _solve(lights, values, weights)
    predicted = np.sum(lights * g[None], axis=1)
    residual = np.sum(weights * (values - predicted) ** 2, axis=0) / np.maximum(np.sum(weights * values * values, axis=0), 1e-30)
    return g, residual, used


def _rays(device: Device):
    """w = (a, b, -1) per pixel and its derivatives along columns and rows, each (3, rows,
    columns); analytic without lens distortion ((1/f, 0, 0) and (0, -1/f, 0), f in pixels),
    else numerical."""
    a, b = device.camera.rays()
    w = np.stack([a, b, -np.ones_like(a)])
    if any(device.camera.radial_distortion):
        w_v, w_u = np.gradient(w, axis=(1, 2))
        return w, w_u, w_v
    step = 1 / device.camera.focal_length_px
    return w, np.array([step, 0.0, 0.0])[:, None, None], np.array([0.0, -step, 0.0])[:, None, None]


def surface_grid(device: Device):
    """The regular skin-plane grid of a near-field result: (x, y) in mm per node, the
    camera's size, spacing :attr:`Device.pixel_um`, centred on the optical axis."""
    rows, columns = device.camera.size_px
    step = device.pixel_um / 1000
    x = (np.arange(columns) - (columns - 1) / 2) * step
    y = ((rows - 1) / 2 - np.arange(rows)) * step
    return np.broadcast_arrays(x[None, :], y[:, None])


def resample_to_surface_grid(depth_mm, device: Device, tolerance_mm=1e-5, max_iterations=20):
    """Heights (um, toward the camera, 0 at the working distance) on :func:`surface_grid`
    from per-pixel depths, and the (row, column) of the image each node was read at.

    Each node (x, y) is found on the image by the fixed point
    (column, row) = project(x, y, -d(column, row)), d read by bilinear interpolation; it
    contracts by about the surface slope times the ray's obliquity per step. It is run first
    on every 4th node (to convergence) and then on all nodes from that start, until the
    depth changes by less than ``tolerance_mm`` RMS (10 nm) and 500 times that at any node
    (a few nodes on the steepest microrelief walls contract slowly, by about 0.7 a step).
    Nodes outside the image or on
    invalid pixels are masked.
    """
    x, y = surface_grid(device)
    valid = np.isfinite(depth_mm)
    if not valid.any():
        raise SkinTopoError("no valid pixel: nothing to resample")
    (filled,) = fill_from_nearest(valid, depth_mm)

    def fixed_point(x, y, depth):
        for _ in range(max_iterations):
            column, row = device.camera.project(np.stack([x, y, -depth]))
            previous, depth = depth, scipy.ndimage.map_coordinates(filled, [row, column], order=1, mode="nearest")
            change = np.abs(depth - previous)
            if np.sqrt(np.mean(change**2)) < tolerance_mm and change.max() < 500 * tolerance_mm:
                break
        return depth, column, row

    step = 4
    start, _, _ = fixed_point(x[::step, ::step], y[::step, ::step], np.full(x[::step, ::step].shape, float(np.median(depth_mm[valid]))))
    node_rows, node_columns = np.mgrid[0 : x.shape[0], 0 : x.shape[1]] / step
    depth, column, row = fixed_point(x, y, scipy.ndimage.map_coordinates(start, [node_rows, node_columns], order=1, mode="nearest"))
    rows, columns = depth_mm.shape
    inside = (row >= 0) & (row <= rows - 1) & (column >= 0) & (column <= columns - 1)
    inside &= scipy.ndimage.map_coordinates(valid.astype(np.float32), [row, column], order=1, mode="constant") > 0.999
    z = (device.working_distance_mm - depth) * 1000
    return HeightMap(np.where(inside, z, np.nan), device.pixel_um, inside), (row, column)


def near_field_photometric_stereo(images, device: Device, band, *, mask=None, shadow_fraction=DEFAULT_SHADOW_FRACTION,
                                  scale="photometric", tolerance_um=DEFAULT_TOLERANCE_UM, max_iterations=30,
                                  integrator=DEFAULT_INTEGRATOR, start=None):
    """Normals, albedo and height from images taken under the device's LEDs (module notes).

    The alternation first runs to convergence on images binned to about 256 pixels across
    (the depth's effect on the light vectors is smooth), then at full resolution from that
    depth, with its scale kept (the median depth of the binned solution).

    Parameters
    ----------
    images : ndarray (m, rows, columns)
        One image per LED, in the device's LED order, linear, flat-fielded for the camera
        only; NaN where saturated.
    device : Device
    band : str
        Which of the LEDs' per-band intensities applies.
    mask : ndarray of bool, optional
        Camera pixels to reconstruct (default: all).
    scale : {"photometric", "working-distance"}
        How the constant of integration is fixed (module notes).
    start : NearFieldResult, optional
        Another band's result for the same capture: its depth is the starting point and its
        scale (median depth) is kept, and the binned stage is skipped. The bands see the same
        skin, whose depth they differ on by micrometres where the light vectors change over
        millimetres; the alternation still runs to this band's own fixed point (measured at
        1000 px: about 2 s per band instead of 3; after form removal the error is that of a
        start from scratch, 3.47 against 3.36 um at 256 px, tests/nearfield/test_nearfield.py).
    tolerance_um, max_iterations
        Stop when the RMS depth change is below ``tolerance_um``.

    Returns
    -------
    NearFieldResult
    """
    started = time.perf_counter()
    images = np.asarray(images, dtype=np.float32)
    m = len(device.leds)
    shape = tuple(device.camera.size_px)
    if images.ndim != 3 or images.shape[0] != m or images.shape[1:] != shape:
        raise SkinTopoError(f"expected {m} images (one per LED) of {shape} pixels, got an array of shape {images.shape}")
    if scale not in SCALES:
        raise SkinTopoError(f"unknown scale {scale!r}; choose from {list(SCALES)}")
    mask = np.ones(shape, bool) if mask is None else np.asarray(mask, dtype=bool)
    if mask.shape != shape:
        raise ValueError(f"mask shape {mask.shape} differs from the camera's {shape}")
    settings = dict(band=band, shadow_fraction=shadow_fraction, tolerance_um=tolerance_um, max_iterations=max_iterations,
                    integrator=integrator)
    options = {"scale": scale, **settings}
    factor = max(1, min(shape) // COARSE_PIXELS)
    depth = np.full(shape, device.working_distance_mm)
    if start is not None:
        known = np.isfinite(start.depth_mm)
        if start.depth_mm.shape != shape or not known.any():
            raise SkinTopoError(f"the start result has no depth for this camera's {shape} pixels")
        (depth,) = fill_from_nearest(known, start.depth_mm)
        scale = float(np.median(start.depth_mm[known]))
        options["start"] = {"band": start.options["band"], "median_depth_mm": scale}
    elif factor > 1:
        coarse_device = replace(device, camera=device.camera.binned(factor))
        rows, columns = coarse_device.camera.size_px
        crop = (slice(0, rows * factor), slice(0, columns * factor))
        binned = np.stack([block_mean(image[crop], factor) for image in images]).astype(np.float32)
        coarse_mask = block_mean(mask[crop].astype(float), factor) > 0.999
        coarse_depth, *_, coarse_changes, coarse_scales = _alternate(
            binned, coarse_device, coarse_mask, np.full((rows, columns), device.working_distance_mm), scale, **settings)
        options["binned"] = {"factor": factor, "changes_um": coarse_changes, "scales": coarse_scales}
        known = np.isfinite(coarse_depth)
        if not known.any():
            raise SkinTopoError("no pixel could be solved: check the images and the device's LED order")
        v, u = np.mgrid[0 : shape[0], 0 : shape[1]].astype(float)
        position = [(v - (factor - 1) / 2) / factor, (u - (factor - 1) / 2) / factor]
        depth = scipy.ndimage.map_coordinates(fill_from_nearest(known, coarse_depth)[0], position, order=1, mode="nearest")
        scale = float(np.median(coarse_depth[known]))
    depth_map, g, residual, used, valid, changes, scales = _alternate(images, device, mask, depth, scale,
                                                                      keep_shadows=factor > 1 or start is not None, **settings)
    options["iterations"] = len(changes)
    albedo = np.full(shape, np.nan, dtype=np.float32)
    normals = np.full((*shape, 3), np.nan, dtype=np.float32)
    albedo[mask] = np.sqrt(np.sum(g * g, axis=0))
    normals[mask] = (g / albedo[mask]).T
    residual_map = np.full(shape, np.nan, dtype=np.float32)
    residual_map[mask] = residual
    used_map = np.zeros((len(device.leds), *shape), bool)
    used_map[:, mask] = used
    height, sampling = resample_to_surface_grid(depth_map, device)
    return NearFieldResult(height, depth_map, normals, albedo, residual_map, used_map, valid, sampling, changes, scales,
                           time.perf_counter() - started, options)


def _alternate(images, device, mask, depth, scale, *, band, shadow_fraction, tolerance_um, max_iterations, integrator,
               keep_shadows=False):
    """The alternation of the module notes from an initial depth map (mm). ``scale`` is
    ``photometric``, ``working-distance`` or a number: the median depth to keep (mm).
    ``keep_shadows``: the observations the shadow rule left out in the first iteration stay
    out (for a start close to the solution, where the light vectors change by a fraction of
    a percent). Returns (depth map, g (3, P), residual (P,), used (m, P), valid map,
    changes_um, scales) of the last iteration."""
    shape = mask.shape
    w, w_u, w_v = _rays(device)
    rays = w[:, mask].astype(np.float32)
    intensity = images[:, mask]
    sample = np.zeros(shape, bool)
    sample[::SCALE_SAMPLE_STEP, ::SCALE_SAMPLE_STEP] = True
    sample = sample[mask]
    depth = depth[mask].astype(np.float64)
    changes, scales = [], []
    g = used = holes = None
    for _ in range(max_iterations):
        g, residual, used_now = _normals_at(intensity, rays, depth, device, band, shadow_fraction, used)
        if keep_shadows:
            used = used_now
        n = np.full((3, *shape), np.nan, dtype=np.float32)
        n[:, mask] = g / np.sqrt(np.sum(g * g, axis=0))
        along = np.sum(n * w, axis=0)
        log_du = -np.sum(n * w_u, axis=0) / along
        log_dv = -np.sum(n * w_v, axis=0) / along
        # integrate_slopes works in x right, y up: p = d/dcolumn, q = -d/drow, on a unit grid
        solved = mask & np.isfinite(log_du) & np.isfinite(log_dv)
        if integrator == "least-squares":
            log_depth = integrate_slopes(log_du, -log_dv, 1.0, mask=solved, method=integrator).z[mask]
        else:  # holes (pixels in shadow from too many LEDs) bridged, as the auto integrator does for small ones
            if not solved.all() and (holes is None or not np.array_equal(holes[0], solved)):
                holes = (solved, nearest_valid_index(solved))  # the holes rarely change between passes
            slopes = fill_from_nearest(solved, log_du, -log_dv, index=None if solved.all() else holes[1])
            log_depth = integrate_slopes(*slopes, 1.0, method=integrator).z[mask]
        shape_only = np.exp(log_depth - np.nanmedian(log_depth))
        if scale == "photometric":
            factor = _photometric_scale(intensity[:, sample], rays[:, sample], shape_only[sample], device, band, shadow_fraction)
            if scales and abs(factor / device.working_distance_mm - scales[-1]) < SCALE_SETTLED:
                scale = factor  # settled: kept from here on, so that the search's own tolerance cannot stall convergence
        elif scale == "working-distance":
            factor = device.working_distance_mm
        else:
            factor = scale
        scales.append(float(factor / device.working_distance_mm))
        updated = factor * shape_only
        change = float(np.sqrt(np.nanmean((updated - depth) ** 2)) * 1000)
        depth = np.where(np.isfinite(updated), updated, depth)
        changes.append(change)
        if change < tolerance_um:
            break
    valid = np.zeros(shape, bool)
    valid[mask] = np.all(np.isfinite(g), axis=0)
    depth_map = np.full(shape, np.nan)
    depth_map[valid] = depth[valid[mask]]
    return depth_map, g, residual, used_now, valid, changes, scales


def _photometric_scale(intensity, rays, shape_only, device, band, shadow_fraction):
    """The depth d = k x shape that minimises the mean relative photometric residual (mm)."""
    import scipy.optimize  # here, not at the top: it takes 0.1 s to import and measure rarely needs it

    def cost(log_k):
        _, residual, _ = _normals_at(intensity, rays, np.exp(log_k) * shape_only, device, band, shadow_fraction)
        return float(np.nanmean(residual))

    centre = np.log(device.working_distance_mm)
    found = scipy.optimize.minimize_scalar(cost, bounds=(centre - 0.5, centre + 0.5), method="bounded", options={"xatol": 1e-5})
    return float(np.exp(found.x))
