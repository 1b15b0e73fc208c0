"""Before/after comparison between visits: registration, difference map, parameter changes.

Registration of the follow-up onto the baseline: :func:`skintopo.registration.register_height_maps`
(rigid, optionally a small scale, robust to what changed between the visits); the albedo
images, when given, are carried by the same transform and their residual misalignment is
measured: an independent check, since the albedo did not drive the registration.

Visits with different pixel sizes are refused (resampling silently would change every
texture parameter); no overlap is refused; a visit with no wrinkles compares its texture and
reports its wrinkles as unmatched.

Repeatability: comparing the baseline with repeat captures of the same unchanged skin gives
each parameter's noise; :func:`detection_limits` turns one or more such pairs into the
smallest detectable change (a prediction limit in the sense of ISO 5725-6's repeatability
limit, with Student's t for the few degrees of freedom; see there).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from skintopo.defaults import DEFAULT_DETECTION_CONFIDENCE
from skintopo.errors import SkinTopoError
from skintopo.heightmap import HeightMap
from skintopo.registration import Registration, apply_registration, register_height_maps, residual_misalignment

MIN_DEGREES_OF_FREEDOM = 5  # detection limits from fewer differences come with a warning


def _change(before, after):
    change = after - before
    with np.errstate(invalid="ignore", divide="ignore"):
        percent = 100.0 * change / abs(before) if before not in (0, None) and np.isfinite(before) else float("nan")
    return {"baseline": before, "follow_up": after, "change": change, "change_percent": percent}


def match_wrinkles(baseline_labels, follow_up_labels, min_overlap=0.2):
    """Baseline id -> follow-up id, one to one: a baseline wrinkle and a follow-up wrinkle are
    matched when each is the other's largest overlap (of their half-depth regions) and that
    overlap is at least ``min_overlap`` of the smaller region; unmatched ids map to None. Two
    baseline wrinkles merged into one in the follow-up (a crossing pair segmented as one) are
    then not both compared with it: only the one covering most of it is, and the other is
    reported unmatched rather than with its partner's measures."""
    from skintopo.evaluation import label_overlap

    overlap = label_overlap(baseline_labels, follow_up_labels)
    sizes_baseline, sizes_follow_up = overlap.sum(axis=1), overlap.sum(axis=0)
    overlap[0, :] = overlap[:, 0] = 0
    best_follow_up, best_baseline = overlap.argmax(axis=1), overlap.argmax(axis=0)
    matches = {}
    for index in range(1, len(overlap)):
        best = int(best_follow_up[index])
        shared = overlap[index, best]
        mutual = best > 0 and best_baseline[best] == index
        matches[index] = best if mutual and shared >= min_overlap * min(sizes_baseline[index], sizes_follow_up[best]) else None
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
    pores: dict = field(default_factory=dict)  # pore totals -> change record
    colour: dict = field(default_factory=dict)  # "melanin.mean", ... -> change record, over the common overlap


def compare_visits(baseline: HeightMap, follow_up: HeightMap, *, allow_scale=False, segmentation_options=None, wrinkle_options=None,
                   baseline_albedo=None, follow_up_albedo=None, pore_options=None, baseline_colour=None, follow_up_colour=None) -> Comparison:
    """Register ``follow_up`` onto ``baseline`` and report every change (see the module notes).

    Texture parameters and pores are computed on the common overlap of both visits; wrinkles
    are segmented in each visit independently and matched by overlap after registration. When
    both albedo images are given, the follow-up's is resampled with the same transform and
    its residual misalignment against the baseline's is measured as for the heights. When
    both visits' colour maps are given (``{"melanin": map, "haemoglobin": map}`` on each
    visit's grid), the follow-up's are resampled the same way and each map's mean, standard
    deviation and relative variation compared over the pixels both visits have.
    """
    from skintopo.evaluation import height_difference
    from skintopo.segmentation import segment_wrinkles
    from skintopo.texture import measure_texture, parameters_by_name
    from skintopo.wrinkles import measure_wrinkles

    aligned, registration = register_height_maps(baseline, follow_up, allow_scale=allow_scale)
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
    from skintopo.chromophores import STATISTICS, region_statistics
    from skintopo.pores import measure_pores

    pores_before, pores_after = (measure_pores(visit, **(pore_options or {})).totals for visit in (before, after))
    pores = {name: _change(pores_before[name], pores_after[name]) for name in pores_before}
    colour = {}
    for name in sorted(set(baseline_colour or {}) & set(follow_up_colour or {})):
        if np.shape(baseline_colour[name]) != baseline.shape or np.shape(follow_up_colour[name]) != follow_up.shape:
            raise SkinTopoError(f"the {name} maps ({np.shape(baseline_colour[name])}, {np.shape(follow_up_colour[name])}) do not match "
                                f"their height maps ({baseline.shape}, {follow_up.shape})")
        fixed, moved = np.asarray(baseline_colour[name], float), apply_registration(follow_up_colour[name], registration)
        both = common & np.isfinite(fixed) & np.isfinite(moved)
        statistics = (region_statistics(fixed, both), region_statistics(moved, both))
        for statistic in STATISTICS:
            colour[f"{name}.{statistic}"] = _change(*(float("nan") if s[statistic] is None else s[statistic] for s in statistics))
    aligned_albedo = albedo_residual = None
    if baseline_albedo is not None and follow_up_albedo is not None:
        for name, image in (("baseline", baseline_albedo), ("follow-up", follow_up_albedo)):
            if np.shape(image) != baseline.shape:
                raise SkinTopoError(f"the {name} albedo image is {np.shape(image)}, its height map {baseline.shape}: they must match")
        aligned_albedo = apply_registration(follow_up_albedo, registration)
        fixed = np.nan_to_num(np.asarray(baseline_albedo, dtype=float), nan=float(np.nanmean(baseline_albedo)))
        albedo_residual = residual_misalignment(fixed, np.where(np.isfinite(aligned_albedo), aligned_albedo, fixed))
    return Comparison(registration, difference, texture, per_wrinkle, totals, wrinkles_before, wrinkles_after, aligned_albedo, albedo_residual,
                      pores, colour)


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

    Every parameter has its own s_r, from its own differences: texture parameters, wrinkle and
    pore totals, colour statistics, and each wrinkle's measures (nu = the repeats in which the
    wrinkle was matched). Wrinkle measures were once pooled in relative terms over the
    wrinkles of the field (nu = their number), on the assumption that a measure's
    repeatability is proportional to its value. 100 simulated trials (3 repeats each) refuted
    it: the relative spread of one wrinkle's length was 1.8 times another's of the same length,
    so pooled limits flagged the less repeatable wrinkle in 4% of unchanged follow-ups at 99%
    confidence (docs/wrinkle-measures.md).
    """
    repeats = [repeats] if isinstance(repeats, Comparison) else list(repeats)
    if not repeats:
        raise SkinTopoError("detection limits need at least one repeat comparison")
    if not 0.5 < confidence < 1:
        raise SkinTopoError(f"the confidence must lie in (0.5, 1), got {confidence}")
    import scipy.stats

    def factor(nu):
        return float(scipy.stats.t.ppf(0.5 + confidence / 2, nu) * np.sqrt(2))

    differences = {}
    for repeat in repeats:
        for group, prefix in (("texture", ""), ("totals", "wrinkles."), ("pores", "pores."), ("colour", "")):
            for name, change in getattr(repeat, group).items():
                differences.setdefault(prefix + name, []).append(change["change"])
        for wrinkle_id, record in repeat.wrinkles.items():
            for name, change in record.items():
                if isinstance(change, dict):
                    differences.setdefault(f"wrinkle{wrinkle_id}.{name}", []).append(change["change"])
    limits, dof = {}, {}
    for name, values in differences.items():
        e = np.asarray(values, float)
        e = e[np.isfinite(e)]
        if e.size:  # t sqrt(2) s_r with s_r^2 = sum(e^2) / (2 nu)
            dof[name] = int(e.size)
            limits[name] = factor(e.size) * float(np.sqrt(np.sum(e**2) / (2 * e.size)))
    warnings = []
    fewest = min(dof.values()) if dof else 0
    if fewest < MIN_DEGREES_OF_FREEDOM:
        warnings.append(f"detection limits from {len(repeats)} repeat pair(s): {fewest} degree(s) of freedom for some parameters, so "
                        f"their limits are wide (t factor {factor(max(fewest, 1)) / np.sqrt(2):.1f} instead of "
                        f"{factor(1e9) / np.sqrt(2):.2f}); more repeat captures narrow them")
    return DetectionLimits(limits, dof, confidence, len(repeats), tuple(warnings))
