"""Pores: small round pits of the height map, told apart from wrinkles and microrelief furrows.

A pore is a pit whose opening is about 0.05-0.5 mm across; a furrow or a wrinkle is a
valley, long in one direction. The closing of the height with a level line segment longer
than the largest pore fills a pit whatever the segment's direction, but fills a valley only
across it: along the valley the segment lies inside it. So the pit depth

    P(x) = min over directions theta of [closing_theta(z) - z](x),  12 directions 15 degrees apart,

is the depth of a point below the rim of the pit it lies in and about zero in furrows and
wrinkles, which some direction runs along (the straight-valley closing of
:mod:`skintopo.segmentation`, used here the other way round). Segments are ``max_opening_um``
x 1.2 long. A valley shorter than the segment (a furrow ending after a few tenths of a
millimetre) is filled from every direction too; the shape rules below reject most of those.

Pores are the connected regions of P above ``edge_um`` (the opening; hysteresis) that hold a
point deeper than ``min_depth_um``, whose opening's equivalent diameter is within
[``min_opening_um``, ``max_opening_um``], which are round (minor / major axis of the
region's inertia ellipse at least ``min_roundness``, scikit-image ``regionprops``) and which
stand alone: the valley depth V (the max over the directions, any valley) above half the
pore's depth, connected to it, covers at most twice its opening (looked for within
``max_opening_um`` of it). Where furrows of the microrelief network
meet, their short segments are filled from every direction and look like pits; V joins them
to the network's other furrows, and they are rejected. A real pore at a furrow junction is
rejected with them (a limit). A pore touching the field's edge or the mask is not counted
(its opening is not seen whole; counts then stay the same between visits that see the field
differently cut).

Measures per pore: area of the opening (mm^2, pixels counted), equivalent diameter (um),
depth (the deepest P, um), mean depth (um) and volume below the rim (sum of P times the pixel
area, mm^3). Totals: count, count per cm^2 of measured field, mean area, mean depth, total
volume. The opening is where P exceeds ``edge_um``: for a bowl-shaped (paraboloid) pore of
depth d that is the disc where its depth exceeds ``edge_um``, whose area is 1 - edge / d of
the rim's (98.75% for edge 0.5 um and d 40 um): a documented bias, not corrected, since real
profiles differ.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, replace

import numpy as np

from skintopo.defaults import DEFAULT_PORE_EDGE_UM, DEFAULT_PORE_MAX_OPENING_UM, DEFAULT_PORE_MIN_DEPTH_UM, DEFAULT_PORE_MIN_OPENING_UM
from skintopo.filters import block_means_of_valid, ellipse_axes, expanded_blocks, line_segment_closing_extremes, pixel_spacing
from skintopo.heightmap import HeightMap

PORE_DIRECTIONS_DEG = tuple(range(0, 180, 15))
SEGMENT_FACTOR = 1.2  # the closing's segment is this times the largest opening
DEFAULT_MIN_ROUNDNESS = 0.5
MAX_VALLEY_RATIO = 2.0  # a pore's valley region (V above VALLEY_LEVEL of its depth) is at most this times its opening
VALLEY_LEVEL = 0.5
MAX_SEGMENT_PX = 120  # finer maps are binned first (measure_pores)
PORE_COLUMNS = ("id", "row", "column", "area_mm2", "diameter_um", "depth_um", "mean_depth_um", "volume_mm3", "roundness")


@dataclass(frozen=True)
class Pore:
    """One pore: centroid (pixels), opening area (mm^2) and equivalent diameter (um), depth
    and mean depth below the rim (um), volume (mm^3), roundness (minor / major axis)."""

    id: int
    row: float
    column: float
    area_mm2: float
    diameter_um: float
    depth_um: float
    mean_depth_um: float
    volume_mm3: float
    roundness: float


@dataclass(frozen=True, eq=False)
class PoreMeasures:
    """The pores of a height map, their label image (0 = none, i = pore i) and the pit depth
    map P (um) they were found on, with the settings."""

    pores: tuple
    labels: np.ndarray
    pit_depth: np.ndarray
    field_area_mm2: float
    parameters: dict

    @property
    def totals(self):
        """count, count_per_cm2, mean_area_mm2, mean_diameter_um, mean_depth_um, total_volume_mm3."""
        count = len(self.pores)
        mean = (lambda name: float(np.mean([getattr(p, name) for p in self.pores]))) if count else (lambda name: float("nan"))
        return {"count": count, "count_per_cm2": count / (self.field_area_mm2 / 100.0) if self.field_area_mm2 > 0 else float("nan"),
                "mean_area_mm2": mean("area_mm2"), "mean_diameter_um": mean("diameter_um"), "mean_depth_um": mean("depth_um"),
                "total_volume_mm3": float(sum(p.volume_mm3 for p in self.pores))}

    def as_dict(self):
        """JSON-ready: totals, per-pore rows and the settings."""
        return {"totals": self.totals, "pores": [asdict(p) for p in self.pores], "settings": self.parameters,
                "units": "areas mm2, diameters and depths um, volumes mm3, row/column pixels"}


def pit_and_valley_depth(height: HeightMap, segment_um):
    """(P, V): the pit depth P = min over :data:`PORE_DIRECTIONS_DEG` of (line-segment
    closing - z) and the valley depth V = the max over the same directions (a point in any
    valley narrower than the segment across), um (module notes); NaN outside the mask.
    (:func:`~skintopo.filters.line_segment_closing_extremes` holds two maps, not twelve: a
    20-megapixel field would otherwise hold 1.9 GB of closings.)"""
    extremes = line_segment_closing_extremes(height.z, height.spacing, segment_um, PORE_DIRECTIONS_DEG, height.mask)
    return tuple(np.where(height.mask, np.maximum(d - height.z, 0.0), np.nan) for d in extremes)


def _stands_alone(region, valley, level, margin):
    """True when the part of ``valley`` above ``level`` connected to ``region`` (a
    regionprops region), within ``margin`` (rows, columns) pixels of its box, is at most
    :data:`MAX_VALLEY_RATIO` times the region's area and does not reach the window's edge."""
    import skimage.measure

    top, left, bottom, right = region.bbox
    rows = slice(max(top - margin[0], 0), min(bottom + margin[0], valley.shape[0]))
    columns = slice(max(left - margin[1], 0), min(right + margin[1], valley.shape[1]))
    window = skimage.measure.label(valley[rows, columns] > level, connectivity=2)
    inside = np.zeros(window.shape, bool)
    inside[top - rows.start : bottom - rows.start, left - columns.start : right - columns.start] = region.image
    touched = np.unique(window[inside])
    touched = touched[touched > 0]
    component = np.isin(window, touched)
    edge_free = rows.start == 0 or not component[0].any()
    edge_free &= rows.stop == valley.shape[0] or not component[-1].any()
    edge_free &= columns.start == 0 or not component[:, 0].any()
    edge_free &= columns.stop == valley.shape[1] or not component[:, -1].any()
    return bool(edge_free and component.sum() <= MAX_VALLEY_RATIO * region.area)


def measure_pores(height: HeightMap, *, max_opening_um=DEFAULT_PORE_MAX_OPENING_UM, min_opening_um=DEFAULT_PORE_MIN_OPENING_UM,
                  min_depth_um=DEFAULT_PORE_MIN_DEPTH_UM, edge_um=DEFAULT_PORE_EDGE_UM, min_roundness=DEFAULT_MIN_ROUNDNESS) -> PoreMeasures:
    """Find and measure the pores of ``height`` (micrometres; see the module notes for the
    method and every option).

    A closing costs its segment's length in pixels per pixel: on maps finer than the
    segment / :data:`MAX_SEGMENT_PX` (5 um pixels for the default 0.6 mm segment) the pores
    are found on the map averaged over blocks of pixels that bring the segment under that
    length (recorded as ``binning`` in the settings; row, column and labels are then on the
    binned grid's pixels scaled back to the map's)."""
    dy, dx = pixel_spacing(height.spacing)
    factor = max(1, int(np.ceil(SEGMENT_FACTOR * max_opening_um / min(dx, dy) / MAX_SEGMENT_PX)))
    options = dict(max_opening_um=max_opening_um, min_opening_um=min_opening_um, min_depth_um=min_depth_um, edge_um=edge_um,
                   min_roundness=min_roundness)
    if factor == 1:
        return _measure_pores(height, **options)
    z, whole, spacing = block_means_of_valid(height.z, height.mask, height.spacing, factor, min_valid=0.999)
    binned = _measure_pores(HeightMap(np.where(whole, z, np.nan), spacing, whole), **options)
    labels = expanded_blocks(binned.labels, height.shape, factor) * height.mask
    pores = tuple(replace(p, row=(p.row + 0.5) * factor - 0.5, column=(p.column + 0.5) * factor - 0.5) for p in binned.pores)
    depth = expanded_blocks(binned.pit_depth, height.shape, factor)
    field_mm2 = float(height.mask.sum() * dx * dy * 1e-6)
    return PoreMeasures(pores, labels.astype(np.int32), depth, field_mm2, binned.parameters | {"binning": factor})


def _measure_pores(height: HeightMap, *, max_opening_um, min_opening_um, min_depth_um, edge_um, min_roundness) -> PoreMeasures:
    """:func:`measure_pores` on the map as it is."""
    import scipy.ndimage
    import skimage.filters
    import skimage.measure

    dy, dx = pixel_spacing(height.spacing)
    depth, valley = pit_and_valley_depth(height, SEGMENT_FACTOR * max_opening_um)
    finite = np.nan_to_num(depth, nan=0.0)
    candidates = skimage.measure.label(skimage.filters.apply_hysteresis_threshold(finite, edge_um, min_depth_um), connectivity=2)
    valley = np.nan_to_num(valley, nan=0.0)
    outside = ~height.mask
    outside = np.pad(outside, 1, constant_values=True)  # the frame counts as outside
    border = scipy.ndimage.binary_dilation(outside, structure=np.ones((3, 3), bool))[1:-1, 1:-1]
    margin = (int(np.ceil(max_opening_um / dy)), int(np.ceil(max_opening_um / dx)))
    labels = np.zeros(candidates.shape, dtype=np.int32)
    pores = []
    pixel_mm2 = dx * dy * 1e-6
    areas, major, minor = ellipse_axes(candidates)
    roundness = np.divide(minor, major, out=np.ones_like(major), where=major > 0)  # minor / major axis; 1 for a single pixel
    diameters = 2.0 * np.sqrt(areas * dx * dy / np.pi)
    plausible = (min_opening_um <= diameters) & (diameters <= max_opening_um) & (roundness >= min_roundness)
    for region in skimage.measure.regionprops(candidates, intensity_image=finite):
        if not plausible[region.label]:  # most candidates are specks: decided from the arrays above
            continue
        if border[region.slice][region.image].any():  # cut by the field's edge or the mask: not seen whole
            continue
        if not _stands_alone(region, valley, VALLEY_LEVEL * region.intensity_max, margin):
            continue
        diameter = float(diameters[region.label])
        values = finite[region.slice][region.image]
        labels[region.slice][region.image] = len(pores) + 1
        row, column = region.centroid
        pores.append(Pore(len(pores) + 1, float(row), float(column), float(region.area * pixel_mm2), float(diameter),
                          float(values.max()), float(values.mean()), float(values.sum() * pixel_mm2 * 1e-3),
                          float(roundness[region.label])))
    settings = {"max_opening_um": max_opening_um, "min_opening_um": min_opening_um, "min_depth_um": min_depth_um, "edge_um": edge_um,
                "min_roundness": min_roundness, "segment_um": SEGMENT_FACTOR * max_opening_um, "directions_deg": list(PORE_DIRECTIONS_DEG),
                "binning": 1}
    field_mm2 = float(height.mask.sum() * pixel_mm2)
    return PoreMeasures(tuple(pores), labels, depth.astype(np.float32), field_mm2, settings)
