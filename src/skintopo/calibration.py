"""Light calibration for a real device: light directions from a chrome (mirror) sphere or a
matte white sphere, with relative intensities from the matte one.

Chrome sphere. The sphere is found from a mask or, by default, automatically: the brightest
value each pixel takes over all images, thresholded (Otsu, on the logarithm of the
intensity, so that the highlights cannot take the threshold for themselves), its largest component, and a
least-squares circle through that component's boundary (Kasa fit) for the centre, and the
radius from its area. In each image the
specular highlight is the intensity-weighted centroid of the pixels within 10% of the
brightest value inside the sphere (a saturated highlight is a flat plateau whose centroid is
still its centre). The sphere normal there is n = ((x - cx) / r, -(y - cy) / r, n_z), image
rows running downward and y up, and the light is the mirror direction of the view vector
v = (0, 0, 1) (orthographic camera):

    L = 2 (n . v) n - v.

(Returning n instead of L is the classic bug: the light is twice as far from the view axis.)

Skin's diffusion profile (for the physically based height's scattering kernels,
:mod:`skintopo.physics`), from an image per band of an opaque black mask with a straight edge
laid on the skin (e.g. black tape), all LEDs on, through crossed polarisers (no surface
reflection): light entering the skin at x' >= 0 re-emerges spread by the radial profile R; the
part that re-emerges under the mask is lost. Averaged along the edge, the skin's radiance at
distance x from it is

    I(x) = A [(1 - w) + sum_k w_k Phi(x / sigma_k)],   x > 0,

for R = (1 - w) delta + sum_k w_k G(sigma_k) (Phi the standard normal distribution function:
the 1-D marginal of a 2-D Gaussian is a Gaussian of the same sigma). The widths sigma_k are a
fixed geometric ladder (ratio sqrt 2) from one pixel to a third of the skin's extent beside
the edge, not a chosen family: the weights, found by non-negative least squares, are the
profile, and heavy tails come out as weight on wide rungs. Narrower than a pixel is taken as
re-emerging where it entered; wider than a third of the profile is not measured.

The surface reflection's colour (for the cross-band separation,
:func:`skintopo.normals.separate_specular`), from two captures of the same skin under the same
lights and exposure: one through parallel polarisers (a linear polariser on the LEDs, the
camera's analyser parallel to it) and one through crossed ones. The surface reflection keeps
the light's polarisation and is blocked by the crossed analyser; the diffuse light,
depolarised by its scattering in the skin, passes either analyser by half. So per observation
(light i, band b; each light's relative intensity per band divided out) the difference is
the surface reflection alone,

    D_bi = I_bi(parallel) - I_bi(crossed) = T s_i w_b,

T the polarisers' transmission (the same in every band), s_i the observation's surface
reflection and w its colour. w_b = sum D_bi / sum mean_b(D_bi) over every observation finite
in every band: sums, so that the two captures' noise, of zero mean, averages out (taking only
the strongest differences would also take the noise that made them strongest, which noise
shared between the bands, a renderer's or a demosaiced camera's, would colour: on Mitsuba
renders it took a fifth off the colour's departure from white). The strongest differences
(the top ``SPECULAR_TOP_SHARE`` by mean_b D) only show that there is a reflection: they must
exceed the most negative ones, the noise, ``SPECULAR_OVER_NOISE`` times.

Matte (Lambertian) white sphere. The normal of every sphere pixel is known from the fitted
circle; I = e rho max(0, n . l) is solved for g = e rho l by least squares over the lit
pixels (above 10% of the image's maximum on the sphere, away from the terminator), giving
the direction g / |g| and the relative intensity |g| / max |g|.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import scipy.ndimage
import scipy.optimize
import scipy.special

from skintopo.acquisition import read_image
from skintopo.acquisition.manifest import IMAGE_SUFFIXES
from skintopo.device import Camera, Device, Led, aimed_at, check_device
from skintopo.errors import SkinTopoError
from skintopo.normals import checked_specular_colour
from skintopo.optics import BANDS, ScatteringProfile

HIGHLIGHT_LEVEL = 0.9
NEAR_HIGHLIGHT_LEVEL = 0.2  # near-field LED calibration: the spot's flanks too (a saturated plateau above 0.9 is a few pixels)
MIN_SPHERE_FRACTION = 0.005
MAX_SATURATED_FRACTION = 0.2


def _grey(image):
    image = np.asarray(image, dtype=np.float64)
    return image.mean(axis=2) if image.ndim == 3 else image


def fit_circle(points_xy):
    """Least-squares circle (Kasa): returns (cx, cy, r) in the points' units."""
    x, y = points_xy[:, 0], points_xy[:, 1]
    design = np.column_stack([2 * x, 2 * y, np.ones_like(x)])
    (cx, cy, c), *_ = np.linalg.lstsq(design, x * x + y * y, rcond=None)
    return float(cx), float(cy), float(np.sqrt(c + cx * cx + cy * cy))


def find_sphere(images, mask=None, *, names=None):
    """Centre (x, y) and radius of the sphere in pixels, from a mask or automatically.

    Raises
    ------
    SkinTopoError
        If no sphere-like bright round region is found.
    """
    region = sphere_region(images, mask)
    boundary = region & ~scipy.ndimage.binary_erosion(region)
    rows, columns = np.nonzero(boundary)
    cx, cy, r = fit_circle(np.column_stack([columns, rows]).astype(float))
    # A round region fills its fitted disc; anything else (a bright background, a blob) does not.
    fill = region.sum() / (np.pi * r * r)
    # The boundary pixels' centres lie about half a pixel inside the rim: the radius comes
    # from the area instead (a digitised disc of radius r holds pi r^2 pixel centres).
    r = float(np.sqrt(region.sum() / np.pi))
    if not 0.85 < fill < 1.15:
        raise SkinTopoError(f"sphere not found: the bright region is not round (it fills {fill:.0%} of its fitted circle)")
    return cx, cy, r


def sphere_region(images, mask=None):
    """The sphere's pixels (bool image): the mask if given, else the largest region of the
    brightest value each pixel takes, thresholded (Otsu on log intensity), holes filled."""
    if mask is None:
        from skimage.filters import threshold_otsu

        brightest = np.max([_grey(image) for image in images], axis=0)
        if not np.ptp(brightest) > 0:
            raise SkinTopoError("sphere not found: the images are uniform")
        # Otsu on log intensity: a chrome sphere's highlights (a few dozen saturated pixels per
        # light) would otherwise take the threshold for themselves and leave the dim sphere out;
        # the floor of 1% of the maximum keeps the sensor noise of a dark background from
        # splitting it (with 0.1%, a background of noise around 0 took the threshold)
        level = np.log(np.maximum(brightest, 0.0) + 1e-2 * brightest.max())
        region = level > threshold_otsu(level)
        labels, count = scipy.ndimage.label(region)
        if count == 0:
            raise SkinTopoError("sphere not found in the images")
        sizes = np.bincount(labels.ravel())
        sizes[0] = 0
        region = scipy.ndimage.binary_fill_holes(labels == np.argmax(sizes))
    else:
        region = np.asarray(mask, dtype=bool)
    if region.sum() < MIN_SPHERE_FRACTION * region.size:
        source = "the mask" if mask is not None else "the images"
        raise SkinTopoError(f"sphere not found: the largest bright region in {source} covers only {region.sum()} pixels")
    return region


def highlight_centroid(image, sphere, *, name="image", saturation=None, level=HIGHLIGHT_LEVEL):
    """Sub-pixel (x, y) of the specular highlight inside the sphere: the centroid of the
    pixels above ``level`` of the way from the sphere's median to its peak, weighted by how
    far above they are."""
    cx, cy, r = sphere
    grey = _grey(image)
    rows, columns = np.indices(grey.shape)
    inside = (columns - cx) ** 2 + (rows - cy) ** 2 <= (0.98 * r) ** 2
    values = grey[inside]
    peak = values.max()
    if saturation is not None and np.mean(values >= saturation) > MAX_SATURATED_FRACTION:
        raise SkinTopoError(f"{name}: {np.mean(values >= saturation):.0%} of the sphere is saturated; lower the exposure")
    background = np.median(values)
    if not peak > 3 * max(background, 1e-12):
        raise SkinTopoError(f"{name}: no specular highlight on the sphere (brightest {peak:.4g} vs median {background:.4g})")
    level = background + level * (peak - background)
    spot = inside & (grey >= level)
    labels, _ = scipy.ndimage.label(spot)
    brightest = labels[np.unravel_index(np.argmax(np.where(inside, grey, -np.inf)), grey.shape)]
    spot = labels == brightest
    weights = grey[spot] - level + 1e-12 * peak
    return float(np.average(columns[spot], weights=weights)), float(np.average(rows[spot], weights=weights))


def chrome_sphere_light(sphere, highlight_xy):
    """Light direction L = 2 (n . v) n - v from the highlight position on a mirror sphere."""
    cx, cy, r = sphere
    nx = (highlight_xy[0] - cx) / r
    ny = -(highlight_xy[1] - cy) / r
    planar = nx * nx + ny * ny
    if planar >= 1:
        raise SkinTopoError("the highlight lies on or outside the sphere's rim")
    normal = np.array([nx, ny, np.sqrt(1 - planar)])
    view = np.array([0.0, 0.0, 1.0])
    return 2 * (normal @ view) * normal - view


def sphere_normals(shape, sphere):
    """Unit normals of a sphere seen orthographically, NaN outside it."""
    cx, cy, r = sphere
    rows, columns = np.indices(shape)
    nx = (columns - cx) / r
    ny = -(rows - cy) / r
    nz2 = 1 - nx * nx - ny * ny
    with np.errstate(invalid="ignore"):
        normals = np.stack([nx, ny, np.sqrt(nz2)], axis=-1)
    normals[nz2 <= 0] = np.nan
    return normals


def matte_sphere_light(image, sphere, *, name="image", lit_fraction=0.1):
    """(direction, strength) from a Lambertian sphere by least squares over its lit pixels."""
    grey = _grey(image)
    normals = sphere_normals(grey.shape, sphere)
    on_sphere = np.isfinite(normals[..., 2]) & (normals[..., 2] > 0.1)  # away from the rim
    values = grey[on_sphere]
    lit = values > lit_fraction * values.max()
    if lit.sum() < 10:
        raise SkinTopoError(f"{name}: too few lit pixels on the matte sphere")
    g, *_ = np.linalg.lstsq(normals[on_sphere][lit], values[lit], rcond=None)
    strength = float(np.linalg.norm(g))
    return g / strength, strength


def read_grey_images(paths):
    """Grey images as fractions of full scale (integer images divided by their type's
    maximum), all of one size, and each one's full scale (None for float images)."""
    raw = [read_image(path) for path in paths]
    full_scale = [float(np.iinfo(image.dtype).max) if np.issubdtype(image.dtype, np.integer) else None for image in raw]
    images = [_grey(image) / (scale or 1.0) for image, scale in zip(raw, full_scale)]
    shapes = {image.shape for image in images}
    if len(shapes) > 1:
        raise SkinTopoError(f"calibration images differ in size: {sorted(shapes)}")
    return images, full_scale


def folder_images(folder):
    """The PNG and TIFF files of a folder, sorted by name (one per LED, in LED order)."""
    folder = Path(folder)
    if not folder.is_dir():
        raise SkinTopoError(f"{folder}: no such folder")
    paths = sorted(p for p in folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
    if not paths:
        raise SkinTopoError(f"{folder}: no PNG or TIFF images")
    return paths


def calibrate_lights(paths, *, mask=None, method="chrome", saturation=0.995):
    """Light directions (and, for a matte sphere, relative intensities) from sphere images.

    Parameters
    ----------
    paths : sequence of path
        One image of the sphere per light (PNG, TIFF or camera raw).
    mask : path or array, optional
        Sphere mask (non-zero inside); default: found automatically.
    method : ``"chrome"`` or ``"matte"``

    Returns
    -------
    dict
        ``sphere`` (centre and radius, pixels) and ``lights``: one entry per image with
        ``file``, ``light`` (unit vector, camera frame) and, for ``matte``, ``intensity``.
    """
    if method not in ("chrome", "matte"):
        raise SkinTopoError(f"unknown sphere method {method!r}; choose chrome or matte")
    if not paths:
        raise SkinTopoError("no sphere images given")
    images, full_scale = read_grey_images(paths)
    if mask is not None and not isinstance(mask, np.ndarray):
        mask_image = read_image(mask)
        mask = (mask_image.any(axis=2) if mask_image.ndim == 3 else mask_image > 0)
        if mask.shape != images[0].shape:
            raise SkinTopoError(f"sphere mask size {mask.shape} differs from the images {images[0].shape}")
    sphere = find_sphere(images, mask)
    lights = []
    for path, image, scale in zip(paths, images, full_scale):
        name = Path(path).name
        if method == "chrome":
            highlight = highlight_centroid(image, sphere, name=name, saturation=saturation if scale else None)
            lights.append({"file": name, "light": chrome_sphere_light(sphere, highlight).tolist(), "highlight_px": list(highlight)})
        else:
            direction, strength = matte_sphere_light(image, sphere, name=name)
            lights.append({"file": name, "light": direction.tolist(), "strength": strength})
    if method == "matte":
        strongest = max(entry["strength"] for entry in lights)
        for entry in lights:
            entry["intensity"] = entry.pop("strength") / strongest
    return {"sphere": {"centre_px": [sphere[0], sphere[1]], "radius_px": sphere[2]}, "method": method, "lights": lights}


# Near-field LEDs (skintopo.device): positions from a chrome sphere seen at two or more
# places, emission (principal direction, mu, intensity) from a flat matte target.


def sphere_centre_from_silhouette(region, camera: Camera, radius_mm):
    """Centre (mm, camera frame) of a sphere of known radius from its silhouette.

    Under a perspective camera every ray through the silhouette's rim is tangent to the
    sphere: its distance to the centre C is the radius, |C x r| = R for unit rays r. The rim
    is the 0.5 level line of the region (sub-pixel, scikit-image's marching squares); C
    comes from nonlinear least squares (SciPy), started on the ray through the region's
    centroid at the distance its area implies.
    """
    from skimage.measure import find_contours

    region = np.asarray(region, dtype=bool)
    contours = find_contours(np.pad(region, 1).astype(float), 0.5)
    rim = max(contours, key=len) - 1  # (row, column), undo the padding
    a, b = camera.rays(rim[:, 1], rim[:, 0])
    rays = np.stack([a, b, -np.ones_like(a)], axis=1)
    rays /= np.linalg.norm(rays, axis=1, keepdims=True)
    rows, columns = np.nonzero(region)
    ca, cb = camera.rays(columns.mean(), rows.mean())
    towards = np.array([ca, cb, -1.0]) / np.linalg.norm([ca, cb, -1.0])
    angular_radius = np.sqrt(region.sum() / np.pi) / camera.focal_length_px
    start = towards * radius_mm / np.sin(angular_radius)

    def distance_to_rays(centre):
        return np.linalg.norm(np.cross(centre, rays), axis=1) - radius_mm

    return scipy.optimize.least_squares(distance_to_rays, start, x_scale="jac").x


def mirror_ray(camera: Camera, highlight_xy, centre_mm, radius_mm):
    """(point, direction) of the ray a mirror sphere reflects toward the light from the
    highlight at image position ``highlight_xy``: the camera ray r meets the sphere at P with
    normal N = (P - C) / R and leaves along m = r - 2 (r . N) N."""
    a, b = camera.rays(highlight_xy[0], highlight_xy[1])
    ray = np.array([a, b, -1.0]) / np.linalg.norm([a, b, -1.0])
    along = ray @ centre_mm
    discriminant = along**2 - (centre_mm @ centre_mm - radius_mm**2)
    if discriminant < 0:
        raise SkinTopoError("the highlight's ray misses the fitted sphere")
    point = (along - np.sqrt(discriminant)) * ray
    normal = (point - centre_mm) / radius_mm
    return point, ray - 2 * (ray @ normal) * normal


def closest_point_to_lines(points, directions):
    """The point nearest (least squares) to lines through ``points`` along ``directions``:
    sum_k (I - m_k m_k^T) X = sum_k (I - m_k m_k^T) P_k. Also returns the RMS distance."""
    directions = np.asarray(directions, dtype=float)
    directions = directions / np.linalg.norm(directions, axis=1, keepdims=True)
    projectors = np.eye(3)[None] - directions[:, :, None] * directions[:, None, :]
    point = np.linalg.solve(projectors.sum(axis=0), np.einsum("kij,kj->i", projectors, points))
    offsets = np.einsum("kij,kj->ki", projectors, point - np.asarray(points, dtype=float))
    return point, float(np.sqrt(np.mean(np.sum(offsets**2, axis=1))))


def led_positions_from_chrome_spheres(image_sets, camera: Camera, radius_mm, *, saturation=None):
    """LED positions (mm, camera frame) from a chrome sphere of known radius imaged at two or
    more places, one image per LED at each place (the same LED order everywhere).

    Each place gives the sphere's centre (:func:`sphere_centre_from_silhouette`) and, per LED,
    the reflected ray through its highlight (:func:`mirror_ray`); the LED is the point
    nearest to its rays (:func:`closest_point_to_lines`). Returns the positions (m, 3) and
    the details (sphere centres, the rays' RMS miss distance per LED, mm).
    """
    if len(image_sets) < 2:
        raise SkinTopoError(f"LED positions need the chrome sphere at two or more places, got {len(image_sets)}")
    counts = {len(images) for images in image_sets}
    if len(counts) != 1:
        raise SkinTopoError(f"every place needs one image per LED; got {sorted(len(images) for images in image_sets)} images")
    rays = []
    centres = []
    for place, images in enumerate(image_sets, start=1):
        images = [_grey(image) for image in images]
        region = sphere_region(images)
        centre = sphere_centre_from_silhouette(region, camera, radius_mm)
        circle = find_sphere(images, region)
        centres.append(centre)
        rays.append([mirror_ray(camera, highlight_centroid(image, circle, name=f"place {place}, LED {i + 1}", saturation=saturation,
                                                           level=NEAR_HIGHLIGHT_LEVEL), centre, radius_mm)
                     for i, image in enumerate(images)])
    positions, misses = [], []
    for led in range(counts.pop()):
        point, miss = closest_point_to_lines([r[led][0] for r in rays], [r[led][1] for r in rays])
        positions.append(point)
        misses.append(miss)
    return np.array(positions), {"sphere_centres_mm": np.array(centres).tolist(), "ray_miss_rms_mm": misses}


def led_emission_from_flat_target(image, camera: Camera, position_mm, depth_mm, *, step=4, lit_fraction=0.05):
    """(direction, mu, strength) of one LED from an image of a flat matte target facing the
    camera at ``depth_mm``.

    The target's points P = depth (a, b, -1) show I = k (cos theta)^mu (n . (L - P)) / |L - P|^3,
    n = (0, 0, 1), cos theta = d . (P - L) / |P - L|: log I is fitted for log k, mu and the
    principal direction d (two angles) by nonlinear least squares over every ``step``-th
    pixel lit above ``lit_fraction`` of the maximum. The image must be corrected for the
    camera's own vignetting (flat-field of the camera, not of the LEDs).
    """
    grey = _grey(image)[::step, ::step]
    rows, columns = np.mgrid[0 : grey.shape[0], 0 : grey.shape[1]] * step
    a, b = camera.rays(columns, rows)
    lit = grey > lit_fraction * grey.max()
    if lit.sum() < 20:
        raise SkinTopoError("too few lit pixels on the flat target")
    points = depth_mm * np.stack([a[lit], b[lit], -np.ones(lit.sum())], axis=1)
    towards = np.asarray(position_mm, dtype=float) - points
    distance = np.linalg.norm(towards, axis=1)
    geometric = np.log(towards[:, 2] / distance**3)  # n . (L - P) / |L - P|^3 with n = (0, 0, 1)
    observed = np.log(grey[lit])
    aim = -np.asarray(position_mm, dtype=float) + np.array([0.0, 0.0, -depth_mm])
    aim /= np.linalg.norm(aim)

    def direction(angles):
        polar, azimuth = angles
        return np.array([np.sin(polar) * np.cos(azimuth), np.sin(polar) * np.sin(azimuth), -np.cos(polar)])

    def residual(parameters):
        log_k, mu, polar, azimuth = parameters
        cos_theta = -(towards @ direction((polar, azimuth))) / distance
        return log_k + mu * np.log(np.maximum(cos_theta, 1e-9)) + geometric - observed

    start_polar = np.arccos(-aim[2])
    start = [float(np.median(observed - geometric)), 1.0, start_polar, np.arctan2(aim[1], aim[0])]
    fit = scipy.optimize.least_squares(residual, start, x_scale="jac")
    log_k, mu, polar, azimuth = fit.x
    return direction((polar, azimuth)), float(mu), float(np.exp(log_k))


def calibrate_device(camera: Camera, working_distance_mm, chrome_image_sets, sphere_radius_mm, *, flat_images=None,
                     flat_depth_mm=None, names=None, saturation=None):
    """A :class:`~skintopo.device.Device` from calibration images: LED positions from the
    chrome sphere at two or more places, and, with ``flat_images`` (one per LED, the flat
    matte target at ``flat_depth_mm``, default the working distance), each LED's principal
    direction, mu and relative intensity (the same in every band); without them the LEDs are
    taken as aimed at the field centre with mu = 1 and equal intensities. Returns the device
    and the calibration details (JSON-ready)."""
    positions, details = led_positions_from_chrome_spheres(chrome_image_sets, camera, sphere_radius_mm, saturation=saturation)
    names = list(names) if names else [f"led{i + 1}" for i in range(len(positions))]
    if len(names) != len(positions):
        raise SkinTopoError(f"{len(names)} LED names for {len(positions)} LEDs")
    target = (0.0, 0.0, -working_distance_mm)
    leds = []
    if flat_images is not None:
        if len(flat_images) != len(positions):
            raise SkinTopoError(f"{len(flat_images)} flat-target images for {len(positions)} LEDs: one per LED")
        depth = working_distance_mm if flat_depth_mm is None else flat_depth_mm
        emission = [led_emission_from_flat_target(image, camera, position, depth) for image, position in zip(flat_images, positions)]
        strongest = max(strength for _, _, strength in emission)
        for name, position, (direction, mu, strength) in zip(names, positions, emission):
            share = strength / strongest
            leds.append(Led(name, tuple(map(float, position)), tuple(map(float, direction)), mu,
                            {"red": share, "green": share, "blue": share}))
        details["flat_depth_mm"] = depth
    else:
        leds = [Led(name, tuple(map(float, position)), aimed_at(position, target)) for name, position in zip(names, positions)]
    device = Device(camera, tuple(leds), float(working_distance_mm), description="calibrated with skintopo.calibration.calibrate_device")
    problems, _ = check_device(device)
    if problems:
        raise SkinTopoError("the calibrated device is not usable: " + "; ".join(problems))
    return device, details


SPECULAR_COLOUR_FORMAT = "skintopo-specular-colour"
SPECULAR_TOP_SHARE = 0.1  # the observations with the strongest surface reflection, which must stand out of the noise
SPECULAR_OVER_NOISE = 3.0  # the strongest differences must exceed the strongest opposite ones (noise) this many times


def specular_colour_from_polarised(parallel, crossed, *, top_share=SPECULAR_TOP_SHARE):
    """The surface reflection's colour from a parallel- and a cross-polarised capture of the
    same skin (module notes).

    Parameters
    ----------
    parallel, crossed : skintopo.acquisition.Acquisition
        The two captures: the same camera, lights (or LEDs), exposure and pose; red, green and
        blue in both.
    top_share : float
        Share of the observations, strongest difference first, that must show a reflection.

    Returns
    -------
    colour : tuple of 3 floats
        Red, green, blue, scaled to a mean of 1 (what ``--specular-colour`` takes).
    record : dict
        Observations used; of the strongest differences, how many, their share of the
        parallel capture's light, and the spread (quartiles) of their per-observation colour.
    """
    names = f"{parallel.source} (parallel) and {crossed.source} (crossed)"
    missing = {str(a.source): [b for b in BANDS if b not in a.bands] for a in (parallel, crossed)}
    missing = {source: bands for source, bands in missing.items() if bands}
    if missing:
        raise SkinTopoError("the surface reflection's colour needs red, green and blue in both captures; missing: "
                            + "; ".join(f"{source}: {', '.join(bands)}" for source, bands in missing.items()))
    if parallel.shape != crossed.shape:
        raise SkinTopoError(f"{names}: images of {parallel.shape} and {crossed.shape} pixels: the two captures must be taken "
                            "with the same camera")
    for band in BANDS:
        one, other = parallel.bands[band], crossed.bands[band]
        if len(one.images) != len(other.images) or not np.allclose(one.lights, other.lights, atol=1e-3) or one.leds != other.leds:
            raise SkinTopoError(f"{names}: the {band} images were not taken under the same lights ({len(one.images)} and "
                                f"{len(other.images)} images): the two captures must use the same lights, in the same order")
    inside = parallel.mask & crossed.mask
    return specular_colour_from_differences({b: parallel.bands[b].images[:, inside] for b in BANDS},
                                            {b: crossed.bands[b].images[:, inside] for b in BANDS}, top_share=top_share, name=names)


def specular_colour_from_differences(parallel, crossed, *, top_share=SPECULAR_TOP_SHARE, name="the captures"):
    """:func:`specular_colour_from_polarised` on arrays: ``parallel`` and ``crossed`` map red,
    green and blue to observations of the same shape (any), each light's relative intensity
    divided out; NaN: left out. ``name`` names the captures in errors. Returns (colour,
    record) as that function."""
    difference = np.stack([np.asarray(parallel[b], dtype=np.float64) - np.asarray(crossed[b], dtype=np.float64) for b in BANDS])
    difference = difference.reshape(3, -1)
    level = np.stack([np.asarray(parallel[b], dtype=np.float64) for b in BANDS]).reshape(3, -1).mean(axis=0)
    usable = np.isfinite(difference).all(axis=0) & np.isfinite(level)
    difference, level = difference[:, usable], level[usable]
    if difference.shape[1] < 100:
        raise SkinTopoError(f"{name}: fewer than 100 observations unsaturated in every band inside both masks")
    mean = difference.mean(axis=0)
    strongest = mean >= np.quantile(mean, 1 - top_share)
    # the noise of two captures is symmetric: the most negative differences show how far it reaches
    signal, opposite = float(mean[strongest].mean()), float(-mean[mean <= np.quantile(mean, top_share)].mean())
    share = float(mean[strongest].sum() / max(level[strongest].sum(), np.finfo(float).tiny))
    if signal < SPECULAR_OVER_NOISE * max(opposite, 0.0):
        hint = ("the crossed capture is the brighter one: are the two swapped?" if opposite >= SPECULAR_OVER_NOISE * max(signal, 0.0)
                else "are the polarisers parallel in the first capture and crossed in the second?")
        raise SkinTopoError(f"{name}: no surface reflection found: the largest differences parallel minus crossed ({signal:.3g}) are "
                            f"not {SPECULAR_OVER_NOISE:g}x the largest opposite ones ({opposite:.3g}: the two captures' noise); {hint}")
    totals = difference.sum(axis=1)
    if not (totals > 0).all():
        raise SkinTopoError(f"{name}: the difference is not positive in every band ({dict(zip(BANDS, totals.round(6).tolist()))}): "
                            "the captures differ by more than the surface reflection (exposure, pose or lights changed?)")
    colour = totals / totals.mean()
    ratios = difference[:, strongest] / mean[strongest]  # their spread: how well one colour describes them
    record = {"observations": int(mean.size), "observations_strongest": int(strongest.sum()),
              "specular_share_of_parallel_light": share,
              "per_observation_quartiles": {b: np.percentile(r, [25, 50, 75]).round(4).tolist() for b, r in zip(BANDS, ratios)}}
    return tuple(float(c) for c in colour), record


def write_specular_colour(path, colour, *, record=None, source=None):
    """Write the surface reflection's colour as JSON (``--specular-colour FILE``)."""
    from skintopo.outputs import write_json_atomic

    write_json_atomic(Path(path), {"format": SPECULAR_COLOUR_FORMAT, "version": 1, "specular_colour": list(colour),
                                   "source": source, "fit": record})


def _read_calibration_file(path, file_format, what, command):
    """The JSON object of a calibration file of ``file_format``; a clear error naming the file
    (and the ``command`` that writes one) otherwise."""
    import json

    path = Path(path)
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as error:
        raise SkinTopoError(f"{path}: cannot read {what} ({error})") from None
    if not isinstance(data, dict) or data.get("format") != file_format:
        raise SkinTopoError(f"{path}: not a {what} file (format {file_format!r} expected; write one with 'skintopo {command}')")
    return data


def read_specular_colour(path):
    """The (red, green, blue) colour of a file of :func:`write_specular_colour`; a clear
    error naming the file otherwise."""
    data = _read_calibration_file(path, SPECULAR_COLOUR_FORMAT, "specular-colour", "calibrate highlight")
    try:
        return checked_specular_colour(data.get("specular_colour"))
    except SkinTopoError as error:
        raise SkinTopoError(f"{path}: {error}") from None


DIFFUSION_FORMAT = "skintopo-diffusion-profiles"
MIN_EDGE_SKIN_PX = 30  # the skin beside the edge must span this many pixels (a ladder of several widths)


def diffusion_profile_from_edge(image, pixel_um, *, name="image"):
    """Skin's radial diffusion profile from an image of an opaque straight edge on it
    (module notes).

    Parameters
    ----------
    image : ndarray (rows, columns)
        Linear image of one band; the mask is the dark side, on any side of the field.
    pixel_um : float
        Pixel size on the skin, micrometres.
    name : str
        The image's name in error messages.

    Returns
    -------
    profile : :class:`skintopo.optics.ScatteringProfile`
        Weights and widths (0: the light that re-emerges where it entered).
    record : dict
        The edge found (angle, the skin's extent beside it), the level A, the widths tried and
        the fit's RMS misfit relative to A.
    """
    image = np.asarray(image, dtype=float)
    if image.ndim != 2 or not np.isfinite(image).all():
        raise SkinTopoError(f"{name}: need one finite grey image of one band")
    low, high = np.percentile(image, [2, 98])
    # a quarter of the way up: right beside the edge the skin is only half as bright as far from it
    # when no light re-emerges where it entered (w = 1), so a mid-level threshold would take skin for mask
    dark = image < low + (high - low) / 4
    if high <= 2 * max(low, 0) or not 0.1 < dark.mean() < 0.9:
        raise SkinTopoError(f"{name}: no dark mask found: an edge image needs an opaque black mask over 10-90% of the field "
                            f"(dark share {dark.mean():.2f}, 2nd/98th percentiles {low:.3g}/{high:.3g})")
    # turn the image so that the mask lies on the left: the dark share falls along the columns
    across_columns = np.ptp(dark.mean(axis=0)) >= np.ptp(dark.mean(axis=1))
    if not across_columns:
        image, dark = image.T, dark.T
    if dark[:, 0].mean() < dark[:, -1].mean():
        image, dark = image[:, ::-1], dark[:, ::-1]
    rows = np.arange(image.shape[0], dtype=float)
    edge = dark.sum(axis=1).astype(float)  # per row, the number of dark pixels: where the mask ends
    slope, offset = np.polyfit(rows, edge, 1)
    misfit = edge - (offset + slope * rows)
    if np.sqrt(np.mean(misfit**2)) > 2.0:
        raise SkinTopoError(f"{name}: the mask's edge is not straight (the edge points scatter by {np.sqrt(np.mean(misfit**2)):.1f} px "
                            "RMS about a line): lay a straight-edged mask")
    columns = np.arange(image.shape[1], dtype=float)
    # distance of each pixel centre from the edge line, on the skin side (pixel k spans [k, k + 1])
    distance = (columns[None, :] + 0.5 - (offset + slope * rows[:, None])) / np.hypot(1.0, slope) * pixel_um
    skin = distance >= 1.5 * pixel_um  # whole pixels beside the edge (the ones it crosses are mixed)
    extent = float(distance[skin].max()) if skin.any() else 0.0
    if extent < MIN_EDGE_SKIN_PX * pixel_um:
        raise SkinTopoError(f"{name}: only {extent / pixel_um:.0f} px of skin beside the mask's edge; at least {MIN_EDGE_SKIN_PX} needed")
    width = pixel_um / 2  # mean radiance in bins of half a pixel of distance
    index = np.floor(distance[skin] / width).astype(int)
    count = np.bincount(index)
    used = count > 0
    x = np.bincount(index, distance[skin])[used] / count[used]
    radiance = np.bincount(index, image[skin])[used] / count[used]
    ladder = pixel_um * np.sqrt(2.0) ** np.arange(64)
    ladder = ladder[ladder <= extent / 3]
    design = np.column_stack([np.ones_like(x), scipy.special.ndtr(x[:, None] / ladder[None, :])])
    weight = np.sqrt(count[used])
    coefficients, _ = scipy.optimize.nnls(design * weight[:, None], radiance * weight)
    level = float(coefficients.sum())
    if level <= 0:
        raise SkinTopoError(f"{name}: the skin beside the edge is not brighter than the mask")
    widths = np.concatenate([[0.0], ladder])
    keep = coefficients > 0
    profile = ScatteringProfile(tuple(float(w) for w in coefficients[keep] / level), tuple(float(s) for s in widths[keep]))
    rms = float(np.sqrt(np.average((design @ coefficients - radiance) ** 2, weights=count[used])) / level)
    record = {"edge_angle_deg": float(np.degrees(np.arctan(slope))), "edge_across": "columns" if across_columns else "rows",
              "skin_extent_um": extent, "level": level, "widths_tried_um": [float(ladder[0]), float(ladder[-1])],
              "rms_misfit_relative": rms}
    return profile, record


def write_diffusion_profiles(path, profiles, *, pixel_um, records=None, source=None):
    """Write band -> :class:`~skintopo.optics.ScatteringProfile` as JSON (``--physics-kernels FILE``)."""
    from skintopo.outputs import write_json_atomic

    write_json_atomic(Path(path), {
        "format": DIFFUSION_FORMAT, "version": 1, "pixel_um": pixel_um, "source": source,
        "bands": {band: {"weights": list(p.weights), "sigmas_um": list(p.sigmas_um),
                         "transfer_at_cycles_per_mm": {str(f): round(float(p.transfer(f / 1000)), 4) for f in (0.5, 1, 2, 4, 8)},
                         **({"fit": records[band]} if records else {})} for band, p in profiles.items()}})


def read_diffusion_profiles(path):
    """band -> :class:`~skintopo.optics.ScatteringProfile` from a file of
    :func:`write_diffusion_profiles`; a clear error naming the file otherwise."""
    path = Path(path)
    data = _read_calibration_file(path, DIFFUSION_FORMAT, "diffusion-profile", "calibrate skin")
    bands = data.get("bands") or {}
    missing = [band for band in BANDS if band not in bands]
    if missing:
        raise SkinTopoError(f"{path}: no diffusion profile for {missing}")
    try:
        return {band: ScatteringProfile(tuple(map(float, bands[band]["weights"])), tuple(map(float, bands[band]["sigmas_um"])))
                for band in BANDS}
    except (KeyError, TypeError, ValueError) as error:
        raise SkinTopoError(f"{path}: a band's profile needs 'weights' and 'sigmas_um' ({error})") from None
