"""Accuracy of a reconstruction against a reference height map (ground truth, replica scan).

* Registration: sub-pixel translation by phase correlation (scikit-image,
  ``phase_cross_correlation`` with upsampling) of the levelled maps, refined by least
  squares over the interior (cubic-spline shifts), then removal of the
  least-squares plane (tilt and offset) of the difference: neither is measurable by
  photometric stereo's integration, so neither counts as error.
* RMS height error (um) over the field and inside the wrinkles (paper Table 1).
* Normal errors (paper Table 2): both normal fields from the height maps' central
  differences (the same operator on both, so discretisation cancels); L2 = mean over pixels
  of |n - n_ref|, and the mean angle between them in degrees.
* Max depth of each wrinkle where the reference's wrinkles are (``wrinkle_labels``), in the
  result and in the reference, by the one definition of :mod:`skintopo.wrinkles`
  (docs/wrinkle-measures.md). It was once the ring median minus the lowest point inside,
  which counted a furrow at a wrinkle's floor as wrinkle (152 um for a 120 um wrinkle).
"""

from __future__ import annotations

import numpy as np
import scipy.ndimage
from skimage.registration import phase_cross_correlation

from skintopo.errors import SkinTopoError
from skintopo.filters import polynomial_form
from skintopo.height import height_normals
from skintopo.heightmap import HeightMap

MIN_CORRELATION = 0.3  # of the levelled maps once aligned; unrelated surfaces give about 0


def _check_comparable(result: HeightMap, reference: HeightMap):
    if not np.allclose(result.spacing, reference.spacing, rtol=1e-6):
        raise SkinTopoError(
            f"the height maps have different pixel sizes ({result.spacing[1]:g} and {reference.spacing[1]:g} um); resample one first"
        )
    if result.shape != reference.shape:
        raise SkinTopoError(f"the height maps have different sizes ({result.shape} and {reference.shape} pixels)")


def register_translation(result: HeightMap, reference: HeightMap, *, upsample=20):
    """Shift ``result`` onto ``reference`` by the sub-pixel translation that best aligns them.

    Returns
    -------
    aligned : HeightMap
        ``result`` resampled (bilinear) at the shifted positions; NaN where it has no data.
    shift_px : (float, float)
        The (row, column) shift applied.
    """
    _check_comparable(result, reference)

    def prepared(height):
        z = height.z - polynomial_form(height.z, height.spacing, 1, height.mask)
        return np.where(height.mask, z, 0.0)

    fixed, moving = prepared(reference), prepared(result)
    shift, _, _ = phase_cross_correlation(fixed, moving, upsample_factor=upsample)
    rows, columns = result.shape
    whole = np.round(shift).astype(int)
    overlap_rows = slice(max(0, whole[0]), rows + min(0, whole[0]))
    overlap_columns = slice(max(0, whole[1]), columns + min(0, whole[1]))
    moved = np.roll(moving, tuple(whole), axis=(0, 1))[overlap_rows, overlap_columns]
    overlap = fixed[overlap_rows, overlap_columns]
    correlation = np.corrcoef(moved.ravel(), overlap.ravel())[0, 1] if moved.size > 16 else 0.0
    if abs(shift[0]) > rows / 2 or abs(shift[1]) > columns / 2 or not correlation > MIN_CORRELATION:
        raise SkinTopoError(
            f"the fields do not overlap: best shift ({shift[0]:.1f}, {shift[1]:.1f}) pixels with correlation "
            f"{correlation:.2f} (needs > {MIN_CORRELATION}); are these maps of the same skin?"
        )
    shift = _refine_shift(fixed, moving, shift)
    if np.allclose(shift, 0, atol=1e-3):
        return result, (0.0, 0.0)
    z = scipy.ndimage.shift(np.where(result.mask, result.z, 0.0), shift, order=1, mode="constant", cval=np.nan)
    coverage = scipy.ndimage.shift(result.mask.astype(float), shift, order=1, mode="constant", cval=0.0)
    return HeightMap(np.where(coverage > 0.999, z, np.nan), result.spacing), (float(shift[0]), float(shift[1]))


def _refine_shift(fixed, moving, start):
    """Least-squares sub-pixel refinement of a translation: minimise the mean squared
    difference over the interior between ``fixed`` and ``moving`` shifted by cubic splines
    (phase correlation alone is biased by the field's edges)."""
    from scipy.optimize import minimize

    rows, columns = fixed.shape
    margin = int(np.ceil(np.abs(start).max())) + 4
    interior = (slice(margin, rows - margin), slice(margin, columns - margin))
    coefficients = scipy.ndimage.spline_filter(moving, order=3)

    def cost(shift):
        moved = scipy.ndimage.shift(coefficients, shift, order=3, mode="nearest", prefilter=False)
        return float(np.mean((moved[interior] - fixed[interior]) ** 2))

    best = minimize(cost, np.asarray(start, dtype=float), method="Powell", options={"xtol": 1e-3, "ftol": 1e-10})
    return best.x if best.fun <= cost(start) else np.asarray(start, dtype=float)


def height_difference(result: HeightMap, reference: HeightMap, mask=None):
    """result - reference with the least-squares plane of the difference removed (NaN where
    either is missing)."""
    _check_comparable(result, reference)
    common = result.mask & reference.mask
    if mask is not None:
        common &= np.asarray(mask, dtype=bool)
    if common.sum() < 3:
        raise SkinTopoError("the height maps have fewer than 3 valid points in common")
    difference = result.z - reference.z
    return np.where(common, difference - polynomial_form(difference, result.spacing, 1, common), np.nan)


def slope_normals(height: HeightMap):
    """Unit normals from central differences of a height map (camera frame, y up)."""
    return height_normals(height.z, height.spacing)


def wrinkle_max_depths(height: HeightMap, labels):
    """Max depth (um) of each labelled wrinkle (ids 1..n of ``labels``, half-depth regions) by the
    definition of :mod:`skintopo.wrinkles` (docs/wrinkle-measures.md), read from ``height``
    where the wrinkles are known; NaN for a wrinkle that cannot be measured there."""
    from skintopo.segmentation import segmentation_from_labels
    from skintopo.wrinkles import measure_wrinkles

    labels = np.asarray(labels)
    measures = measure_wrinkles(height, segmentation_from_labels(labels, height.spacing))
    depths = []
    for index in range(1, int(labels.max()) + 1):
        measured = match_wrinkle(measures, labels == index)
        depths.append(float("nan") if measured is None else measured.max_depth_um)
    return np.array(depths)


def evaluate_height(result: HeightMap, reference: HeightMap, *, wrinkle_labels=None, register=True, reference_wrinkle_depths=None):
    """All accuracy figures of ``result`` against ``reference``, as a dict (units in keys).
    ``reference_wrinkle_depths``: :func:`wrinkle_max_depths` of ``reference`` when it is
    already known (several results against one reference need it once)."""
    shift = (0.0, 0.0)
    if register:
        result, shift = register_translation(result, reference)
    difference = height_difference(result, reference)
    normals, normals_reference = slope_normals(result), slope_normals(reference)
    valid = np.isfinite(difference) & np.isfinite(normals).all(-1) & np.isfinite(normals_reference).all(-1)
    distance = np.linalg.norm(normals - normals_reference, axis=-1)
    angle = np.degrees(np.arccos(np.clip((normals * normals_reference).sum(-1), -1, 1)))
    report = {
        "shift_px": list(shift),
        "rms_height_error_um": float(np.sqrt(np.nanmean(difference**2))),
        "l2_normal_error": float(distance[valid].mean()),
        "mean_angular_error_deg": float(angle[valid].mean()),
        "valid_fraction": float(np.isfinite(difference).mean()),
    }
    if wrinkle_labels is not None and np.max(wrinkle_labels) > 0:
        inside = np.asarray(wrinkle_labels) > 0
        report["rms_height_error_in_wrinkles_um"] = float(np.sqrt(np.nanmean(difference[inside] ** 2)))
        aligned = HeightMap(reference.z + difference, reference.spacing)  # result levelled onto the reference
        true_depths = (wrinkle_max_depths(reference, wrinkle_labels) if reference_wrinkle_depths is None
                       else np.asarray(reference_wrinkle_depths, dtype=float))
        found_depths = wrinkle_max_depths(aligned, wrinkle_labels)
        report["wrinkle_max_depth_true_um"] = true_depths.tolist()
        report["wrinkle_max_depth_um"] = found_depths.tolist()
        report["wrinkle_depth_error_relative"] = (np.abs(found_depths - true_depths) / true_depths).tolist()
    return report


def cross_section_line(labels, index, spacing, length_factor=3.0):
    """End points (um, image coordinates: x right, y down) of a line across wrinkle
    ``index`` through its centroid, perpendicular to its main axis, ``length_factor`` times
    its width long (clipped to the map)."""
    from skimage.measure import regionprops

    regions = {r.label: r for r in regionprops(np.asarray(labels))}
    if index not in regions:
        raise SkinTopoError(f"no wrinkle with id {index}")
    region = regions[index]
    dy, dx = spacing
    row, column = region.centroid
    # skimage orientation: angle between the row axis and the major axis
    major = np.array([np.cos(region.orientation), np.sin(region.orientation)])  # (row, column)
    across = np.array([-major[1], major[0]])
    half = length_factor * max(region.axis_minor_length, 2) / 2
    rows, columns = np.asarray(labels).shape
    ends = []
    for sign in (-1, 1):
        r = np.clip(row + sign * half * across[0], 0, rows - 1)
        c = np.clip(column + sign * half * across[1], 0, columns - 1)
        ends.append((c * dx, r * dy))
    return ends[0], ends[1]


def match_wrinkle(measures, region):
    """The measured wrinkle (of a :class:`skintopo.wrinkles.WrinkleMeasures`) whose id covers
    most of ``region`` (a true wrinkle's half-depth region), or None when none touches it."""
    found = np.bincount(measures.labels[np.asarray(region, bool)], minlength=len(measures.wrinkles) + 1)
    found[0] = 0
    if found.max() == 0:
        return None
    return next(w for w in measures.wrinkles if w.id == int(found.argmax()))
