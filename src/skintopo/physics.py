"""Physically based height: invert subsurface scattering, interreflection and highlights.

Image formation of one band c under light i (linear images divided by the light's
relative intensity, orthographic camera, directional lights):

    I_ci = T_c[ rho_c (E_i + K B_ci) ] + s_i,     E_i = max(0, n . l_i) V_i,   B_ci = I_ci - s_i

* T_c, subsurface scattering: light entering the skin re-emerges spread around the entry
  point, a linear shift-invariant blur per band (widest in red). Its transfer function is
  modelled as T(f) = (1 - w) + w (1 + (2 pi f l)^2 / (2 a))^(-a): a fraction w re-emerges
  spread by a Matern-type profile of length l and shape a. a = 3/2 is the 2-D exponential
  profile exp(-r sqrt(3) / l) (heavy-tailed, as measured diffusion profiles are); a -> infinity
  is the Gaussian of standard deviation l. The family contains both, and the shape is fitted.
* K, interreflection: the radiosity gather of :mod:`skintopo.transport` on the current
  height (Nayar, Ikeuchi & Kanade 1991: for a Lambertian surface the observed radiance *is*
  the radiosity, so the light arriving from the rest of the surface is K I, known once the
  shape is).
* s_i, surface (specular) reflection: the same in every band once images are divided by
  each light's intensity (sebum reflects at the surface, before any absorption), modelled as
  a microfacet lobe s_i = k D(n . h_i; m) / (n . v) with a Beckmann facet distribution D of
  roughness m; k and m are fitted globally, not per pixel.

Estimation, alternating until the height stops changing (``tolerance``):

1. Kernels, from the capture itself: photometric stereo is linear, so each band's scaled
   normal field g_c = rho_c n is the true one blurred by T_c. The cross-spectrum of the
   bands' g_x, g_y against blue's, averaged over rings of spatial frequency, measures
   T_red / T_blue and T_green / T_blue; the three kernels (w, l per band, a shared) are the
   least-squares fit of these two ratio curves (each band's g normalised by its median
   albedo, so the ratios tend to 1 at zero frequency). The ratio of two members of the
   family is not itself a member, which is what makes the absolute kernels identifiable,
   weakly: a blur shared by all bands barely changes the ratios. When the fit puts a band's
   spread weight at its bound, the ratios have not fixed that shared blur, and the fit is
   redone with a least-blur prior on blue's weight (the least blur the ratios allow; see
   :func:`estimate_scattering_kernels`). Where every band does spread (the ``literature``
   profile), an unblurred blue is wrong, yet a smaller error than the bound's blur, which the
   deconvolution amplified (bench_physics, docs/method.md).
2. Direct images: J_ci = I_ci - s_i - T_c[rho_c K (I_ci - s_i)], which is T_c[rho_c E_i].
3. Fusion and deconvolution in one step: per spatial frequency f the bands give
   J_ci(f) = rho_c T_c(f) S_i(f), and the least-squares S_i(f) = sum_c a_c J_ci / sum_c a_c^2,
   a_c = rho_c T_c(f), weights each band by how much of the shading it kept at that
   frequency (a band blurred to nothing there contributes nothing), instead of the paper's
   fixed 1/2, 1/4, 1/4. S_i is the unblurred direct shading, E_i up to the albedo pattern.
   No frequency is amplified more than ``MAX_DECONVOLUTION_GAIN`` times: S_i is multiplied
   by min(1, G / A), A = sqrt(sum_c rho_c^2 / sum_c a_c^2) (a blur shared by all bands is
   invisible to the band ratios, so where every band lost a frequency the kernels' absolute
   level is a guess, and an unbounded inverse turned that guess into 20x amplification).
4. Photometric stereo of S (all bands at once), integration, and from the new height: K,
   cast shadows and the specular lobe's k, m (fitted to the bands' disagreement, see
   ``_fit_specular``) for the next pass (the last pass prepares none). Pixels without a
   height (fewer than 3 usable lights) take their nearest pixel's height for K and the
   shadows (a mean height there would stand as a wall on a wrinkle's floor and hide its
   walls from it). An observation in a cast shadow of any pass's height is left out of
   every later pass's photometric stereo: once interreflection is removed it holds only
   what the model did not remove, and on a deep wrinkle's floor that residual, fitted as
   light, made the floor too shallow, which lowered K, which made the floor shallower
   (Mitsuba, forehead-high, diffuse, the true kernels given and no highlight fit: 10.9 -> 4.3
   um RMS in 4 passes; the render with direct light only: 2.4).
   Kept rather than recomputed each pass: recomputed, a floor shadowed in one pass and lit
   in the next made the height oscillate. The model residual
   I_ci - s_i - T_c[rho_c (E_i + K B_ci)] of each pass's height, with the K and s it was
   made with, is recorded per iteration. The last iteration's height is returned, unless the
   height changed by more than half its RMS in one pass (diverging): then the one before.

The first pass has no height of its own to fit the lobe to. It starts from a lobe fitted
(as in step 4) to the normals of the plain bands' mean height when that lobe carries more
than ``SEED_SPECULAR_FRACTION`` of the images' light, and from none otherwise (always none
without the scattering model, whose absence the lobe fit takes for a highlight: the
ablation's heights went from 6-15 um to unregistrable). A highlight that
strong bends the first pass so far that the next one diverges: in the simulator's
``paper-calibrated`` optics (surface reflection 8x skin's; the seed lobe 20-25% of the light)
with calibrated kernels, mean RMS error over 12 fields 154 -> 25 um. Weaker ones are
corrected by the later passes, and seeding them cost accuracy: ``default-v1`` (seed lobe
0.1-11% of the light) with calibrated kernels, 3.35 -> 4.15 um (bench_physics, 2026-12-05).

A sanity check, not a validation: the result records its agreement with the mean of the
plain band heights (relief ratio and correlation, both levelled) and is flagged not
plausible outside ``PLAUSIBLE_RELIEF`` or below ``PLAUSIBLE_CORRELATION``.

Known limits (numbers in docs/method.md): the method is validated in the simulator's
``default-v1`` skin optics and on Mitsuba renders; in the ``literature`` profile (every band
blurred, no sharp diffuse band) it is below the best band on average but not on every field
(9 of 12), and in the ``paper-calibrated`` one (strong highlights) it is worse than the best
band on every field. The highlight fit assumes a white highlight; a
slightly coloured one (Fresnel dispersion) cannot be told from a stronger white one plus a
skin-coloured part, so its scale comes out high and the deepest wrinkles on dark skin come
out too shallow; a smooth coat (Beckmann alpha 0.2) defeats the fit. The kernel fit needs
the field to span several times the red diffusion length (a 5 mm field holds it), and it
is made from the plain bands, where interreflection on the microrelief (stronger in the
brighter bands) looks like a red blur: on deep-wrinkled diffuse renders it finds kernels
where there is no scattering (Mitsuba forehead-high: w 0.8-0.95). The
iteration often stops at its pass limit before the 2% tolerance (reported). Through a device
(:func:`near_field_physics_height`) the height matches the ideal device's on skin without
highlights, and falls short of it with highlights (35.5 um with its own lobe, 7.1 um on the
cross-band diffuse images with the highlight taken as white, 0.44 um with its colour measured
by ``skintopo calibrate highlight``; 1000 px; docs, "The real device").
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.fft
import scipy.ndimage

from skintopo.device import Device
from skintopo.errors import SkinTopoError
from skintopo.filters import bilinear_resize, block_mean, polynomial_form
from skintopo.height import DEFAULT_INTEGRATOR, fill_from_nearest, height_normals, integrate_normals
from skintopo.heightmap import HeightMap, pixel_spacing
from skintopo.lights import check_light_directions
from skintopo.normals import DEFAULT_SOLVER, SpecularLobe, photometric_stereo
from skintopo.transport import cast_shadow, interreflection_operator

REQUIRED_BANDS = ("red", "green", "blue")
DEFAULT_ITERATIONS = 4
DEFAULT_TOLERANCE = 0.02  # stop when the RMS height change is below 2% of the height's RMS
DIVERGENCE = 0.5  # a height that changes by more than half its RMS in one iteration is diverging
MAX_DECONVOLUTION_GAIN = 4.0  # at most this amplification of any spatial frequency of the shading
SEED_SPECULAR_FRACTION = 0.15  # the first pass starts from a lobe that carries more than this share of the light (module notes)
PLAUSIBLE_RELIEF = (1 / 3, 3.0)  # physics relief / the plain bands' mean relief, outside: not plausible
PLAUSIBLE_CORRELATION = 0.5  # least correlation of the physics height with the plain bands' mean height
DEFAULT_RADIUS_UM = 700.0  # interreflection reach: the widest wrinkles of the field notes' range
MAX_INTERREFLECTION_PIXELS = 256 * 256  # larger fields gather interreflection on a coarser grid
MAX_SPECULAR_FIT_PIXELS = 512 * 512  # larger fields search the highlight lobe's roughness on a coarser grid
ROUGHNESS_GRID = np.linspace(0.15, 0.5, 15)  # Beckmann m searched: skin 0.3-0.45 (field notes), oily skin smoother; a
# broader lobe is not skin's and took up what the model missed (Mitsuba diffuse renders: m 0.55-0.7). Steps of 0.025:
# with steps of 0.05 the height moved by 0.3-3 um between neighbouring m (simulator default-v1: mean 3.45 -> 2.48 um)
SHAPE_BOUNDS = (0.6, 50.0)  # Matern shape a: 3/2 = exponential profile, 50 ~ Gaussian
MAX_SPREAD_WEIGHT = 0.95  # the kernel fit's bound on each band's spread weight w
LEAST_BLUR_PRIOR = 2.0  # the prior's strength when a fitted weight sits at that bound (estimate_scattering_kernels)


@dataclass(frozen=True)
class ScatteringKernel:
    """Subsurface scattering of one band: T(f) = (1 - w) + w (1 + (2 pi f l)^2 / (2 a))^(-a).

    ``weight`` w is the fraction of diffuse light that re-emerges spread, ``length_um`` l the
    profile's length, ``shape`` a (3/2: exponential profile; large: Gaussian of sigma l).
    """

    weight: float
    length_um: float
    shape: float

    def transfer(self, frequency):
        """T(f) at spatial frequency ``frequency`` (cycles per micrometre)."""
        f = np.asarray(frequency, dtype=float)
        return (1 - self.weight) + self.weight * (1 + (2 * np.pi * f * self.length_um) ** 2 / (2 * self.shape)) ** (-self.shape)

    def as_dict(self):
        return {"weight": self.weight, "length_um": self.length_um, "shape": self.shape} | _transfer_record(self)


def _transfer_record(kernel):
    return {"transfer_at_cycles_per_mm": {str(f): float(kernel.transfer(f / 1000)) for f in (0.5, 1, 2, 4, 8)}}


IDENTITY_KERNEL = ScatteringKernel(0.0, 1.0, 1.5)


@dataclass(frozen=True, eq=False)
class PhysicsResult:
    """Output of :func:`physics_height`.

    ``height`` is the last iteration's (or the one before, when the last one diverged); ``kernels``: band -> :class:`ScatteringKernel` (estimated from the capture) or the kernels given;
    ``specular``: fitted lobe (``roughness`` m, ``scale`` k; ``first_pass``: the seed lobe, module notes); ``changes``: RMS height change
    per iteration relative to the height's RMS; ``residuals``: RMS model residual per
    iteration (fraction of full scale); ``converged``: the last change is below the tolerance;
    ``diverged``: the last change exceeded DIVERGENCE and the iterations stopped there.
    """

    height: HeightMap
    albedo: np.ndarray
    kernels: dict
    specular: dict
    iterations: int
    changes: list
    residuals: list
    converged: bool
    diverged: bool
    kernel_fit_rms: float | None  # None when the kernels were given
    components: dict = field(default_factory=dict)
    agreement: dict = field(default_factory=dict)

    @property
    def plausible(self):
        """The height agrees with plain photometric stereo to within the limits of
        ``PLAUSIBLE_RELIEF`` and ``PLAUSIBLE_CORRELATION`` (a sanity check, not a validation)."""
        low, high = PLAUSIBLE_RELIEF
        return bool(low <= self.agreement.get("relief_ratio", 1.0) <= high
                    and self.agreement.get("correlation", 1.0) >= PLAUSIBLE_CORRELATION)

    def convergence_note(self):
        """A sentence for the user when the iteration did not converge or the height is not
        plausible, else None."""
        notes = []
        if not self.converged:
            state = "diverged (the pass before it is kept)" if self.diverged else "did not converge"
            notes.append(f"the physics height {state} in {self.iterations} passes "
                         f"(relative height changes {[round(c, 3) for c in self.changes]})")
        if not self.plausible:
            notes.append(f"the physics height disagrees with plain photometric stereo (relief {self.agreement['relief_ratio']:.2f}x "
                         f"the bands' mean, correlation {self.agreement['correlation']:.2f}): its model does not describe "
                         "these images; do not use it")
        return "; ".join(notes) or None

    def as_dict(self):
        return {
            "method": "physics",
            "components": self.components,
            "kernels": {band: kernel.as_dict() if isinstance(kernel, ScatteringKernel) else _transfer_record(kernel)
                        for band, kernel in self.kernels.items()},
            "kernel_fit_rms": self.kernel_fit_rms,
            "specular": self.specular,
            "iterations": self.iterations,
            "relative_height_changes": self.changes,
            "rms_residuals": self.residuals,
            "converged": self.converged,
            "diverged": self.diverged,
            "agreement_with_plain_bands": self.agreement,
            "plausible": self.plausible,
        }


def band_transfer_ratios(scaled_normals, spacing):
    """Measured T_red / T_blue and T_green / T_blue per ring of spatial frequency.

    Parameters
    ----------
    scaled_normals : dict band -> ndarray (rows, columns, 3)
        g = albedo x normal of red, green and blue from plain photometric stereo.
    spacing : (dy, dx) in micrometres

    Returns
    -------
    frequency : ndarray
        Ring centres, cycles per micrometre (ring width: one frequency step of the longer side).
    ratios : dict ``"red"``/``"green"`` -> ndarray
        Re(sum G_c conj G_blue) / sum |G_blue|^2 over the ring and the x, y components
        (Hann-windowed fields, each divided by its median albedo).
    power : ndarray
        Blue's power per ring (a weight: rings without signal say nothing).
    """
    spectra = {}
    shape = scaled_normals["blue"].shape[:2]
    window = np.outer(np.hanning(shape[0]), np.hanning(shape[1]))
    for band, g in scaled_normals.items():
        albedo = np.nanmedian(np.linalg.norm(g, axis=-1))
        spectra[band] = [scipy.fft.rfft2(np.nan_to_num((g[..., k] - np.nanmean(g[..., k])) / albedo) * window, workers=-1) for k in (0, 1)]
    dy, dx = spacing
    f = np.hypot(*np.meshgrid(scipy.fft.fftfreq(shape[0], dy), scipy.fft.rfftfreq(shape[1], dx), indexing="ij"))
    # the real transform's half plane: a column stands for itself and its mirror -f (the same ring, the same
    # cross-spectrum by Hermitian symmetry), except the zero and Nyquist columns, which have none
    counted = np.full(f.shape[1], 2.0)
    counted[0] = 1.0
    if shape[1] % 2 == 0:
        counted[-1] = 1.0
    step = 1 / (max(spacing[0] * shape[0], spacing[1] * shape[1]))
    rings = int(0.5 / max(spacing) / step)
    index = np.minimum(np.rint(f / step).astype(int), rings + 1).ravel()
    power = np.bincount(index, (counted * sum(np.abs(s) ** 2 for s in spectra["blue"])).ravel(), rings + 2)[: rings + 1]
    ratios = {}
    for band in ("red", "green"):
        cross = counted * sum((a * np.conj(b)).real for a, b in zip(spectra[band], spectra["blue"]))
        ratios[band] = np.bincount(index, cross.ravel(), rings + 2)[: rings + 1] / np.maximum(power, 1e-300)
    return np.arange(rings + 1) * step, ratios, power


def estimate_scattering_kernels(scaled_normals, spacing):
    """Fit red, green and blue :class:`ScatteringKernel` to the measured band ratios.

    Uses the rings from 3 frequency steps up (lower rings are dominated by the window and the
    form) whose power is above 1e-3 of the strongest; least squares of the two ratio curves
    (weights sqrt(log(1 + P / P_min)), P blue's ring power) from six starts.

    A blur shared by all bands is invisible to the ratios. When the best fit puts a band's
    spread weight at its bound (``MAX_SPREAD_WEIGHT``), the ratios have pushed that common blur
    as far as the family allows and did not fix its level; then every start and that optimum
    are refitted with one more residual, c w_blue (the least-blur prior), where
    c = ``LEAST_BLUR_PRIOR`` x r x sqrt(sum of the squared ring weights of both curves), r the first
    fit's RMS misfit: taking blue's weight from 0.5 to 0 is worth a misfit of r at every ring
    (numbers in docs/method.md).

    Returns
    -------
    kernels : dict band -> ScatteringKernel
    misfit : float
        RMS misfit of the ratios (without the prior's residual).
    least_blur : bool
        Whether the least-blur prior was applied.
    """
    import scipy.optimize  # here, not at the top: it takes 0.1 s to import and measure rarely needs it

    frequency, ratios, power = band_transfer_ratios(scaled_normals, spacing)
    low = frequency >= 3 * frequency[1]
    use = low & (power > power[low].max() * 1e-3)
    if use.sum() < 8:
        raise SkinTopoError("the field is too small or too smooth to estimate the scattering kernels (fewer than 8 usable frequency rings)")
    f = frequency[use]
    weight = np.sqrt(np.log1p(power[use] / power[use].min()))

    def kernels_of(x):
        shape = np.exp(x[6])
        return {band: ScatteringKernel(float(x[i]), float(x[3 + i]), float(shape)) for i, band in enumerate(REQUIRED_BANDS)}

    def misfit(x):
        kernels = kernels_of(x)
        blue = kernels["blue"].transfer(f)
        return np.concatenate([(kernels[band].transfer(f) / blue - ratios[band][use]) * weight for band in ("red", "green")])

    def rms(fit):
        return float(np.sqrt(np.mean((fit.fun[: 2 * f.size] / np.repeat(weight, 2)) ** 2)))

    lower = [0, 0, 0, 5, 5, 5, np.log(SHAPE_BOUNDS[0])]
    upper = [MAX_SPREAD_WEIGHT] * 3 + [2000, 2000, 2000, np.log(SHAPE_BOUNDS[1])]
    starts = [[0.3, 0.3, 0.1, 200, 120, blue_length, np.log(shape)] for shape in (1.0, 2.0, 6.0) for blue_length in (20.0, 60.0)]
    best = min((scipy.optimize.least_squares(misfit, start, bounds=(lower, upper)) for start in starts), key=lambda fit: fit.cost)
    least_blur = bool(np.any(best.x[:3] >= MAX_SPREAD_WEIGHT - 1e-3))
    if least_blur:
        strength = LEAST_BLUR_PRIOR * rms(best) * np.sqrt(2 * np.sum(weight**2))

        def with_prior(x):
            return np.append(misfit(x), strength * x[2])

        best = min((scipy.optimize.least_squares(with_prior, start, bounds=(lower, upper)) for start in [*starts, best.x]),
                   key=lambda fit: fit.cost)
    return kernels_of(best.x), rms(best), least_blur


class _Filter:
    """Fourier filtering of real image stacks with symmetric padding (no wrap-around at the
    edges); ``frequency`` is the half-plane grid of the real transform.

    At least ``pad`` pixels on each side, more after the image up to the next length whose
    prime factors are small (``scipy.fft.next_fast_len``): 1000 + 2 x 54 = 1108 = 4 x 277
    transforms about 3x slower than 1125 = 9 x 125 (measured).

    In single precision (images, transfer functions and spectra): these passes are bound by
    memory traffic, and float32 makes padding, transforms and products 3-6x faster at
    1000 x 1000 (measured); the heights move by under 1e-3 um."""

    def __init__(self, shape, spacing, pad):
        self.pad = pad
        self.shape = tuple(shape)
        self.padded = tuple(scipy.fft.next_fast_len(n + 2 * pad, real=True) for n in shape)
        fy, fx = scipy.fft.fftfreq(self.padded[0], spacing[0]), scipy.fft.rfftfreq(self.padded[1], spacing[1])
        self.frequency = np.hypot(*np.meshgrid(fy, fx, indexing="ij"))

    def forward(self, stack):
        pad = self.pad
        widths = [(pad, m - n - pad) for n, m in zip(self.shape, self.padded)]
        padded = np.pad(np.asarray(stack, dtype=np.float32), [(0, 0)] * (stack.ndim - 2) + widths, mode="symmetric")
        return scipy.fft.rfft2(padded, axes=(-2, -1), workers=-1)

    def inverse(self, spectrum):
        pad, (rows, columns) = self.pad, self.shape
        image = scipy.fft.irfft2(spectrum, s=self.padded, axes=(-2, -1), workers=-1)
        return image[..., pad: pad + rows, pad: pad + columns]

    def apply(self, stack, transfer):
        return self.inverse(self.forward(stack) * transfer)


def _grid_factor(shape, max_pixels):
    """The smallest block size whose grid of block means has at most ``max_pixels``."""
    return int(np.ceil(np.sqrt(shape[0] * shape[1] / max_pixels)))


class _Interreflection:
    """K of the current height, on a grid of at most MAX_INTERREFLECTION_PIXELS (block means;
    interreflection varies over the wrinkle's width, far more slowly than the microrelief)."""

    def __init__(self, height: HeightMap, radius_um):
        self.factor = self.grid_factor(height.shape)
        self.shape = height.shape
        z = block_mean(fill_from_nearest(height.mask, height.z)[0], self.factor, "trim")
        spacing = tuple(s * self.factor for s in height.spacing)
        self.operator = interreflection_operator(z, height_normals(z, spacing), spacing[1], radius_um=radius_um)
        self.coarse = z.shape

    @staticmethod
    def grid_factor(shape):
        """Block size of the coarse grid for a field of ``shape``."""
        return _grid_factor(shape, MAX_INTERREFLECTION_PIXELS)

    def gather(self, stack):
        """K B for each image of ``stack`` (m, rows, columns), at full resolution."""
        coarse = block_mean(stack, self.factor, "trim")
        gathered = (self.operator @ coarse.reshape(coarse.shape[0], -1).T).T.reshape(coarse.shape)
        if self.factor == 1:
            return gathered
        # each block mean at its block's centre; single precision, as the Fourier passes it feeds
        return bilinear_resize(gathered.astype(np.float32), self.shape, self.factor, (self.factor - 1) / 2)


def _check_inputs(images, lights):
    missing = [band for band in REQUIRED_BANDS if band not in images]
    if missing:
        raise SkinTopoError(f"the physics height needs red, green and blue images; missing {missing} (have {sorted(images)})")
    lights = np.asarray(lights, dtype=float)
    problems = check_light_directions(lights)
    if problems:
        raise SkinTopoError("the physics height cannot use these lights: " + "; ".join(problems))
    shapes = {band: np.shape(images[band]) for band in REQUIRED_BANDS}
    if len(set(shapes.values())) != 1 or len(shapes["red"]) != 3 or shapes["red"][0] != len(lights):
        raise SkinTopoError(f"the physics height needs one image per light in every band, all of one size; got {shapes} for {len(lights)} lights")
    return {band: np.asarray(images[band], dtype=float) for band in REQUIRED_BANDS}, lights


def physics_height(images, lights, spacing, *, mask=None, scattering=True, kernels=None, interreflection=True, highlights=True,
                   iterations=DEFAULT_ITERATIONS, tolerance=DEFAULT_TOLERANCE, radius_um=DEFAULT_RADIUS_UM,
                   integrator=DEFAULT_INTEGRATOR, solver=DEFAULT_SOLVER, progress=iter) -> PhysicsResult:
    """Height that inverts scattering, interreflection and highlights (module notes).

    Parameters
    ----------
    images : dict band -> ndarray (m, rows, columns)
        Red, green and blue linear images divided by each light's relative intensity, taken
        under the same ``lights``. NaN (saturated) observations are filled from the band's
        Lambertian fit.
    lights : ndarray (m, 3)
        Unit light directions, camera frame.
    spacing : float or (dy, dx)
        Pixel size in micrometres.
    mask : ndarray of bool, optional
        Pixels of skin; the others are filled for the Fourier steps and left out of the height.
    scattering, interreflection, highlights : bool
        Which effects to invert (all by default; switching one off is the ablation).
    kernels : dict band -> kernel, optional
        Scattering kernels known beforehand (a measured or published diffusion profile)
        instead of estimated from the capture: objects with ``transfer(frequency)`` (cycles
        per micrometre) and ``length_um`` (their widest length), e.g. a
        :class:`ScatteringKernel` or a simulator profile's
        :class:`~skintopo.optics.ScatteringProfile`. A blur shared by all bands cannot
        be estimated from the bands' ratios; known kernels remove that ambiguity.
    iterations : int
        At most this many passes of steps 2-4; ``tolerance`` stops earlier.
    progress : callable, optional
        Wraps the iteration over the iterations (each named "iteration k"; e.g. a progress bar).
    solver : str
        The photometric-stereo solver of step 4 (:func:`skintopo.normals.photometric_stereo`):
        ``"robust"`` leaves out an observation that a residual highlight makes clearly brighter
        than the other lights predict.
    integrator : str
        How normals become heights (:func:`skintopo.height.integrate_normals`).

    Returns
    -------
    PhysicsResult
    """
    images, lights = _check_inputs(images, lights)
    spacing = pixel_spacing(spacing)
    shape = images["red"].shape[1:]
    mask = np.ones(shape, bool) if mask is None else np.asarray(mask, dtype=bool)
    scaled_normals, plain = {}, []
    for band in REQUIRED_BANDS:
        stereo = photometric_stereo(images[band], lights, mask=mask)
        plain.append(integrate_normals(stereo.normals, spacing, mask=mask & stereo.valid, method=integrator))
        scaled_normals[band] = stereo.albedo[..., None] * stereo.normals
    return _physics_passes(images, _DistantLights(lights, solver), spacing, mask, scaled_normals, plain, scattering=scattering,
                           kernels=kernels, interreflection=interreflection, highlights=highlights, iterations=iterations,
                           tolerance=tolerance, radius_um=radius_um, integrator=integrator, progress=progress)


def near_field_physics_height(images, device: Device, *, mask=None, scattering=True, kernels=None, interreflection=True, highlights=True,
                              iterations=DEFAULT_ITERATIONS, tolerance=DEFAULT_TOLERANCE, radius_um=DEFAULT_RADIUS_UM,
                              integrator=DEFAULT_INTEGRATOR, progress=iter, solved=None) -> PhysicsResult:
    """The physics height (module notes) of a capture through a device: near LEDs and a
    perspective camera (:mod:`skintopo.device`).

    Each band is first solved by near-field photometric stereo
    (:func:`skintopo.nearfield.near_field_photometric_stereo`; green and blue started from
    red), which fixes the skin-plane grid (:func:`skintopo.nearfield.surface_grid`), the
    depth scale and where each node lies on the image. The images, divided by each LED's
    intensity in their band, are read at those places (bilinear; the bands' own heights move
    a node by hundredths of a pixel) and the passes of :func:`physics_height` run on that
    grid, an orthographic height field, with each node's own light vectors
    s_i(P), P = (x, y, -D + h), in step 4's least squares (that of
    :func:`skintopo.nearfield.per_pixel_photometric_stereo`, its shadow rule included), in
    the shading of the residual and in the highlight lobe (with each node's view toward the
    centre of projection). Cast shadows are marched along the directions from the field centre
    to the LEDs (the simulator's approximation); interreflection and scattering are
    operators on the grid and do not depend on the lights.

    Parameters
    ----------
    images : dict band -> ndarray (m, rows, columns)
        Red, green and blue camera images, one per LED in the device's LED order, linear,
        flat-fielded for the camera only; NaN where saturated.
    device : Device
    mask : ndarray of bool, optional
        Camera pixels of skin.
    solved : dict band -> NearFieldResult, optional
        The bands' near-field photometric stereo of these images, when already made (the
        pipeline's); else it is made here.

    The other parameters are those of :func:`physics_height` (step 4 uses least squares:
    the near-field solver has no robust variant). Returns a :class:`PhysicsResult` whose
    height and albedo are on the skin-plane grid.
    """
    from skintopo.nearfield import near_field_photometric_stereo, surface_grid  # here: Numba takes 0.3 s to import

    missing = [band for band in REQUIRED_BANDS if band not in images]
    if missing:
        raise SkinTopoError(f"the physics height needs red, green and blue images; missing {missing} (have {sorted(images)})")
    solved, start = dict(solved or {}), None
    for band in REQUIRED_BANDS:
        if band not in solved:
            solved[band] = near_field_photometric_stereo(images[band], device, band, mask=mask, integrator=integrator, start=start)
        start = solved[band]
    plain = [solved[band].height for band in REQUIRED_BANDS]
    scaled_normals = {}
    for band in REQUIRED_BANDS:
        stereo = solved[band].stereo_on_surface_grid()
        # nodes without a normal take their nearest node's: the images of nodes the camera does not see are
        # filled from these, and zeros there would ring through the deconvolution into the seen field
        known = stereo.valid & np.isfinite(stereo.albedo)
        scaled_normals[band] = np.stack(fill_from_nearest(known, *np.moveaxis(stereo.albedo[..., None] * stereo.normals, -1, 0)), axis=-1)
    divided = {}
    for band in REQUIRED_BANDS:
        intensity = np.array([led.intensity.get(band, 1.0) for led in device.leds], dtype=np.float32)
        divided[band] = np.asarray(images[band], dtype=np.float32) / intensity[:, None, None]
    x, y = surface_grid(device)
    geometry = _DeviceLights(device, x, y, fill_from_nearest(plain[0].mask, plain[0].z)[0], divided)
    return _physics_passes(geometry.read(geometry.start), geometry, pixel_spacing(device.pixel_um), geometry.seen(mask), scaled_normals,
                           plain, scattering=scattering, kernels=kernels, interreflection=interreflection, highlights=highlights,
                           iterations=iterations, tolerance=tolerance, radius_um=radius_um, integrator=integrator, progress=progress)


class _DistantLights:
    """Step 4's photometric stereo and the shading model of the passes under distant lights
    and an orthographic camera. ``start``: no height is needed to solve (None)."""

    kind, start = "distant", None

    def __init__(self, lights, solver=DEFAULT_SOLVER):
        self.lights, self.solver = lights, solver
        self.shadow_directions = lights

    def coarse(self, factor):
        """The same lights on a grid of ``factor`` x ``factor`` block means."""
        return self

    def stereo(self, shading, z, mask):
        """(normals, albedo, valid) of the shading stack (NaN: left out)."""
        # its highlights are modelled by the passes
        stereo = photometric_stereo(shading, self.lights, mask=mask, solver=self.solver, specular_lobe=False)
        return stereo.normals, stereo.albedo, stereo.valid

    def integrated(self, normals, valid, mask, spacing, integrator):
        """The height of the ``valid`` normals inside ``mask``."""
        return integrate_normals(np.where(valid[..., None], normals, np.nan), spacing, mask=mask & valid, method=integrator)

    def anchored(self, height: HeightMap):
        """The integrated ``height`` with the level the lights need (none: as it is)."""
        return height

    def irradiance(self, normals, z):
        """n . l_i per light (m, rows, columns), not clipped."""
        return np.einsum("rck,mk->mrc", normals, self.lights)

    def lobe(self, normals, z, visible):
        """The :class:`~skintopo.normals.SpecularLobe` of these normals."""
        return SpecularLobe(normals, self.lights, visible)


class _DeviceLights:
    """The same on a device's skin-plane grid (:func:`near_field_physics_height`): node (x, y)
    in mm at height h (um) is the point P = (x, y, -D + h / 1000); its light vectors are
    s_i(P) D^2 with unit intensities (the images are divided by each LED's intensity in their
    band), as :func:`skintopo.nearfield.per_pixel_photometric_stereo` takes them. ``start``:
    the height of the first pass's light vectors (the plain red band's, holes filled)."""

    kind, solver = "device", DEFAULT_SOLVER

    def __init__(self, device: Device, x_mm, y_mm, start, camera_images=None):
        self.device, self.x, self.y, self.start, self.camera_images = device, x_mm, y_mm, start, camera_images
        self._vectors = None  # (z, its vectors): a pass asks for them twice (residual, lobe), 0.7 s each at 1000 x 1000
        self.shadow_directions = device.central_directions()  # marched from the field centre's directions (the simulator's approximation)

    def coarse(self, factor):
        return _DeviceLights(self.device, block_mean(self.x, factor, "trim"), block_mean(self.y, factor, "trim"),
                             block_mean(self.start, factor, "trim"))

    def seen(self, mask=None):
        """The nodes whose point (at the start height) the camera sees on a pixel of ``mask``
        (default: every pixel). Not the plain heights' masks: their resampling leaves out the
        nodes where its fixed point did not settle, which the passes can still solve."""
        column, row = self.device.camera.project(self.points(self.start))
        rows, columns = self.device.camera.size_px
        seen = (column >= 0) & (column <= columns - 1) & (row >= 0) & (row <= rows - 1)
        if mask is not None:
            seen[seen] = np.asarray(mask, dtype=bool)[np.rint(row[seen]).astype(int), np.rint(column[seen]).astype(int)]
        return seen

    def read(self, z):
        """The camera images (band -> (m, rows, columns)) at the nodes' points of height
        ``z``: where each node's point projects (bilinear)."""
        column, row = self.device.camera.project(self.points(z))
        return {band: np.stack([scipy.ndimage.map_coordinates(image, [row, column], order=1, mode="nearest") for image in stack])
                for band, stack in self.camera_images.items()}

    def points(self, z):
        return np.stack(np.broadcast_arrays(self.x, self.y, np.asarray(z) / 1000 - self.device.working_distance_mm)).astype(float)

    def vectors(self, z):
        """s_i(P) D^2 per LED, (m, 3, rows, columns); kept for the last ``z`` asked (the passes
        never change a height in place)."""
        if self._vectors is None or self._vectors[0] is not z:
            points = self.points(z)
            self._vectors = (z, np.stack([led.light_vectors(points) for led in self.device.leds]) * self.device.working_distance_mm**2)
        return self._vectors[1]

    def stereo(self, shading, z, mask):
        from skintopo.nearfield import per_pixel_photometric_stereo  # here: Numba takes 0.3 s to import

        depth = self.device.working_distance_mm - (self.start if z is None else z) / 1000
        rays = np.stack(np.broadcast_arrays(self.x / depth, self.y / depth, -1.0))
        normals, albedo, _, _ = per_pixel_photometric_stereo(shading[:, mask], rays[:, mask], depth[mask], self.device, None)
        normal_map, albedo_map = np.full(mask.shape + (3,), np.nan, np.float32), np.full(mask.shape, np.nan, np.float32)
        normal_map[mask], albedo_map[mask] = normals.T, albedo
        return normal_map, albedo_map, mask & np.isfinite(albedo_map)

    def integrated(self, normals, valid, mask, spacing, integrator):
        """The height of the normals inside ``mask``, the invalid ones bridged by their nearest
        valid node's (and left out of the result): a wrinkle wall left with too few LEDs cut
        a corner of the grid off, which the masked least squares then put at a level of its
        own (simulated paper-like device at 1000 px, translucent skin: 9.7 mm too high)."""
        bridged = np.stack(fill_from_nearest(valid, *np.moveaxis(normals, -1, 0)), axis=-1)
        height = integrate_normals(bridged, spacing, mask=mask, method=integrator)
        return HeightMap(np.where(valid, height.z, np.nan), height.spacing, height.mask & valid)

    def anchored(self, height: HeightMap):
        """``height`` moved to the plain red height's mean over their common nodes: the
        integration leaves the level free, and the light vectors depend on it. The plain
        band's depth scale fixed it photometrically (:mod:`skintopo.nearfield`); a fit of the
        level to the pass's shading is not used: that scale is weakly determined, and with the
        height of a pass (6 um RMS from the truth) it came out 2.1 mm (1.4%) off, against
        0.01 mm with the true shape (simulated paper-like device, 512 px, forehead with
        translucency and interreflection)."""
        common = height.mask & np.isfinite(self.start)
        offset = float(np.mean(self.start[common]) - np.mean(height.z[common]))
        return HeightMap(height.z + offset, height.spacing, height.mask)

    def irradiance(self, normals, z):
        return np.einsum("rck,mkrc->mrc", normals, self.vectors(z))

    def lobe(self, normals, z, visible):
        points, vectors = self.points(z), self.vectors(z)
        strength = np.linalg.norm(vectors, axis=1)
        directions = np.moveaxis(vectors / np.maximum(strength, 1e-30)[:, None], 1, -1)
        view = np.moveaxis(-points / np.linalg.norm(points, axis=0), 0, -1)
        return SpecularLobe(normals, directions, visible, view, strength)


def _physics_passes(images, geometry, spacing, mask, scaled_normals, plain, *, scattering, kernels, interreflection, highlights,
                    iterations, tolerance, radius_um, integrator, progress) -> PhysicsResult:
    """Steps 1-4 of the module notes on one grid: ``images`` band -> (m, rows, columns),
    ``geometry`` the lights' model (:class:`_DistantLights`, :class:`_DeviceLights`), ``scaled_normals`` and ``plain``
    the bands' plain photometric stereo (rho n) and heights on that grid."""
    shape = images["red"].shape[1:]
    albedo_level = {band: float(np.nanmedian(np.linalg.norm(scaled_normals[band], axis=-1))) for band in REQUIRED_BANDS}
    images = _filled(images, geometry, scaled_normals, mask)
    if not scattering:
        kernels, kernel_fit_rms, least_blur = {band: IDENTITY_KERNEL for band in REQUIRED_BANDS}, 0.0, None
    elif kernels is not None:
        kernels, kernel_fit_rms, least_blur = _checked_kernels(kernels), None, None
    else:
        kernels, kernel_fit_rms, least_blur = estimate_scattering_kernels(scaled_normals, spacing)
    pad = int(min(max(shape) // 2, np.ceil(4 * max(k.length_um for k in kernels.values()) / min(spacing)) + 4))
    fourier = _Filter(shape, spacing, pad)
    transfer = {band: kernels[band].transfer(fourier.frequency) for band in REQUIRED_BANDS}
    gain = _band_gains(albedo_level, transfer)
    power = (gain**2).sum(0)
    # S = (sum_c a_c J_c / sum_c a_c^2) min(1, G / A), A = sqrt(sum_c rho_c^2 / sum_c a_c^2) the deconvolution's gain
    fusion = gain / power * np.minimum(1.0, MAX_DECONVOLUTION_GAIN * np.sqrt(power / sum(albedo_level[b] ** 2 for b in REQUIRED_BANDS)))
    # single precision for the Fourier passes only after the division: a_c^2 of a wide kernel underflows float32
    transfer, gain, fusion = {band: t.astype(np.float32) for band, t in transfer.items()}, gain.astype(np.float32), fusion.astype(np.float32)
    specular_images, specular_spectrum = np.zeros_like(images["red"]), 0.0
    albedo_pattern = np.ones(shape)
    # spectra of the direct images J_c = I_c - T_c[rho_c v K B_c] (no interreflection known yet: I_c);
    # the transform is linear, F(J - s) = F(J) - F(s)
    direct_images = [images[band] for band in REQUIRED_BANDS]
    direct_spectra = [fourier.forward(direct) for direct in direct_images]
    specular, seed = {"roughness": None, "scale": 0.0}, {}
    if highlights and scattering:  # without the scattering model the lobe fit takes the bands' blur difference for a highlight
        seed, seed_lobe, seed_images = _seed_lobe(plain, _Bands(direct_images, direct_spectra, gain, kernels, albedo_level), fourier,
                                                  spacing, geometry, images)
        if seed["seeded"]:
            specular, specular_images, specular_spectrum = seed_lobe, seed_images, fourier.forward(seed_images)
    changes, residuals = [], []
    previous = best = shadowed = z = None
    for k, _ in enumerate(progress([f"iteration {n}" for n in range(1, iterations + 1)]), start=1):  # ends early once converged
        shading = fourier.inverse(sum(weight * (d - specular_spectrum) for weight, d in zip(fusion, direct_spectra)))
        if shadowed is not None:
            shading[shadowed] = np.nan  # left out of the fit, as a saturated observation is
        fitted, albedo, valid = geometry.stereo(shading, z, mask)
        albedo_pattern = np.nan_to_num(albedo / np.nanmedian(albedo), nan=1.0)
        height = geometry.anchored(geometry.integrated(fitted, valid, mask, spacing, integrator))
        z = fill_from_nearest(height.mask, height.z)[0]
        if previous is not None:
            changes.append(float(np.sqrt(np.mean((z - previous) ** 2)) / max(np.std(z), 1e-12)))
            if changes[-1] > DIVERGENCE:
                break  # the model cannot explain these images (e.g. an effect left out): keep the last good one
        previous = z
        best = (height, albedo_pattern, specular)
        normals, visible = _normals_and_visibility(z, spacing, geometry.shadow_directions)
        shadowed = ~visible if shadowed is None else shadowed | ~visible
        # the residual of the model this pass's height was made with (its K and s), with the height's own shading
        diffuse = fourier.forward(np.maximum(geometry.irradiance(normals, z), 0.0) * visible * albedo_pattern)
        residual = [np.ascontiguousarray(fourier.inverse(d - specular_spectrum - a * diffuse)) for d, a in zip(direct_spectra, gain)]
        residuals.append(float(np.sqrt(sum(_dot(r, r) for r in residual) / sum(r.size for r in residual))))
        if (changes and changes[-1] < tolerance) or k == iterations:
            break  # no next pass to prepare
        if geometry.kind == "device":  # the images where this height puts the nodes' points
            images = _filled(geometry.read(z), geometry, scaled_normals, mask)
            direct_images = [images[band] for band in REQUIRED_BANDS]
            direct_spectra = [fourier.forward(direct) for direct in direct_images]
        if interreflection:
            gather = _Interreflection(HeightMap(z, height.spacing), radius_um)  # z: its holes already filled
            reflectance = albedo_pattern.astype(np.float32)
            direct_images = [images[band] - fourier.apply(albedo_level[band] * reflectance * gather.gather(images[band] - specular_images),
                                                          transfer[band])
                             for band in REQUIRED_BANDS]
            direct_spectra = [fourier.forward(direct) for direct in direct_images]
        if highlights:
            specular, specular_images = _fit_specular(_Bands(direct_images, direct_spectra, gain, kernels, albedo_level), fourier,
                                                      spacing, geometry.lobe(normals, z, visible))
            specular_spectrum = fourier.forward(specular_images)
    height, albedo_pattern, specular = best
    if seed:
        specular = specular | {"first_pass": seed}
    converged = bool(changes) and changes[-1] < tolerance
    diverged = bool(changes) and changes[-1] > DIVERGENCE
    components = {"scattering": scattering, "kernels_given": scattering and kernel_fit_rms is None,
                  "least_blur_prior": least_blur,
                  "interreflection": interreflection, "highlights": highlights, "solver": geometry.solver,
                  "lights": geometry.kind,
                  "interreflection_radius_um": radius_um if interreflection else None,
                  "interreflection_grid_factor": _Interreflection.grid_factor(shape) if interreflection else None}
    return PhysicsResult(height, albedo_pattern * albedo_level["red"], kernels, specular, len(residuals), changes, residuals,
                         converged, diverged, kernel_fit_rms, components, _agreement(height, plain))


def _filled(images, geometry, scaled_normals, mask):
    """The images in single precision (as the Fourier passes), each missing (saturated, or
    outside ``mask``) observation replaced by its band's Lambertian fit (rho n . l_i)."""
    filled = {}
    for band in REQUIRED_BANDS:
        filled[band] = np.asarray(images[band], dtype=np.float32)
        missing = ~(np.isfinite(filled[band]) & mask)
        if missing.any():
            predicted = geometry.irradiance(np.nan_to_num(scaled_normals[band]), geometry.start)
            filled[band] = np.where(missing, predicted, filled[band]).astype(np.float32)
    return filled


def _checked_kernels(kernels):
    missing = [band for band in REQUIRED_BANDS if band not in kernels]
    if missing:
        raise SkinTopoError(f"scattering kernels are missing for {missing}")
    for band in REQUIRED_BANDS:
        kernel = kernels[band]
        if not (callable(getattr(kernel, "transfer", None)) and float(getattr(kernel, "length_um", -1)) >= 0):
            raise SkinTopoError(f"the {band} scattering kernel needs transfer(frequency) and length_um")
        if not np.isclose(float(kernel.transfer(0.0)), 1.0, atol=1e-3):
            raise SkinTopoError(f"the {band} scattering kernel must transmit 1 at zero frequency (it conserves light), "
                                f"got {float(kernel.transfer(0.0)):.4g}")
    return {band: kernels[band] for band in REQUIRED_BANDS}


def _agreement(height, plain):
    """Relief ratio and correlation of ``height`` with the mean of the plain band heights,
    both levelled (least-squares plane removed) over their common points."""
    common = height.mask & np.logical_and.reduce([p.mask for p in plain])

    def levelled(z):
        z = np.where(common, z, 0.0)
        return (z - polynomial_form(z, height.spacing, 1, common))[common]

    found, reference = levelled(height.z), levelled(np.mean([p.z for p in plain], axis=0))
    return {"relief_ratio": round(float(found.std() / max(reference.std(), 1e-12)), 4),
            "correlation": round(float(np.corrcoef(found, reference)[0, 1]), 4)}


@dataclass(frozen=True, eq=False)
class _Bands:
    """What :func:`_fit_specular` needs of the current pass: the direct images J_c (m, rows,
    columns) and their spectra, the gains a_c(f) on the full grid, and the kernels and albedo
    levels that make them (for a coarser grid)."""

    images: list
    spectra: list
    gain: np.ndarray
    kernels: dict
    albedo_level: dict


def _band_gains(albedo_level, transfer):
    """a_c(f) = rho_c T_c(f), stacked red, green, blue (``transfer``: band -> T_c on a grid)."""
    return np.stack([albedo_level[band] * transfer[band] for band in REQUIRED_BANDS])


def _normals_and_visibility(z, spacing, lights):
    """The normals of a (hole-free) height map and, per light direction (m, 3), where it is
    not in a cast shadow (m, rows, columns)."""
    z32 = z.astype(np.float32)  # shadows in single precision (6e-5 um steps at 1 mm of relief): half the memory traffic
    return height_normals(z, spacing), ~np.stack([cast_shadow(z32, spacing[1], light) for light in lights])


def _seed_lobe(plain, bands: _Bands, fourier, spacing, geometry, images):
    """The first pass's lobe (module notes), fitted to the normals of the plain bands' mean
    height. Returns (record: ``seeded`` when it carries more than ``SEED_SPECULAR_FRACTION``
    of the light of the red, green and blue images, that ``fraction`` and the lobe's
    parameters; the lobe's parameters; its specular images)."""
    common = np.logical_and.reduce([p.mask for p in plain])
    mean = np.mean([np.where(common, p.z - np.mean(p.z[common]), 0.0) for p in plain], axis=0)
    z = fill_from_nearest(common, np.where(common, mean, np.nan))[0]
    brightness = np.mean([np.mean(images[band]) for band in REQUIRED_BANDS])

    def lobe(z, bands, fourier, spacing, geometry):
        normals, visible = _normals_and_visibility(z, spacing, geometry.shadow_directions)
        return _fit_specular(bands, fourier, spacing, geometry.lobe(normals, z, visible))

    # whether to seed is decided on block means (the interreflection grid's): the full-resolution
    # fit costs as much as a pass's (measured: physics at 1000 x 1000 4.6 -> 5.3 s), and is
    # needed only when the lobe is kept
    factor = _Interreflection.grid_factor(z.shape)
    if factor > 1:
        coarse, coarse_spacing, coarse_bands = _coarse_bands(bands, fourier, spacing, factor)
        parameters, specular_images = lobe(block_mean(z, factor, "trim"), coarse_bands, coarse, coarse_spacing, geometry.coarse(factor))
    else:
        parameters, specular_images = lobe(z, bands, fourier, spacing, geometry)
    fraction = float(np.mean(specular_images) / brightness)
    seeded = fraction > SEED_SPECULAR_FRACTION
    if seeded and factor > 1:
        parameters, specular_images = lobe(z, bands, fourier, spacing, geometry)
    return {"seeded": seeded, "fraction": round(fraction, 4)} | parameters, parameters, specular_images


def _coarse_bands(bands: _Bands, fourier, spacing, factor):
    """(filter, spacing, :class:`_Bands`) of the block means of ``factor`` x ``factor``
    pixels: the direct images averaged, their spectra and the gains on the coarser grid."""
    coarse_spacing = tuple(d * factor for d in spacing)
    coarse = _Filter(tuple(n // factor for n in fourier.shape), coarse_spacing, -(-fourier.pad // factor))
    transfer = {band: bands.kernels[band].transfer(coarse.frequency) for band in REQUIRED_BANDS}
    direct = [block_mean(images, factor, "trim") for images in bands.images]
    gain = _band_gains(bands.albedo_level, transfer).astype(np.float32)
    return coarse, coarse_spacing, _Bands(direct, [coarse.forward(d) for d in direct], gain, bands.kernels, bands.albedo_level)


def _fit_specular(bands: _Bands, fourier, spacing, lobes):
    """Scale k and roughness m of the lobe, from the bands' disagreement alone.

    With J_c = T_c[rho_c v E] + s (interreflection removed), the cross-blurred difference of
    two bands, a_c' J_c - a_c J_c' with a_c = rho_c T_c, cancels the diffuse part exactly (the
    blurs commute) and leaves (a_c' - a_c) s: it is free of the current shape's errors. k
    (>= 0, least squares over the three band pairs, every pixel and light) and m (on
    ROUGHNESS_GRID) fit the lobe of the current normals to it; each pair's part that a
    multiple of its leak a_c J_c' explains is left out of the fit. Returns
    (parameters, s_i).

    The least squares is written with inner products only: with o the observed difference
    (orthogonal to the leak L) and p the predicted one, the orthogonalised prediction
    q = p - L <p, L> / <L, L> gives <o, q> = <o, p> and |q|^2 = |p|^2 - <p, L>^2 / <L, L>;
    k = sum <o, p> / sum |q|^2 explains k (2 sum <o, p> - k sum |q|^2) of sum |o|^2, and the
    best m explains the most (compared directly, not as a small difference of two large
    misfits: the sums are single-precision BLAS dot products, 2e-7 relative on 4e6 terms).
    The third pair's prediction is the difference of the other two:
    a_2 - a_1 = (a_2 - a_0) - (a_1 - a_0).

    The misfit is searched on ROUGHNESS_GRID: every other grid value, then the two neighbours
    of the best (the grid's best where the misfit is unimodal in m). Not a walk from the last
    pass's m: on a diffuse Mitsuba render the misfit of a spurious highlight has two minima,
    and a walk changed the height (1.66 -> 1.90 um RMS).

    Fields of more than ``MAX_SPECULAR_FIT_PIXELS`` search m on block means of J_c and of the
    lobe (computed from the full-resolution normals, then averaged: the block mean commutes
    with the blurs, so both sides are the same linear images of the full-resolution ones seen
    through the block's box filter), then choose between that m and its two neighbours, and
    fit k, at full resolution: the search was most of the fit, and the fit 40% of the
    method's time at 1000 x 1000. The block means alone chose one step off the full search on
    2 of 4 simulated 1000 x 1000 foreheads (RMS error 2.28 -> 3.00 and 12.25 -> 16.50 um); with
    the neighbours decided at full resolution all 4 get the full search's m, k and height (and
    4 of 4 256 x 256 foreheads made to search on 128 x 128). k is not taken from the block
    means: there it came out 2% high and the heights 0.3-0.8 um RMS worse.

    A best m at the grid's broadest value is no highlight, and no lobe is subtracted (its fit
    is recorded as ``rejected``): the bands' disagreement then grows with a lobe's breadth
    beyond any skin's (m 0.3-0.45, field notes), which is what a smooth model error does
    (interreflection on the microrelief, a non-Lambertian diffuse part), not a highlight. On
    Mitsuba's diffuse renders (bench_physics_mitsuba, edge-calibrated kernels) the lobe fit
    chose m = 0.5 (the grid's broadest), and subtracting it cost 2.68 -> 2.12 um (forehead-moderate)
    and 6.80 -> 4.33 um (forehead-high); on every coated render the best m was inside the grid.
    In the simulator (seeds 1-6 of default-v1, 1-3 of literature and paper-calibrated, each
    with estimated, true and edge-calibrated kernels) one height changed: paper-calibrated
    forehead-high light seed 2, edge-calibrated, 40.06 -> 20.60 um (2026-12-06).
    """
    fit = _LobeFit(fourier, bands.spectra, bands.gain, lobes)
    factor = _grid_factor(fourier.shape, MAX_SPECULAR_FIT_PIXELS)
    search = fit
    if factor > 1:
        coarse, _, coarse_bands = _coarse_bands(bands, fourier, spacing, factor)
        search = _LobeFit(coarse, coarse_bands.spectra, coarse_bands.gain, lambda roughness: block_mean(lobes(roughness), factor, "trim"))
    last = len(ROUGHNESS_GRID) - 1

    def with_neighbours(k):
        return [j for j in (k - 1, k, k + 1) if 0 <= j <= last]

    best = max(range(0, last + 1, 2), key=search.explained)
    best = max(with_neighbours(best), key=search.explained)
    if search is not fit:  # the block means find the neighbourhood; the full resolution decides within it
        best = max(with_neighbours(best), key=fit.explained)
    _, scale, lobe = fit.fits[best]
    if best == last:  # the broadest lobe searched: the disagreement is not a highlight (docstring)
        rejected = {"roughness": float(ROUGHNESS_GRID[best]), "scale": float(scale)}
        return {"roughness": None, "scale": 0.0, "rejected": rejected}, np.zeros_like(lobe)
    return {"roughness": float(ROUGHNESS_GRID[best]), "scale": float(scale)}, scale * lobe


class _LobeFit:
    """The inner products of :func:`_fit_specular` on one grid: ``explained(k)``, the part of
    sum |o|^2 that the best scale of the lobe of roughness ROUGHNESS_GRID[k] explains;
    ``fits[k]``: (explained, scale, lobe) of each k evaluated. ``lobe_of(m)``: the
    (lights, rows, columns) lobe on this grid."""

    def __init__(self, fourier, spectra, gain, lobe_of):
        pairs = [(0, 1), (0, 2), (1, 2)]
        self.fourier, self.lobe_of, self.fits = fourier, lobe_of, {}
        self.leaks = [np.ascontiguousarray(fourier.inverse(gain[i] * spectra[j])) for i, j in pairs]
        self.leak_norms = [_dot(leak, leak) for leak in self.leaks]
        self.observed = []
        for (i, j), leak, norm in zip(pairs, self.leaks, self.leak_norms):
            difference = np.ascontiguousarray(fourier.inverse(gain[j] * spectra[i] - gain[i] * spectra[j]))
            self.observed.append(difference - leak * np.float32(_dot(difference, leak) / norm))
        self.differences = (gain[1] - gain[0], gain[2] - gain[0])

    def explained(self, k):
        if k not in self.fits:
            lobe = self.lobe_of(ROUGHNESS_GRID[k])
            spectrum = self.fourier.forward(lobe)
            first, second = (np.ascontiguousarray(self.fourier.inverse(difference * spectrum)) for difference in self.differences)
            along = cross = 0.0
            for o, p, leak, norm in zip(self.observed, (first, second, second - first), self.leaks, self.leak_norms):
                along += _dot(o, p)
                cross += _dot(p, p) - _dot(p, leak) ** 2 / norm
            scale = max(0.0, along / cross)
            self.fits[k] = (scale * (2 * along - scale * cross), scale, lobe)
        return self.fits[k][0]


def _dot(a, b):
    """Sum of a * b over two contiguous arrays of one shape (BLAS dot, no temporary)."""
    return float(np.dot(a.ravel(), b.ravel()))
