"""Synthetic skin surfaces with exact ground truth: height, slopes, normals, wrinkle labels.

Every component returns its height *and its exact slopes* (p = dz/dx, q = dz/dy, camera
frame: x right, y up), so ground-truth normals are analytic, not finite differences.
Coordinates: x = (column - (W-1)/2) * pixel, y = ((H-1)/2 - row) * pixel, micrometres.

Components (sources for the numbers: ``../shared/reference/field-notes.md``, "Skin"):

* **Microrelief furrows** -- a polygonal network: the edges of a Voronoi tessellation whose
  cells (plates) are ``plate_um`` across (0.1-1 mm). With d1 <= d2 the distances to the two
  nearest seeds, the distance to the shared edge is e = (d2^2 - d1^2) / (2 |s2 - s1|) (the
  smallest such e over the next five seeds, so e is the distance to the cell's boundary) and
  the furrow is z = -D exp(-e^2 / (2 sigma^2)) with depth D varying smoothly over the field
  within 20-60 um and sigma set from the furrow width (FWHM = 2.355 sigma).
* **Fractal roughness** -- fractional Brownian surface by spectral synthesis: amplitude
  |k|^-(H + 1) (Hurst exponent H), a Gaussian roll-off at ``roughness_cutoff_px`` pixels
  (the optics do not resolve finer detail), scaled to RMS ``roughness_rms_um``; slopes by
  spectral differentiation of the same series (exact).
* **Wrinkles** -- a centre line (straight or a circular arc of curvature kappa), length L,
  width w, depth D and cross-section: ``V`` z = -D (sqrt(1 + a^2) - sqrt(u^2 + a^2)) /
  (sqrt(1 + a^2) - a) with a = 0.15 (rounded bottom), ``U`` z = -D cos^2(pi u / 2), both for
  |u| <= 1, and ``G`` z = -D exp(-u^2 / (2 s^2)) with s = 1/2 (sigma = w / 4, the depth falls
  to e^-2 of D at the width's edges; not truncated), where u = 2 d / w, d the signed distance
  to the centre line. The depth tapers with a smoothstep over the last 15% of the length at
  each end. Wrinkle depths are 50-300 um, widths 0.2-1.7 mm, lengths 5-30 mm in the field
  notes. :func:`geometric_measures` gives each wrinkle's measures by the definitions of
  ``docs/wrinkle-measures.md``, exactly, from this geometry.
* **Pores** -- bowls of opening radius r and depth d: z = -d (1 - (rho / r)^2) for rho < r
  (a paraboloid with a sharp rim; rho the distance to the pore's centre), slopes exact.
  :func:`place_pores` puts them on the skin's plateaus, away from furrows, wrinkles and each
  other (pores of 0.05-0.5 mm openings, issue 26).
* **Form** -- the gentle curvature of a forehead: a cylinder of radius ``form_radius_mm``
  bending about the vertical axis, z = -x^2 / (2 R).

The ground-truth wrinkle mask marks, for each wrinkle, the pixels where its own depth is at
least half of its local maximum (the half-depth region, where width is measured).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field, replace

import numpy as np
from scipy.spatial import cKDTree

from skintopo.errors import SkinTopoError
from skintopo.heightmap import HeightMap

V_ROUNDING = 0.15
END_TAPER = 0.15
GAUSSIAN_SIGMA_HALF_WIDTHS = 0.5  # G profile: sigma in units of the half-width w / 2
SHAPES = ("V", "U", "G")


@dataclass(frozen=True)
class Wrinkle:
    """One wrinkle. Lengths in micrometres, angles in degrees, curvature in 1/mm.

    ``centre_um`` is (x, y) from the field centre (x right, y up); ``orientation_deg`` is the
    angle of the centre line from +x, counter-clockwise; ``curvature_per_mm`` bends the line
    into an arc (0 = straight; positive bends toward +y of the line's left normal).
    """

    depth_um: float
    width_um: float
    length_um: float
    orientation_deg: float = 0.0
    centre_um: tuple = (0.0, 0.0)
    curvature_per_mm: float = 0.0
    shape: str = "V"


@dataclass(frozen=True)
class Pore:
    """One pore: centre (x, y) in micrometres from the field centre (x right, y up; on the
    skin, as wrinkle centres: a ``shift_um`` moves the field, not the pore), opening radius
    and depth in micrometres."""

    centre_um: tuple
    radius_um: float
    depth_um: float


@dataclass(frozen=True)
class SurfaceSpec:
    """Everything that defines a synthetic surface. Lengths in micrometres."""

    size_px: tuple = (256, 256)
    pixel_um: float = 20.0
    wrinkles: tuple = ()
    furrow_depth_um: tuple = (20.0, 60.0)
    furrow_width_um: float = 70.0
    plate_um: float = 400.0
    roughness_rms_um: float = 1.5
    hurst: float = 0.7
    roughness_cutoff_px: float = 3.0
    form_radius_mm: float | None = 80.0
    form_shape: str = "cylinder"  # "cylinder": -x^2 / 2R (forehead, across); "sphere": exact sphere of radius R
    microrelief: bool = True
    shift_um: tuple = (0.0, 0.0)  # (x, y): the field sees the same skin displaced by this (a later visit)
    pores: tuple = ()


@dataclass(frozen=True, eq=False)
class SkinSurface:
    """A synthetic surface with its exact ground truth.

    Attributes
    ----------
    height : HeightMap
        Heights in micrometres.
    p, q : ndarray
        Exact slopes dz/dx, dz/dy (x right, y up).
    normals : ndarray, (rows, columns, 3)
        Exact unit normals (-p, -q, 1) / norm.
    wrinkle_labels : ndarray of int
        0 outside wrinkles, i + 1 inside the half-depth region of wrinkle i.
    wrinkle_depth : ndarray
        Depth contribution of the wrinkles alone (micrometres, >= 0), for evaluation.
    spec : SurfaceSpec
    pore_labels : ndarray of int
        0 outside pores, i + 1 inside the opening of pore i (of ``spec.pores``).
    """

    height: HeightMap
    p: np.ndarray
    q: np.ndarray
    normals: np.ndarray
    wrinkle_labels: np.ndarray
    wrinkle_depth: np.ndarray
    spec: SurfaceSpec = field(repr=False)
    pore_labels: np.ndarray | None = field(default=None, repr=False)

    def describe(self):
        """The spec as plain data (for ground_truth/surface.json)."""
        return asdict(self.spec)


def _coordinates(shape, pixel, shift=(0.0, 0.0)):
    rows, columns = shape
    x = (np.arange(columns) - (columns - 1) / 2) * pixel + shift[0]
    y = ((rows - 1) / 2 - np.arange(rows)) * pixel + shift[1]
    return np.broadcast_to(x[None, :], shape), np.broadcast_to(y[:, None], shape)


def microrelief_furrows(x, y, rng, *, plate_um, depth_um, width_um):
    """Polygonal furrow network on Voronoi edges; returns (z, p, q)."""
    # Seeds over a region fixed in skin coordinates (the field's size about the origin, plus a
    # margin of two plates and a quarter field), so a displaced view (a later visit with
    # ``shift_um``) sees the same network.
    half_width = (x.max() - x.min()) / 2 * 1.25 + 2 * plate_um
    half_height = (y.max() - y.min()) / 2 * 1.25 + 2 * plate_um
    count = max(4, int(4 * half_width * half_height / plate_um**2))
    seeds = np.column_stack([rng.uniform(-half_width, half_width, count), rng.uniform(-half_height, half_height, count)])
    points = np.column_stack([x.ravel(), y.ravel()])
    _, nearest = cKDTree(seeds).query(points, k=6)
    own = seeds[nearest[:, 0]]
    # Distance to the boundary of the own cell: the nearest of the bisectors with the next
    # seeds j, e_j = (|x - s_j|^2 - |x - s_1|^2) / (2 |s_j - s_1|), with gradient (s_1 - s_j) / |s_j - s_1|.
    others = seeds[nearest[:, 1:]]  # (P, 5, 2)
    between = others - own[:, None, :]
    separation = np.linalg.norm(between, axis=2)
    candidates = (((points[:, None, :] - others) ** 2).sum(2) - ((points - own) ** 2).sum(1)[:, None]) / (2 * separation)
    which = candidates.argmin(axis=1)
    take = np.arange(points.shape[0])
    distance = candidates[take, which]
    gradient = -between[take, which] / separation[take, which][:, None]
    sigma = width_um / 2.3548
    # Depth varies smoothly over the field between the two limits (two random plane waves of
    # about three plates' wavelength), so the furrow height stays continuous where cells meet.
    wavevectors = rng.normal(size=(2, 2))
    wavevectors *= (2 * np.pi / (3 * plate_um)) / np.linalg.norm(wavevectors, axis=1, keepdims=True)
    phases = rng.uniform(0, 2 * np.pi, 2)
    arguments = points @ wavevectors.T + phases  # (P, 2)
    level = 0.5 + 0.25 * np.sin(arguments).sum(axis=1)  # in [0, 1]
    d_level = 0.25 * np.cos(arguments) @ wavevectors  # (P, 2)
    depth = depth_um[0] + (depth_um[1] - depth_um[0]) * level
    bump = np.exp(-(distance**2) / (2 * sigma**2))
    z = -depth * bump
    grad = (z * (-distance / sigma**2))[:, None] * gradient - (bump * (depth_um[1] - depth_um[0]))[:, None] * d_level
    shape = x.shape
    return z.reshape(shape), grad[:, 0].reshape(shape), grad[:, 1].reshape(shape)


def fractal_roughness(shape, pixel, rng, *, rms_um, hurst, cutoff_px, shift_um=(0.0, 0.0)):
    """Fractional Brownian roughness by spectral synthesis; returns (z, p, q), exact slopes.
    ``shift_um`` displaces it exactly (a phase ramp; the synthesis is periodic)."""
    rows, columns = shape
    ky = 2 * np.pi * np.fft.fftfreq(rows)[:, None]  # rad per pixel along rows (downward)
    kx = 2 * np.pi * np.fft.rfftfreq(columns)[None, :]
    k = np.hypot(kx, ky)
    k[0, 0] = np.inf
    amplitude = k ** (-(hurst + 1.0)) * np.exp(-((k * cutoff_px / (2 * np.pi)) ** 2))
    spectrum = amplitude * (rng.standard_normal(k.shape) + 1j * rng.standard_normal(k.shape))
    # the field sees skin coordinate x + shift: column c shows what column c + shift_x / pixel
    # showed (rows run against y), a phase ramp exp(i k . offset) in the spectrum
    spectrum = spectrum * np.exp(1j * (kx * shift_um[0] / pixel - ky * shift_um[1] / pixel))
    z = np.fft.irfft2(spectrum, s=shape)
    scale = rms_um / z.std() if z.std() > 0 else 0.0
    z *= scale
    dz_dcol = np.fft.irfft2(1j * kx * spectrum, s=shape) * scale / pixel
    dz_drow = np.fft.irfft2(1j * ky * spectrum, s=shape) * scale / pixel
    return z, dz_dcol, -dz_drow  # y is up: dz/dy = -dz/drow


def _smoothstep(t):
    t = np.clip(t, 0.0, 1.0)
    return t * t * (3 - 2 * t), 6 * t * (1 - t)


def cross_section_profile(shape, u):
    """Depth across a wrinkle as a fraction of its local depth, and its derivative, at
    u = 2 d / w (see the module notes for the three shapes)."""
    u = np.asarray(u, dtype=float)
    if shape == "G":
        s2 = GAUSSIAN_SIGMA_HALF_WIDTHS**2
        profile = np.exp(-u * u / (2 * s2))
        return profile, -u / s2 * profile
    inside = np.abs(u) < 1
    if shape == "V":
        a = V_ROUNDING
        top = np.sqrt(1 + a * a)
        root = np.sqrt(u * u + a * a)
        return np.where(inside, (top - root) / (top - a), 0.0), np.where(inside, -(u / root) / (top - a), 0.0)
    return np.where(inside, np.cos(np.pi * u / 2) ** 2, 0.0), np.where(inside, -np.pi / 2 * np.sin(np.pi * u), 0.0)


def geometric_measures(wrinkle: Wrinkle):
    """The wrinkle's measures by the definitions of ``docs/wrinkle-measures.md``, exact for
    its geometry (the ground truth of :func:`skintopo.wrinkles.measure_wrinkles`).

    With the depth d(s, t) = D e(s) f(u) (s along the centre line, t = u w / 2 across it, e
    the end taper, f the cross-section of :func:`cross_section_profile`):

    * centre line: t = 0 where e(s) >= 1/2; the smoothstep taper is at half depth half-way
      along it, so ``length_mm`` = (1 - T) L with T = ``END_TAPER``;
    * ``max_depth_um`` = D; ``mean_depth_um`` = D x the mean of e over the centre line,
      ((1 - 2T) + 2 (T / 2) m) / (1 - T) with m = 2 int_{1/2}^1 (3t^2 - 2t^3) dt = 0.8125;
    * ``mean_width_mm`` = the width where f >= 1/2 (the same at every s: e scales f);
    * ``volume_mm3`` = D (w / 2) int f du x int e ds = D (w / 2) int f du x (1 - T) L (exact
      also on an arc: the area element (1 - kappa t) adds an odd term that integrates to 0);
      ``cross_section_mm2`` = volume / length = D (w / 2) int f du;
    * ``orientation_deg``: the axial mean of the centre line's direction, which on a
      symmetric arc is its direction at the midpoint, ``orientation_deg`` mod 180.
    """
    import scipy.integrate
    import scipy.optimize

    taper = END_TAPER
    mean_envelope = ((1 - 2 * taper) + taper * 0.8125) / (1 - taper)
    half_u = scipy.optimize.brentq(lambda u: cross_section_profile(wrinkle.shape, u)[0] - 0.5, 0.0, 1.0 if wrinkle.shape != "G" else 5.0)
    reach = 1.0 if wrinkle.shape != "G" else 20 * GAUSSIAN_SIGMA_HALF_WIDTHS
    area_u = scipy.integrate.quad(lambda u: float(cross_section_profile(wrinkle.shape, u)[0]), -reach, reach, points=[0.0])[0]
    length_um = (1 - taper) * wrinkle.length_um
    cross_section_um2 = wrinkle.depth_um * wrinkle.width_um / 2 * area_u
    return {
        "length_mm": length_um / 1000,
        "orientation_deg": wrinkle.orientation_deg % 180.0,
        "mean_depth_um": wrinkle.depth_um * mean_envelope,
        "max_depth_um": wrinkle.depth_um,
        "mean_width_mm": 2 * half_u * wrinkle.width_um / 2 / 1000,
        "cross_section_mm2": cross_section_um2 * 1e-6,
        "volume_mm3": cross_section_um2 * length_um * 1e-9,
    }


def wrinkle_relief(x, y, wrinkle: Wrinkle):
    """Height, slopes and the fraction of local depth (for the mask) of one wrinkle."""
    theta = np.radians(wrinkle.orientation_deg)
    tangent = np.array([np.cos(theta), np.sin(theta)])
    normal = np.array([-np.sin(theta), np.cos(theta)])
    rx, ry = x - wrinkle.centre_um[0], y - wrinkle.centre_um[1]
    kappa = wrinkle.curvature_per_mm / 1000.0  # per micrometre
    if abs(kappa) < 1e-12:
        along = rx * tangent[0] + ry * tangent[1]
        signed = rx * normal[0] + ry * normal[1]
        d_along = np.broadcast_to(tangent, x.shape + (2,))
        d_signed = np.broadcast_to(normal, x.shape + (2,))
    else:
        radius = 1.0 / kappa  # signed; the centre of curvature lies at radius * normal
        cx, cy = radius * normal
        ox, oy = rx - cx, ry - cy
        rho = np.hypot(ox, oy)
        rho = np.where(rho == 0, 1e-9, rho)
        signed = np.sign(radius) * (abs(radius) - rho)  # positive on the line's normal side, as when straight
        # angle from the arc's midpoint (which lies at -radius * normal from the centre)
        start = np.arctan2(-normal[1] * radius, -normal[0] * radius)
        angle = np.angle(np.exp(1j * (np.arctan2(oy, ox) - start)))
        along = angle * radius
        radial = np.stack([ox / rho, oy / rho], axis=-1)
        d_signed = -np.sign(radius) * radial
        tangential = np.stack([-oy / rho, ox / rho], axis=-1)
        d_along = tangential * (abs(radius) / rho)[..., None] * np.sign(radius)
    half_width = wrinkle.width_um / 2
    profile, d_profile = cross_section_profile(wrinkle.shape, signed / half_width)
    half_length = wrinkle.length_um / 2
    taper_length = END_TAPER * wrinkle.length_um
    envelope, d_envelope = _smoothstep((half_length - np.abs(along)) / taper_length)
    d_envelope = d_envelope * (-np.sign(along)) / taper_length
    depth = wrinkle.depth_um
    z = -depth * envelope * profile
    dz_dsigned = -depth * envelope * d_profile / half_width
    dz_dalong = -depth * d_envelope * profile
    p = dz_dsigned * d_signed[..., 0] + dz_dalong * d_along[..., 0]
    q = dz_dsigned * d_signed[..., 1] + dz_dalong * d_along[..., 1]
    return z, p, q, envelope * profile


def pore_relief(x, y, pore: Pore):
    """(z, p, q, inside) of one pore (module notes), micrometres."""
    dx, dy = x - pore.centre_um[0], y - pore.centre_um[1]
    inside = dx * dx + dy * dy < pore.radius_um**2
    scale = pore.depth_um / pore.radius_um**2
    z = np.where(inside, -pore.depth_um + scale * (dx * dx + dy * dy), 0.0)
    return z, np.where(inside, 2 * scale * dx, 0.0), np.where(inside, 2 * scale * dy, 0.0), inside


def place_pores(spec: SurfaceSpec, seed, count, *, radius_um=(25.0, 250.0), depth_um=(20.0, 120.0)) -> SurfaceSpec:
    """``spec`` with ``count`` pores placed at random on the plateaus of the surface it makes
    with ``seed``: radius and depth log-uniform in their ranges, each pore's disc (and a ring
    of a quarter of its radius, at least 2 pixels, around it) clear of wrinkles (their relief below
    1 um), of furrows (the surface within 3 um of its 0.6 mm line-segment closing, a plateau)
    and of the other pores. The base surface is the same as without pores (they are added
    last). Raises SkinTopoError when the field has no room for that many."""
    from skintopo.filters import line_segment_closing_extremes

    base = make_surface(spec, seed=seed)
    rng = np.random.default_rng(seed)
    pixel = spec.pixel_um
    _, closed = line_segment_closing_extremes(base.height.z, base.height.spacing, 600.0, (0, 45, 90, 135))
    free = ((closed - base.height.z) < 3.0) & (base.wrinkle_depth < 1.0)
    x, y = _coordinates(base.height.shape, pixel, spec.shift_um)
    pores = []
    for _ in range(50 * count):
        if len(pores) == count:
            break
        radius = float(np.exp(rng.uniform(*np.log(radius_um))))
        depth = float(np.exp(rng.uniform(*np.log(depth_um))))
        reach = radius + max(0.25 * radius, 2 * pixel)
        half = np.array(base.height.shape) * pixel / 2 - reach
        if np.any(half <= 0):
            continue
        centre = (float(rng.uniform(-half[1], half[1]) + spec.shift_um[0]), float(rng.uniform(-half[0], half[0]) + spec.shift_um[1]))
        if any(np.hypot(centre[0] - p.centre_um[0], centre[1] - p.centre_um[1]) < reach + p.radius_um * 1.25 for p in pores):
            continue
        disc = (x - centre[0]) ** 2 + (y - centre[1]) ** 2 < reach**2
        if free[disc].all():
            pores.append(Pore(centre, radius, depth))
    if len(pores) < count:
        raise SkinTopoError(f"room for only {len(pores)} of {count} pores on the plateaus of this field")
    return replace(spec, pores=tuple(pores))


def validate_spec(spec: SurfaceSpec):
    """Raise SkinTopoError listing what is wrong with ``spec``."""
    problems = []
    rows, columns = spec.size_px
    if not (rows >= 16 and columns >= 16):
        problems.append(f"field size must be at least 16 x 16 pixels, got {rows} x {columns}")
    if not spec.pixel_um > 0:
        problems.append(f"pixel size must be positive, got {spec.pixel_um} um")
    field_um = min(rows, columns) * spec.pixel_um if spec.pixel_um > 0 else 0
    for i, w in enumerate(spec.wrinkles):
        if w.depth_um <= 0:
            problems.append(f"wrinkle {i}: depth must be positive, got {w.depth_um} um")
        if w.width_um <= 0:
            problems.append(f"wrinkle {i}: width must be positive, got {w.width_um} um")
        elif w.width_um >= field_um:
            problems.append(f"wrinkle {i}: width {w.width_um:g} um is not smaller than the field ({field_um:g} um)")
        if w.length_um <= 0:
            problems.append(f"wrinkle {i}: length must be positive, got {w.length_um} um")
        if w.shape not in SHAPES:
            problems.append(f"wrinkle {i}: shape must be one of {', '.join(SHAPES)}, got {w.shape!r}")
        if w.curvature_per_mm and abs(1000.0 / w.curvature_per_mm) < w.width_um:
            problems.append(f"wrinkle {i}: radius of curvature smaller than its width")
    if spec.microrelief:
        low, high = spec.furrow_depth_um
        if not 0 <= low <= high:
            problems.append(f"furrow depth range must be 0 <= low <= high, got {spec.furrow_depth_um}")
        if spec.plate_um <= 0 or spec.furrow_width_um <= 0:
            problems.append("plate size and furrow width must be positive")
        if spec.roughness_rms_um < 0 or not 0 < spec.hurst < 1:
            problems.append(f"roughness RMS must be >= 0 and the Hurst exponent in (0, 1), got {spec.roughness_rms_um}, {spec.hurst}")
    for i, pore in enumerate(spec.pores):
        if not (pore.radius_um > 0 and pore.depth_um > 0):
            problems.append(f"pore {i}: radius and depth must be positive, got {pore.radius_um}, {pore.depth_um} um")
    if spec.form_radius_mm is not None and spec.form_radius_mm <= 0:
        problems.append(f"form radius must be positive, got {spec.form_radius_mm} mm")
    if spec.form_shape not in ("cylinder", "sphere"):
        problems.append(f"form shape must be 'cylinder' or 'sphere', got {spec.form_shape!r}")
    elif spec.form_shape == "sphere" and spec.form_radius_mm is not None and spec.form_radius_mm > 0:
        corner_um = np.hypot(rows, columns) * spec.pixel_um / 2 + np.hypot(*spec.shift_um)
        if corner_um >= spec.form_radius_mm * 1000:
            problems.append(f"the field ({corner_um / 1000:.1f} mm to its corner) does not fit on a sphere of radius {spec.form_radius_mm} mm")
    if problems:
        raise SkinTopoError("invalid surface: " + "; ".join(problems))


def make_surface(spec: SurfaceSpec, seed=0) -> SkinSurface:
    """Build the surface described by ``spec``, reproducibly from ``seed``."""
    validate_spec(spec)
    rng = np.random.default_rng(seed)
    shape = tuple(spec.size_px)
    x, y = _coordinates(shape, spec.pixel_um, spec.shift_um)
    z = np.zeros(shape)
    p = np.zeros(shape)
    q = np.zeros(shape)
    if spec.microrelief:
        for component in (
            microrelief_furrows(x, y, rng, plate_um=spec.plate_um, depth_um=spec.furrow_depth_um, width_um=spec.furrow_width_um),
            fractal_roughness(shape, spec.pixel_um, rng, rms_um=spec.roughness_rms_um, hurst=spec.hurst,
                              cutoff_px=spec.roughness_cutoff_px, shift_um=spec.shift_um),
        ):
            z += component[0]
            p += component[1]
            q += component[2]
    labels = np.zeros(shape, dtype=np.int32)
    best_fraction = np.zeros(shape)
    wrinkle_depth = np.zeros(shape)
    for index, wrinkle in enumerate(spec.wrinkles):
        wz, wp, wq, fraction = wrinkle_relief(x, y, wrinkle)
        z += wz
        p += wp
        q += wq
        wrinkle_depth -= wz
        take = (fraction >= 0.5) & (fraction > best_fraction)
        labels[take] = index + 1
        best_fraction = np.maximum(best_fraction, fraction)
    pore_labels = np.zeros(shape, dtype=np.int32)
    for index, pore in enumerate(spec.pores):
        pz, pp, pq, inside = pore_relief(x, y, pore)
        z += pz
        p += pp
        q += pq
        pore_labels[inside] = index + 1
    if spec.form_radius_mm is not None and spec.form_shape == "sphere":
        radius = spec.form_radius_mm * 1000.0
        cap = np.sqrt(radius**2 - x**2 - y**2)
        z += cap - radius
        p += -x / cap
        q += -y / cap
    elif spec.form_radius_mm is not None:
        radius = spec.form_radius_mm * 1000.0
        z += -(x**2) / (2 * radius)
        p += -x / radius
    normals = np.stack([-p, -q, np.ones(shape)], axis=-1)
    normals /= np.linalg.norm(normals, axis=-1, keepdims=True)
    return SkinSurface(HeightMap(z, spec.pixel_um), p, q, normals, labels, wrinkle_depth, spec, pore_labels)


def random_wrinkle_spec(rng, *, size_px=384, pixel_um=20.0, microrelief=True, crossing=False) -> SurfaceSpec:
    """A field of two wrinkles drawn at random over the ranges that the wrinkle measures are
    validated on (issue 17): shape V, U or G; width 0.15-1.2 mm and depth 20-300 um (both
    log-uniform); length 2.5-5 mm; straight or (half of them) an arc of radius 5-50 mm.
    Without ``crossing`` the two run within 15 degrees of +x, one in each half of the field,
    apart; with it they cross near the centre at 30-90 degrees. The forehead's 80 mm cylinder
    is kept; ``microrelief`` adds the furrows and roughness."""
    field_um = size_px * pixel_um
    wrinkles = []
    first_angle = rng.uniform(-15.0, 15.0)
    for index in range(2):
        radius_mm = np.exp(rng.uniform(np.log(5.0), np.log(50.0)))
        curvature = rng.choice([-1.0, 1.0]) / radius_mm if rng.random() < 0.5 else 0.0
        if crossing:
            angle = first_angle + (rng.choice([-1.0, 1.0]) * rng.uniform(30.0, 90.0) if index else 0.0)
            centre = tuple(rng.uniform(-0.1, 0.1, 2) * field_um)
        else:
            angle = rng.uniform(-15.0, 15.0)
            centre = (rng.uniform(-0.05, 0.05) * field_um, (0.25 if index == 0 else -0.25) * field_um)
        wrinkles.append(Wrinkle(
            depth_um=float(np.exp(rng.uniform(np.log(20.0), np.log(300.0)))),
            width_um=float(np.exp(rng.uniform(np.log(150.0), np.log(1200.0)))),
            length_um=float(rng.uniform(2500.0, 5000.0)),
            orientation_deg=float(angle % 360.0), centre_um=centre, curvature_per_mm=float(curvature),
            shape=str(rng.choice(SHAPES)),
        ))
    return SurfaceSpec(size_px=(size_px, size_px), pixel_um=float(pixel_um), wrinkles=tuple(wrinkles), microrelief=microrelief)
