"""Per-wrinkle measures from a height map and its wrinkle segmentation.

All measures are taken on the scale-limited surface: the height is first S-filtered with the
ISO Gaussian at ``short_cutoff_um`` (default 0.25 mm), which removes the microrelief's
finest furrows, as ISO 25178 measures are always taken on an S-filtered surface.

Local surrounding skin level: the S-filtered height is low-passed at ``reference_cutoff_um``
(default 2.5 mm) with the wrinkles (their full extent, widened by ``margin_um``) masked out;
the first-order Gaussian regression fills them from the skin around them. The wrinkle depth
is d = reference - height, positive in the wrinkle.

For each wrinkle (ids 1..n ordered by the centroid, top to bottom then left to right, so the
same map always gives the same ids):

* centre line: skeleton of the wrinkle's half-depth region; ``length_mm`` is the skeleton's
  length (8-connected steps of 1 or sqrt(2) pixels) extended by the mean width (half a width
  at each end, where the skeleton stops short of the region's ends);
* ``orientation_deg``: of the region's major axis, counter-clockwise from +x (y up), in
  [0, 180);
* ``max_depth_um``: the median of d over the deepest part of the centre line (where d is at
  least 0.6 x its 95th percentile): the depth of the wrinkle's floor, robust to furrows
  crossing it; ``mean_depth_um``: mean of d along the centre line;
* ``mean_width_mm`` at half depth: area where d >= 0.5 x the local centre-line depth (a
  Gaussian average of the centre line's depths, about one width wide), within one core width
  of the centre line (a furrow branching off is not width), divided by the length;
* ``volume_mm3``: integral of the signed d over the half-depth region widened by one width
  plus ``margin_um`` (other wrinkles left out); signed because the microrelief has zero mean
  about the reference level, so clipping d at zero would add the surrounding furrows' volume;
  ``cross_section_mm2`` = volume / length;
* ``severity`` = mean depth (um) x length (mm) / 100: a depth-length index that grows with
  either; a ranking aid within a study, not a clinical grading scale.

Field totals: count, total length, length-weighted mean depth, and the wrinkle area
fraction (half-depth area / measured area).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
import scipy.ndimage
from skimage.measure import label, regionprops
from skimage.morphology import skeletonize

from skintopo.errors import SkinTopoError
from skintopo.filters import areal_gaussian_filter
from skintopo.heightmap import HeightMap
from skintopo.segmentation import WrinkleSegmentation

DEFAULT_SHORT_CUTOFF_UM = 250.0
DEFAULT_REFERENCE_CUTOFF_UM = 2500.0
DEFAULT_MARGIN_UM = 150.0
MAX_DEPTH_PERCENTILE = 95


@dataclass(frozen=True)
class Wrinkle:
    """Measures of one wrinkle (units in the names)."""

    id: int
    centroid_x_mm: float
    centroid_y_mm: float
    length_mm: float
    orientation_deg: float
    mean_depth_um: float
    max_depth_um: float
    mean_width_mm: float
    cross_section_mm2: float
    volume_mm3: float
    severity: float


@dataclass(frozen=True, eq=False)
class WrinkleMeasures:
    """Per-wrinkle measures, field totals, and the maps they came from."""

    wrinkles: list
    totals: dict
    labels: np.ndarray  # half-depth regions with the measure ids
    depth: np.ndarray  # d in micrometres (NaN where not measured)
    lines: np.ndarray  # centre lines

    def as_dict(self):
        return {"wrinkles": [asdict(w) for w in self.wrinkles], "totals": self.totals}


def _skeleton_length(skeleton, spacing):
    """Length of an 8-connected skeleton: axis steps of dx or dy, diagonal steps of their
    hypotenuse, a diagonal step not counted where two axis steps already join its pixels."""
    dy, dx = spacing
    s = np.asarray(skeleton, dtype=bool)
    horizontal = s[:, :-1] & s[:, 1:]
    vertical = s[:-1, :] & s[1:, :]
    down_right = s[:-1, :-1] & s[1:, 1:] & ~s[:-1, 1:] & ~s[1:, :-1]
    down_left = s[:-1, 1:] & s[1:, :-1] & ~s[:-1, :-1] & ~s[1:, 1:]
    diagonal = np.hypot(dx, dy)
    return float(dx * horizontal.sum() + dy * vertical.sum() + diagonal * (down_right.sum() + down_left.sum()))


def wrinkle_depth_map(height: HeightMap, extent, *, short_cutoff_um=DEFAULT_SHORT_CUTOFF_UM,
                      reference_cutoff_um=DEFAULT_REFERENCE_CUTOFF_UM, margin_um=DEFAULT_MARGIN_UM):
    """d = local surrounding skin level - S-filtered height (um), see the module notes."""
    smooth = areal_gaussian_filter(height.z, height.spacing, short_cutoff_um, height.mask) if short_cutoff_um else height.z
    margin_px = max(1, int(round(margin_um / min(height.spacing))))
    widened = scipy.ndimage.binary_dilation(np.asarray(extent, bool), iterations=margin_px)
    around = height.mask & ~widened
    if around.sum() < 0.05 * height.mask.sum():
        raise SkinTopoError("too little skin around the wrinkles to set the local reference level")
    reference = areal_gaussian_filter(smooth, height.spacing, reference_cutoff_um, around)
    return np.where(height.mask, reference - smooth, np.nan)


def measure_wrinkles(height: HeightMap, segmentation: WrinkleSegmentation, *, short_cutoff_um=DEFAULT_SHORT_CUTOFF_UM,
                     reference_cutoff_um=DEFAULT_REFERENCE_CUTOFF_UM, margin_um=DEFAULT_MARGIN_UM, depth_fraction=0.5) -> WrinkleMeasures:
    """Per-wrinkle measures and field totals (see the module notes)."""
    if segmentation.labels.shape != height.shape:
        raise SkinTopoError(f"segmentation shape {segmentation.labels.shape} differs from the height map {height.shape}")
    dy, dx = height.spacing
    pixel_area_mm2 = dx * dy * 1e-6
    extent_labels = label(segmentation.extent)
    if segmentation.count == 0:
        depth = np.full(height.shape, np.nan)
        return WrinkleMeasures([], _totals([], height, 0), np.zeros(height.shape, np.int32), depth, np.zeros(height.shape, bool))
    depth = wrinkle_depth_map(height, segmentation.extent, short_cutoff_um=short_cutoff_um,
                              reference_cutoff_um=reference_cutoff_um, margin_um=margin_um)
    filled = np.nan_to_num(depth, nan=0.0)
    margin_px = max(1, int(round(margin_um / min(height.spacing))))
    extent_any = np.asarray(segmentation.extent, bool)
    order = sorted(regionprops(segmentation.labels), key=lambda r: (round(r.centroid[0] / 4), r.centroid[1]))
    wrinkles, ids, lines = [], np.zeros(height.shape, np.int32), np.zeros(height.shape, bool)
    half_area_total = 0
    for new_id, region in enumerate(order, start=1):
        whole_full = extent_labels == np.bincount(extent_labels[segmentation.labels == region.label]).argmax()
        # Work in a window around the wrinkle (its extent plus the smoothing and margin reach).
        sigma = max(1.0, region.axis_minor_length)
        pad = int(3 * sigma + margin_px + 2)
        rows_any, columns_any = np.nonzero(whole_full)
        window = (slice(max(0, rows_any.min() - pad), rows_any.max() + pad + 1), slice(max(0, columns_any.min() - pad), columns_any.max() + pad + 1))
        core = segmentation.labels[window] == region.label
        whole = whole_full[window]
        depth_window = filled[window]
        skeleton = skeletonize(core)
        line_depth = depth_window[skeleton]
        if line_depth.size == 0:
            continue
        # Maximum depth: the median of the deepest part of the centre line (d >= 0.6 x its
        # 95th percentile), robust to furrows crossing the wrinkle's bottom.
        deepest = line_depth[line_depth >= 0.6 * np.percentile(line_depth, MAX_DEPTH_PERCENTILE)]
        # Local centre-line depth spread across the wrinkle: a normalised Gaussian average of
        # the centre line's depths (sigma about one wrinkle width), so microrelief noise on the
        # centre line does not raise the half-depth threshold as a maximum would.
        weight = scipy.ndimage.gaussian_filter(skeleton.astype(float), sigma)
        with np.errstate(invalid="ignore", divide="ignore"):
            local = scipy.ndimage.gaussian_filter(np.where(skeleton, depth_window, 0.0), sigma) / weight
        # The half-depth region stays within one core width of the centre line, so a furrow
        # branching off the wrinkle (as deep as half the wrinkle) is not counted as its width.
        skeleton_length = _skeleton_length(skeleton, height.spacing)
        distance = scipy.ndimage.distance_transform_edt(~skeleton, sampling=(dy, dx))
        core_width = np.count_nonzero(core) * dx * dy / max(skeleton_length, dx)
        near = distance <= max(core_width, 2 * max(dx, dy))
        half = whole & near & (depth_window >= depth_fraction * np.nan_to_num(local)) & (weight > 1e-3 * weight.max())
        half_area = np.count_nonzero(half) * dx * dy
        width = half_area / max(skeleton_length, dx)
        length = skeleton_length + width
        width = half_area / length
        # Volume: the signed depth integrated over the wrinkle and its walls (within one width
        # plus the margin of the half-depth region), other wrinkles left out. Signed, because the
        # skin's microrelief has zero mean about the reference level: clipping d at zero
        # would add the furrows' volume around the wrinkle.
        reach = width + margin_um
        walls = (scipy.ndimage.distance_transform_edt(~half, sampling=(dy, dx)) <= reach) & ~(extent_any[window] & ~whole)
        volume = depth_window[walls].sum() * pixel_area_mm2 * 1e-3  # um x mm^2 -> mm^3
        mean_depth = float(line_depth.mean())
        orientation = (np.degrees(region.orientation) + 90.0) % 180.0  # skimage: angle of the major axis from the row axis
        row, column = region.centroid
        wrinkles.append(Wrinkle(
            id=new_id, centroid_x_mm=column * dx / 1000, centroid_y_mm=row * dy / 1000, length_mm=length / 1000,
            orientation_deg=float(orientation), mean_depth_um=mean_depth,
            max_depth_um=float(np.median(deepest)), mean_width_mm=width / 1000,
            cross_section_mm2=volume / (length / 1000), volume_mm3=volume, severity=mean_depth * (length / 1000) / 100,
        ))
        ids[window][core] = new_id
        lines[window] |= skeleton
        half_area_total += np.count_nonzero(half)
    return WrinkleMeasures(wrinkles, _totals(wrinkles, height, half_area_total), ids, depth, lines)


def _totals(wrinkles, height, half_area_pixels):
    total_length = sum(w.length_mm for w in wrinkles)
    return {
        "count": len(wrinkles),
        "total_length_mm": total_length,
        "mean_depth_um": (sum(w.mean_depth_um * w.length_mm for w in wrinkles) / total_length) if total_length else float("nan"),
        "area_fraction": half_area_pixels / max(1, int(height.mask.sum())),
    }
