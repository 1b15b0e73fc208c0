"""Skin-optics profiles: albedo, subsurface scattering and surface reflection, with sources.

The simulator (:mod:`skintopo.synth`) renders a profile; the physically based height
(:mod:`skintopo.physics`, ``kernels=``; ``--physics-kernels`` on the command line) can take a
profile's diffusion profiles as known scattering kernels instead of estimating them.

Which effect dominates skin's photometric stereo, light spread under the surface (it blurs
the diffuse normals, most in red) or light reflected at the surface (it steepens slopes, most
where the albedo is lowest, blue), decides which band and which correction look best. So the
simulator's optical parameters are named, sourced profiles, and every accuracy claim of the
project is made in each of them.

Model (per band c)
    diffuse    I_c = T_c[ rho_c (E + K I_c) ],  T_c[I] = sum_k w_ck G(sigma_k) * I
    specular   I_s = k_s pi F(v.h; eta_c) D(n.h; m) G / (4 n.v)   (Torrance-Sparrow, Beckmann D)

T_c is a sum of normalised 2-D Gaussians (a Gaussian of width 0 is the identity: light that
re-emerges where it entered), the form in which layered-skin diffusion profiles are
published for rendering. It is applied with a type-II discrete cosine transform, i.e. with
symmetric (reflecting) borders, exactly, whatever the width: a 2.7 mm Gaussian on a 5 mm
field is not truncated.

Profiles (:data:`PROFILES`)
    ``default-v1``
        The simulator's parameters before profiles existed, kept for reproducing earlier
        results: one Gaussian per band (red: 50% of the light spread with sigma 250 um,
        green 35% at 150 um, blue 25% at 90 um), Fresnel index 1.37 / 1.38 / 1.39, m 0.35,
        k_s 1. The translucency strengths are an unsourced choice.
    ``literature``
        Every number from a published table. Diffusion profile: the six-Gaussian fit of the
        three-layer skin multipole profile (Donner & Jensen 2005) by d'Eon & Luebke 2007
        (GPU Gems 3, ch. 14), variances 0.0064, 0.0484, 0.187, 0.567, 1.99, 7.41 mm^2, RGB
        weights from the same table; heavy-tailed (red keeps 44% of its light in Gaussians
        wider than 1.4 mm). Albedo: the total diffuse reflectance of the dipole model
        (Jensen, Marschner, Levoy & Hanrahan 2001, eq. 5 and its Fig. 5 table) for their
        measured "skin2" (light skin) and "skin1" (darker skin) coefficients, eta 1.3. Surface:
        Torrance-Sparrow with Beckmann roughness m 0.35 and index 1.38 in every band (field
        notes: m 0.3-0.45, n 1.38), k_s 1, i.e. the Fresnel reflectance of the skin surface
        itself, no extra scale.
    ``paper-calibrated``
        The ``literature`` profile with two numbers fitted (``bench/bench_optics.py --fit``)
        so that the paper's four subjects reproduce its Table 1 order and ratios (red < green
        < blue on RMS height error, blue/red 1.5-3, white between) and its Fig. 3 (red too
        shallow, green and blue too deep): the width of the diffusion profile (all variances
        times ``scattering_scale``^2) and the specular scale k_s (a sebum film on the
        forehead). See the values and the fit's record below and in ``docs/method.md``.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
import scipy.fft

from skintopo.defaults import DEFAULT_SKIN_OPTICS
from skintopo.errors import SkinTopoError

BANDS = ("red", "green", "blue")


def dipole_diffuse_reflectance(reduced_scattering_per_mm, absorption_per_mm, eta=1.3):
    """Total diffuse reflectance of the dipole model (Jensen et al. 2001, eq. 5):

    R_d = (alpha'/2) (1 + exp(-(4/3) A sqrt(3 (1 - alpha')))) exp(-sqrt(3 (1 - alpha'))),

    alpha' = sigma_s' / (sigma_s' + sigma_a), A = (1 + F_dr) / (1 - F_dr),
    F_dr = -1.440 / eta^2 + 0.710 / eta + 0.668 + 0.0636 eta.
    """
    albedo = reduced_scattering_per_mm / (reduced_scattering_per_mm + absorption_per_mm)
    fresnel = -1.440 / eta**2 + 0.710 / eta + 0.668 + 0.0636 * eta
    boundary = (1 + fresnel) / (1 - fresnel)
    root = np.sqrt(3 * (1 - albedo))
    return float(albedo / 2 * (1 + np.exp(-4 / 3 * boundary * root)) * np.exp(-root))


@dataclass(frozen=True)
class ScatteringProfile:
    """Radial diffusion profile R(r) = sum_k w_k G(r; sigma_k), normalised (sum w_k = 1).

    ``sigmas_um`` of 0 is the identity (light re-emerging within the pixel it entered).
    """

    weights: tuple[float, ...]
    sigmas_um: tuple[float, ...]

    def __post_init__(self):
        if len(self.weights) != len(self.sigmas_um) or not np.isclose(sum(self.weights), 1.0, atol=1e-3):
            raise SkinTopoError(f"profile weights must pair with widths and sum to 1, got {self.weights}")

    def transfer(self, frequency_per_um):
        """Modulation transfer sum_k w_k exp(-2 pi^2 sigma_k^2 f^2) at spatial frequency f."""
        f2 = np.asarray(frequency_per_um, dtype=float) ** 2
        return sum(w * np.exp(-2 * np.pi**2 * s**2 * f2) for w, s in zip(self.weights, self.sigmas_um))

    @property
    def length_um(self):
        """The widest component's width (um)."""
        return max(self.sigmas_um)

    def scaled(self, factor):
        """The same profile with every width times ``factor``."""
        return replace(self, sigmas_um=tuple(s * factor for s in self.sigmas_um))

    def operator(self, shape, pixel_um):
        """T[I] on images of ``shape`` (symmetric borders), or None when T is the identity.

        The DCT-II diagonalises convolution with a symmetric kernel under half-sample
        symmetric extension (scipy.ndimage's "reflect"), so T is a product per DCT frequency
        f_k = k / (2 N pixel).
        """
        if all(w == 0 or s == 0 for w, s in zip(self.weights, self.sigmas_um)):
            return None
        fy = np.arange(shape[0]) / (2 * shape[0] * pixel_um)
        fx = np.arange(shape[1]) / (2 * shape[1] * pixel_um)
        gain = self.transfer(np.hypot(fy[:, None], fx[None, :]))

        def apply(image):
            return scipy.fft.idctn(scipy.fft.dctn(image, type=2, norm="ortho", axes=(-2, -1)) * gain, type=2, norm="ortho",
                                   axes=(-2, -1))

        return apply


@dataclass(frozen=True)
class SkinOptics:
    """A named skin-optics profile: what the simulator renders (see the module docs).

    Attributes
    ----------
    albedo : dict skin -> band -> float
        Diffuse albedo rho per skin type ("light", "dark") and band.
    scattering : dict band -> ScatteringProfile
    fresnel_index : dict band -> float
        Refractive index of the surface in the specular Fresnel term.
    specular_roughness : float
        Beckmann m.
    specular_scale : float
        k_s: 1 is the Fresnel reflectance of a smooth dielectric interface of that index.
    sources : tuple of str
        Where each number comes from.
    """

    name: str
    albedo: dict
    scattering: dict
    fresnel_index: dict
    specular_roughness: float = 0.35
    specular_scale: float = 1.0
    sources: tuple[str, ...] = field(default=())

    def adjusted(self, *, scattering_scale=1.0, specular_scale=None, name=None):
        """The profile with every diffusion width times ``scattering_scale`` and, if given,
        another specular scale (for fits and sensitivity studies)."""
        return replace(
            self,
            name=name or self.name,
            scattering={band: profile.scaled(scattering_scale) for band, profile in self.scattering.items()},
            specular_scale=self.specular_scale if specular_scale is None else float(specular_scale),
        )

    def diffusion_width_um(self, band):
        """RMS radius of the band's diffusion profile, sqrt(2 sum_k w_k sigma_k^2) (um)."""
        profile = self.scattering[band]
        return float(np.sqrt(2 * sum(w * s**2 for w, s in zip(profile.weights, profile.sigmas_um))))

    def describe(self):
        """JSON-ready record (surface.json, reports of benchmarks)."""
        return {
            "name": self.name,
            "albedo": self.albedo,
            "scattering": {band: {"weights": list(p.weights), "sigmas_um": list(p.sigmas_um)} for band, p in self.scattering.items()},
            "diffusion_rms_radius_um": {band: round(self.diffusion_width_um(band), 1) for band in self.scattering},
            "fresnel_index": self.fresnel_index,
            "specular_roughness": self.specular_roughness,
            "specular_scale": self.specular_scale,
            "sources": list(self.sources),
        }


# --- default-v1: the parameters used before profiles existed --------------------------------
DEFAULT_V1 = SkinOptics(
    name=DEFAULT_SKIN_OPTICS,
    albedo={
        "light": {"red": 0.60, "green": 0.41, "blue": 0.33},
        "dark": {"red": 0.42, "green": 0.22, "blue": 0.13},
    },
    scattering={
        "red": ScatteringProfile((0.5, 0.5), (0.0, 250.0)),
        "green": ScatteringProfile((0.65, 0.35), (0.0, 150.0)),
        "blue": ScatteringProfile((0.75, 0.25), (0.0, 90.0)),
    },
    fresnel_index={"red": 1.37, "green": 1.38, "blue": 1.39},
    specular_roughness=0.35,
    specular_scale=1.0,
    sources=(
        "albedo: field notes (NCSU skin reflectance data), light 0.60/0.41/0.33, dark 0.42/0.22/0.13",
        "translucency weights and widths: unsourced choice (red widest)",
        "specular: Torrance-Sparrow, m 0.35, n 1.38 (field notes), dispersion 1.37/1.39 unsourced",
    ),
)

# --- literature ----------------------------------------------------------------------------
# Jensen et al. 2001 (Fig. 5 table), reduced scattering and absorption coefficients in 1/mm (R, G, B)
JENSEN_2001_SKIN = {
    "skin1": {"reduced_scattering": (0.74, 0.88, 1.01), "absorption": (0.032, 0.17, 0.48)},
    "skin2": {"reduced_scattering": (1.09, 1.59, 1.79), "absorption": (0.013, 0.070, 0.145)},
}
JENSEN_2001_ETA = 1.3
# d'Eon & Luebke 2007 (GPU Gems 3, ch. 14): six-Gaussian fit of the three-layer skin profile
DEON_LUEBKE_2007_VARIANCES_MM2 = (0.0064, 0.0484, 0.187, 0.567, 1.99, 7.41)
DEON_LUEBKE_2007_WEIGHTS = {
    "red": (0.233, 0.100, 0.118, 0.113, 0.358, 0.078),
    "green": (0.455, 0.336, 0.198, 0.007, 0.004, 0.000),
    "blue": (0.649, 0.344, 0.000, 0.007, 0.000, 0.000),
}


def _jensen_albedo(measurement):
    coefficients = JENSEN_2001_SKIN[measurement]
    return {
        band: round(dipole_diffuse_reflectance(s, a, JENSEN_2001_ETA), 4)
        for band, s, a in zip(BANDS, coefficients["reduced_scattering"], coefficients["absorption"])
    }


LITERATURE = SkinOptics(
    name="literature",
    albedo={"light": _jensen_albedo("skin2"), "dark": _jensen_albedo("skin1")},
    scattering={
        band: ScatteringProfile(DEON_LUEBKE_2007_WEIGHTS[band], tuple(1000.0 * np.sqrt(v) for v in DEON_LUEBKE_2007_VARIANCES_MM2))
        for band in BANDS
    },
    fresnel_index={band: 1.38 for band in BANDS},
    specular_roughness=0.35,
    specular_scale=1.0,
    sources=(
        "albedo: dipole total diffuse reflectance (Jensen, Marschner, Levoy & Hanrahan, SIGGRAPH 2001, eq. 5) "
        "of their skin2 (light) and skin1 (dark) coefficients, eta 1.3",
        "diffusion profile: d'Eon & Luebke 2007 (GPU Gems 3 ch. 14) six-Gaussian fit of the Donner & Jensen 2005 "
        "three-layer skin profile",
        "specular: Torrance-Sparrow, Beckmann m 0.35 (field notes 0.3-0.45), n 1.38 (field notes), k_s 1",
    ),
)

# --- paper-calibrated ----------------------------------------------------------------------
# Fitted by bench/bench_optics.py --fit on the paper's four subjects (see the module docs).
# Best of a 7 x 7 x 2 grid (23 of 24 conditions; bench/results/optics_fit.json). Both values lie
# outside the published ranges: the diffusion widths 0.2x the literature profile's (published
# scattering spans 0.33-1x) and k_s 8, i.e. a 20% specular reflectance at normal incidence
# where skin's regular reflectance is 4-7% (Anderson & Parrish 1981; k_s 1.6-2.7).
PAPER_SCATTERING_SCALE = 0.2
PAPER_SPECULAR_SCALE = 8.0
PAPER_CALIBRATED = replace(
    LITERATURE.adjusted(scattering_scale=PAPER_SCATTERING_SCALE, specular_scale=PAPER_SPECULAR_SCALE, name="paper-calibrated"),
    sources=LITERATURE.sources + (
        f"fitted to the paper's Table 1 ratios and Fig. 3 (bench/bench_optics.py --fit): diffusion widths x "
        f"{PAPER_SCATTERING_SCALE:g}, specular scale {PAPER_SPECULAR_SCALE:g}",
    ),
)

PROFILES = {profile.name: profile for profile in (DEFAULT_V1, LITERATURE, PAPER_CALIBRATED)}


def optics_profile(name_or_profile):
    """A :class:`SkinOptics` from its name (or the profile itself)."""
    if isinstance(name_or_profile, SkinOptics):
        return name_or_profile
    if name_or_profile not in PROFILES:
        raise SkinTopoError(f"unknown skin-optics profile {name_or_profile!r}; choose from {list(PROFILES)}")
    return PROFILES[name_or_profile]
