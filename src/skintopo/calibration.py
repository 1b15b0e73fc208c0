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

Matte (Lambertian) white sphere. The normal of every sphere pixel is known from the fitted
circle; I = e rho max(0, n . l) is solved for g = e rho l by least squares over the lit
pixels (above 10% of the image's maximum on the sphere, away from the terminator), giving
the direction g / |g| and the relative intensity |g| / max |g|.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import scipy.ndimage

from skintopo.acquisition import read_image
from skintopo.errors import SkinTopoError

HIGHLIGHT_LEVEL = 0.9
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
    if mask is None:
        from skimage.filters import threshold_otsu

        brightest = np.max([_grey(image) for image in images], axis=0)
        if not np.ptp(brightest) > 0:
            raise SkinTopoError("sphere not found: the images are uniform")
        # Otsu on log intensity: a chrome sphere's highlights (a few dozen saturated pixels per
        # light) would otherwise take the threshold for themselves and leave the dim sphere out
        level = np.log(np.maximum(brightest, 0.0) + 1e-3 * brightest.max())
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


def highlight_centroid(image, sphere, *, name="image", saturation=None):
    """Sub-pixel (x, y) of the specular highlight inside the sphere."""
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
    level = background + HIGHLIGHT_LEVEL * (peak - background)
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
    raw = [read_image(path) for path in paths]
    full_scale = [float(np.iinfo(image.dtype).max) if np.issubdtype(image.dtype, np.integer) else None for image in raw]
    images = [_grey(image) / (scale or 1.0) for image, scale in zip(raw, full_scale)]
    shapes = {image.shape for image in images}
    if len(shapes) > 1:
        raise SkinTopoError(f"sphere images differ in size: {sorted(shapes)}")
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
