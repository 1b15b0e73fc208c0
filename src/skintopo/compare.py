"""Before/after comparison between visits: registration, difference map, parameter changes.

Registration of a follow-up height map onto the baseline (rigid: rotation and translation,
optionally a small scale), in two steps:

1. coarse: rotation from the phase correlation of the log-polar magnitude spectra (Reddy &
   Chatterji 1996, via scikit-image), then the translation by phase correlation;
2. fine: the parameters minimising a robust (Cauchy) misfit sum log(1 + (r / c)^2) between
   the baseline and the warped follow-up (cubic splines filtered once, form-levelled maps,
   interior only; ``scipy.optimize.least_squares`` with ``loss="cauchy"``), so that what
   changed between the visits (a treated wrinkle) weighs little. The Cauchy scale c is
   2.385 x the median absolute residual after the coarse step.

The residual misalignment is measured afterwards: tile-wise phase correlation (4 x 4 tiles)
between the baseline and the registered follow-up; its RMS, in pixels, is reported. The
albedo images, when given, are carried by the same transform (:func:`apply_registration`) and
their residual misalignment is measured the same way: an independent check, since the albedo
did not drive the registration.

Visits with different pixel sizes are refused (resampling silently would change every
texture parameter); no overlap is refused; a visit with no wrinkles compares its texture and
reports its wrinkles as unmatched.

Repeatability: comparing the baseline with repeat captures of the same unchanged skin gives
each parameter's noise; :func:`detection_limits` turns one or more such pairs into the
smallest detectable change (a prediction limit in the sense of ISO 5725-6's repeatability
limit, with Student's t for the few degrees of freedom; see there).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.ndimage
import scipy.optimize
from skimage.registration import phase_cross_correlation
from skimage.transform import warp_polar

from skintopo.defaults import DEFAULT_DETECTION_CONFIDENCE
from skintopo.errors import SkinTopoError
from skintopo.filters import polynomial_form
from skintopo.heightmap import HeightMap

CAUCHY_FACTOR = 2.385
MIN_DEGREES_OF_FREEDOM = 5  # detection limits from fewer differences come with a warning


@dataclass(frozen=True)
class Registration:
    """Follow-up -> baseline transform (pixels, degrees counter-clockwise in the image as
    displayed, scale) and the residual misalignment after it (pixels RMS)."""

    shift_px: tuple
    rotation_deg: float
    scale: float
    residual_px: float


def _levelled(height: HeightMap):
    return np.where(height.mask, height.z - polynomial_form(height.z, height.spacing, 2, height.mask), 0.0)


def _warp(image, shift, angle_deg, scale, order=3, cval=np.nan, prefilter=True):
    """Sample ``image`` at the follow-up positions of baseline pixels: x_f = s R (x_b - c) + c - t.

    ``prefilter=False`` takes ``image`` as spline coefficients already
    (``scipy.ndimage.spline_filter``), so that repeated warps of one image filter it once."""
    rows, columns = image.shape
    centre = np.array([(rows - 1) / 2, (columns - 1) / 2])
    theta = np.radians(angle_deg)
    rotation = np.array([[np.cos(theta), np.sin(theta)], [-np.sin(theta), np.cos(theta)]]) * scale
    offset = centre - rotation @ centre - np.asarray(shift)
    return scipy.ndimage.affine_transform(image, rotation, offset=offset, order=order, mode="constant", cval=cval, prefilter=prefilter)


def _coarse(fixed, moving):
    radius = min(fixed.shape) // 2
    window = np.outer(np.hanning(fixed.shape[0]), np.hanning(fixed.shape[1]))
    spectra = [np.abs(np.fft.fftshift(np.fft.fft2(image * window))) for image in (fixed, moving)]
    polar = [warp_polar(np.log1p(s), radius=radius, scaling="log") for s in spectra]
    shifts, _, _ = phase_cross_correlation(polar[0], polar[1], upsample_factor=20)
    angle = -shifts[0] * 360.0 / polar[0].shape[0]
    angle = (angle + 90) % 180 - 90  # the magnitude spectrum is point-symmetric: angles modulo 180
    best = None
    for candidate in (angle, angle + 180):
        rotated = np.nan_to_num(_warp(moving, (0, 0), candidate, 1.0, order=1))
        shift, error, _ = phase_cross_correlation(fixed, rotated, upsample_factor=10)
        if best is None or error < best[2]:
            best = (candidate, shift, error)
    return best[0], best[1]


def register_visits(baseline: HeightMap, follow_up: HeightMap, *, allow_scale=False, margin_fraction=0.15):
    """Rigid (optionally similarity) registration of ``follow_up`` onto ``baseline``.

    Returns
    -------
    aligned : HeightMap
        The follow-up resampled on the baseline grid (NaN where it has no data).
    registration : Registration
    """
    if not np.allclose(baseline.spacing, follow_up.spacing, rtol=1e-6):
        raise SkinTopoError(
            f"the visits have different pixel sizes ({baseline.spacing[1]:g} and {follow_up.spacing[1]:g} um): "
            "refusing to compare (resample one to the other's pixel size first)"
        )
    if baseline.shape != follow_up.shape:
        raise SkinTopoError(f"the visits have different sizes ({baseline.shape} and {follow_up.shape} pixels)")
    fixed, moving = _levelled(baseline), _levelled(follow_up)
    angle, shift = _coarse(fixed, moving)
    rows, columns = fixed.shape
    margin = int(margin_fraction * min(rows, columns)) + int(np.ceil(np.abs(shift).max()))
    interior = (slice(margin, rows - margin), slice(margin, columns - margin))
    if min(rows, columns) - 2 * margin < 16:
        raise SkinTopoError(f"the visits do not overlap enough to compare (coarse shift {shift[0]:.1f}, {shift[1]:.1f} pixels)")
    target = fixed[interior]
    coefficients = scipy.ndimage.spline_filter(moving, order=3)  # once, not at every evaluation

    def residual(parameters):
        dy, dx, theta = parameters[:3]
        scale = parameters[3] if allow_scale else 1.0
        return _warp(coefficients, (dy, dx), theta, scale, prefilter=False)[interior] - target

    start = np.array([shift[0], shift[1], angle] + ([1.0] if allow_scale else []))
    first = residual(start)
    ok = np.isfinite(first)
    if ok.mean() < 0.5 or np.corrcoef(first[ok] + target[ok], target[ok])[0, 1] < 0.3:
        raise SkinTopoError("the visits do not overlap: no consistent alignment of the same skin was found")
    scale_c = CAUCHY_FACTOR * 1.4826 * np.median(np.abs(first[ok] - np.median(first[ok])))

    def finite_residual(parameters):  # a sample warped in from outside the follow-up weighs nothing
        r = residual(parameters).ravel()
        return np.where(np.isfinite(r), r, 0.0)

    # sum of log(1 + (r / c)^2): the Cauchy misfit, by trust-region least squares
    result = scipy.optimize.least_squares(finite_residual, start, loss="cauchy", f_scale=scale_c, x_scale=np.ones_like(start),
                                          diff_step=1e-4, xtol=1e-8, ftol=1e-10)
    parameters = result.x
    dy, dx, theta = parameters[:3]
    scale = float(parameters[3]) if allow_scale else 1.0
    aligned = _warp(np.where(follow_up.mask, follow_up.z, np.nan), (dy, dx), theta, scale, order=1)
    aligned_height = HeightMap(aligned, baseline.spacing)
    misalignment = residual_misalignment(fixed, np.nan_to_num(_warp(moving, (dy, dx), theta, scale)))
    return aligned_height, Registration((float(dy), float(dx)), float(theta), scale, misalignment)


def apply_registration(image, registration: Registration, *, order=1):
    """An image of the follow-up visit (its albedo, say) resampled onto the baseline grid
    with the transform found from the height maps (bilinear by default; NaN outside)."""
    image = np.asarray(image, dtype=float)
    if image.ndim != 2:
        raise SkinTopoError(f"apply_registration needs a single-channel image, got shape {image.shape}")
    return _warp(image, registration.shift_px, registration.rotation_deg, registration.scale, order=order)


def residual_misalignment(fixed, moving, tiles=4):
    """RMS (pixels) of the local shifts between two registered maps, one per tile of a
    tiles x tiles grid, each found by Lucas-Kanade least squares (the shift d minimising
    sum (moving(x + d) - fixed(x))^2 over the tile, linearised and iterated three times).
    Phase correlation is not used here: for sub-pixel shifts of smooth content its peak
    stays on the integer lag (a 0.5 px offset of a smooth albedo read as 0.0 in a test)."""
    rows, columns = fixed.shape
    th, tw = rows // tiles, columns // tiles
    border = 3  # pixels at each tile edge left out of the sums (the shifted tile's edge values are guessed)
    shifts = []
    for i in range(tiles):
        for j in range(tiles):
            a = np.asarray(fixed[i * th : (i + 1) * th, j * tw : (j + 1) * tw], dtype=float)
            b = np.asarray(moving[i * th : (i + 1) * th, j * tw : (j + 1) * tw], dtype=float)
            inner = (slice(border, -border), slice(border, -border))
            gradient = np.stack([g[inner].ravel() for g in np.gradient(a)], axis=1)
            normal = gradient.T @ gradient
            if a.shape[0] <= 2 * border or a.shape[1] <= 2 * border or np.linalg.cond(normal) > 1e8:
                continue  # a flat or tiny tile says nothing about alignment
            d = np.zeros(2)
            for _ in range(3):
                back = scipy.ndimage.shift(b, -d, order=3, mode="nearest")  # moving(x + d)
                d -= np.linalg.solve(normal, gradient.T @ (back[inner] - a[inner]).ravel())
            shifts.append(d)
    return float(np.sqrt(np.mean(np.sum(np.square(shifts), axis=1)))) if shifts else float("nan")


def _change(before, after):
    change = after - before
    with np.errstate(invalid="ignore", divide="ignore"):
        percent = 100.0 * change / abs(before) if before not in (0, None) and np.isfinite(before) else float("nan")
    return {"baseline": before, "follow_up": after, "change": change, "change_percent": percent}


def match_wrinkles(baseline_labels, follow_up_labels, min_overlap=0.2):
    """Baseline id -> follow-up id by the largest overlap of their half-depth regions (as a
    fraction of the smaller region, at least ``min_overlap``); unmatched ids map to None."""
    matches = {}
    for index in range(1, int(baseline_labels.max()) + 1):
        region = baseline_labels == index
        counts = np.bincount(follow_up_labels[region], minlength=int(follow_up_labels.max()) + 1)
        counts[0] = 0
        best = int(counts.argmax())
        if best and counts[best] >= min_overlap * min(region.sum(), (follow_up_labels == best).sum()):
            matches[index] = best
        else:
            matches[index] = None
    return matches


@dataclass(frozen=True, eq=False)
class Comparison:
    """Everything ``skintopo compare`` reports."""

    registration: Registration
    difference: np.ndarray  # follow-up - baseline (um), plane removed, NaN outside the overlap
    texture: dict  # name -> change record
    wrinkles: dict  # baseline id -> {"follow_up_id", measure -> change record}
    totals: dict  # wrinkle field totals -> change record
    baseline_wrinkles: object
    follow_up_wrinkles: object
    aligned_albedo: np.ndarray | None = None  # follow-up albedo on the baseline grid (NaN outside)
    albedo_residual_px: float | None = None  # residual misalignment of the albedo images (pixels RMS)


def compare_visits(baseline: HeightMap, follow_up: HeightMap, *, allow_scale=False, segmentation_options=None, wrinkle_options=None,
                   baseline_albedo=None, follow_up_albedo=None) -> Comparison:
    """Register ``follow_up`` onto ``baseline`` and report every change (see the module notes).

    Texture parameters are computed on the common overlap of both visits; wrinkles are
    segmented in each visit independently and matched by overlap after registration. When
    both albedo images are given, the follow-up's is resampled with the same transform and
    its residual misalignment against the baseline's is measured as for the heights.
    """
    from skintopo.evaluation import height_difference
    from skintopo.segmentation import segment_wrinkles
    from skintopo.texture import measure_texture, parameters_by_name
    from skintopo.wrinkles import measure_wrinkles

    aligned, registration = register_visits(baseline, follow_up, allow_scale=allow_scale)
    common = baseline.mask & aligned.mask
    if common.sum() < 0.25 * baseline.mask.sum():
        raise SkinTopoError(f"the registered visits overlap on only {common.mean():.0%} of the field: too little to compare")
    before = HeightMap(baseline.z, baseline.spacing, common)
    after = HeightMap(aligned.z, baseline.spacing, common)
    difference = height_difference(after, before)
    texture_before = parameters_by_name(measure_texture(before))
    texture_after = parameters_by_name(measure_texture(after))
    texture = {name: _change(texture_before[name], texture_after[name]) for name in texture_before}
    options = segmentation_options or {}
    wrinkles_before, wrinkles_after = (measure_wrinkles(visit, segment_wrinkles(visit, **options), **(wrinkle_options or {}))
                                       for visit in (before, after))
    matches = match_wrinkles(wrinkles_before.labels, wrinkles_after.labels)
    per_wrinkle = {}
    fields = ("length_mm", "mean_depth_um", "max_depth_um", "mean_width_mm", "volume_mm3", "severity")
    for wrinkle in wrinkles_before.wrinkles:
        partner = matches.get(wrinkle.id)
        record = {"follow_up_id": partner}
        if partner is not None:
            other = wrinkles_after.wrinkles[partner - 1]
            record.update({name: _change(getattr(wrinkle, name), getattr(other, name)) for name in fields})
        per_wrinkle[wrinkle.id] = record
    # (the mean orientation is an axial angle: 179 -> 1 degrees is a change of 2, not -178; it
    # is reported per visit, not as a change)
    totals = {name: _change(float(wrinkles_before.totals[name]), float(wrinkles_after.totals[name])) for name in wrinkles_before.totals
              if not name.endswith("_deg")}
    aligned_albedo = albedo_residual = None
    if baseline_albedo is not None and follow_up_albedo is not None:
        for name, image in (("baseline", baseline_albedo), ("follow-up", follow_up_albedo)):
            if np.shape(image) != baseline.shape:
                raise SkinTopoError(f"the {name} albedo image is {np.shape(image)}, its height map {baseline.shape}: they must match")
        aligned_albedo = apply_registration(follow_up_albedo, registration)
        fixed = np.nan_to_num(np.asarray(baseline_albedo, dtype=float), nan=float(np.nanmean(baseline_albedo)))
        albedo_residual = residual_misalignment(fixed, np.where(np.isfinite(aligned_albedo), aligned_albedo, fixed))
    return Comparison(registration, difference, texture, per_wrinkle, totals, wrinkles_before, wrinkles_after, aligned_albedo, albedo_residual)


@dataclass(frozen=True)
class DetectionLimits:
    """Smallest detectable change per parameter (its units; ``wrinkleN.measure`` per wrinkle,
    ``wrinkles.name`` for the totals), the degrees of freedom behind it, the confidence and
    warnings for the user."""

    limits: dict
    degrees_of_freedom: dict
    confidence: float
    repeat_pairs: int
    warnings: tuple

    def as_dict(self):
        return {"confidence": self.confidence, "repeat_pairs": self.repeat_pairs, "warnings": list(self.warnings),
                "degrees_of_freedom": self.degrees_of_freedom}


def detection_limits(repeats, *, confidence=DEFAULT_DETECTION_CONFIDENCE) -> DetectionLimits:
    """Detection limits from k >= 1 comparisons of the baseline with repeat captures of the
    same unchanged skin (each through registration, resampling, noise and relighting, as a
    real follow-up).

    A repeat difference e of a parameter has variance 2 s_r^2 (two captures), so
    s_r^2 = sum(e_j^2) / (2 nu) with nu the number of differences. The limit is the two-sided
    prediction limit for the difference of two captures of unchanged skin,
    L = t_((1 + confidence) / 2, nu) sqrt(2) s_r: ISO 5725-6's repeatability limit
    r = 2.8 s_r (= 1.96 sqrt(2) s_r) is its 95% value for a known s_r; Student's t takes
    account of s_r being estimated from few differences (one repeat pair: t_(0.995, 1) = 63.7,
    so a single repeat gives wide limits, and a warning).

    Texture parameters and wrinkle totals: absolute differences, nu = k. Per-wrinkle measures:
    relative differences pooled over every wrinkle matched in every repeat (nu = their
    number), the limit of each wrinkle L x its baseline value, on the assumption that the
    repeatability of a wrinkle measure is proportional to it.
    """
    repeats = [repeats] if isinstance(repeats, Comparison) else list(repeats)
    if not repeats:
        raise SkinTopoError("detection limits need at least one repeat comparison")
    if not 0.5 < confidence < 1:
        raise SkinTopoError(f"the confidence must lie in (0.5, 1), got {confidence}")
    import scipy.stats

    def factor(nu):
        return float(scipy.stats.t.ppf(0.5 + confidence / 2, nu) * np.sqrt(2))

    def limit(e):  # t sqrt(2) s_r with s_r^2 = sum(e^2) / (2 nu)
        return factor(e.size) * float(np.sqrt(np.sum(e**2) / (2 * e.size)))

    limits, dof = {}, {}
    for group, prefix in (("texture", ""), ("totals", "wrinkles.")):
        for name in getattr(repeats[0], group):
            e = np.array([getattr(r, group)[name]["change"] for r in repeats], float)
            e = e[np.isfinite(e)]
            if e.size:
                dof[prefix + name] = int(e.size)
                limits[prefix + name] = limit(e)
    relative, baselines = {}, {}
    for repeat in repeats:
        for wrinkle_id, record in repeat.wrinkles.items():
            for name, change in record.items():
                if isinstance(change, dict) and change["baseline"] and np.isfinite(change["change"]):
                    relative.setdefault(name, []).append(change["change"] / change["baseline"])
                    baselines[(wrinkle_id, name)] = abs(change["baseline"])
    for (wrinkle_id, name), baseline in baselines.items():
        e = np.asarray(relative[name])
        dof[f"wrinkle{wrinkle_id}.{name}"] = int(e.size)
        limits[f"wrinkle{wrinkle_id}.{name}"] = limit(e) * baseline
    warnings = []
    fewest = min(dof.values()) if dof else 0
    if fewest < MIN_DEGREES_OF_FREEDOM:
        warnings.append(f"detection limits from {len(repeats)} repeat pair(s): {fewest} degree(s) of freedom for some parameters, so "
                        f"their limits are wide (t factor {factor(max(fewest, 1)) / np.sqrt(2):.1f} instead of "
                        f"{factor(1e9) / np.sqrt(2):.2f}); more repeat captures narrow them")
    return DetectionLimits(limits, dof, confidence, len(repeats), tuple(warnings))
