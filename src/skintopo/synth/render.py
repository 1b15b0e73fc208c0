"""Physically based rendering of a skin height field under directional lights, per band.

Orthographic camera looking down -z (view vector v = (0, 0, 1)); directional lights of unit
intensity. Intensities are normalised so that a Lambertian surface gives I = rho n . s
(radiance times pi), the model photometric stereo inverts. Each effect can be switched off.

Diffuse, with cast shadows and interreflection (radiosity)
    B = T[ rho (E + K B) ],   E(x) = max(0, n . s) V_s(x)

    E is the direct irradiance, V_s the cast-shadow visibility and K the interreflection
    operator, both from :mod:`skintopo.transport` (horizon marching over the height field).
    Rows of K sum to at most 1 (the hemisphere's projected solid angle is pi),
    so for rho < 1 the iteration B_{k+1} = T[rho (E + K B_k)] converges (multi-bounce);
    ``bounces=1`` stops after one bounce. Higher albedo gives more interreflection, as
    B ~ rho E / (1 - rho F) in a groove of form factor F (field notes).

Translucency
    T[I] = sum_k w_k G_sigma_k * I: the band's diffusion profile, a sum of normalised Gaussians
    (a width of 0 is light re-emerging where it entered), widest in red (deepest penetration).
    The weights and widths come from the skin-optics profile (:mod:`skintopo.optics`).

Specular (Torrance-Sparrow with Beckmann facets and Fresnel)
    I_s = k_s pi F(v.h; eta) D(n.h) G / (4 n.v) V_s,
    D = exp(-tan^2 alpha / m^2) / (pi m^2 cos^4 alpha),  G = min(1, 2 (n.h)(n.v)/(v.h), 2 (n.h)(n.l)/(v.h)),
    times the profile's specular scale k_s, with its roughness m and refractive index eta per
    band (``default-v1``: m = 0.35, eta 1.37 / 1.38 / 1.39). Relative to the diffuse part it
    weighs most where the albedo is lowest (blue), biasing those normals.

Pigmentation (optional, ``RenderSettings.pigmentation``)
    the albedo maps are made from melanin and haemoglobin maps through the model of
    :mod:`skintopo.chromophores`, R_b = 10^-(M m_b + H h_b + B), with (M, H, B) of the skin
    type's albedo as the mean and smooth variations plus pigmented spots (lentigines) and a
    reddened patch (erythema) on top; the maps are the ground truth of the melanin and
    haemoglobin indices. Without it the albedo is the profile's, times a mild variation
    common to all bands (the default: earlier renders stay reproducible).

Sensor
    auto-exposure per band, shot noise (full well 20 000 e-), read noise (3 e-), both scaled
    by ``noise``; optional saturation (clipping); 16-bit quantisation when written.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
import scipy.ndimage
import scipy.special

from skintopo.chromophores import RGB, chromophore_indices, forward_reflectance
from skintopo.optics import DEFAULT_V1, SkinOptics
from skintopo.transport import cast_shadow, interreflection_operator

BAND_WAVELENGTH_NM = {"red": 625.0, "green": 523.0, "blue": 462.0}
FULL_WELL_ELECTRONS = 20000.0
READ_NOISE_ELECTRONS = 3.0
ALBEDO_VARIATION = 0.05  # relative RMS of the mild spatial albedo variation


@dataclass(frozen=True)
class Effects:
    """Which physical effects the renderer includes (all on by default)."""

    shadows: bool = True
    interreflection: bool = True
    bounces: int | None = None  # None: iterate to convergence; 1: single bounce
    specular: bool = True
    translucency: bool = True
    albedo_variation: bool = True

    @classmethod
    def none(cls):
        """Pure Lambertian: every effect off."""
        return cls(shadows=False, interreflection=False, specular=False, translucency=False, albedo_variation=False)


def default_lights(slant_degrees=45.0, count=4):
    """Lights at one slant, evenly spaced in azimuth (the paper's device: 4 at 90 degrees)."""
    slant = np.radians(slant_degrees)
    tilt = 2 * np.pi * np.arange(count) / count
    return np.stack([np.sin(slant) * np.cos(tilt), np.sin(slant) * np.sin(tilt), np.full(count, np.cos(slant))], axis=1)


def solve_radiosity(direct, albedo, operator, *, transport=None, bounces=None, tolerance=1e-7, max_iterations=200):
    """Diffuse radiosity B = T[rho (E + K B)] by fixed-point iteration.

    Parameters
    ----------
    direct : ndarray (rows, columns)
        Direct irradiance E (unit light).
    albedo : float or ndarray
        rho, below 1.
    operator : sparse matrix or None
        K from :func:`interreflection_operator`; None means no interreflection.
    transport : callable, optional
        The translucency T (identity by default).
    bounces : int, optional
        Number of interreflection bounces; None iterates until the largest change is below
        ``tolerance`` times the largest radiosity.

    Returns
    -------
    B : ndarray
    iterations : int
    changes : list of float
        Largest change per iteration (relative), to show convergence.
    """
    transport = transport or (lambda image: image)
    shape = direct.shape
    radiosity = transport(albedo * direct)
    changes = []
    if operator is None or operator.nnz == 0:
        return radiosity, 0, changes
    limit = bounces if bounces is not None else max_iterations
    for _ in range(limit):
        gathered = (operator @ radiosity.ravel()).reshape(shape)
        updated = transport(albedo * (direct + gathered))
        change = float(np.abs(updated - radiosity).max() / max(np.abs(updated).max(), 1e-30))
        changes.append(change)
        radiosity = updated
        if bounces is None and change < tolerance:
            break
    return radiosity, len(changes), changes


def fresnel_dielectric(cos_incidence, eta):
    """Unpolarised Fresnel reflectance of a dielectric of relative index ``eta``."""
    c = np.clip(cos_incidence, 0.0, 1.0)
    g2 = eta**2 - 1 + c**2
    g = np.sqrt(np.maximum(g2, 0.0))
    a = (g - c) / (g + c)
    b = (c * (g + c) - 1) / (c * (g - c) + 1)
    return 0.5 * a**2 * (1 + b**2)


def torrance_sparrow(normals, light, *, roughness=0.35, eta=1.38, view=(0.0, 0.0, 1.0)):
    """Specular intensity pi F D G / (4 n.v) for unit light and view vectors (one vector, or
    one per pixel: (rows, columns, 3); the orthographic camera's view is (0, 0, 1))."""
    light = np.asarray(light, dtype=float)
    view = np.asarray(view, dtype=float)
    half = light + view
    half = half / np.linalg.norm(half, axis=-1, keepdims=True)
    n_dot_h = np.clip(np.sum(normals * half, axis=-1), 1e-6, 1.0)
    n_dot_v = np.clip(np.sum(normals * view, axis=-1), 1e-6, 1.0)
    n_dot_l = np.sum(normals * light, axis=-1)
    v_dot_h = np.sum(view * half, axis=-1)
    tan2 = (1 - n_dot_h**2) / n_dot_h**2
    facets = np.exp(-tan2 / roughness**2) / (np.pi * roughness**2 * n_dot_h**4)
    masking = np.minimum(1.0, np.minimum(2 * n_dot_h * n_dot_v / v_dot_h, 2 * n_dot_h * np.maximum(n_dot_l, 0) / v_dot_h))
    specular = np.pi * fresnel_dielectric(v_dot_h, eta) * facets * masking / (4 * n_dot_v)
    return np.where(n_dot_l > 0, specular, 0.0)


@dataclass(frozen=True, eq=False)
class NearLighting:
    """Lighting by point LEDs seen by a perspective camera, per point of the height field
    (from :func:`skintopo.synth.nearfield.near_lighting`).

    Attributes
    ----------
    vectors : ndarray (m, rows, columns, 3)
        s(P) D^2 of each LED at unit intensity (:meth:`skintopo.device.Led.light_vectors`; D the
        working distance: irradiance 1 at D on the LED's axis, the near-field solver's convention).
    intensities : dict of str to ndarray (m,)
        Each LED's relative intensity per band.
    view : ndarray (rows, columns, 3)
        Unit vector from each point to the camera's centre of projection.
    shadow_directions : ndarray (m, 3)
        The direction from the field centre to each LED: cast shadows are marched along it
        (an approximation: the true direction changes across the field).
    """

    vectors: np.ndarray
    intensities: dict
    view: np.ndarray
    shadow_directions: np.ndarray


@dataclass(frozen=True)
class Pigmentation:
    """Melanin and haemoglobin maps behind the albedo (module notes). Relative variations
    are RMS values of a smooth Gaussian random field of correlation length ``scale_um``;
    each spot multiplies the melanin index by 1 + ``spot_strength`` inside a disc (smooth
    edge), the erythema patch the haemoglobin index by 1 + ``erythema_strength``. The maps
    belong to the skin, not to the capture: they are drawn from ``seed`` in the skin's
    coordinates, so a later visit of the same skin (``SurfaceSpec.shift_um``) sees the same
    pigmentation, displaced."""

    melanin_variation: float = 0.15
    haemoglobin_variation: float = 0.2
    scale_um: float = 600.0
    spots: int = 3
    spot_strength: float = 1.0
    spot_radius_um: tuple = (250.0, 700.0)
    erythema_strength: float = 0.8
    erythema_radius_um: float = 1200.0
    seed: int = 0


@dataclass(frozen=True)
class RenderSettings:
    """Rendering options. Lengths in micrometres."""

    skin: str = "light"
    lights: np.ndarray = field(default_factory=default_lights)
    effects: Effects = field(default_factory=Effects)
    interreflection_radius_um: float | None = None  # default: the widest wrinkle, at least 0.4 mm
    n_azimuth: int = 16
    optics: SkinOptics = DEFAULT_V1  # albedo, diffusion profiles, surface reflection (skintopo.optics)
    specular_strength: float = 1.0  # multiplies the profile's specular scale
    specular_roughness: float | None = None  # Beckmann m; None: the profile's (skin 0.3-0.45, field notes)
    noise: float = 1.0
    saturate: bool = False
    pigmentation: Pigmentation | None = None  # albedo from melanin and haemoglobin maps (module notes)
    white_reference: float | None = None  # reflectance of a flat white target in the field's top-left corner (a tenth of each side)


def with_interreflection_radius(settings: RenderSettings, wrinkles):
    """``settings`` with the interreflection radius filled in when it is None: the widest of
    ``wrinkles``, at least 0.4 mm."""
    if settings.interreflection_radius_um is not None:
        return settings
    widest = max((w.width_um for w in wrinkles), default=0.0)
    return replace(settings, interreflection_radius_um=max(400.0, widest))


def _smooth_field(shape, sigma_px, rng, shift_px=(0.0, 0.0)):
    """A zero-mean, unit-RMS Gaussian random field of correlation length ``sigma_px``
    (white noise smoothed with wrap-around), displaced by ``shift_px`` (x right, y up; a phase
    ramp, exact for the periodic field)."""
    pattern = scipy.ndimage.gaussian_filter(rng.standard_normal(shape), sigma=max(1.0, sigma_px), mode="wrap")
    if any(shift_px):
        ky = np.fft.fftfreq(shape[0])[:, None]
        kx = np.fft.fftfreq(shape[1])[None, :]
        pattern = np.fft.ifft2(np.fft.fft2(pattern) * np.exp(2j * np.pi * (kx * shift_px[0] - ky * shift_px[1]))).real
    return pattern / (pattern.std() if pattern.std() > 0 else 1)


def _discs(shape, pixel, count, radius_range, rng, shift_um=(0.0, 0.0)):
    """Sum of ``count`` discs at random places of the skin (the field displaced by
    ``shift_um``, x right, y up), 1 inside with a smooth edge (a logistic over 2 pixels),
    radii uniform in ``radius_range`` (um)."""
    rows, columns = np.mgrid[0 : shape[0], 0 : shape[1]]
    total = np.zeros(shape)
    for _ in range(count):
        radius = rng.uniform(*radius_range) / pixel
        centre = rng.uniform(radius, np.array(shape) - radius) - np.array([-shift_um[1], shift_um[0]]) / pixel
        distance = np.hypot(rows - centre[0], columns - centre[1])
        total += scipy.special.expit((radius - distance) / 0.5)
    return total


def pigmentation_maps(shape, pixel, base_albedo, pigmentation: Pigmentation, shift_um=(0.0, 0.0)):
    """(melanin, haemoglobin, baseline) maps (optical densities at 523 nm) of the field
    displaced by ``shift_um`` on the skin, whose mean (before spots) reproduces
    ``base_albedo`` (dict band -> value) through the model of :mod:`skintopo.chromophores`."""
    rng = np.random.default_rng(pigmentation.seed)
    melanin0, haemoglobin0, baseline0 = chromophore_indices({b: np.array(base_albedo[b]) for b in RGB})
    sigma = pigmentation.scale_um / pixel
    shift_px = (shift_um[0] / pixel, shift_um[1] / pixel)
    melanin = melanin0 * (1 + pigmentation.melanin_variation * np.clip(_smooth_field(shape, sigma, rng, shift_px), -3, 3))
    spots = _discs(shape, pixel, pigmentation.spots, pigmentation.spot_radius_um, rng, shift_um)
    melanin *= 1 + pigmentation.spot_strength * np.minimum(spots, 1)
    haemoglobin = haemoglobin0 * (1 + pigmentation.haemoglobin_variation * np.clip(_smooth_field(shape, sigma, rng, shift_px), -3, 3))
    radius = pigmentation.erythema_radius_um
    haemoglobin *= 1 + pigmentation.erythema_strength * _discs(shape, pixel, 1, (radius, radius), rng, shift_um)
    return melanin, haemoglobin, np.full(shape, float(baseline0))


def _albedo_maps(shape, pixel, base, vary, rng, shift_um=(0.0, 0.0)):
    if not vary:
        return {band: np.full(shape, value) for band, value in base.items()}
    shift_px = (shift_um[0] / pixel, shift_um[1] / pixel)
    variation = 1 + ALBEDO_VARIATION * np.clip(_smooth_field(shape, 200.0 / pixel, rng, shift_px), -3, 3)
    return {band: value * variation for band, value in base.items()}


def skin_generator(seed, skin_seed):
    """The skin's own generator when a capture's ``seed`` differs from its ``skin_seed``, else
    None: the capture's generator then draws the skin's albedo variation first, as a capture
    always has (the renders of the default case are unchanged)."""
    return None if skin_seed is None or skin_seed == seed else np.random.default_rng(skin_seed)


def render_bands(height, normals, settings: RenderSettings, rng, progress=iter, *, near: NearLighting | None = None, shift_um=(0.0, 0.0),
                 skin_rng=None):
    """Linear images per band, before the sensor: dict band -> (m, rows, columns), on the
    height field's grid.

    Also returns the render diagnostics (iterations, operator size). ``progress`` wraps the
    iteration over the three bands (e.g. a progress bar). With ``near``, the lights are point
    LEDs and the view is a perspective camera's (``settings.lights`` is then not used); the
    images are still on the height field's grid (:mod:`skintopo.synth.nearfield` projects
    them into the camera). ``shift_um``: where the field lies on the skin (the pigmentation
    maps and the albedo variation follow it). ``skin_rng``: the generator of the skin's own
    albedo variation, for a repeat capture of the same skin (its noise from ``rng``); default
    ``rng``.
    """
    z = np.asarray(height.z, dtype=float)
    pixel = height.spacing[1]
    effects = settings.effects
    optics = settings.optics
    if settings.pigmentation is None:
        base = optics.albedo[settings.skin]
        if skin_rng is not None:  # the capture's generator still draws what a first capture's map draws: its noise stays its seed's
            _albedo_maps(z.shape, pixel, base, effects.albedo_variation, rng)
        albedo = _albedo_maps(z.shape, pixel, base, effects.albedo_variation, rng if skin_rng is None else skin_rng, shift_um)
    else:
        melanin, haemoglobin, baseline = pigmentation_maps(z.shape, pixel, optics.albedo[settings.skin], settings.pigmentation, shift_um)
        albedo = forward_reflectance(melanin, haemoglobin, baseline)
    roughness = optics.specular_roughness if settings.specular_roughness is None else settings.specular_roughness
    operator = None
    info = {"interreflection_nonzeros": 0, "iterations": {}}
    if settings.pigmentation is not None:  # the ground truth of the chromophore maps
        info["chromophores"] = {"melanin": melanin, "haemoglobin": haemoglobin, "baseline": baseline}
    if effects.interreflection:
        operator = interreflection_operator(z, normals, pixel, radius_um=settings.interreflection_radius_um, n_azimuth=settings.n_azimuth)
        info["interreflection_nonzeros"] = int(operator.nnz)
    if near is None:
        lights = np.asarray(settings.lights, dtype=float)
        shadow_directions = lights
        direct = np.maximum(np.einsum("rci,mi->mrc", normals, lights), 0.0)
        unit_lights, view = lights, np.array([0.0, 0.0, 1.0])
    else:
        shadow_directions = near.shadow_directions
        direct = np.maximum(np.einsum("rci,mrci->mrc", normals, near.vectors), 0.0)
        unit_lights = near.vectors / np.linalg.norm(near.vectors, axis=-1, keepdims=True)
        view = near.view
    if effects.shadows:
        direct *= ~np.stack([cast_shadow(z, pixel, light) for light in shadow_directions])
    images = {}
    for band in progress(("red", "green", "blue")):
        transport = optics.scattering[band].operator(z.shape, pixel) if effects.translucency else None
        scale = np.ones(len(direct)) if near is None else np.asarray(near.intensities[band], dtype=float)
        stack = []
        for i in range(len(direct)):
            radiosity, iterations, _ = solve_radiosity(scale[i] * direct[i], albedo[band], operator, transport=transport, bounces=effects.bounces)
            info["iterations"][f"{band}_{i}"] = iterations
            if effects.specular:
                lit = direct[i] > 0
                irradiance = 1.0 if near is None else scale[i] * np.linalg.norm(near.vectors[i], axis=-1)
                lobe = torrance_sparrow(normals, unit_lights[i], roughness=roughness, eta=optics.fresnel_index[band], view=view)
                radiosity = radiosity + settings.specular_strength * optics.specular_scale * lit * irradiance * lobe
            stack.append(radiosity)
        images[band] = np.stack(stack)
    return images, info


def sensor(images, *, noise, saturate, rng):
    """Auto-exposure, shot and read noise; values as fractions of full scale.

    Exposure puts the 99.5th percentile of the band at 80% of full scale (with ``saturate``,
    the 95th percentile at 90%, so highlights clip). Returns the signal and the exposure gain
    (signal = gain x rendered intensity, before noise), which the acquisition records as the
    band's relative light intensity, as a calibrated device would.
    """
    level = np.percentile(images, 95 if saturate else 99.5)
    scale = (0.9 if saturate else 0.8) / level if level > 0 else 1.0
    signal = images * scale
    if noise > 0:
        electrons = np.maximum(signal, 0) * FULL_WELL_ELECTRONS
        sigma = np.sqrt(electrons + READ_NOISE_ELECTRONS**2) / FULL_WELL_ELECTRONS
        signal = signal + noise * sigma * rng.standard_normal(signal.shape)
    return np.clip(signal, 0.0, 1.0), float(scale)
