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

until the depth changes by less than ``tolerance_um`` RMS, or the distance still to go that
the changes imply (:func:`remaining_change_um`) is below it, starting from the plane at the
working distance. The default tolerance, 0.25 um RMS of depth, is a sixth of the height error
the method leaves after form removal on a simulated forehead (1.6 um at 1000 px, diffuse skin):
a remaining 0.25 um would add at most 0.02 um to it in quadrature (measured: 1.5923 against
1.5879 um between one and two passes of a band started from another).

The per-pixel solves and the resampling's fixed point are compiled loops
(:mod:`skintopo._nearfield_kernels`, Numba): 12 images of 1000 x 1000 take about 3x the
distant-light solver (2.8-3.2x, `bench/bench_nearfield.py`); the first call in a process loads them
(about 0.3 s with Numba's import, after a compilation of a few seconds once per installation).

The result is resampled to a regular grid in the skin plane (:func:`surface_grid`): the
device's pixel footprint at the working distance, centred on the optical axis, heights in
micrometres toward the camera (h = (D - d) 1000), so every measure of the project applies.

Flat-field images for a device acquisition must correct the camera only (vignetting, pixel
gain), not the LEDs' fall-off: the device model holds that. Cast shadows and highlights
are handled by the shadow rule; interreflection and subsurface scattering are not modelled
here.
"""

from __future__ import annotations

import functools
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field, replace

import numpy as np
import scipy.ndimage

from skintopo.defaults import DEFAULT_INTEGRATOR, DEFAULT_SHADOW_FRACTION
from skintopo.device import Device
from skintopo.errors import SkinTopoError
from skintopo.filters import bilinear_resize, block_mean
from skintopo.height import fill_from_nearest, integrate_slopes, nearest_valid_index
from skintopo.heightmap import HeightMap
from skintopo.normals import PhotometricStereoResult

SCALES = ("photometric", "working-distance")
SCALE_SAMPLE_PIXELS = 16384  # the photometric scale is fitted on a regular subsample of at most about this many pixels
CHUNK = 1 << 15  # the per-pixel solves run on two threads from this many pixels
COARSE_PIXELS = 256  # the alternation first converges on images binned to about this many pixels across
# ... to this tolerance: the binned depth is only the start of the full-resolution stage, whose
# first change (the microrelief the binned images cannot see: 12-34 um RMS on bench_nearfield's
# forehead) dwarfs it. 0.25 instead of 5 um took one more binned iteration (about 25 ms at
# 1000 x 1000), saved no full-resolution one and changed the heights by under 0.002 um RMS
# (that scene, diffuse and with skin optics, 2026-12-04).
COARSE_TOLERANCE_UM = 5.0
DEFAULT_TOLERANCE_UM = 0.25
SCALE_SETTLED = 1e-4  # the photometric scale is kept once it changes by less than this between iterations


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
    bridged_depth_mm : ndarray (rows, columns)
        The same with the invalid pixels inside the mask filled by the integration of the
        bridged slopes (NaN outside the mask only): the start of another band, and what
        the resampling reads.
    normals, albedo, residual : ndarray
        Per camera pixel (normals in the camera frame; residual relative, as
        :func:`per_pixel_photometric_stereo` gives it); NaN where invalid.
    used : ndarray of bool (m, rows, columns)
        Which LEDs' observations entered each camera pixel's fit.
    shadowed : ndarray of bool (m, rows, columns)
        The observations the shadow rule left out (not the saturated ones): what a band
        started from this one leaves out too.
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
    bridged_depth_mm: np.ndarray
    normals: np.ndarray
    albedo: np.ndarray
    residual: np.ndarray
    used: np.ndarray
    shadowed: np.ndarray
    valid: np.ndarray
    sampling: tuple
    changes_um: list
    scales: list
    seconds: float
    options: dict = field(default_factory=dict)

    @functools.cached_property
    def median_depth_mm(self):
        """The median depth of the valid pixels (mm): the scale a band started from this one
        keeps."""
        return float(np.median(self.depth_mm[self.valid]))

    @property
    def converged(self):
        """True when the last depth change, or the distance still to go that the changes
        imply (:func:`remaining_change_um`), was below the tolerance."""
        return _settled(self.changes_um, self.options["tolerance_um"], self.options.get("start", {}).get("contraction"))

    @property
    def contraction(self):
        """The contraction factor of the alternation's last two iterations (None with fewer
        than two, or when they did not shrink): the prior of a band started from this one."""
        return contraction(self.changes_um)

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


def per_pixel_photometric_stereo(intensity, rays, depth_mm, device: Device, band, *, shadow_fraction=DEFAULT_SHADOW_FRACTION,
                                 used=None):
    """Lambertian least squares with a light matrix per pixel: each LED's light vector
    s_i(P) (:meth:`skintopo.device.Led.light_vectors`) at the pixel's point P = d w.

    g = (S^T W S)^-1 S^T W I per pixel, S the (m, 3) matrix of the s_i(P); NaN where fewer
    than 3 usable observations remain or the used lights do not span 3-D (det(S^T W S) below
    1e-6 (trace / 3)^3).

    Parameters
    ----------
    intensity : ndarray (m, P)
        Observations (NaN: saturated, left out).
    rays : ndarray (3, P)
        Each pixel's ray w = (a, b, -1) in the camera frame (its point is P = d w).
    depth_mm : ndarray (P,)
    device : Device
    band : str
        Which of the LEDs' per-band intensities applies.
    shadow_fraction : float
        An observation is shadowed when I_i / |s_i| < f rho_0, rho_0 the smaller albedo of two
        first fits (all observations; all but the brightest), as in :mod:`skintopo.normals`.
    used : ndarray of bool (m, P), optional
        Which observations to use, decided before (the shadow rule is then not applied: one
        solve instead of three).

    Returns
    -------
    normals : ndarray (3, P)
        n = g / |g|; NaN where invalid.
    albedo : ndarray (P,)
        rho = |g| (the light vectors are taken times D^2, D the working distance, so that rho
        is in the units of the distant-light albedo); NaN where invalid.
    residual : ndarray (P,)
        Sum of squared residuals over the usable observations divided by the sum of squared
        observations (a relative misfit, independent of the albedo).
    used : ndarray of bool (m, P)

    Runs on two threads (the compiled loop releases the GIL; the pixels are independent, so
    the numbers are those of one thread).
    """
    # here, not at the top: Numba takes 0.3 s to import
    from skintopo._nearfield_kernels import per_pixel_solve

    intensity, rays = np.asarray(intensity, dtype=np.float32), np.asarray(rays, dtype=np.float32)
    depth = np.ascontiguousarray(depth_mm, dtype=np.float64)
    used = None if used is None else np.asarray(used, dtype=bool)
    m, count = intensity.shape
    leds = device.leds
    positions = np.array([led.position_mm for led in leds], dtype=np.float64)
    directions = np.array([led.direction for led in leds], dtype=np.float64)
    mu = np.array([led.mu for led in leds], dtype=np.float64)
    # the light vectors times D^2, so that they are about 1 in size (as the distant lights)
    phi = np.array([led.intensity.get(band, 1.0) for led in leds], dtype=np.float64) * device.working_distance_mm**2
    normals = np.empty((3, count), np.float32)
    albedo = np.empty(count, np.float32)
    residual = np.empty(count, np.float32)
    used_now = np.empty((m, count), bool)

    def solve(part):
        per_pixel_solve(intensity[:, part], rays[:, part], depth[part], positions, directions, mu, phi, float(shadow_fraction),
                        (used_now if used is None else used)[:, part], used is not None, normals[:, part], albedo[part], residual[part],
                        used_now[:, part])

    if count < CHUNK:  # one thread: a pool costs more than it saves
        solve(slice(0, count))
    else:
        with ThreadPoolExecutor(max_workers=2) as pool:
            list(pool.map(solve, [slice(0, count // 2), slice(count // 2, count)]))
    return normals, albedo, residual, used_now


@functools.lru_cache(maxsize=4)
def _rays(camera):
    """w = (a, b, -1) per pixel and its derivatives along columns and rows, each (3, rows,
    columns); analytic without lens distortion ((1/f, 0, 0) and (0, -1/f, 0), f in pixels),
    else numerical. Kept for the camera (a band's passes and the next bands reuse them),
    read-only."""
    a, b = camera.rays()
    w = np.stack([a, b, -np.ones_like(a)])
    if any(camera.radial_distortion):
        w_v, w_u = np.gradient(w, axis=(1, 2))
    else:
        step = 1 / camera.focal_length_px
        w_u, w_v = np.array([step, 0.0, 0.0])[:, None, None], np.array([0.0, -step, 0.0])[:, None, None]
    for array in (w, w_u, w_v):
        array.setflags(write=False)
    return w, w_u, w_v


def surface_grid(device: Device):
    """The regular skin-plane grid of a near-field result: (x, y) in mm per node, the
    camera's size, spacing :attr:`Device.pixel_um`, centred on the optical axis."""
    rows, columns = device.camera.size_px
    step = device.pixel_um / 1000
    x = (np.arange(columns) - (columns - 1) / 2) * step
    y = ((rows - 1) / 2 - np.arange(rows)) * step
    return np.broadcast_arrays(x[None, :], y[:, None])


def resample_to_surface_grid(depth_mm, device: Device, tolerance_px=1e-3, max_iterations=60, start=None, valid=None):
    """Heights (um, toward the camera, 0 at the working distance) on :func:`surface_grid`
    from per-pixel depths, and the (row, column) of the image each node was read at.

    Each node (x, y) is found on the image by the fixed point
    (column, row) = project(x, y, -d(column, row)), d read by bilinear interpolation; it
    contracts by about the surface slope times the ray's obliquity per step, and each node
    is iterated alone (a compiled loop) until the projection of its depth moves by less than
    ``tolerance_px`` from where that depth was read (1e-3 pixel: the height read is then that
    of a point within 0.07 um of the node at 65 um pixels; a few nodes on the steepest
    microrelief walls contract by about 0.7 a step). It is run first on every 4th node from
    the median depth and then on all nodes from that start, or, with ``start`` (the (height,
    sampling) of another band of the same capture), from that band's depths. Nodes outside
    the image or on invalid pixels are masked: the pixels where ``depth_mm`` is NaN, or
    outside ``valid`` when it is given (``depth_mm`` may then hold bridged depths there, read
    near the valid pixels' edge instead of the nearest valid depth).
    """
    x, y = surface_grid(device)
    known = np.isfinite(depth_mm)
    valid = known if valid is None else valid & known
    if not valid.any():
        raise SkinTopoError("no valid pixel: nothing to resample")
    filled = np.ascontiguousarray(fill_from_nearest(known, depth_mm)[0], dtype=np.float64)
    valid_share = valid.astype(np.float64)

    def fixed_point(x, y, depth):
        # here, not at the top: Numba takes 0.3 s to import
        from skintopo._nearfield_kernels import surface_grid_fixed_point

        shape = x.shape
        x, y = np.ascontiguousarray(x, dtype=np.float64).ravel(), np.ascontiguousarray(y, dtype=np.float64).ravel()
        depth = np.array(depth, dtype=np.float64).ravel()
        column, row, inside = np.empty_like(depth), np.empty_like(depth), np.empty(depth.size, bool)
        camera = device.camera
        half = depth.size // 2

        def solve(part):
            surface_grid_fixed_point(filled, valid_share, x[part], y[part], depth[part], camera.focal_length_px, *camera.centre,
                                     *camera.radial_distortion, tolerance_px, max_iterations, column[part], row[part], inside[part])

        with ThreadPoolExecutor(max_workers=2) as pool:  # the compiled loop releases the GIL
            list(pool.map(solve, [slice(0, half), slice(half, depth.size)]))
        return depth.reshape(shape), column.reshape(shape), row.reshape(shape), inside.reshape(shape)

    if start is None:
        step = 4
        median = float(np.median(depth_mm[valid]))
        coarse = fixed_point(x[::step, ::step], y[::step, ::step], np.full(x[::step, ::step].shape, median))[0]
        first = bilinear_resize(coarse, x.shape, step)
    else:
        previous = start.z[start.mask]
        # nodes the start lacks start from the median of a regular sample of its heights (a
        # start only: the fixed point converges from it as from any other)
        first = np.full(x.shape, device.working_distance_mm - float(np.median(previous[::16])) / 1000)
        first[start.mask] = device.working_distance_mm - previous / 1000
    depth, column, row, inside = fixed_point(x, y, first)
    z = (device.working_distance_mm - depth) * 1000
    return HeightMap(np.where(inside, z, np.nan), device.pixel_um, inside), (row, column)


def near_field_photometric_stereo(images, device: Device, band, *, mask=None, shadow_fraction=DEFAULT_SHADOW_FRACTION,
                                  scale="photometric", tolerance_um=DEFAULT_TOLERANCE_UM, max_iterations=30,
                                  integrator=DEFAULT_INTEGRATOR, start=None):
    """Normals, albedo and height from images taken under the device's LEDs (module notes).

    The alternation first runs on images binned to about 256 pixels across (the depth's
    effect on the light vectors is smooth) until its depth changes by under 5 um
    (``COARSE_TOLERANCE_UM``, or ``tolerance_um`` when larger), then to convergence at full
    resolution from that depth, with its scale kept (the median depth of the binned solution).

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
        millimetres; the alternation still runs to this band's own fixed point, its distance
        to it bounded with the start band's contraction factor while this band has one change
        only (one pass at 1000 px, about 0.18 s; after form removal the error is that of a
        start from scratch, tests/nearfield/test_nearfield.py). The start's shadow decisions
        are kept (shadows are geometry, which the bands share; this band's own saturated
        observations are left out, the start's are not): 0.22 instead of 0.27 s per band,
        heights after form removal within 0.01 um of the band's own shadow rule on the
        simulated forehead, diffuse or with skin optics (bench_nearfield's scenes, 2026-12-03).
    tolerance_um, max_iterations
        Stop when the RMS depth change, or the distance to the fixed point it implies
        (:func:`remaining_change_um`), is below ``tolerance_um``.

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
        known = np.isfinite(start.bridged_depth_mm)
        if start.bridged_depth_mm.shape != shape or not known.any():
            raise SkinTopoError(f"the start result has no depth for this camera's {shape} pixels")
        (depth,) = fill_from_nearest(known, start.bridged_depth_mm)
        scale = start.median_depth_mm
        options["start"] = {"band": start.options["band"], "median_depth_mm": scale, "contraction": start.contraction}
    elif factor > 1:
        coarse_device = replace(device, camera=device.camera.binned(factor))
        rows, columns = coarse_device.camera.size_px
        binned = block_mean(images, factor, "trim")  # float32, as the images
        coarse_mask = block_mean(mask, factor, "trim") > 0.999
        coarse_settings = {**settings, "tolerance_um": max(tolerance_um, COARSE_TOLERANCE_UM)}
        coarse_depth, _, _, _, _, coarse_valid, coarse_changes, coarse_scales = _alternate(
            binned, coarse_device, coarse_mask, np.full((rows, columns), device.working_distance_mm), scale, **coarse_settings)
        options["binned"] = {"factor": factor, "changes_um": coarse_changes, "scales": coarse_scales}
        known = np.isfinite(coarse_depth)
        if not coarse_valid.any():
            raise SkinTopoError("no pixel could be solved: check the images and the device's LED order")
        depth = bilinear_resize(fill_from_nearest(known, coarse_depth)[0], shape, factor, offset=(factor - 1) / 2)  # the blocks' centres
        scale = float(np.median(coarse_depth[coarse_valid]))
    bridged, normals, albedo, residual, used, valid, changes, scales = _alternate(
        images, device, mask, depth, scale, keep_shadows=factor > 1 or start is not None,
        prior=None if start is None else start.contraction, shadowed=None if start is None else start.shadowed, **settings)
    options["iterations"] = len(changes)
    normals = np.moveaxis(_expand(normals, mask), 0, -1)  # (rows, columns, 3), a view when the mask is full
    used_map = _expand(used, mask, fill=False)
    shadowed = np.isfinite(images) & mask & ~used_map
    height, sampling = resample_to_surface_grid(bridged, device, valid=valid, start=None if start is None else start.height)
    return NearFieldResult(height, np.where(valid, bridged, np.nan), bridged, normals, _expand(albedo, mask), _expand(residual, mask),
                           used_map, shadowed, valid, sampling, changes, scales, time.perf_counter() - started, options)


def _alternate(images, device, mask, depth, scale, *, band, shadow_fraction, tolerance_um, max_iterations, integrator,
               keep_shadows=False, prior=None, shadowed=None):
    """The alternation of the module notes from an initial depth map (mm). ``scale`` is
    ``photometric``, ``working-distance`` or a number: the median depth to keep (mm).
    ``keep_shadows``: the observations the shadow rule left out in the first iteration stay
    out (for a start close to the solution, where the light vectors change by a fraction of
    a percent); ``shadowed`` (m, rows, columns): observations left out from the start as
    shadowed (another band's decisions; the saturated ones of these images are left out
    too). Stops when :func:`_settled` (``prior``: the contraction factor it may use before
    two changes are known). Returns (depth map (NaN outside the mask; where the normals are
    invalid, integrated over the bridged slopes with the DCT integrators, NaN with least
    squares), normals (3, P), albedo (P,), residual (P,), used (m, P), valid map, changes_um,
    scales) of the last iteration."""
    # here, not at the top: Numba takes 0.3 s to import
    from skintopo._nearfield_kernels import log_depth_slopes

    shape = mask.shape
    w, w_u, w_v = _rays(device.camera)
    rays = _compact(w, mask).astype(np.float32)
    rays_u, rays_v = (np.ascontiguousarray(_compact(v, mask) if v.ndim == 3 and v.shape[1:] == shape else v.reshape(3, 1), dtype=np.float64)
                      for v in (w_u, w_v))
    intensity = _compact(images, mask)
    sample = np.zeros(shape, bool)
    stride = int(np.ceil(np.sqrt(mask.size / SCALE_SAMPLE_PIXELS)))  # 2 at 256 x 256, 3 for the binned 333 x 333 of 1000 x 1000
    sample[::stride, ::stride] = True
    sample = _compact(sample, mask)
    depth = _compact(depth, mask).astype(np.float64)
    changes, scales = [], []
    holes = None
    used = None if shadowed is None else ~_compact(shadowed, mask) & np.isfinite(intensity)
    for _ in range(max_iterations):
        normals, albedo, residual, used_now = per_pixel_photometric_stereo(intensity, rays, depth, device, band, shadow_fraction=shadow_fraction,
                                                                           used=used)
        if keep_shadows:
            used = used_now
        slope_u, slope_v = np.empty(albedo.size), np.empty(albedo.size)  # slopes of log depth
        log_depth_slopes(normals, rays, rays_u, rays_v, slope_u, slope_v)  # integrate_slopes works in x right, y up: q = -d/drow
        log_du, log_dv = _expand(slope_u, mask), _expand(slope_v, mask)
        solved = np.isfinite(log_du) & np.isfinite(log_dv)
        if integrator == "least-squares":
            log_depth = _compact(integrate_slopes(log_du, log_dv, 1.0, mask=solved, method=integrator).z, mask)
        else:  # holes (pixels in shadow from too many LEDs) bridged, as the auto integrator does for small ones
            if not solved.all() and (holes is None or not np.array_equal(holes[0], solved)):
                holes = (solved, nearest_valid_index(solved))  # the holes rarely change between passes
            slopes = fill_from_nearest(solved, log_du, log_dv, index=None if solved.all() else holes[1])
            log_depth = _compact(integrate_slopes(*slopes, 1.0, method=integrator).z, mask)
        finite = np.isfinite(log_depth)
        shape_only = np.exp(log_depth - (np.median(log_depth) if finite.all() else np.nanmedian(log_depth)))
        if scale == "photometric":
            factor = _photometric_scale(intensity[:, sample], rays[:, sample], shape_only[sample], device, band, shadow_fraction,
                                        near=scales[-1] * device.working_distance_mm if scales else None)
            if scales and abs(factor / device.working_distance_mm - scales[-1]) < SCALE_SETTLED:
                scale = factor  # settled: kept from here on, so that the search's own tolerance cannot stall convergence
        elif scale == "working-distance":
            factor = device.working_distance_mm
        else:
            factor = scale
        scales.append(float(factor / device.working_distance_mm))
        updated = factor * shape_only
        step = np.where(finite, updated - depth, 0.0)
        changes.append(float(np.sqrt(np.sum(step * step) / max(int(finite.sum()), 1)) * 1000))
        depth += step
        if _settled(changes, tolerance_um, prior):
            break
    valid = np.zeros(shape, bool)
    valid[mask] = np.isfinite(albedo)
    return _expand(depth, mask), normals, albedo, residual, used_now, valid, changes, scales


def contraction(changes_um):
    """The contraction factor q of a linearly converging iteration from its last two changes
    (q = c_k / c_(k-1)); None before two changes or while they do not shrink."""
    if len(changes_um) < 2 or changes_um[-1] >= changes_um[-2]:
        return None
    return changes_um[-1] / changes_um[-2]


def remaining_change_um(changes_um, prior=None):
    """How far (RMS, um) the depth may still be from the fixed point after the last
    iteration, for a linearly converging iteration: q / (1 - q) times the last change (the
    a-posteriori bound of Banach's fixed-point theorem), q from :func:`contraction`, or
    ``prior`` (the contraction measured on another iteration of the same map, e.g. another
    band of the capture: q is set by how the LEDs' light vectors change with depth, which
    the bands share) while the changes cannot give it; infinity when neither can.
    The alternation stops when this or the last change is below the tolerance (with q about
    0.05-0.07, measured at 1000 px, this saves the last iteration of each band)."""
    q = contraction(changes_um)
    if q is None and changes_um and prior is not None and prior < 1:
        q = prior
    if q is None:
        return float("inf")
    return changes_um[-1] * q / (1 - q)


def _settled(changes_um, tolerance_um, prior=None):
    """The stopping rule: the last depth change, or the distance still to go that the
    changes imply (:func:`remaining_change_um`), is below ``tolerance_um``."""
    return bool(changes_um) and min(changes_um[-1], remaining_change_um(changes_um, prior)) < tolerance_um


def _compact(values, mask):
    """The (..., rows, columns) array's pixels inside ``mask`` as (..., P): a view when the
    mask is full (no copy)."""
    return values.reshape(*values.shape[:-2], -1) if mask.all() else values[..., mask]


def _expand(values, mask, fill=np.nan):
    """Inverse of :func:`_compact`: (..., P) values as (..., rows, columns) maps with
    ``fill`` outside ``mask``."""
    if mask.all():
        return values.reshape(*values.shape[:-1], *mask.shape)
    out = np.full((*values.shape[:-1], *mask.shape), fill, dtype=values.dtype)
    out[..., mask] = values
    return out


def _photometric_scale(intensity, rays, shape_only, device, band, shadow_fraction, near=None):
    """The depth d = k x shape that minimises the mean relative photometric residual (mm),
    searched within a factor 1.65 of the working distance, or, given ``near`` (the last
    iteration's scale, mm), within 2% of it (the scale changes by under 0.1% after the first
    iteration: fewer evaluations), widened to the full range when it lands on that bracket's
    edge."""
    import scipy.optimize  # here, not at the top: it takes 0.1 s to import and measure rarely needs it

    def cost(log_k):
        residual = per_pixel_photometric_stereo(intensity, rays, np.exp(log_k) * shape_only, device, band, shadow_fraction=shadow_fraction)[2]
        return float(np.nanmean(residual))

    def search(centre, half_width):
        found = scipy.optimize.minimize_scalar(cost, bounds=(centre - half_width, centre + half_width), method="bounded",
                                               options={"xatol": 1e-5})
        return found.x, abs(found.x - centre) > 0.99 * half_width

    if near is not None:
        log_k, on_edge = search(np.log(near), 0.02)
        if not on_edge:
            return float(np.exp(log_k))
    return float(np.exp(search(np.log(device.working_distance_mm), 0.5)[0]))
