"""Per-wrinkle measures from a height map and its wrinkle segmentation.

Depth is measured from the skin's surface, the plateaus of the microrelief, not from its
mean level: skin is plateaus cut by furrows (20-200 um deep, about 0.1 mm wide), and where a
furrow crosses a wrinkle's floor it deepens it locally; the mean level of the skin around
a wrinkle sits below the plateaus by an amount that varies with the furrows' local depth.
Both made the measures of shallow wrinkles (50 um among 20-60 um furrows, simulator) off
by up to 25% in depth and 38% in volume.
The furrows are therefore removed first, with the closing filter (ISO 16610-41/-81: the
upper envelope of a level line segment, :func:`~skintopo.filters.line_segment_closing`):

* around the wrinkles: the largest of four closings with a ``furrow_closing_um`` (0.2 mm)
  segment at 0, 45, 90 and 135 degrees, which fills every furrow narrower than the segment
  along some direction (each furrow crosses one of the four at 45 degrees or more);
* on each wrinkle (its extent widened by ``margin_um``): a closing
  with an ``along_closing_um`` (0.5 mm) segment laid along the centre line's local direction
  (in 1-degree steps), which bridges the furrows crossing the wrinkle and leaves the wrinkle,
  long in that direction, as it is. It leaves the furrows that run along the wrinkle, which
  the four-way closing fills; their mean depth, measured with the same closing on the skin
  around the wrinkle, is added back, so both closings share one level.

The least-squares quadratic form is removed before (so the reference's regression, which
passes planes, does not lift a curved forehead's level), and all measures are then taken on
the scale-limited surface: the furrow-free height is
S-filtered with the ISO Gaussian at ``short_cutoff_um`` (default 0.25 mm), as ISO 25178
measures are always taken on an S-filtered surface.

Local surrounding skin level: the S-filtered furrow-free height is low-passed at
``reference_cutoff_um`` (default 2.5 mm) with the wrinkles (their full extent, widened by
``margin_um``) masked out; the first-order Gaussian regression fills them from the skin
around them. The wrinkle depth is d = reference - height, positive in the wrinkle.

For each wrinkle (ids 1..n ordered by the centroid, top to bottom then left to right, so the
same map always gives the same ids):

* centre line: the longest path through the skeleton of the wrinkle's half-depth region
  (per piece, if the region is broken; side branches of the skeleton are not length),
  trimmed at each end to where d is at least half the maximum depth (which cuts a furrow
  continuing the wrinkle's line, and drops a piece that is no part of its floor);
  ``length_mm``: the pieces' lengths (8-connected steps of 1 or sqrt(2) pixels) plus the
  gaps between them, plus, at each of the two outer ends the skeleton stopped short of, the
  straight run on to where d falls below half the maximum depth (at most half a width): the
  length at half depth;
* ``orientation_deg``: of the region's major axis, counter-clockwise from +x (y up), in
  [0, 180);
* ``max_depth_um``: the median of d over the deepest part of the skeleton's longest paths
  (where d is at least 0.6 x its 95th percentile): the depth of the wrinkle's floor;
  ``mean_depth_um``: mean of d along the centre line;
* ``mean_width_mm`` at half depth: area where d >= 0.5 x the local centre-line depth (a
  Gaussian average of the centre line's depths, about one width wide), within one core width
  of the centre line, divided by the length;
* ``volume_mm3``: integral of the signed d over the half-depth region widened by half a
  width plus ``margin_um`` (other wrinkles left out); signed, because what is left of the skin's
  relief after the closing has zero mean about the reference level;
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
from skimage.graph import MCP_Geometric
from skimage.measure import label, regionprops
from skimage.morphology import skeletonize

from skintopo.errors import SkinTopoError
from skintopo.filters import (
    areal_gaussian_filter,
    gaussian_sigma_px,
    gaussian_smooth,
    line_segment_closing,
    line_segment_footprint,
    polynomial_form,
)
from skintopo.heightmap import HeightMap
from skintopo.segmentation import REFERENCE_CUTOFF_UM, REFERENCE_MARGIN_UM, REFERENCE_SHORT_CUTOFF_UM, WrinkleSegmentation

DEFAULT_SHORT_CUTOFF_UM = REFERENCE_SHORT_CUTOFF_UM  # the depth's S-filter (not the segmentation's band-pass lambda_s)
DEFAULT_REFERENCE_CUTOFF_UM = REFERENCE_CUTOFF_UM  # the surrounding skin level, as the segmentation confirms candidates
DEFAULT_MARGIN_UM = REFERENCE_MARGIN_UM
DEFAULT_FURROW_CLOSING_UM = 200.0
DEFAULT_ALONG_CLOSING_UM = 500.0
PLATEAU_DIRECTIONS_DEG = (0.0, 45.0, 90.0, 135.0)
ANGLE_STEP_DEG = 1.0
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


def plateau_surface(height: HeightMap, furrow_closing_um=DEFAULT_FURROW_CLOSING_UM):
    """The skin without its furrows: the largest of the closings with a level segment of
    ``furrow_closing_um`` at 0, 45, 90 and 135 degrees (see the module notes). Fills the
    wrinkles too where they are narrower than the segment; use it away from them."""
    closings = [line_segment_closing(height.z, height.spacing, furrow_closing_um, angle, height.mask)
                for angle in PLATEAU_DIRECTIONS_DEG]
    return np.max(closings, axis=0)


def centre_lines(skeleton, spacing, smoothing_um):
    """The longest path through each piece of a skeleton, with its local direction.

    The longest path is found by two sweeps of a minimum-cost path search over the skeleton
    (scikit-image ``MCP_Geometric``, steps of dx, dy or the diagonal): the point farthest
    from any start, then the point farthest from that one; exact when the piece has no
    loops, as skeletons of wrinkles have not. Returns a list of (pixels (n, 2) as row,
    column, in order along the path; direction in degrees counter-clockwise from +x, y up,
    in [0, 180), from the path smoothed over ``smoothing_um``).
    """
    dy, dx = spacing
    pieces = label(skeleton, connectivity=2)
    cost = np.where(skeleton, 1.0, np.inf)
    sigma = max(1.0, smoothing_um / min(dy, dx) / 2)
    lines = []
    for piece in range(1, pieces.max() + 1):
        start = tuple(np.argwhere(pieces == piece)[0])
        far = _farthest(cost, start, spacing)[0]
        end, search = _farthest(cost, far, spacing)
        path = np.array(search.traceback(end))
        smooth = scipy.ndimage.gaussian_filter1d(path.astype(float), sigma, axis=0, mode="nearest")
        step = np.gradient(smooth, axis=0) if len(path) > 1 else np.array([[0.0, 1.0]])
        direction = np.degrees(np.arctan2(-step[:, 0] * dy, step[:, 1] * dx)) % 180.0
        lines.append((path, direction))
    return lines


def _farthest(cost, start, spacing):
    """The skeleton point farthest (along the skeleton) from ``start``, and the search."""
    search = MCP_Geometric(cost, fully_connected=True, sampling=spacing)
    distance = search.find_costs([start])[0]
    distance[~np.isfinite(distance)] = -1.0
    farthest = np.unravel_index(distance.argmax(), distance.shape)
    return farthest, search


def _joined_length(paths, spacing):
    """Length (um) of a wrinkle's centre-line pieces, ordered along their principal axis:
    their lengths plus the straight gaps between consecutive pieces; and the outer ends (of
    the two) that are open (the skeleton stopped there, not trimmed), as (pixel, outward
    direction in pixels) pairs.
    ``paths``: (kept pixels, start open, end open, the whole path) for each piece."""
    scale = np.asarray(spacing, float)
    points = np.concatenate([kept for kept, *_ in paths]) * scale
    axis = np.linalg.svd(points - points.mean(axis=0), full_matrices=False)[2][0]
    ends = []
    for kept, start_open, end_open, whole in paths:
        first, last = kept[0], kept[-1]
        # (pixel, open, outward direction from a point 3 pixels inward along the path)
        start = (first, start_open, first - whole[min(len(whole) - 1, 3)])
        end = (last, end_open, last - whole[max(0, len(whole) - 4)])
        if (last * scale) @ axis < (first * scale) @ axis:
            start, end = end, start
        ends.append((start, end, _path_length(kept, spacing)))
    ends.sort(key=lambda e: (e[0][0] * scale) @ axis)
    length = sum(piece_length for *_, piece_length in ends)
    for (_, previous_end, _), (next_start, _, _) in zip(ends[:-1], ends[1:]):
        if (next_start[0] * scale) @ axis > (previous_end[0] * scale) @ axis:
            length += float(np.hypot(*((next_start[0] - previous_end[0]) * scale)))
    outer = (ends[0][0], max((e[1] for e in ends), key=lambda p: (p[0] * scale) @ axis))
    return length, [(pixel, outward) for pixel, is_open, outward in outer if is_open]


def _run_beyond(depth, end, outward, threshold, spacing, reach_um):
    """How far (um, at most ``reach_um``) ``depth`` stays at or above ``threshold`` past a
    path's ``end``, straight along ``outward`` (pixels), sampled bilinearly every 0.25 pixel."""
    if not np.hypot(*outward) > 0:  # no direction to follow (a one-pixel path end)
        return 0.0
    step = np.asarray(outward, float) / np.hypot(*outward)
    pixel_um = np.hypot(step[0] * spacing[0], step[1] * spacing[1])
    t = np.arange(1, int(4 * reach_um / pixel_um) + 1) * 0.25
    samples = scipy.ndimage.map_coordinates(depth, [end[0] + t * step[0], end[1] + t * step[1]], order=1, mode="nearest")
    below = np.flatnonzero(samples < threshold)
    run = (t[below[0]] - 0.25 if below.size else t[-1]) if t.size else 0.0
    return float(run * pixel_um)


def _path_length(path, spacing):
    """Length (um) of an 8-connected pixel path: steps of dy, dx or their hypotenuse."""
    steps = np.diff(path, axis=0) * np.asarray(spacing)
    return float(np.hypot(steps[:, 0], steps[:, 1]).sum())


def _bounding_box(points, pad):
    """Slices of the bounding box of the true ``points``, widened by ``pad`` pixels (one
    number, or one per axis) and clipped at the array's start."""
    pad = np.broadcast_to(pad, 2)
    rows, columns = np.nonzero(points)
    return (slice(max(0, rows.min() - pad[0]), rows.max() + pad[0] + 1),
            slice(max(0, columns.min() - pad[1]), columns.max() + pad[1] + 1))


def _closed_along(z, mask, spacing, direction, region, length_um):
    """Heights of ``region`` after the closing along each point's ``direction`` image (in
    ANGLE_STEP_DEG steps); the closing of each step runs on the bounding box of its points
    plus the segment's double reach (erosion after dilation), not on the whole window."""
    out = np.array(z, dtype=np.float64)
    steps = np.rint(direction / ANGLE_STEP_DEG).astype(int) % int(round(180 / ANGLE_STEP_DEG))
    for step in np.unique(steps[region]):
        angle = step * ANGLE_STEP_DEG
        reach = 2 * (np.array(line_segment_footprint(length_um, angle, spacing).shape) // 2)
        box = _bounding_box(region & (steps == step), reach)
        closed = line_segment_closing(z[box], spacing, length_um, angle, mask[box])
        pick = region[box] & (steps[box] == step)
        out[box][pick] = closed[pick]
    return out


def measure_wrinkles(height: HeightMap, segmentation: WrinkleSegmentation, *, short_cutoff_um=DEFAULT_SHORT_CUTOFF_UM,
                     reference_cutoff_um=DEFAULT_REFERENCE_CUTOFF_UM, margin_um=DEFAULT_MARGIN_UM, depth_fraction=0.5,
                     furrow_closing_um=DEFAULT_FURROW_CLOSING_UM, along_closing_um=DEFAULT_ALONG_CLOSING_UM) -> WrinkleMeasures:
    """Per-wrinkle measures and field totals (see the module notes)."""
    if segmentation.labels.shape != height.shape:
        raise SkinTopoError(f"segmentation shape {segmentation.labels.shape} differs from the height map {height.shape}")
    dy, dx = height.spacing
    pixel_area_mm2 = dx * dy * 1e-6
    if segmentation.count == 0:
        depth = np.full(height.shape, np.nan)
        return WrinkleMeasures([], _totals([], height, 0), np.zeros(height.shape, np.int32), depth, np.zeros(height.shape, bool))

    margin_px = max(1, int(round(margin_um / min(height.spacing))))
    extent_any = np.asarray(segmentation.extent, bool)
    around = height.mask & ~scipy.ndimage.binary_dilation(extent_any, iterations=margin_px)
    if around.sum() < 0.05 * height.mask.sum():
        raise SkinTopoError("too little skin around the wrinkles to set the local reference level")
    # The least-squares quadratic form of the skin around the wrinkles is removed first: the
    # reference's Gaussian regression passes planes but lifts a curved forehead's level by
    # sigma^2 / (2 R) (1.4 um at 2.5 mm and R = 80 mm), which summed over a wrinkle's walls
    # is 10-15% of a shallow one's volume.
    height = HeightMap(height.z - polynomial_form(height.z, height.spacing, 2, around), height.spacing, height.mask)
    # Local surrounding skin level, from the furrow-free skin outside the widened wrinkles.
    plateau = plateau_surface(height, furrow_closing_um)
    smooth = areal_gaussian_filter(plateau, height.spacing, short_cutoff_um, height.mask) if short_cutoff_um else plateau
    reference = areal_gaussian_filter(smooth, height.spacing, reference_cutoff_um, around)
    depth = np.where(height.mask, reference - smooth, np.nan)

    extent_labels = label(extent_any)
    order = sorted(regionprops(segmentation.labels), key=lambda r: (round(r.centroid[0] / 4), r.centroid[1]))
    wrinkles, ids, lines = [], np.zeros(height.shape, np.int32), np.zeros(height.shape, bool)
    half_area_total = 0
    for new_id, region in enumerate(order, start=1):
        whole_full = extent_labels == np.bincount(extent_labels[segmentation.labels == region.label]).argmax()
        # Work in a window around the wrinkle (its extent plus the smoothing, closing and margin reach).
        sigma = max(1.0, region.axis_minor_length)
        pad = int(3 * sigma + margin_px + along_closing_um / min(dy, dx) + 2)
        window = _bounding_box(whole_full, pad)
        core = segmentation.labels[window] == region.label
        whole = whole_full[window]
        pieces = centre_lines(skeletonize(core), height.spacing, along_closing_um)
        skeleton_paths = np.zeros(core.shape, bool)
        direction_on_paths = np.zeros(core.shape)
        for path, direction in pieces:
            skeleton_paths[path[:, 0], path[:, 1]] = True
            direction_on_paths[path[:, 0], path[:, 1]] = direction
        path_distance, nearest = scipy.ndimage.distance_transform_edt(~skeleton_paths, sampling=(dy, dx), return_indices=True)
        # On the wrinkle (its extent widened by the margin), furrows are closed along the centre
        # line's local direction instead: the four-way closing would fill the wrinkle's floor.
        # That closing leaves the furrows that run along the wrinkle, which the four-way one
        # fills: their mean depth, measured with the same closing on the skin around the
        # wrinkle (up to a segment's length beyond it), is added back, so both closings share
        # one level.
        near = scipy.ndimage.binary_dilation(whole, iterations=margin_px) & height.mask[window]
        ring = around[window] & (path_distance <= path_distance[near].max() + along_closing_um)
        closed = _closed_along(height.z[window], height.mask[window], height.spacing,
                               direction_on_paths[nearest[0], nearest[1]], near | ring, along_closing_um)
        left_by_along = float(np.mean(plateau[window][ring] - closed[ring])) if ring.any() else 0.0
        # The S-filter is linear: S(closed) = S(plateau), known, + S(the change on the wrinkle),
        # which is zero beyond the filter's reach from it, so it is filtered on that box alone.
        change = np.where(near, closed + left_by_along - plateau[window], 0.0)
        smooth_window = smooth[window].copy()
        if short_cutoff_um:
            box = _bounding_box(near, 2 * int(np.ceil(4 * gaussian_sigma_px(short_cutoff_um, min(dy, dx)))) + 2)
            smooth_window[box] += areal_gaussian_filter(change[box], height.spacing, short_cutoff_um, height.mask[window][box])
        else:
            smooth_window += change
        depth_window = np.nan_to_num(np.where(height.mask[window], reference[window] - smooth_window, np.nan))
        depth[window][near] = depth_window[near]
        # Maximum depth: the median of the deepest part of the paths (d >= 0.6 x its 95th
        # percentile), robust to what the closing left of the furrows.
        path_depth = depth_window[skeleton_paths]
        max_depth = float(np.median(path_depth[path_depth >= 0.6 * np.percentile(path_depth, MAX_DEPTH_PERCENTILE)]))
        # The centre line is where the paths are at least half as deep as the wrinkle (the
        # length at half depth): their ends are trimmed to the first and last such point,
        # which cuts a furrow that continues the wrinkle's line and drops a piece that is no
        # part of the wrinkle's floor. The length is the pieces' lengths plus the gaps between
        # them, plus what the skeleton left out at the wrinkle's two ends (see below).
        threshold = depth_fraction * max_depth
        kept_paths = []
        for path, _ in pieces:
            deep = np.flatnonzero(depth_window[path[:, 0], path[:, 1]] >= threshold)
            if deep.size:
                kept_paths.append((path[deep[0]:deep[-1] + 1], deep[0] == 0, deep[-1] == len(path) - 1, path))
        if not kept_paths:
            continue
        line = np.zeros(core.shape, bool)
        for kept, *_ in kept_paths:
            line[kept[:, 0], kept[:, 1]] = True
        line_length, open_ends = _joined_length(kept_paths, height.spacing)
        core_pieces = label(core)
        core &= np.isin(core_pieces, np.unique(core_pieces[line]))
        distance = scipy.ndimage.distance_transform_edt(~line, sampling=(dy, dx))
        core_width = np.count_nonzero(core) * dx * dy / max(line_length, dx)
        line_depth = depth_window[line]
        # Local centre-line depth spread across the wrinkle: a normalised Gaussian average of
        # the centre line's depths (sigma about one wrinkle width), so noise on the centre
        # line does not raise the half-depth threshold as a maximum would.
        weight, weighted = gaussian_smooth([line.astype(float), np.where(line, depth_window, 0.0)], (sigma, sigma))
        with np.errstate(invalid="ignore", divide="ignore"):
            local = weighted / weight
        # The half-depth region stays within one core width of the centre line, so a furrow
        # branching off the wrinkle (as deep as half the wrinkle) is not counted as its width.
        within = distance <= max(core_width, 2 * max(dx, dy))
        half = whole & within & (depth_window >= depth_fraction * np.nan_to_num(local)) & (weight > 1e-3 * weight.max())
        half_area = np.count_nonzero(half) * dx * dy
        # At an open end the skeleton of an elongated region stops about half a width short of
        # its end: d is followed on, straight, to where it falls below half depth, at most
        # half a width (further on, the microrelief left in d would carry it along).
        half_width = half_area / max(line_length, dx) / 2
        length = line_length + sum(_run_beyond(depth_window, pixel, outward, threshold, height.spacing, half_width)
                                   for pixel, outward in open_ends)
        width = half_area / length
        # Volume: the signed depth integrated over the wrinkle and its walls (within half a
        # width plus the margin of the half-depth region), other wrinkles left out.
        reach = 0.5 * width + margin_um
        walls = (scipy.ndimage.distance_transform_edt(~half, sampling=(dy, dx)) <= reach) & ~(extent_any[window] & ~whole)
        volume = depth_window[walls].sum() * pixel_area_mm2 * 1e-3  # um x mm^2 -> mm^3
        mean_depth = float(line_depth.mean())
        orientation = (np.degrees(region.orientation) + 90.0) % 180.0  # skimage: angle of the major axis from the row axis
        row, column = region.centroid
        wrinkles.append(Wrinkle(
            id=new_id, centroid_x_mm=column * dx / 1000, centroid_y_mm=row * dy / 1000, length_mm=length / 1000,
            orientation_deg=float(orientation), mean_depth_um=mean_depth,
            max_depth_um=max_depth, mean_width_mm=width / 1000,
            cross_section_mm2=volume / (length / 1000), volume_mm3=volume, severity=mean_depth * (length / 1000) / 100,
        ))
        ids[window][core] = new_id
        lines[window] |= line
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
