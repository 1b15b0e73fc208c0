"""Accuracy of a reconstruction against a reference height map (ground truth, replica scan).

* Registration: the sub-pixel translation of :func:`skintopo.registration.register_height_maps`
  (phase correlation, then a robust least-squares refinement: the reconstruction's own
  errors weigh little in it), then removal of the least-squares plane (tilt and offset) of
  the difference: neither is measurable by photometric stereo's integration, so neither
  counts as error.
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

from skintopo.errors import SkinTopoError
from skintopo.filters import polynomial_form
from skintopo.height import height_normals
from skintopo.heightmap import HeightMap
from skintopo.registration import check_comparable, register_height_maps


def height_difference(result: HeightMap, reference: HeightMap, mask=None):
    """result - reference with the least-squares plane of the difference removed (NaN where
    either is missing)."""
    check_comparable(result, reference)
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
    from skintopo.wrinkles import wrinkle_table

    labels = np.asarray(labels)
    table = wrinkle_table(height, segmentation_from_labels(labels, height.spacing), properties=("label", "max_depth_um"))
    depths = np.full(int(labels.max()), np.nan)
    depths[table["label"].astype(int) - 1] = table["max_depth_um"]
    return depths


def evaluate_height(result: HeightMap, reference: HeightMap, *, wrinkle_labels=None, register=True, reference_wrinkle_depths=None):
    """All accuracy figures of ``result`` against ``reference``, as a dict (units in keys).
    ``reference_wrinkle_depths``: :func:`wrinkle_max_depths` of ``reference`` when it is
    already known (several results against one reference need it once)."""
    shift = (0.0, 0.0)
    if register:
        result, registration = register_height_maps(reference, result, rotation=False)
        shift = registration.shift_px
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


def label_overlap(labels_a, labels_b, shape=None):
    """counts[i, j]: the number of pixels labelled i in ``labels_a`` and j in ``labels_b`` (0:
    background), of ``shape`` (default: (max(labels_a) + 1, max(labels_b) + 1))."""
    a, b = (np.asarray(labels, dtype=np.int64).ravel() for labels in (labels_a, labels_b))
    rows, columns = shape or (int(a.max(initial=0)) + 1, int(b.max(initial=0)) + 1)
    return np.bincount(a * columns + b, minlength=rows * columns).reshape(rows, columns)


def match_wrinkles_to_truth(measures, truth_labels):
    """One measured wrinkle at most per true wrinkle: each measured wrinkle (of a
    :class:`skintopo.wrinkles.WrinkleMeasures`) belongs to the true wrinkle (``truth_labels``:
    0 outside, i + 1 in wrinkle i's half-depth region) of which it covers the largest share,
    and a true wrinkle is found when the measured wrinkle covering most of it belongs to it.
    A shallow wrinkle that the segmentation merged into a deeper one it crosses is then not
    found, rather than found with the deep one's measures. Returns a list (true wrinkle i at
    index i) of measured wrinkles or None."""
    truth_labels = np.asarray(truth_labels)
    count_true, count_measured = int(truth_labels.max()), len(measures.wrinkles)
    ids = [0] + [w.id for w in measures.wrinkles]
    index = np.zeros(max(int(np.max(measures.labels)), *ids) + 1, int)  # measured id -> column (0: none)
    index[ids] = np.arange(count_measured + 1)
    inside = truth_labels > 0
    overlap = label_overlap(truth_labels[inside], index[measures.labels[inside]], shape=(count_true + 1, count_measured + 1))[1:]
    share = overlap / np.maximum(overlap.sum(axis=1, keepdims=True), 1)
    share[:, 0] = 0.0
    owner = share.argmax(axis=0)  # the true wrinkle each measured one belongs to
    found = []
    for i in range(count_true):
        best = int(share[i].argmax())
        found.append(measures.wrinkles[best - 1] if share[i, best] > 0 and owner[best] == i else None)
    return found


def match_wrinkle(measures, region):
    """The measured wrinkle (of a :class:`skintopo.wrinkles.WrinkleMeasures`) whose id covers
    most of ``region`` (a true wrinkle's half-depth region), or None when none touches it."""
    found = np.bincount(measures.labels[np.asarray(region, bool)], minlength=len(measures.wrinkles) + 1)
    found[0] = 0
    if found.max() == 0:
        return None
    return next(w for w in measures.wrinkles if w.id == int(found.argmax()))
