"""Wrinkle segmentation from a height map: ISO Gaussian band-pass, then watershed (paper §5).

The paper segments wrinkles on the Gaussian-filtered height map rather than on an image,
because the height map does not over-segment. Steps:

1. Remove the least-squares quadratic form, then band-pass with the ISO 16610-61 Gaussian: ``short_cutoff_um`` (lambda_s,
   default 0.6 mm) removes the microrelief furrows (about 0.1 mm wide) and ``cutoff_um``
   (lambda_c, default 8 mm) removes the form (forehead curvature). The defaults were chosen
   on the simulator presets: they find every wrinkle of all three forehead states and none
   on the plain microrelief (see the tests for precision, recall and IoU). d = -band-pass is the local depth (positive in valleys).
   The lambda_c mean line is computed on block means with 16 samples per Gaussian sigma
   (:func:`~skintopo.filters.coarse_areal_gaussian_filter`; 4 x 4 blocks at 20 um): 0.13 s
   less per 1024 x 1024 map. It moves the wrinkle measures a little: in bench_wrinkles
   (seeds 0-479) 362 of 960 rows' errors changed, by up to 1.6 points; max depth within 5% on
   microrelief fields went 93.3% -> 93.0% (one wrinkle -4.9% -> -6.5%); within all five
   tolerances nothing changed on seeds 0-479, and on held-out seeds 480-959 two wrinkles fewer
   (one crossing, one not). 8 samples per sigma changed more (a crossing wrinkle lost on each
   seed range, a false one gained) and was not kept.
2. Markers: connected valleys deeper than ``min_depth_um`` seed one region each; points
   shallower than a quarter of that seed the background.
3. Watershed (scikit-image) of -d from those markers: each seeded valley floods outward
   until it meets the background.
4. Each valley is kept down to half of its local maximum depth (the maximum of d within
   ``width_window_um`` over the valleys that run the same way,
   :func:`local_maximum_along_valley`: a shallow wrinkle crossing a deeper one is held against
   its own floor, also when it reads below ``min_depth_um`` on the band-pass but runs
   straight, step 6): the half-depth region, where width is measured. Touching
   regions merge, and regions shorter than ``min_length_um`` (major axis) are dropped; a
   kept wrinkle keeps every half-depth piece of its basin group.
5. Confirmation: a candidate is kept only if its core lies at least ``min_depth_um``
   (median) below the skin around it, judged on the surface S-filtered at 0.25 mm against a
   Gaussian regression (2.5 mm) over the skin outside all candidates. This removes valleys
   that the long-wave mean line invents at the field's edges next to deep wrinkles.
6. Straight valleys (``straight_valley_um``, default 1.5 mm; 0 = steps 1-5 alone, the
   paper's method): the band-pass's lambda_s leaves narrow shallow wrinkles below the minimum
   depth (a 54 um deep, 0.27 mm wide one reads 22 um). Valleys that run straight over that
   length in some direction survive the lowest of 48 line-segment closings
   (:func:`straight_valley_depth`), the microrelief's polygons do not; such valleys at least
   ``min_length_um`` long, outside the wrinkles already found, are added
   (:func:`_straight_valleys`). On 480 random simulated fields (bench_wrinkles) this raised
   the wrinkles found (30 um deep or more) from 84% to 99.2% (every one of them in 98.5% of
   the fields), with a false wrinkle in 3.8% of the fields; counting a shallow wrinkle merged
   into a deeper one it crosses as not found (one true wrinkle per measured one), 94.6% and
   90.5% (99.4% and 98.9% outside crossing pairs, 75% and 57% in them; 95.0% and 91.3%,
   78% and 61% in crossing pairs since the crossing split of 2026-12-04, step 7; 95.3% and
   91.7%, 79% and 63% since the straight-valley reference of step 4).
7. Crossing wrinkles (one basin group, so one label) are split, one label per wrinkle
   (:func:`split_crossing_wrinkles`): the skeleton is cut at its junctions and its arms are
   continued by the straightest continuation, through a junction or across a gap.

Returns wrinkle labels (0 = none, half-depth regions), the centre lines (skeleton), and the
full extent of the kept wrinkles (their watershed basins, walls included).
"""

from __future__ import annotations

from collections import Counter
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np
import scipy.ndimage
from skimage.measure import label, regionprops
from skimage.morphology import skeletonize
from skimage.segmentation import watershed

from skintopo.defaults import (
    DEFAULT_CUTOFF_UM,
    DEFAULT_MIN_DEPTH_UM,
    DEFAULT_MIN_LENGTH_UM,
    DEFAULT_SHORT_CUTOFF_UM,
    DEFAULT_STRAIGHT_VALLEY_UM,
)
from skintopo.errors import SkinTopoError
from skintopo.filters import (
    areal_gaussian_filter,
    block_mean,
    block_means_of_valid,
    coarse_areal_gaussian_filter,
    ellipse_axes,
    expanded_blocks,
    gaussian_bandpass,
    gaussian_moments,
    level,
    line_segment_closing_extremes,
)
from skintopo.heightmap import HeightMap, pixel_spacing

DEFAULT_WIDTH_WINDOW_UM = 1500.0
REFERENCE_CUTOFF_UM = 2500.0  # local skin level for confirming candidates
REFERENCE_MARGIN_UM = 150.0
REFERENCE_SHORT_CUTOFF_UM = 250.0  # ISO lambda_s series value; keeps most of a 0.4 mm wrinkle's depth
# 3.75 degrees apart: a 1.5 mm segment laid at most 1.9 degrees off a valley's axis strays
# 25 um from it at its ends, inside a 0.15 mm wide wrinkle's floor (16 directions strayed
# 74 um: the closing filled a narrow wrinkle, a 64 um deep one read 21 um). On bench_wrinkles'
# seeds 120-479, fields with every detectable wrinkle found / without a false wrinkle:
# 16 directions 94.1% / 98.1%, 24: 96.9 / 98.1, 32: 97.8 / 97.2, 48: 98.6 / 96.4,
# 64: 98.9 / 94.2; the false wrinkles that more directions add are narrow straight furrows.
# The half-depth reference follows the valley's direction (local_maximum_along_valley): 8 bins
# of 22.5 degrees (a point's own and the two beside it: the same way is within 22.5-56 degrees),
# structure tensor integrated over 200 um (100 / 200 / 300 um on bench_wrinkles' seeds 0-479,
# crossing pairs with every detectable wrinkle found, one-to-one matching: 200 um chosen; held
# out on seeds 480-959, docs/method.md). 12 bins of 15 degrees found more crossing wrinkles
# (seeds 0-479: fields with every detectable wrinkle 61 -> 68 of 96; held out 70 -> 70) but made
# wrinkle measures less repeatable between captures of unchanged skin (bench_change_detection:
# five parameters flagged in 6-10% of 50 trials, was at most 4%): not kept (2026-12-04).
ORIENTATION_BINS = 8
LONG_WAVE_SAMPLES_PER_SIGMA = 16  # the band-pass's lambda_c mean line on block means (module notes, step 1)
ORIENTATION_SCALE_UM = 200.0
STRAIGHT_VALLEY_DIRECTIONS = tuple(np.arange(48) * 180.0 / 48)
STRAIGHT_VALLEY_PIXEL_UM = 40.0
# A straight-valley candidate's core must reach 80% of the minimum depth (median): the closing
# along a 1.5 mm segment fills part of a curved or tapered wrinkle's floor. Chosen on the
# wrinkles that bench_wrinkles' first run missed (13 of 15 recovered, none on 6 furrowed fields).
STRAIGHT_VALLEY_CONFIRMATION = 0.8
STRAIGHT_VALLEY_RING_UM = 500.0  # the skin around a straight-valley candidate that it must lie below


@dataclass(frozen=True, eq=False)
class WrinkleSegmentation:
    """Output of :func:`segment_wrinkles`.

    Attributes
    ----------
    labels : ndarray of int
        0 outside wrinkles, 1..n inside wrinkle i (half-depth region).
    lines : ndarray of bool
        Centre lines (skeleton of each region).
    extent : ndarray of bool
        The whole wrinkle, walls included: each kept wrinkle's watershed basin, down to where
        the local depth falls to the background level (a quarter of ``min_depth_um``).
    depth : ndarray
        The band-passed local depth d in micrometres (positive in valleys).
    parameters : dict
        The parameters used.
    """

    labels: np.ndarray
    lines: np.ndarray
    extent: np.ndarray
    depth: np.ndarray
    parameters: dict

    @property
    def mask(self):
        return self.labels > 0

    @property
    def count(self):
        return int(self.labels.max())


def segment_wrinkles(
    height: HeightMap,
    *,
    cutoff_um=DEFAULT_CUTOFF_UM,
    short_cutoff_um=DEFAULT_SHORT_CUTOFF_UM,
    min_depth_um=DEFAULT_MIN_DEPTH_UM,
    min_length_um=DEFAULT_MIN_LENGTH_UM,
    width_window_um=DEFAULT_WIDTH_WINDOW_UM,
    straight_valley_um=DEFAULT_STRAIGHT_VALLEY_UM,
) -> WrinkleSegmentation:
    """Segment wrinkles in a height map (micrometres). See the module notes for the steps."""
    if min_depth_um <= 0 or min_length_um < 0:
        raise SkinTopoError(f"minimum depth must be positive and minimum length >= 0, got {min_depth_um}, {min_length_um}")
    # The least-squares quadratic form (a forehead's curvature) is removed first: near the
    # field's edges the Gaussian regression cannot follow curvature, and its residual there
    # would look like valleys.
    levelled = level(height, order=2)
    valid = levelled.mask
    with ThreadPoolExecutor(max_workers=1) as pool:
        # The straight valleys' closings need only the levelled height: on a thread of their
        # own beside the band-pass and the watershed (OpenCV's and SciPy's filters release the
        # GIL; the measure runs all this beside the texture, so it is its critical path). They
        # come back on their grid of block means, repeated onto the pixels once the band-pass
        # is freed (20 megapixels: 12 bytes a pixel not held beside it).
        straight_valleys = pool.submit(straight_valley_depth, levelled, valid, straight_valley_um, cutoff_um) if straight_valley_um else None
        # the lambda_c mean line on block means (module notes, step 1): smooth on their scale
        band = gaussian_bandpass(levelled, short_cutoff_um, cutoff_um, long_samples_per_sigma=LONG_WAVE_SAMPLES_PER_SIGMA)
        depth = np.where(valid, -band.z, 0.0)
        del band  # its heights are the depth's: freed early (8 bytes a pixel)
        in_basin = _valley_basins(depth, valid, min_depth_um)
        straight_blocks = None if straight_valleys is None else straight_valleys.result()
    regions = in_basin.copy()
    pixel = min(height.spacing)
    window = max(3, int(round(width_window_um / pixel)) | 1)
    straight = straight_direction = None
    if straight_valley_um:
        factor, straight, direction = straight_blocks
        straight, direction = (expanded_blocks(image, levelled.shape, factor) for image in (straight, direction))  # 8 + 4 bytes a pixel
        straight = np.where(valid, straight, 0.0)
        straight_direction = np.where(straight >= STRAIGHT_VALLEY_CONFIRMATION * min_depth_um, direction, np.float32(np.nan))
        del direction
    regions &= depth >= 0.5 * local_maximum_along_valley(depth, regions, window, height.spacing, min_depth_um,
                                                         straight_direction)  # half the local maximum
    del straight_direction
    labels = label(regions)
    keep = ellipse_axes(labels)[1] * pixel >= min_length_um
    kept = keep[labels] & regions
    # Full extent: the watershed basins (down to the background level). Basins that touch
    # belong to one wrinkle (a furrow crossing can split its seed in two): each connected
    # group of basins holding a kept core is one wrinkle, and its cores share its id.
    basins = label(in_basin)
    kept_basins = np.unique(basins[kept])
    kept_basins = _confirmed_against_surrounding_skin(levelled, valid, basins, kept, kept_basins[kept_basins > 0], short_cutoff_um,
                                                      min_depth_um)
    extent = np.isin(basins, kept_basins)
    # A kept wrinkle's half-depth region is all of its basin group's half-depth points, also
    # the pieces that a shallower stretch of the floor cut off from the core that passed the
    # length test (each piece alone may be short).
    labels = np.where(regions & extent, basins, 0)
    if straight_valley_um:
        cores, walls = _straight_valleys(straight, levelled, valid, extent, min_depth_um, min_length_um, window)
        labels = np.where(cores > 0, cores + basins.max(), labels)
        extent |= walls
    labels = split_crossing_wrinkles(labels, height.spacing, min_length_um)
    lines = skeletonize(labels > 0)
    parameters = {
        "cutoff_um": cutoff_um,
        "short_cutoff_um": short_cutoff_um,
        "min_depth_um": min_depth_um,
        "min_length_um": min_length_um,
        "width_window_um": width_window_um,
        "straight_valley_um": straight_valley_um,
    }
    labels = _relabel(labels)
    return WrinkleSegmentation(labels, lines, extent, np.where(valid, depth, np.nan), parameters)


def local_maximum_along_valley(depth, region, window, spacing, min_depth_um, straight_direction_deg=None):
    """The half-depth reference of each point of ``region``: the maximum of ``depth`` within
    the square ``window`` (pixels) around it over the points of ``region`` whose valley runs
    about the same way (direction bins of 180 / ORIENTATION_BINS degrees: its own and the two
    beside it), when that maximum reaches ``min_depth_um`` or the point lies on a valley that
    runs straight that way (``straight_direction_deg``: the direction of the straight valley
    at each point, degrees counter-clockwise from +x, y up, NaN where there is none; the
    segmentation gives the direction of :func:`straight_valley_depth` where that depth is at
    least ``STRAIGHT_VALLEY_CONFIRMATION`` x ``min_depth_um``); otherwise (no such valley, e.g.
    a furrow's branch beside a wrinkle) the maximum over all of ``region`` in the window.

    With the square window alone, a shallow wrinkle crossing a deeper one was held against the
    deep one's floor up to half a window from the crossing and cut there, often to less than
    the minimum length (and then merged into the deep one). The direction across a valley is
    the principal axis of the structure tensor of the depth's gradient, G_rho * (grad d
    grad d^T), rho = ORIENTATION_SCALE_UM (Bigun & Granlund 1987). A narrow shallow wrinkle
    reads below ``min_depth_um`` on the band-pass (a 29 um deep, 0.29 mm wide one: 11 um) and
    so was still held against a deeper one it crosses; on the straight-valley depth it reads
    about 23 um, which tells it from a furrow; a furrow in a deeper wrinkle's wall lies on
    that wrinkle's straight valley, which runs another way than the furrow.
    """
    dy, dx = pixel_spacing(spacing)
    gradient_y, gradient_x = np.gradient(depth, dy, dx)
    sigma = (ORIENTATION_SCALE_UM / dy, ORIENTATION_SCALE_UM / dx)
    # in single precision: the tensor gives only each point's direction bin (the same
    # segmentation as in double precision on the bench's fields; 1024 x 1024: 0.09 -> 0.05 s)
    jxx, jxy, jyy = (gaussian_moments((a * b).astype(np.float32), sigma, ((0, 0),))[0] for a, b in
                     ((gradient_x, gradient_x), (gradient_x, gradient_y), (gradient_y, gradient_y)))
    bins = _orientation_bins(0.5 * np.arctan2(2 * jxy, jxx - jyy))  # of the gradient's axial direction
    if straight_direction_deg is not None:
        # the same bins for the straight valleys (-1 where there is none): the axial direction
        # across each, with rows down, from its direction counter-clockwise from +x, y up
        straight_direction_deg = np.asarray(straight_direction_deg)
        straight = np.isfinite(straight_direction_deg)
        straight_bins = np.full(straight.shape, -1, np.int8)
        straight_bins[straight] = _orientation_bins(np.radians((180.0 - straight_direction_deg[straight]) % 180.0 - 90.0))
    maximum = scipy.ndimage.maximum_filter(np.where(region, depth, 0.0), size=window)
    half = window // 2
    for b in range(ORIENTATION_BINS):
        here = region & (bins == b)
        if not here.any():
            continue
        # only the box of this bin's points, widened by half a window, is filtered: a point
        # there sees the same window as in the whole map (the box ends at the map's edges or
        # half a window beyond every point)
        rows, columns = np.nonzero(here)
        box = (slice(max(rows.min() - half, 0), rows.max() + half + 1), slice(max(columns.min() - half, 0), columns.max() + half + 1))
        members = region[box] & _same_way(bins[box], b)
        along = scipy.ndimage.maximum_filter(np.where(members, depth[box], 0.0), size=window)[here[box]]
        own = along >= min_depth_um
        if straight_direction_deg is not None:
            own |= (straight_bins[here] >= 0) & _same_way(straight_bins[here], b) & (along > 0)
        maximum[here] = np.where(own, along, maximum[here])
    return maximum


def _same_way(bins, b):
    """Where direction ``bins`` are bin ``b`` or a bin beside it (modulo ORIENTATION_BINS)."""
    return ((bins - b + 1) % ORIENTATION_BINS) <= 2


def _orientation_bins(across):
    """The direction bin (0 to ORIENTATION_BINS - 1) of axial angles ``across`` a valley, in
    radians in [-pi/2, pi/2] (the two ends share bin 0)."""
    return np.floor((across / np.pi + 0.5) * ORIENTATION_BINS).astype(int) % ORIENTATION_BINS


def _valley_basins(depth, valid, min_depth_um):
    """Where the watershed of -``depth`` floods from the seeds (connected valleys deeper than
    ``min_depth_um``) and not from the background (points shallower than a quarter of it)."""
    seeds = label((depth > min_depth_um) & valid)
    n_seeds = int(seeds.max())
    background = (depth < 0.25 * min_depth_um) & valid
    markers = np.where(background, n_seeds + 1, seeds)
    # Only the points that are not background, and the background points beside them, take
    # part: a background point farther away has only background neighbours, so it floods
    # nothing, and leaving it out keeps the flooding order of the others (but for exact ties
    # of height): the same basins (identical labels on a 1024 x 1024 forehead, where the
    # watershed went from 0.63 s to 0.04 s; 13% of the points take part).
    near = valid & scipy.ndimage.binary_dilation(valid & ~background)
    flooded = watershed(-depth, markers=np.where(near, markers, 0), mask=near)
    return (flooded >= 1) & (flooded <= n_seeds)


def straight_valley_depth(levelled: HeightMap, valid, length_um, cutoff_um):
    """Depth of the valleys that run straight for ``length_um`` in some direction: the
    ``levelled`` height (least-squares quadratic form removed) closed with a level segment of that length at each of
    ``STRAIGHT_VALLEY_DIRECTIONS`` angles, the lowest of the closings kept (a valley survives
    the closing laid along it), below its Gaussian regression at ``cutoff_um``; and the
    direction of the closing that kept each point lowest (degrees counter-clockwise from +x,
    y up): the way its valley runs. Furrows of the microrelief (polygons of 0.1-1 mm) are
    filled by the closings across them and by the one along them where they turn. Computed
    on block means of at most ``STRAIGHT_VALLEY_PIXEL_UM`` (the cost grows as the segment's
    length in pixels times the number of pixels): returns (block factor, depth, direction),
    both images of blocks (:func:`skintopo.filters.expanded_blocks` repeats them back onto
    the pixels)."""
    factor = max(1, int(STRAIGHT_VALLEY_PIXEL_UM // max(levelled.spacing)))
    z, coarse_valid, spacing = block_means_of_valid(levelled.z, valid, levelled.spacing, factor)
    closed, _, lowest = line_segment_closing_extremes(z, spacing, length_um, STRAIGHT_VALLEY_DIRECTIONS, coarse_valid, return_lowest_index=True)
    depth = areal_gaussian_filter(closed, spacing, cutoff_um, coarse_valid) - closed
    return factor, depth, np.asarray(STRAIGHT_VALLEY_DIRECTIONS, np.float32)[lowest]


def _straight_valleys(depth, levelled, valid, taken, min_depth_um, min_length_um, window):
    """Wrinkles that the band-pass misses: valleys at least ``min_length_um`` long that run
    straight over ``length_um`` (:func:`straight_valley_depth`) and whose core lies (median)
    at least ``STRAIGHT_VALLEY_CONFIRMATION`` x ``min_depth_um`` below the skin on each side
    of it (a ring of 0.5 mm beyond its width, each side of its axis on its own: the
    long-wave mean line, pulled down by deep wrinkles, makes ramps at the field's edges that
    are low on one side only; a candidate with skin on one side only is not kept),
    outside the wrinkles already ``taken``. The band-pass's 0.6 mm lambda_s leaves a 54 um
    deep, 0.27 mm wide wrinkle 22 um deep, below the 25 um minimum; this depth leaves it about
    45 um. Returns their half-depth cores (ids 1..k) and their extent (down to a quarter of
    the minimum depth)."""
    local = scipy.ndimage.maximum_filter(np.where(depth > min_depth_um, depth, 0.0), size=window)
    cores = label((depth >= 0.5 * local) & (local > min_depth_um) & valid & ~taken)
    pixel = min(levelled.spacing)
    kept = []
    for region in regionprops(cores):
        if region.axis_major_length * pixel < min_length_um:
            continue
        inner = max(2, int(region.area / max(region.axis_major_length, 1.0)) + 2)
        outer = inner + int(round(STRAIGHT_VALLEY_RING_UM / pixel))
        box = tuple(slice(max(0, start - outer), stop + outer) for start, stop in zip(region.bbox[:2], region.bbox[2:]))
        core = cores[box] == region.label
        ring = (scipy.ndimage.binary_dilation(core, iterations=outer) & ~scipy.ndimage.binary_dilation(core, iterations=inner)
                & valid[box] & ~taken[box] & (cores[box] == 0))
        # each side of the valley's axis on its own (a ramp, the mean line's edge artefact, is
        # low on one side only), and both sides present (a valley along the field's edge
        # cannot be told from such a ramp)
        rows, columns = np.nonzero(ring)
        centre_row, centre_column = region.centroid[0] - box[0].start, region.centroid[1] - box[1].start
        side = (rows - centre_row) * -np.sin(region.orientation) + (columns - centre_column) * np.cos(region.orientation) > 0
        if min(side.sum(), (~side).sum()) < 0.25 * side.size:
            continue
        levels = [np.median(depth[box][rows[pick], columns[pick]]) for pick in (side, ~side)]
        if np.median(depth[box][core]) - max(levels) >= STRAIGHT_VALLEY_CONFIRMATION * min_depth_um:
            kept.append(region.label)
    cores = np.where(np.isin(cores, kept), cores, 0)
    walls = label((depth > 0.25 * min_depth_um) & valid & ~taken)
    walls = np.isin(walls, np.unique(walls[cores > 0])) & (walls > 0)
    return label(cores > 0), walls


def _confirmed_against_surrounding_skin(levelled, valid, basins, cores, candidates, short_cutoff_um, min_depth_um):
    """The candidate basins whose core lies at least ``min_depth_um`` (median) below the skin
    around them. The band-pass's long-wave mean line is pulled down by deep wrinkles and
    cannot follow the field's edges, so a smooth corner can look like a valley; the local
    skin level here is the Gaussian regression (``REFERENCE_CUTOFF_UM``) of the short-pass
    surface over the skin outside every candidate (widened by ``REFERENCE_MARGIN_UM``), which
    a real valley is below and an edge artefact is not."""
    if candidates.size == 0:
        return candidates
    skin = skin_around(valid, np.isin(basins, candidates), levelled.spacing)
    if skin is None:
        return candidates  # too little skin to judge: keep them all
    # Both filters are smooth on the scale of lambda_s, so they run on a grid of block means
    # whose pixel is at most lambda_s / 6 (4 samples per Gaussian sigma of the S-filter).
    factor = max(1, int(min(short_cutoff_um, REFERENCE_SHORT_CUTOFF_UM) / 6 // max(levelled.spacing)))
    z, coarse_valid, spacing = block_means_of_valid(levelled.z, valid, levelled.spacing, factor)
    skin_share = block_mean(skin.astype(float), factor)
    fine = areal_gaussian_filter(z, spacing, min(short_cutoff_um, REFERENCE_SHORT_CUTOFF_UM), coarse_valid)
    below = expanded_blocks(skin_level(fine, spacing, coarse_valid & (skin_share > 0.5)) - fine, levelled.shape, factor)
    return np.array([c for c in candidates if np.median(below[(basins == c) & cores]) >= min_depth_um], dtype=int)


def margin_pixels(margin_um, spacing):
    """A margin in whole pixels (at least one) of the finer pixel side."""
    return max(1, int(round(margin_um / min(pixel_spacing(spacing)))))


def skin_around(valid, wrinkles, spacing, margin_um=REFERENCE_MARGIN_UM):
    """The skin around wrinkles: the ``valid`` points outside the ``wrinkles`` (a mask of
    their whole extent) widened by ``margin_um``; None when that is less than 5% of the valid
    points (too little to set a skin level from). Used by the segmentation's confirmation and
    by the wrinkle measures (:mod:`skintopo.wrinkles`)."""
    skin = valid & ~scipy.ndimage.binary_dilation(wrinkles, iterations=margin_pixels(margin_um, spacing))
    return skin if skin.sum() >= 0.05 * valid.sum() else None


def skin_level(surface, spacing, skin, cutoff_um=REFERENCE_CUTOFF_UM):
    """The local skin level under the wrinkles: the ISO 16610-61 Gaussian regression of
    ``surface`` at ``cutoff_um`` (2.5 mm) over the ``skin`` points alone
    (:func:`skintopo.filters.coarse_areal_gaussian_filter`: a wide filter on block means with
    at least 8 samples per sigma), which carries the skin's level across the wrinkles without
    being pulled down by them. Used by the segmentation's confirmation (on the short-pass
    surface) and by the wrinkle measures (on the skin's plateaus)."""
    return coarse_areal_gaussian_filter(surface, spacing, cutoff_um, skin)


CROSSING_MAX_BEND_DEG = 40.0  # arms this close to straight continue one wrinkle
# Pieces of one wrinkle may be this far apart: a deeper wrinkle cuts a shallower one's half-depth
# region over its own width (up to about 1.2 mm) and the reach of the half-depth window on either
# side (DEFAULT_WIDTH_WINDOW_UM, 1.5 mm). 2.5 mm left bench_wrinkles' field 324 in one label (a
# gap of 2.59 mm); 3 and 3.5 mm gave the same results there.
CROSSING_MAX_GAP_UM = 3000.0
# A label is split when its longest chain spans the minimum length and another at least this
# fraction of it: a wrinkle that crosses a deeper one near its own end keeps on one side only
# the part its half-depth region reaches past the crossing. Such a shorter chain must also
# meet a full one away from that one's ends (:func:`_crosses`), or furrows running on from a
# wrinkle's end became wrinkles of their own (forehead-high seed 10). Chosen among 0.5 / 0.7 /
# 1 on bench_wrinkles' fields (seeds 0-959, 2026-12-04, before the condition on the ends): 0.5
# found the most crossing pairs but made false wrinkles of furrows in 5 more fields.
CROSSING_MIN_SPAN_FRACTION = 0.7


def split_crossing_wrinkles(labels, spacing, min_length_um):
    """Wrinkles that cross share one label (one basin group); give each its own.

    The skeleton of the label's half-depth region (its pieces too) is cut at its junctions
    into arms; arms shorter than the region's mean width are spurs and dropped (a piece of
    skeleton made of spurs alone keeps its longest arm). Arms continue
    one wrinkle where they run on nearly straight (within ``CROSSING_MAX_BEND_DEG``): at a
    junction, the most nearly opposite arms are joined; across a gap (a shallow wrinkle's
    region is cut where a deeper one crosses it, up to ``CROSSING_MAX_GAP_UM``), two free ends
    that point at each other are joined. When one such chain spans at least ``min_length_um``
    (gaps included) and another either as long or at least ``CROSSING_MIN_SPAN_FRACTION`` x
    ``min_length_um`` long and meeting a chain of full length away from its ends (a wrinkle
    that crosses a deeper one near its own end: :func:`_crosses`), every point of the region
    goes to the nearest of those chains; otherwise the label is left as it is."""
    labels = np.asarray(labels)
    pixel = min(pixel_spacing(spacing))
    out = labels.copy()
    next_label = int(labels.max()) + 1
    for region in regionprops(labels):
        core = region.image
        skeleton = skeletonize(core)
        neighbours = scipy.ndimage.convolve(skeleton.astype(int), np.ones((3, 3), int), mode="constant") - 1
        hubs = label(scipy.ndimage.binary_dilation(skeleton & (neighbours >= 3), np.ones((3, 3), bool)) & skeleton, connectivity=2)
        arms = label(skeleton & (hubs == 0), connectivity=2)
        if arms.max() < 2:
            continue
        width = region.area * pixel / max(region.axis_major_length, 1.0)
        points = [np.argwhere(np.isin(arms, chain)) for chain in _chained_arms(arms, hubs, pixel, width)]
        along = [_along_axis(p) for p in points]  # the position of each chain's points along it
        # A chain's length, gaps included: the extent along its axis of the region's points
        # nearest to it. Its skeleton stops about half a width short of each free end (the
        # segmentation's own length test is on the region); on the skeleton alone a wrinkle's
        # piece beyond a deeper one it crosses fell short (bench_wrinkles' field 319: skeleton
        # 0.97 mm, region 1.24 mm). At a junction the region's points belong to the other chain.
        nearest = _nearest_chain(core.shape, points)
        spans = [float(np.ptp(np.argwhere(core & (nearest == number)) @ _principal_axis(chain))) * pixel if len(chain) > 1 else 0.0
                 for number, chain in enumerate(points, start=1)]
        full = [index for index, span in enumerate(spans) if span >= min_length_um]
        if not full:
            continue
        long_chains = full + [index for index, span in enumerate(spans) if CROSSING_MIN_SPAN_FRACTION * min_length_um <= span < min_length_um
                              and _crosses(points[index], [(points[f], along[f]) for f in full], width / pixel)]
        if len(long_chains) < 2:
            continue
        nearest = _nearest_chain(core.shape, [points[index] for index in long_chains])
        box = out[region.slice]
        box[core] = np.where(nearest[core] == 1, region.label, next_label + nearest[core] - 2)
        next_label += len(long_chains) - 1
    return out


def _crosses(mine, full, width_px):
    """Whether the point of one of the ``full`` chains ((points, their positions along the
    chain's principal axis) each) nearest to the points ``mine`` of another chain lies at least
    a width (``width_px``) from that chain's ends: ``mine`` meets it from the side (a wrinkle
    crossing it, its region cut by it), not as a furrow running on from its end."""
    for theirs, along in full:
        distance = np.hypot(*(mine[:, None, :] - theirs[None, :, :]).transpose(2, 0, 1))
        closest = np.unravel_index(distance.argmin(), distance.shape)[1]
        if min(along[closest] - along.min(), along.max() - along[closest]) >= width_px:
            return True
    return False


def _principal_axis(points):
    """The unit direction of the principal axis of ``points`` (n >= 2, 2)."""
    return np.linalg.svd(points - points.mean(axis=0), full_matrices=False)[2][0]


def _along_axis(points):
    """The positions (pixels) of ``points`` (n, 2) along their principal axis (zeros for a
    single point)."""
    return (points - points.mean(axis=0)) @ _principal_axis(points) if len(points) > 1 else np.zeros(1)


def _nearest_chain(shape, chains):
    """The number (1, 2, ...) of the nearest of ``chains`` (point arrays) at every pixel of an
    image of ``shape``."""
    owner = np.zeros(shape, np.int32)
    for number, chain in enumerate(chains, start=1):
        owner[tuple(chain.T)] = number
    _, (rows, columns) = scipy.ndimage.distance_transform_edt(owner == 0, return_indices=True)
    return owner[rows, columns]


def _chained_arms(arms, hubs, pixel, width):
    """Arms (ids of ``arms``) grouped into wrinkles (see :func:`split_crossing_wrinkles`).

    An arm from a junction to a free end shorter than a width is a spur of the skeleton (a
    one-pixel arm too: kept, it made a junction of two kept arms out of a wrinkle's cut end,
    which then could not be joined across the gap to its other piece). Two
    junctions joined by an arm shorter than 2 widths are one crossing (wrinkles crossing at a
    shallow angle share a stretch of skeleton), and that arm belongs to neither; an arm longer
    than a width counts as such a bridge only when both its junctions join at least three arms
    that are not spurs (a wide wrinkle's rounded end forks into spurs). A piece of skeleton too
    short to have a direction at its ends (a wrinkle's stub beyond one that cuts it, a few
    pixels) may end a chain across a gap when the other end points at it and another arm lies
    between them (the wrinkle that cut it); it continues one chain at most."""
    straight = np.cos(np.radians(CROSSING_MAX_BEND_DEG))
    reach = max(3.0, 2 * width / pixel)  # pixels over which an arm's direction at an end is taken
    neighbours = scipy.ndimage.convolve((arms > 0).astype(int), np.ones((3, 3), int), mode="constant") - 1
    from scipy.cluster.hierarchy import DisjointSet  # here, not at the top: scipy.cluster takes 0.1 s to import

    crossings = DisjointSet(range(1, int(hubs.max()) + 1))  # junctions that are one crossing

    tips, points = {}, {}
    for a in range(1, int(arms.max()) + 1):
        points[a] = np.argwhere(arms == a).astype(float)
        ends = [p for p in points[a] if neighbours[int(p[0]), int(p[1])] <= 1] or [points[a][0]]
        tips[a] = [(end, int(hubs[max(0, int(end[0]) - 1):int(end[0]) + 2, max(0, int(end[1]) - 1):int(end[1]) + 2].max()))
                   for end in ends[:2]]
    at_hubs = {a: {hub for _, hub in ends if hub} for a, ends in tips.items()}
    spurs = {a for a in tips if len(at_hubs[a]) == 1 and len(points[a]) * pixel < width}  # a 1-pixel arm too
    # A piece of skeleton made of spurs alone (a wrinkle's stub beyond a deeper one that cuts
    # it, its end forked) keeps its longest arm: it is a piece of a wrinkle, not a side branch,
    # and may continue across the gap (bench_wrinkles' field 309).
    pieces = label((arms > 0) | (hubs > 0), connectivity=2)
    piece_of = {a: int(pieces[tuple(points[a][0].astype(int))]) for a in tips}
    arms_of_piece = {}
    for a in tips:
        arms_of_piece.setdefault(piece_of[a], []).append(a)
    for members in arms_of_piece.values():
        if spurs.issuperset(members):
            spurs.discard(max(members, key=lambda a: len(points[a])))
    # arms shorter than a width, in the tangle of a crossing's skeleton, are bridges between
    # any two hubs (counting only the junctions of three arms lost crossings on held-out fields)
    arms_at = {}
    for a in tips.keys() - spurs:
        for hub in at_hubs[a]:
            arms_at[hub] = arms_at.get(hub, 0) + 1
    ids = []
    for a in sorted(tips.keys() - spurs):
        length = len(points[a]) * pixel
        junctions = at_hubs[a] if length < width else {hub for hub in at_hubs[a] if arms_at[hub] >= 3}
        if len(junctions) == 2 and length < 2 * width:
            crossings.merge(*junctions)
        else:
            ids.append(a)
    kept_in_piece = Counter(piece_of[a] for a in ids)

    def outward(a, end):
        """Unit direction of arm ``a`` at its point ``end``, pointing out of the arm: from the
        arm's points half a width to three widths away (a skeleton's last pixels hook); and
        whether that direction is sure. An arm with no point that far, alone in its piece of
        skeleton, is a stub: its direction is not sure (zero when it is a single pixel)."""
        distance = np.hypot(*(points[a] - end).T)
        close = points[a][(distance >= 0.25 * reach) & (distance <= 1.5 * reach)]
        vector = end - (close if len(close) else points[a]).mean(axis=0)
        norm = np.hypot(*vector)
        if not len(close) and kept_in_piece[piece_of[a]] == 1:
            return (vector / norm if norm > 0 else np.zeros(2)), False
        return (vector / norm, True) if norm > 0 else None

    degree = {}  # kept arms at each crossing: one alone is a free end (its other arms were spurs)
    for a in ids:
        for _, hub in tips[a]:
            if hub:
                degree[crossings[hub]] = degree.get(crossings[hub], 0) + 1
    ends = []  # (arm, tip, outward direction, its crossing or 0, whether the direction is sure)
    for a in ids:
        for end, hub in tips[a]:
            if (found := outward(a, end)) is not None:
                ends.append((a, end, found[0], crossings[hub] if hub and degree[crossings[hub]] > 1 else 0, found[1]))
    arms_near = scipy.ndimage.grey_dilation(arms, size=(3, 3))
    candidates = []
    for i, (a, tip_a, dir_a, hub_a, sure_a) in enumerate(ends):
        for j in range(i + 1, len(ends)):
            b, tip_b, dir_b, hub_b, sure_b = ends[j]
            if a == b:
                continue
            if hub_a and hub_a == hub_b:  # through a crossing: the most nearly opposite arms
                cosine = float(dir_a @ dir_b)
                if cosine <= -straight:
                    candidates.append((cosine, i, j))
            elif not hub_a and not hub_b and (sure_a or sure_b):  # across a gap (a stub has no hub)
                gap = tip_b - tip_a
                distance = np.hypot(*gap)
                if not 0 < distance * pixel <= CROSSING_MAX_GAP_UM:
                    continue
                farther = distance * pixel / CROSSING_MAX_GAP_UM
                if sure_a and sure_b:  # two free ends that point at each other
                    unit = gap / distance
                    if dir_a @ unit >= straight and -(dir_b @ unit) >= straight and float(dir_a @ dir_b) <= -straight:
                        candidates.append((float(dir_a @ dir_b) - 1.0 + farther, i, j))
                else:  # a stub: the other end points at it, over another arm (the wrinkle that cut it)
                    pointing = float(dir_a @ gap if sure_a else -(dir_b @ gap)) / distance
                    between = arms_near[tuple(np.rint(tip_a + np.linspace(0.15, 0.85, 50)[:, None] * gap).astype(int).T)]
                    if pointing >= straight and np.any((between > 0) & (between != a) & (between != b)):
                        candidates.append((-pointing - 1.0 + farther, i, j))
    wrinkles = DisjointSet(ids)
    continued = set()  # ends already joined
    for _, i, j in sorted(candidates):
        if i not in continued and j not in continued:
            wrinkles.merge(ends[i][0], ends[j][0])
            continued |= {i, j}
            for stub in (ends[k][0] for k in (i, j) if not ends[k][4]):  # a stub continues one chain at most
                continued |= {k for k, end in enumerate(ends) if end[0] == stub}
    return [sorted(chain) for chain in wrinkles.subsets()]


def segmentation_from_labels(labels, spacing) -> WrinkleSegmentation:
    """A :class:`WrinkleSegmentation` of known wrinkles (half-depth regions ``labels``, e.g. the
    simulator's ground truth), so that their measures can be read from any height map of the
    same skin (:func:`skintopo.evaluation.wrinkle_max_depths`). Each wrinkle's extent (its
    walls) is its region widened by its own mean width (area / major axis length)."""
    labels = np.asarray(labels, dtype=np.int32)
    dy, dx = pixel_spacing(spacing)
    widths = np.zeros(int(labels.max()) + 1)
    for region in regionprops(labels):
        widths[region.label] = region.area * dy * dx / max(region.axis_major_length * min(dy, dx), min(dy, dx))
    distance, (rows, columns) = scipy.ndimage.distance_transform_edt(labels == 0, sampling=(dy, dx), return_indices=True)
    extent = distance <= widths[labels[rows, columns]]
    return WrinkleSegmentation(labels, skeletonize(labels > 0), extent, np.full(labels.shape, np.nan), {"from": "labels"})


def _relabel(labels):
    """Consecutive ids 1..n in order of first appearance (row-major)."""
    values, first = np.unique(labels.ravel(), return_index=True)
    order = values[np.argsort(first)]
    order = order[order > 0]
    lookup = np.zeros(int(labels.max()) + 1, dtype=np.int32)
    lookup[order] = np.arange(1, order.size + 1)
    return lookup[labels]


def segmentation_quality(predicted_mask, true_mask):
    """Precision, recall and IoU of a wrinkle mask against a reference mask."""
    predicted = np.asarray(predicted_mask, dtype=bool)
    truth = np.asarray(true_mask, dtype=bool)
    hits = np.logical_and(predicted, truth).sum()
    union = np.logical_or(predicted, truth).sum()
    return {
        "precision": float(hits / predicted.sum()) if predicted.any() else float("nan"),
        "recall": float(hits / truth.sum()) if truth.any() else float("nan"),
        "iou": float(hits / union) if union else float("nan"),
    }
