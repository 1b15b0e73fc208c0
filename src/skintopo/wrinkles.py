"""Per-wrinkle measures from a height map and its wrinkle segmentation.

The definitions are written out in ``docs/wrinkle-measures.md`` (with a figure); the simulator's
ground truth (:func:`skintopo.synth.geometric_measures`) applies the same definitions to the
exact geometry. In short:

* Depth d (um, positive in the wrinkle) below the **local skin level**: the skin's plateaus,
  not its mean level (skin is plateaus cut by furrows 20-200 um deep, about 0.1 mm wide). The
  furrows are filled by the largest of four closings (ISO 16610-41/-81, the upper envelope of
  a level line segment, :func:`~skintopo.filters.line_segment_closing`) with a
  ``furrow_closing_um`` (0.2 mm) segment at 0, 45, 90 and 135 degrees, and that plateau
  surface is carried under the wrinkles by the ISO 16610-61 Gaussian regression filter
  (``reference_cutoff_um``, 2.5 mm) over the skin outside them (widened by ``margin_um``).
  Where no skin lies within the regression's reach, the level of the nearest point that has
  one is carried on.
  The least-squares quadratic form of that skin is removed first (the regression passes
  planes but lifts a curved forehead's level by sigma^2 / (2 R)). No smoothing filter
  touches the wrinkle: ``short_cutoff_um`` (an S-filter of the height) is 0 by default,
  because a 0.25 mm S-filter made 0.4-0.6 mm wide wrinkles read 10-25% shallower.
* Each wrinkle is measured in **its own frame** (:class:`WrinkleFrame`): s along its centre
  line, t across it, sampled every half pixel with a cubic spline. The first centre line is
  the longest path through the skeleton of the segmentation's half-depth region (its pieces
  chained along their principal axis); the centre line is then moved to the middle of the
  half-depth cross-sections (:func:`midline`) and smoothed (Savitzky-Golay), and extended
  straight beyond both ends.
* In the frame, the furrows crossing the wrinkle are bridged by a closing along s with a
  ``along_closing_um`` (1 mm) segment, which lies exactly along the floor and so does not
  lift it (:func:`depth_in_frame`); the mean depth of the furrows it leaves (those running
  along the wrinkle) is measured on the skin in the frame and added back.
* ``length_mm``: arc length between the two ends at half depth (where the floor depth,
  averaged over 0.25 mm, falls below half its largest value); ``max_depth_um``: the largest
  mean of the floor depth over ``depth_window_um`` (1 mm) of centre line; ``mean_depth_um``:
  its mean along the line (both from one profile: mean <= max always); ``mean_width_mm``:
  mean width at half the floor depth, perpendicular to the line; ``volume_mm3``: the signed
  depth integrated over the wrinkle and its walls with the frame's area element;
  ``cross_section_mm2`` = volume / length; ``orientation_deg``: the axial (doubled-angle)
  mean of the line's direction, counter-clockwise from +x (y up), in [0, 180);
  ``severity`` = mean depth (um) x length (mm) / 100, a ranking aid, not a clinical grade.

Ids 1..n follow the centroids, top to bottom then left to right. Field totals: count, total
length, length-weighted mean depth, axial mean orientation and the wrinkle area fraction
(half-depth area / measured area).

API, as scikit-image's region properties: :func:`wrinkle_properties` gives one
:class:`WrinkleProperties` per wrinkle, each measure a cached property computed when first
read; :func:`wrinkle_table` gives chosen measures as columns (as ``regionprops_table``),
computing only what they need; :func:`measure_wrinkles` gives every measure, the totals, the
id image, the centre lines and the traces (what the commands and the report use).
"""

from __future__ import annotations

import copy
from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict, dataclass, fields
from functools import cached_property

import numpy as np
import scipy.ndimage
from skimage.graph import MCP_Geometric
from skimage.measure import label, regionprops
from skimage.morphology import skeletonize

from skintopo.defaults import DEFAULT_ALONG_CLOSING_UM, DEFAULT_DEPTH_SHORT_CUTOFF_UM, DEFAULT_DEPTH_WINDOW_UM, DEFAULT_FURROW_CLOSING_UM
from skintopo.errors import SkinTopoError
from skintopo.filters import areal_gaussian_filter, line_segment_closing_extremes, polynomial_form
from skintopo.height import fill_from_nearest
from skintopo.heightmap import HeightMap
from skintopo.segmentation import REFERENCE_CUTOFF_UM, REFERENCE_MARGIN_UM, WrinkleSegmentation, margin_pixels, skin_around, skin_level

DEFAULT_REFERENCE_CUTOFF_UM = REFERENCE_CUTOFF_UM  # the surrounding skin level, as the segmentation confirms candidates
DEFAULT_MARGIN_UM = REFERENCE_MARGIN_UM
PLATEAU_DIRECTIONS_DEG = (0.0, 45.0, 90.0, 135.0)
PROFILE_SMOOTHING_UM = 250.0  # the floor depth is averaged over this to find the ends at half depth
# The ends are found on the smallest depth at t = 0 and t = +-(this fraction of the half-depth
# width): a microrelief furrow running on from a wrinkle's end is deep on its own line but not
# a quarter of the wrinkle's width beside it (shallow wrinkles read 5-30% too long)
ENDS_ACROSS_FRACTION = 0.25


@dataclass(frozen=True, eq=False)
class WrinkleTrace:
    """Where a wrinkle was measured: its centre line and half-depth edges (pixel coordinates,
    row and column, every half pixel of arc length), the floor depth along the line (um, at arc
    lengths ``s_um``) and its mean over the depth window (the profile the max and mean depth
    come from), and the cross-section in the middle of the line (offsets ``t_um`` across it,
    depth ``depth_um``)."""

    s_um: np.ndarray
    floor_depth_um: np.ndarray
    window_mean_depth_um: np.ndarray
    centre_px: np.ndarray  # (n, 2)
    lower_edge_px: np.ndarray  # (n, 2)
    upper_edge_px: np.ndarray  # (n, 2)
    t_um: np.ndarray
    depth_um: np.ndarray


@dataclass(frozen=True, eq=False)
class WrinkleMeasures:
    """Per-wrinkle measures, field totals, the wrinkle ids (on each wrinkle's core, the
    segmentation's half-depth region), the centre lines they were measured along, and one
    :class:`WrinkleTrace` per wrinkle (in the order of ``wrinkles``)."""

    wrinkles: list
    totals: dict
    labels: np.ndarray
    lines: np.ndarray
    traces: tuple = ()

    def as_dict(self):
        return {"wrinkles": [asdict(w) for w in self.wrinkles], "totals": self.totals}


def plateau_surface(height: HeightMap, furrow_closing_um=DEFAULT_FURROW_CLOSING_UM):
    """The skin without its furrows: the largest of the closings with a level segment of
    ``furrow_closing_um`` at 0, 45, 90 and 135 degrees (see the module notes). Fills the
    wrinkles too where they are narrower than the segment; use it away from them."""
    return line_segment_closing_extremes(height.z, height.spacing, furrow_closing_um, PLATEAU_DIRECTIONS_DEG, height.mask)[1]


def centre_lines(skeleton, spacing):
    """The longest path through each piece of a skeleton: a list of (n, 2) arrays of pixels
    (row, column) in order along the path.

    The longest path is found by two sweeps of a minimum-cost path search over the skeleton
    (scikit-image ``MCP_Geometric``, steps of dx, dy or the diagonal): the point farthest
    from any start, then the point farthest from that one; exact when the piece has no
    loops, as skeletons of wrinkles have not. Each piece is searched in its own bounding box
    (pieces do not touch, even diagonally, so no path leaves it).
    """
    pieces = label(skeleton, connectivity=2)
    paths = []
    for piece, box in enumerate(scipy.ndimage.find_objects(pieces), 1):
        own = pieces[box] == piece
        cost = np.where(own, 1.0, np.inf)
        start = tuple(np.argwhere(own)[0])
        far = _farthest(cost, start, spacing)[0]
        end, search = _farthest(cost, far, spacing)
        paths.append(np.array(search.traceback(end)) + [box[0].start, box[1].start])
    return paths


def _farthest(cost, start, spacing):
    """The skeleton point farthest (along the skeleton) from ``start``, and the search."""
    search = MCP_Geometric(cost, fully_connected=True, sampling=spacing)
    distance = search.find_costs([start])[0]
    distance[~np.isfinite(distance)] = -1.0
    farthest = np.unravel_index(distance.argmax(), distance.shape)
    return farthest, search


def chained_path(paths, spacing):
    """One ordered path (pixels, float) through a wrinkle's centre-line pieces: each piece
    turned to run along their common principal axis, the pieces in order along it (the
    gaps between them are crossed straight)."""
    scale = np.asarray(spacing, float)
    points = np.concatenate(paths) * scale
    axis = np.linalg.svd(points - points.mean(axis=0), full_matrices=False)[2][0]
    turned = [path if (path[-1] * scale) @ axis >= (path[0] * scale) @ axis else path[::-1] for path in paths]
    turned.sort(key=lambda path: (path[0] * scale) @ axis)
    return np.concatenate(turned).astype(float)


@dataclass(frozen=True, eq=False)
class WrinkleFrame:
    """A wrinkle's own coordinates: arc length s along its smoothed centre line (extended
    straight beyond both ends) and signed offset t across it, both in micrometres, sampled
    every ``step_um``; the pixel coordinates of every (t, s) sample; the unit tangent (row,
    column components, micrometres) and the area element |dX/ds x dX/dt| of each sample."""

    s: np.ndarray  # (n_s,)
    t: np.ndarray  # (n_t,)
    rows: np.ndarray  # (n_t, n_s) pixel coordinates of the samples
    columns: np.ndarray
    tangent: np.ndarray  # (n_s, 2)
    area_element: np.ndarray  # (n_t, n_s)
    step_um: float
    spacing: tuple  # of the image's pixels (row, column), um

    def sample(self, image, order=1, prefiltered=False):
        """``image`` at the frame's samples (spline of ``order``; nearest beyond the edges).
        ``prefiltered``: ``image`` already holds the spline coefficients
        (``scipy.ndimage.spline_filter(..., mode="nearest")``), shared between frames.
        Order 0 (the masks) is read by indexing, as ``map_coordinates(order=0,
        mode="nearest")`` rounds and clips (the same values, 5-10x faster)."""
        if order == 0:
            rows = np.clip(np.floor(self.rows + 0.5), 0, image.shape[0] - 1).astype(np.intp)
            columns = np.clip(np.floor(self.columns + 0.5), 0, image.shape[1] - 1).astype(np.intp)
            return np.asarray(image)[rows, columns].astype(float)  # only the samples converted, not the map
        return scipy.ndimage.map_coordinates(np.asarray(image, float), [self.rows, self.columns], order=order, mode="nearest",
                                             prefilter=not prefiltered)

    def direction_deg(self):
        """Direction of the centre line at each s, counter-clockwise from +x (y up), in [0, 180)."""
        return np.degrees(np.arctan2(-self.tangent[:, 0], self.tangent[:, 1])) % 180.0


def quadratic_savitzky_golay(values, window):
    """Savitzky-Golay smoothing along the first axis (Savitzky & Golay 1964): each point is
    the value at its centre of the least-squares quadratic over the ``window`` (odd) points
    around it; within half a window of an end, the quadratic of the first (last) window
    evaluated there (``scipy.signal.savgol_filter(values, window, 2, axis=0,
    mode="interp")``, against which it is tested). Written here because importing
    scipy.signal costs about 0.5 s, more than the wrinkle measures of a megapixel map."""
    values = np.asarray(values, dtype=float)
    half = window // 2
    t = np.arange(-half, half + 1, dtype=float)
    basis = np.stack([np.ones_like(t), t, t * t], axis=1)
    hat = basis @ np.linalg.solve(basis.T @ basis, basis.T)  # (window, window): fitted values of a window's points
    smoothed = scipy.ndimage.correlate1d(values, hat[half], axis=0, mode="constant")
    smoothed[:half] = np.tensordot(hat[:half], values[:window], axes=1)
    smoothed[len(values) - half:] = np.tensordot(hat[half + 1:], values[len(values) - window:], axes=1)
    return smoothed


def wrinkle_frame(path, spacing, *, smoothing_um, extension_um, half_span_um, step_um):
    """The :class:`WrinkleFrame` of an ordered pixel ``path``.

    The path is smoothed with a Savitzky-Golay filter (quadratic, over ``smoothing_um``;
    exact on straight lines and arcs up to the second order, ends included), which removes
    the 8-connected staircase (whose step count overstates a line's length by up to 8%),
    resampled every ``step_um`` of arc length, and extended straight along its end
    tangents by ``extension_um`` at both ends.
    """
    scale = np.asarray(spacing, float)
    points = np.asarray(path, float) * scale
    window = min(len(points) - (1 - len(points) % 2), int(smoothing_um / min(spacing)) | 1)
    if window >= 5:
        points = quadratic_savitzky_golay(points, window)
    arc = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(points, axis=0).T))])
    length = arc[-1]
    s = np.arange(-extension_um, length + extension_um + step_um / 2, step_um)
    inside = np.clip(s, 0.0, length)
    centre = np.stack([np.interp(inside, arc, points[:, k]) for k in range(2)], axis=-1)
    if length > 0:
        reach = min(length, 2 * min(spacing))  # the end tangents, over about two pixels
        first = centre_at(arc, points, reach) - points[0]
        last = points[-1] - centre_at(arc, points, length - reach)
        first, last = first / np.hypot(*first), last / np.hypot(*last)
    else:  # a one-pixel line: along the image's x axis (no direction to follow)
        first = last = np.array([0.0, 1.0])
    centre += np.where((s < 0)[:, None], s[:, None] * first, 0.0) + np.where((s > length)[:, None], (s - length)[:, None] * last, 0.0)
    tangent = np.gradient(centre, step_um, axis=0) if len(s) > 1 else first[None, :]
    tangent /= np.hypot(tangent[:, 0], tangent[:, 1])[:, None]
    normal = np.stack([tangent[:, 1], -tangent[:, 0]], axis=-1)  # the tangent turned by 90 degrees
    t = np.arange(-half_span_um, half_span_um + step_um / 2, step_um)
    position = centre[None, :, :] + t[:, None, None] * normal[None, :, :]
    along = np.gradient(position, step_um, axis=1) if len(s) > 1 else np.broadcast_to(tangent, position.shape)
    area_element = np.abs(along[..., 0] * normal[None, :, 1] - along[..., 1] * normal[None, :, 0])
    return WrinkleFrame(s, t, position[..., 0] / scale[0], position[..., 1] / scale[1], tangent, area_element, step_um,
                        tuple(spacing))


def depth_in_frame(frame: WrinkleFrame, z_spline, reference, plateau, around, others, near, along_closing_um):
    """Depth below the surrounding skin in a wrinkle's frame, and where it belongs to the
    wrinkle (inside ``near``, not in ``others``); ``z_spline``: the cubic spline coefficients
    of the height (``scipy.ndimage.spline_filter(z, 3, mode="nearest")``).

    Crossing furrows are bridged by a closing of ``z`` along s with a ``along_closing_um``
    segment: in the wrinkle's own frame the segment lies exactly along the wrinkle, so it does
    not lift its floor (a digital line segment in the image, half a pixel off a narrow floor,
    lifted a 0.15 mm V wrinkle's floor by 3-8%). It leaves the furrows that run along the
    wrinkle, which the four-way closing of the reference (``plateau``) fills: their mean depth
    on the skin in the frame (``around``) is added back, so both closings share one level.
    """
    others = frame.sample(others, order=0) > 0.5
    inside = (frame.sample(near, order=0) > 0.5) & ~others
    heights = frame.sample(z_spline, order=3, prefiltered=True)
    closed = scipy.ndimage.grey_closing(heights, size=(1, _samples(along_closing_um, frame)), mode="nearest")
    ring = (frame.sample(around, order=0) > 0.5) & ~others
    left_by_along = float(np.mean(frame.sample(plateau)[ring] - closed[ring])) if ring.any() else 0.0
    return frame.sample(reference) - (closed + left_by_along), inside


def floor_profile(frame: WrinkleFrame, depth, inside, smoothing_um, across_um=0.0):
    """The depth on the centre line (t = 0) averaged along s over ``smoothing_um`` (what the
    closing and the reference leave of the roughness is noise that a threshold would cross
    back and forth); -inf where the centre line is not inside the wrinkle. ``across_um``: the
    smallest of the depths at t = 0 and t = +-``across_um`` instead (linear between samples;
    a side outside the wrinkle, e.g. in one it crosses, is left out)."""
    centre = int(np.abs(frame.t).argmin())
    valid = inside[centre]
    n = _samples(smoothing_um, frame)
    floor = depth[centre]
    if across_um > 0:
        for side in (-1, 1):
            position = np.clip(centre + side * across_um / frame.step_um, 0, frame.t.size - 1)
            low = min(int(position), frame.t.size - 2)
            fraction = position - low
            beside = np.where(inside[low] & inside[low + 1], (1 - fraction) * depth[low] + fraction * depth[low + 1], np.inf)
            floor = np.minimum(floor, beside)
    total = scipy.ndimage.uniform_filter1d(np.where(valid, floor, 0.0), n, mode="nearest")
    share = scipy.ndimage.uniform_filter1d(valid.astype(float), n, mode="nearest")
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(valid & (share > 0), total / share, -np.inf)


def _samples(length_um, frame):
    """An odd number of frame steps covering ``length_um``."""
    return max(1, int(round(length_um / frame.step_um)) | 1)


def cross_section_edges(frame: WrinkleFrame, depth, level):
    """Offsets (um) of the two edges of each cross-section at ``level`` (per s): where depth
    first falls below it on either side of the centre line."""
    centre = np.full(depth.shape[1], int(np.abs(frame.t).argmin()))
    return _crossing(depth, level, centre, frame.t, -1), _crossing(depth, level, centre, frame.t, +1)


def deep_cross_sections(frame: WrinkleFrame, depth, profile, depth_fraction):
    """(lower, upper, deep): the edges (um) of each cross-section at ``depth_fraction`` of the
    floor ``profile`` there, and where the floor is at that fraction of its deepest or
    deeper (the cross-sections whose edges belong to the wrinkle)."""
    lower, upper = cross_section_edges(frame, depth, depth_fraction * np.where(np.isfinite(profile), profile, 0.0))
    finite = np.isfinite(profile)
    deepest = profile[finite].max() if finite.any() else np.inf
    return lower, upper, finite & (profile >= depth_fraction * deepest)


def midline(frame: WrinkleFrame, depth, profile, depth_fraction, extension_um):
    """The middle of the wrinkle's half-depth cross-sections (pixels, in order along the
    first centre line's arc, not its extensions): the centre line. Median-filtered, then
    Savitzky-Golay smoothed over the frame's extension, so that a furrow crossing a wall
    does not pull it. The skeleton of the half-depth region is a fraction of a pixel off
    the middle, and a closing along a line that is off a narrow floor lifts it."""
    line = (frame.s >= 0) & (frame.s <= frame.s[-1] - extension_um)
    lower, upper, deep = deep_cross_sections(frame, depth, profile, depth_fraction)
    middle = 0.5 * (lower + upper)
    offset = np.interp(frame.s, frame.s[deep], middle[deep]) if deep.any() else np.zeros(frame.s.size)
    n = _samples(extension_um, frame)
    offset = scipy.ndimage.median_filter(offset, size=n, mode="nearest")[line]
    if offset.size >= 5:
        offset = quadratic_savitzky_golay(offset, min(n, offset.size - (1 - offset.size % 2)))
    centre = int(np.abs(frame.t).argmin())
    normal = np.stack([frame.tangent[line, 1], -frame.tangent[line, 0]], axis=-1)
    points = np.stack([frame.rows[centre, line], frame.columns[centre, line]], axis=-1)
    return points + offset[:, None] * normal / np.asarray(frame.spacing)


def centre_at(arc, points, where):
    """The point of a polyline (``points`` at arc lengths ``arc``) at arc length ``where``."""
    return np.array([np.interp(where, arc, points[:, k]) for k in range(2)])


def _bounding_box(points, pad, origin=(0, 0)):
    """Slices of the bounding box of the true ``points``, widened by ``pad`` pixels (one
    number, or one per axis) and clipped at the array's start; ``points`` may be a crop whose
    first pixel is at ``origin`` (row, column) of the array the slices are for."""
    pad = np.broadcast_to(pad, 2)
    rows, columns = np.nonzero(points)
    rows, columns = rows + origin[0], columns + origin[1]
    return (slice(max(0, rows.min() - pad[0]), rows.max() + pad[0] + 1),
            slice(max(0, columns.min() - pad[1]), columns.max() + pad[1] + 1))


def _crossing(depth, threshold, floor, t, side):
    """Offset (um) where each column of ``depth`` (n_t, n) first falls below ``threshold``
    going from its ``floor`` index toward ``side`` (+1 or -1), interpolated linearly between
    samples; the frame's edge when it never does."""
    n_t = depth.shape[0]
    index = np.arange(n_t)[:, None]
    below = ((index - floor[None, :]) * side > 0) & (depth < threshold[None, :])
    if side > 0:
        first = np.where(below, index, n_t).min(axis=0)
        found = first < n_t
    else:
        first = np.where(below, index, -1).max(axis=0)
        found = first >= 0
    first = np.where(found, first, 0)
    inner = np.clip(first - side, 0, n_t - 1)
    columns = np.arange(depth.shape[1])
    high, low = depth[inner, columns], depth[first, columns]
    with np.errstate(invalid="ignore", divide="ignore"):
        fraction = np.clip((high - threshold) / (high - low), 0.0, 1.0)
    return np.where(found, t[inner] + side * fraction * (t[1] - t[0]), t[-1] if side > 0 else t[0])


def axial_mean_deg(angles_deg, weights=None):
    """Mean of axial angles (degrees, period 180) by the doubled-angle circular mean:
    0.5 atan2(sum w sin 2a, sum w cos 2a), in [0, 180) (NaN when there are none)."""
    angles = np.radians(np.asarray(angles_deg, float)) * 2
    weights = np.ones_like(angles) if weights is None else np.asarray(weights, float)
    if angles.size == 0:
        return float("nan")
    return float(np.degrees(0.5 * np.arctan2((weights * np.sin(angles)).sum(), (weights * np.cos(angles)).sum())) % 180.0)


@dataclass(frozen=True)
class WrinkleSettings:
    """Settings of the wrinkle measures (micrometres; see the module notes):

    short_cutoff_um
        S-filter of the height before the depth is read (default 0: none).
    reference_cutoff_um, margin_um
        Gaussian regression cut-off of the local skin level (2.5 mm), and the margin around
        the wrinkles' extents left out of it (0.15 mm).
    depth_fraction
        The level, as a fraction of the floor depth, of the ends and of the width (0.5).
    furrow_closing_um, along_closing_um, depth_window_um
        The closing segments that fill the furrows around a wrinkle (0.2 mm) and bridge those
        crossing it (1 mm), and the stretch of centre line whose mean depth is the max depth (1 mm).
    """

    short_cutoff_um: float = DEFAULT_DEPTH_SHORT_CUTOFF_UM
    reference_cutoff_um: float = DEFAULT_REFERENCE_CUTOFF_UM
    margin_um: float = DEFAULT_MARGIN_UM
    depth_fraction: float = 0.5
    furrow_closing_um: float = DEFAULT_FURROW_CLOSING_UM
    along_closing_um: float = DEFAULT_ALONG_CLOSING_UM
    depth_window_um: float = DEFAULT_DEPTH_WINDOW_UM

    def __post_init__(self):
        for name, value in (("furrow closing", self.furrow_closing_um), ("along closing", self.along_closing_um),
                            ("margin", self.margin_um), ("depth window", self.depth_window_um)):
            if not value > 0:
                raise SkinTopoError(f"the {name} length must be positive, got {value} um")
        if not self.short_cutoff_um >= 0:
            raise SkinTopoError(f"the depth's S-filter cut-off must be 0 (none) or positive, got {self.short_cutoff_um} um")


class _instance_cached_property(cached_property):
    """``functools.cached_property`` without its lock: before Python 3.12 it holds one lock per
    property for every instance, so threads measuring different wrinkles waited for each other
    (3 wrinkles of a 1024 x 1024 forehead on two threads: 0.50-0.63 s with the lock, 0.32-0.38 s
    without). One instance is measured by one thread (:func:`wrinkle_properties`).
    """

    def __get__(self, instance, owner=None):
        if instance is None:
            return self
        cache = instance.__dict__
        if self.attrname not in cache:
            cache[self.attrname] = self.func(instance)
        return cache[self.attrname]


@dataclass(frozen=True, eq=False)
class WrinkleField:
    """A height map prepared for wrinkle measures (see the module notes): the height with the
    skin's quadratic form removed (``z``, missing points at the reference level), the skin
    without furrows (``plateau``), the local skin level (``reference``), the skin around the
    wrinkles, the segmentation's labels, the wrinkles' extents (their walls) and the settings."""

    height: HeightMap
    z: np.ndarray
    plateau: np.ndarray
    reference: np.ndarray
    around: np.ndarray
    labels: np.ndarray
    extent: np.ndarray
    extent_labels: np.ndarray
    settings: WrinkleSettings

    @cached_property
    def nearest_core(self):
        """The label of the nearest half-depth region at every point: where wrinkles touch
        (crossing wrinkles, basins that meet), each point of their shared extent belongs to
        the wrinkle whose half-depth region is nearest. Computed only when some extent holds
        two wrinkles (a map-sized distance transform, 50-80 ms at 1024 x 1024)."""
        _, (rows, columns) = scipy.ndimage.distance_transform_edt(self.labels == 0, return_indices=True)
        return self.labels[rows, columns]

    @property
    def margin_px(self):
        return margin_pixels(self.settings.margin_um, self.height.spacing)

    @cached_property
    def extent_boxes(self):
        """The bounding box (slices) of each extent, index = its label - 1."""
        return scipy.ndimage.find_objects(self.extent_labels)


def wrinkle_field(height: HeightMap, segmentation: WrinkleSegmentation, settings=WrinkleSettings()) -> WrinkleField:
    """The :class:`WrinkleField` of a height map and its segmentation."""
    if segmentation.labels.shape != height.shape:
        raise ValueError(f"segmentation shape {segmentation.labels.shape} differs from the height map {height.shape}")
    extent = np.asarray(segmentation.extent, bool)
    around = skin_around(height.mask, extent, height.spacing, settings.margin_um)
    if around is None:
        raise SkinTopoError("too little skin around the wrinkles to set the local reference level")
    # The least-squares quadratic form of the skin around the wrinkles is removed first: the
    # reference's Gaussian regression passes planes but lifts a curved forehead's level by
    # sigma^2 / (2 R) (1.4 um at 2.5 mm and R = 80 mm), which summed over a wrinkle's walls
    # is 10-15% of a shallow one's volume.
    z = height.z - polynomial_form(height.z, height.spacing, 2, around)
    if settings.short_cutoff_um:  # only when asked: it fills the floor of every wrinkle narrower than about 4 x the cut-off
        z = areal_gaussian_filter(z, height.spacing, settings.short_cutoff_um, height.mask)
    height = HeightMap(z, height.spacing, height.mask)
    plateau = plateau_surface(height, settings.furrow_closing_um)
    reference = skin_level(plateau, height.spacing, around, settings.reference_cutoff_um)
    # no skin within the regression's reach (inside a wide wrinkled area); ``around`` holds some, so some point has a level
    reference, = fill_from_nearest(np.isfinite(reference), reference)
    # Outside the mask (no data) the skin is taken at its reference level, so that the frame's
    # interpolation never reads a missing value; those samples are not part of any wrinkle.
    z, plateau = (np.where(height.mask, image, reference) for image in (height.z, plateau))
    return WrinkleField(height, z, plateau, reference, around, segmentation.labels, extent, label(extent), settings)


@dataclass(frozen=True)
class MeasuredWrinkle:
    """Measures of one wrinkle (units in the names; definitions in the module notes)."""

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


WRINKLE_COLUMNS = tuple(f.name for f in fields(MeasuredWrinkle))


class WrinkleProperties:
    """The measures of one wrinkle, each computed when first read and then cached (the model
    is scikit-image's ``RegionProperties``); the definitions are in the module notes and
    docs/wrinkle-measures.md. ``label``: the wrinkle's label in the segmentation; ``id``: its
    number among the measured wrinkles (:func:`wrinkle_properties`).

    The frame and the depth in it are computed once for all measures; a table of some
    measures (:func:`wrinkle_table`) computes only what those need."""

    def __init__(self, region, field: WrinkleField, id=None):
        self.label = region.label
        self.id = id
        self._region = region
        self._field = field

    def numbered(self, id):
        """This wrinkle as number ``id`` (what was computed is shared)."""
        numbered = copy.copy(self)
        numbered.id = id
        return numbered

    @_instance_cached_property
    def _box(self):
        """The wrinkle's box (its walls and the frame's reach), its whole extent in that box
        and the frame settings."""
        field, (dy, dx) = self._field, self._field.height.spacing
        # Worked on the boxes of the core and of its extent, never on the whole map: a field
        # of many wrinkles would otherwise cost a map-sized mask (and a pass) per wrinkle.
        core_box = self._region.slice
        core = field.labels[core_box] == self.label
        extent = np.bincount(field.extent_labels[core_box][core]).argmax()  # the core lies in its extent
        extent_box = field.extent_boxes[extent - 1]
        whole = field.extent_labels[extent_box] == extent
        touches = np.count_nonzero(np.unique(field.labels[extent_box][whole])) > 1  # its extent touches another wrinkle's
        if touches:
            whole &= field.nearest_core[extent_box] == self.label
        axis = max(self._region.axis_major_length * min(dy, dx), dx)
        core_width = np.count_nonzero(core) * dx * dy / axis
        extent_width = np.count_nonzero(whole) * dx * dy / axis
        half_span = 0.75 * extent_width + field.settings.margin_um + 2 * max(dy, dx)
        extension = core_width + field.settings.along_closing_um
        origin = (extent_box[0].start, extent_box[1].start)
        box = _bounding_box(whole, int((half_span + extension) / min(dy, dx)) + 3, origin)
        in_box = field.extent_labels[box] == extent  # the same extent, in the box's pixels
        if touches:
            in_box &= field.nearest_core[box] == self.label
        options = dict(smoothing_um=field.settings.along_closing_um, extension_um=extension, half_span_um=half_span, step_um=0.5 * min(dy, dx))
        return box, in_box, options

    @property
    def core(self):
        """The wrinkle's half-depth region (the segmentation's) in its box: (box, mask)."""
        box = self._box[0]
        return box, self._field.labels[box] == self.label

    @_instance_cached_property
    def _maps(self):
        """What :func:`depth_in_frame` reads, cut to the box (the height as spline coefficients)."""
        field = self._field
        box, whole, _ = self._box
        near = scipy.ndimage.binary_dilation(whole, iterations=field.margin_px)
        return (scipy.ndimage.spline_filter(field.z[box], order=3, mode="nearest"), field.reference[box], field.plateau[box],
                field.around[box], field.extent[box] & ~whole, near & field.height.mask[box], field.settings.along_closing_um)

    def _depth_along(self, frame):
        """The depth in ``frame``, where it is the wrinkle's, and the floor profile."""
        depth, inside = depth_in_frame(frame, *self._maps)
        return depth, inside, floor_profile(frame, depth, inside, PROFILE_SMOOTHING_UM)

    @_instance_cached_property
    def _measured(self):
        """The frame on the wrinkle's centre line, the depth in it, where it is the wrinkle's,
        and the floor profile; None when the wrinkle has no centre line at half depth."""
        _, _, options = self._box
        spacing = self._field.height.spacing
        first = wrinkle_frame(chained_path(centre_lines(skeletonize(self.core[1]), spacing), spacing), spacing, **options)
        depth, _, profile = self._depth_along(first)
        if not np.isfinite(profile).any():
            return None
        frame = wrinkle_frame(midline(first, depth, profile, self._field.settings.depth_fraction, options["extension_um"]), spacing, **options)
        depth, inside, profile = self._depth_along(frame)
        return (frame, depth, inside, profile) if np.isfinite(profile).any() else None

    @property
    def measurable(self):
        """Whether the wrinkle has a centre line with ends at half depth (:attr:`_ends`)."""
        return self._measured is not None and self._ends is not None

    @property
    def frame(self) -> WrinkleFrame:
        return self._measured[0]

    @_instance_cached_property
    def _ends(self):
        """Indices along s of the first and last samples at half depth or deeper, that level, and
        the profile they are read on: the floor profile of the smallest depth at t = 0 and
        t = +-``ENDS_ACROSS_FRACTION`` of the median half-depth width (of the samples at half
        depth or deeper on the centre line's own profile). For a wrinkle d = D e(s) f(t) the
        ends are those of the centre line's profile; a furrow narrower than half the wrinkle's
        half-depth width that runs on from an end does not carry it on. None when no sample is
        at half depth (a region with no floor below the surrounding skin, or whose floor
        profile is off the map): not measurable."""
        frame, depth, inside, profile = self._measured
        fraction = self._field.settings.depth_fraction
        lower, upper, deep = deep_cross_sections(frame, depth, profile, fraction)
        if not deep.any():
            return None
        across = ENDS_ACROSS_FRACTION * float(np.median((upper - lower)[deep]))
        profile = floor_profile(frame, depth, inside, PROFILE_SMOOTHING_UM, across)
        if not np.isfinite(profile).any():
            return None
        threshold = fraction * float(np.nanmax(profile))
        deep = np.flatnonzero(profile >= threshold)
        return (deep[0], deep[-1], threshold, profile) if deep.size else None  # none: a floor above the skin

    @_instance_cached_property
    def length_mm(self):
        """Arc length between the ends at half depth, each interpolated between the last
        sample above and the first below."""
        frame = self.frame
        first, last, threshold, profile = self._ends
        length = frame.s[last] - frame.s[first]
        for end, outward in ((first, -1), (last, 1)):
            beyond = end + outward
            if 0 <= beyond < frame.s.size and np.isfinite(profile[beyond]) and profile[end] > profile[beyond]:
                length += frame.step_um * (profile[end] - threshold) / (profile[end] - profile[beyond])
        return float(length) / 1000

    @_instance_cached_property
    def _line(self):
        """The centre line between the ends (a slice of s), and the floor profile and the floor
        depth on it: where the line crosses another wrinkle or leaves the field, both are
        interpolated along s from the samples on either side."""
        frame, depth, inside, profile = self._measured
        first, last, _, _ = self._ends
        on_line = slice(first, last + 1)
        centre = int(np.abs(frame.t).argmin())
        on = np.flatnonzero(inside[centre, on_line])
        line_s = frame.s[on_line]
        return (on_line, np.interp(line_s, line_s[on], profile[on_line][on]),
                np.interp(line_s, line_s[on], depth[centre, on_line][on]))

    @_instance_cached_property
    def _edges(self):
        """Offsets (um) of the two half-depth edges of each cross-section, perpendicular to
        the centre line."""
        on_line, line_depth, _ = self._line
        return cross_section_edges(self.frame, self._measured[1][:, on_line], self._field.settings.depth_fraction * line_depth)

    @_instance_cached_property
    def _own_sections(self):
        """The cross-sections whose centre is the wrinkle's (not inside a wrinkle it crosses,
        nor outside the field): those its width and area are read from."""
        frame, _, inside, _ = self._measured
        own = inside[int(np.abs(frame.t).argmin()), self._line[0]]
        return own if own.any() else np.ones_like(own)

    @_instance_cached_property
    def _mean_width_um(self):
        lower, upper = self._edges
        return float(np.mean((upper - lower)[self._own_sections]))

    @property
    def mean_width_mm(self):
        """Mean width at half the floor depth."""
        return self._mean_width_um / 1000

    @property
    def half_depth_area_um2(self):
        """Area between the half-depth edges."""
        lower, upper = self._edges
        return float(np.sum((upper - lower)[self._own_sections]) * self.frame.step_um)

    @_instance_cached_property
    def volume_mm3(self):
        """The signed depth over the whole wrinkle (its ends below half depth included) and
        its walls (within a width plus the margin of the centre line; other wrinkles and the
        field's outside left out), with the frame's area element. Where the centre line runs
        inside a wrinkle it crosses, the volume per length is interpolated from either side."""
        frame, depth, inside, _ = self._measured
        walls = (np.abs(frame.t)[:, None] <= self._mean_width_um + self._field.settings.margin_um) & inside
        step = frame.step_um
        crossed = frame.sample(self._maps[4], order=0)[int(np.abs(frame.t).argmin())] > 0.5  # the line inside a wrinkle it crosses
        if crossed.any() and not crossed.all():  # there, its volume per length is interpolated along s, as its depth is
            per_s = np.where(walls, depth * frame.area_element, 0.0).sum(axis=0)
            s = np.arange(per_s.size)
            return float(np.interp(s, s[~crossed], per_s[~crossed]).sum() * step * step * 1e-9)
        return float((depth * frame.area_element)[walls].sum() * step * step * 1e-9)  # um^3 -> mm^3

    @_instance_cached_property
    def window_mean_depth_um(self):
        """The floor's depth along the centre line averaged over ``depth_window_um`` (mirrored
        at the line's ends, so that its mean is the line's): max and mean depth come from this
        one profile, so mean <= max always."""
        floor_depth = self._line[2]
        return scipy.ndimage.uniform_filter1d(floor_depth, min(_samples(self._field.settings.depth_window_um, self.frame), floor_depth.size),
                                              mode="reflect")

    @property
    def max_depth_um(self):
        return float(self.window_mean_depth_um.max())

    @property
    def mean_depth_um(self):
        return float(self.window_mean_depth_um.mean())

    @property
    def orientation_deg(self):
        return axial_mean_deg(self.frame.direction_deg()[self._line[0]])

    @property
    def centroid_x_mm(self):
        return float(self._region.centroid[1]) * self._field.height.spacing[1] / 1000

    @property
    def centroid_y_mm(self):
        return float(self._region.centroid[0]) * self._field.height.spacing[0] / 1000

    @property
    def cross_section_mm2(self):
        return self.volume_mm3 / self.length_mm

    @property
    def severity(self):
        return self.mean_depth_um * self.length_mm / 100

    @_instance_cached_property
    def trace(self) -> WrinkleTrace:
        """Where the wrinkle was measured, in pixel coordinates of the whole map."""
        frame, depth = self.frame, self._measured[1]
        first, last, _, _ = self._ends
        on_line, _, floor_depth = self._line
        lower, upper = self._edges
        box = self._box[0]
        centre = int(np.abs(frame.t).argmin())
        normal = np.stack([frame.tangent[on_line, 1], -frame.tangent[on_line, 0]], axis=-1) / np.asarray(frame.spacing)
        centre_px = np.stack([frame.rows[centre, on_line], frame.columns[centre, on_line]], axis=-1)
        centre_px += np.array([box[0].start, box[1].start], float)
        return WrinkleTrace(frame.s[on_line] - frame.s[first], floor_depth, self.window_mean_depth_um, centre_px,
                            centre_px + lower[:, None] * normal, centre_px + upper[:, None] * normal, frame.t, depth[:, (first + last) // 2])

    def line_pixels(self):
        """The pixels (rows, columns of the whole map) of the centre line between the ends."""
        box, core = self.core
        centre = int(np.abs(self.frame.t).argmin())
        on_line = self._line[0]
        rows = np.clip(np.rint(self.frame.rows[centre, on_line]).astype(int), 0, core.shape[0] - 1)
        columns = np.clip(np.rint(self.frame.columns[centre, on_line]).astype(int), 0, core.shape[1] - 1)
        return rows + box[0].start, columns + box[1].start

    def row(self) -> MeasuredWrinkle:
        return MeasuredWrinkle(**{name: getattr(self, name) for name in WRINKLE_COLUMNS})


def wrinkle_properties(height: HeightMap, segmentation: WrinkleSegmentation, **settings) -> list:
    """The :class:`WrinkleProperties` of every measurable wrinkle (one with a centre line at
    half depth and a max depth of at least the segmentation's ``min_depth_um``), numbered
    1..n by their centroids, top to bottom then left to right
    (``settings``: those of :class:`WrinkleSettings`)."""
    settings = WrinkleSettings(**settings)
    if segmentation.count == 0 and segmentation.labels.shape == height.shape:
        return []
    field = wrinkle_field(height, segmentation, settings)
    regions = sorted(regionprops(segmentation.labels), key=lambda r: (round(r.centroid[0] / 4), r.centroid[1]))
    wrinkles = [WrinkleProperties(region, field) for region in regions]
    # each wrinkle's frame and depth on one of four threads (NumPy and SciPy release the GIL);
    # every wrinkle is measured whole by one thread, in the same order of operations as alone.
    # Four on two cores: a wrinkle is the unit of work, and with two threads the last of an odd
    # few ran alone on one core (a 1024^2 forehead's 3 wrinkles: 0.305 -> 0.260 s, medians of 4)
    # A segmented valley whose max depth (this module's, from the geometry) is below the
    # segmentation's minimum depth is not a wrinkle: the band-pass and the straight-valley
    # closings only propose candidates. bench_wrinkles (seeds 0-479): microrelief fields
    # without a false wrinkle 92.7% -> 95.8%, every detectable wrinkle still found; the 6 false
    # ones it removes (of 14) were narrow furrows reading 5-25 um.
    minimum = segmentation.parameters.get("min_depth_um", 0.0)
    with ThreadPoolExecutor(max_workers=4) as pool:
        measurable = [w for w, keep in zip(wrinkles, pool.map(lambda w: w.measurable and w.max_depth_um >= minimum, wrinkles)) if keep]
    return [w.numbered(number) for number, w in enumerate(measurable, 1)]


def wrinkle_table(height: HeightMap, segmentation: WrinkleSegmentation, properties=WRINKLE_COLUMNS, **settings) -> dict:
    """Chosen measures of every wrinkle as columns, ``{name: array}`` (the model is
    scikit-image's ``regionprops_table``); only what they need is computed, and each
    wrinkle's max depth, which decides whether it is one (:func:`wrinkle_properties`). ``properties``:
    attributes of :class:`WrinkleProperties` (e.g. ``"label"``, ``"max_depth_um"``);
    ``settings``: those of :class:`WrinkleSettings`."""
    unknown = [name for name in properties if name not in ("id", "label") and not hasattr(WrinkleProperties, name)]
    if unknown:
        raise ValueError(f"unknown wrinkle properties {unknown}; the measures are {', '.join(WRINKLE_COLUMNS)}")
    wrinkles = wrinkle_properties(height, segmentation, **settings)
    return {name: np.array([getattr(w, name) for w in wrinkles]) for name in properties}


def measure_wrinkles(height: HeightMap, segmentation: WrinkleSegmentation, **settings) -> WrinkleMeasures:
    """Per-wrinkle measures and field totals (see the module notes): every measure of
    :func:`wrinkle_properties` as a :class:`MeasuredWrinkle`, the id image, the centre lines
    and the traces. ``height`` in micrometres; ``segmentation``: the wrinkles' half-depth
    regions (labels) and extents; ``settings``: those of :class:`WrinkleSettings`."""
    wrinkles = wrinkle_properties(height, segmentation, **settings)
    ids, lines = np.zeros(height.shape, np.int32), np.zeros(height.shape, bool)
    for wrinkle in wrinkles:
        box, core = wrinkle.core
        ids[box][core] = wrinkle.id
        lines[wrinkle.line_pixels()] = True
    half_area = sum(w.half_depth_area_um2 for w in wrinkles)
    rows = [w.row() for w in wrinkles]
    return WrinkleMeasures(rows, _totals(rows, height, half_area), ids, lines, tuple(w.trace for w in wrinkles))


def _totals(wrinkles, height, half_area_um2):
    total_length = sum(w.length_mm for w in wrinkles)
    return {
        "count": len(wrinkles),
        "total_length_mm": total_length,
        "mean_depth_um": (sum(w.mean_depth_um * w.length_mm for w in wrinkles) / total_length) if total_length else float("nan"),
        "mean_orientation_deg": axial_mean_deg([w.orientation_deg for w in wrinkles], [w.length_mm for w in wrinkles]),
        "area_fraction": half_area_um2 / (height.spacing[0] * height.spacing[1] * max(1, int(height.mask.sum()))),
    }
