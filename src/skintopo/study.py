"""Trial statistics of a study and its summary page.

For every region, visit pair (baseline -> follow-up) and field-level parameter (texture,
fractal, wrinkle totals; per-wrinkle rows are left out because wrinkle ids are not shared
between subjects), over the subjects that have both visits:

- the paired change d_i = follow-up_i - baseline_i (``changes.csv``, measured on the
  registered overlap of the two visits);
- mean change with its 95% confidence interval, mean +- t_(0.975, n-1) s / sqrt(n), and as a
  per cent of the mean baseline's magnitude, 100 mean(d) / |mean(baseline)| over the same
  subjects (so that + is an increase, as ``change_percent`` of ``changes.csv``, also for a
  parameter whose values are negative such as Ssk);
- the paired t test (``scipy.stats.ttest_1samp`` of d against 0, which is
  ``scipy.stats.ttest_rel`` of the two visits) and the Wilcoxon signed-rank test
  (``scipy.stats.wilcoxon``, two-sided; undefined when every d_i is 0);
- the detection limit: the ISO 5725-6 repeatability limit r = 2.8 s_r for the difference of
  two results, s_r^2 = sum(e_j^2) / (2k) pooled over the study's k repeat pairs e_j (two
  captures of the same skin at one visit), and the fraction of subjects whose |d_i| > r.
  Without repeat captures the limit is empty and says so.

Fewer than 2 subjects give no interval and no t test (NaN); a subject measured at one visit
of the pair only is counted in ``unpaired_subjects`` and named on the page.
"""

from __future__ import annotations

import re

import numpy as np

REPEATABILITY_FACTOR = 2.8  # ISO 5725-6 4.1.4: r = 2.8 s_r (1.96 sqrt(2), 95 % of differences)
_PER_WRINKLE = re.compile(r"^wrinkle\d+\.")
STATISTICS_COLUMNS = ["region", "baseline_visit", "visit", "parameter", "unit", "subjects", "unpaired_subjects", "mean_change",
                      "ci95_low", "ci95_high", "mean_change_percent", "t_statistic", "t_p_value", "wilcoxon_statistic",
                      "wilcoxon_p_value", "detection_limit", "repeat_pairs", "fraction_beyond_limit"]

READABLE = {
    "Sa": "Sa, arithmetic mean height", "Sq": "Sq, root mean square height", "Ssk": "Ssk, skewness", "Sku": "Sku, kurtosis",
    "Sp": "Sp, maximum peak height", "Sv": "Sv, maximum pit depth", "Sz": "Sz, maximum height", "Sdq": "Sdq, RMS gradient",
    "Sdr": "Sdr, developed interfacial area ratio", "Sal": "Sal, autocorrelation length", "Str": "Str, texture aspect ratio",
    "Std": "Std, texture direction", "Sk": "Sk, core height", "Spk": "Spk, reduced peak height", "Svk": "Svk, reduced valley depth",
    "Smr1": "Smr1, peak material ratio", "Smr2": "Smr2, valley material ratio", "Sxp": "Sxp, extreme peak height",
    "Vmp": "Vmp, peak material volume", "Vmc": "Vmc, core material volume", "Vvc": "Vvc, core void volume",
    "Vvv": "Vvv, valley void volume", "wrinkles.count": "wrinkle count", "wrinkles.total_length_mm": "total wrinkle length",
    "wrinkles.mean_depth_um": "mean wrinkle depth", "wrinkles.area_fraction": "wrinkle area fraction",
}
PLOTTED = ("Sa", "Sq", "Vvv", "wrinkles.mean_depth_um", "wrinkles.total_length_mm", "wrinkles.count")


def readable_name(parameter):
    """A name a clinician can read: 'Sa, arithmetic mean height', 'fractal dimension (cube counting)'."""
    if parameter.startswith("D_"):
        return f"fractal dimension ({parameter[2:].replace('-', ' ')})"
    region, _, name = parameter.rpartition(".") if parameter.count(".") and not parameter.startswith("wrinkles.") else ("", "", parameter)
    text = READABLE.get(name, name)
    return f"{text} [{region}]" if region else text


def _unit_label(unit):
    return {"um": "µm", "um3/um2": "µm³/µm²", "": "", "%": "%", "deg": "°", "mm": "mm"}.get(unit, unit)


def study_statistics(changes, repeats, units, visits=None):
    """One row per (region, baseline visit, visit, parameter); see the module notes.

    ``changes`` and ``repeats`` have the columns of ``changes.csv`` (subject, region,
    baseline_visit, visit, parameter, baseline, follow_up, change, ...); ``units`` maps a
    parameter to its unit; ``visits`` (optional) maps (region, visit) to the set of subjects
    measured there, to count unpaired subjects.
    """
    import pandas as pd
    from scipy import stats

    keep = ~changes.parameter.str.match(_PER_WRINKLE)
    changes = changes[keep]
    repeats = repeats[~repeats.parameter.str.match(_PER_WRINKLE)] if len(repeats) else repeats
    rows = []
    for (region, baseline_visit, visit, parameter), group in changes.groupby(["region", "baseline_visit", "visit", "parameter"], sort=True):
        d = group.change.to_numpy(dtype=float)
        finite = np.isfinite(d)
        d, baseline = d[finite], group.baseline.to_numpy(dtype=float)[finite]
        n = d.size
        row = {"region": region, "baseline_visit": baseline_visit, "visit": visit, "parameter": parameter, "unit": units.get(parameter, ""),
               "subjects": n, "mean_change": float(np.mean(d)) if n else np.nan}
        row["mean_change_percent"] = float(100 * np.mean(d) / abs(np.mean(baseline))) if n and np.mean(baseline) != 0 else np.nan
        if n >= 2:
            half = stats.t.ppf(0.975, n - 1) * np.std(d, ddof=1) / np.sqrt(n)
            row["ci95_low"], row["ci95_high"] = row["mean_change"] - half, row["mean_change"] + half
            test = stats.ttest_1samp(d, 0.0)
            row["t_statistic"], row["t_p_value"] = float(test.statistic), float(test.pvalue)
        if n >= 1 and np.any(d != 0):
            test = stats.wilcoxon(d)
            row["wilcoxon_statistic"], row["wilcoxon_p_value"] = float(test.statistic), float(test.pvalue)
        if visits is not None:
            before, after = visits.get((region, baseline_visit), set()), visits.get((region, visit), set())
            row["unpaired_subjects"] = len(before ^ after)
        e = repeats[(repeats.region == region) & (repeats.parameter == parameter)].change.to_numpy(dtype=float) if len(repeats) else np.array([])
        e = e[np.isfinite(e)]
        row["repeat_pairs"] = e.size
        if e.size:
            row["detection_limit"] = REPEATABILITY_FACTOR * np.sqrt(np.sum(e**2) / (2 * e.size))
            row["fraction_beyond_limit"] = float(np.mean(np.abs(d) > row["detection_limit"])) if n else np.nan
        rows.append(row)
    return pd.DataFrame(rows, columns=STATISTICS_COLUMNS)


def _paired_plots(long):
    """One small figure per plotted parameter: visits on x, one line per subject."""
    from skintopo.report import figure_png, pyplot

    plt = pyplot()

    pictures = []
    for name in PLOTTED:
        subset = long[long.parameter == name]
        if subset.empty:
            continue
        visits = list(dict.fromkeys(long.visit))  # study order
        figure, axis = plt.subplots(figsize=(4.6, 3.2), layout="constrained")
        for (subject, region), line in subset.groupby(["subject", "region"]):
            line = line.set_index("visit").reindex([v for v in visits if v in set(line.visit)])
            axis.plot([visits.index(v) for v in line.index], line.value.astype(float), marker="o", label=f"{subject} {region}")
        unit = _unit_label(subset.unit.iloc[0])
        axis.set(xticks=range(len(visits)), xticklabels=visits, xlabel="visit", ylabel=unit or "(no unit)", title=readable_name(name))
        axis.title.set_fontsize(10)
        if subset.subject.nunique() <= 8:
            axis.legend(fontsize=7)
        pictures.append((name, figure_png(figure, dpi=90)))
    return pictures


def _number(value, digits=4):
    if value is None or (isinstance(value, float) and not np.isfinite(value)):
        return "—"
    return f"{value:.{digits}g}"


def summary_html(long, changes, statistics, failures, reports):
    """The study's summary page: one self-contained HTML file (no remote resources).

    ``reports`` maps (subject, region, visit) to the relative link of that item's report."""
    from skintopo.report import render_page

    rows = []
    main = statistics[statistics.parameter.isin(PLOTTED) | statistics.parameter.str.match(r"^(S[a-z]{1,2}|V[mv][pcv]|D_)")]
    for r in main.itertuples():
        ci = f"{_number(r.ci95_low)} to {_number(r.ci95_high)}" if np.isfinite(r.ci95_low) else "— (fewer than 2 subjects)"
        limit = (f"{_number(r.detection_limit)} ({r.fraction_beyond_limit:.0%} beyond)" if np.isfinite(r.detection_limit)
                 else "— (no repeat captures)")
        note = f"{r.unpaired_subjects} unpaired subject(s) left out" if (r.unpaired_subjects or 0) > 0 else ""
        rows.append([f"{r.baseline_visit} → {r.visit}", r.region, readable_name(r.parameter), _unit_label(r.unit), r.subjects,
                     _number(r.mean_change), ci, _number(r.mean_change_percent, 3), _number(r.t_p_value, 3), _number(r.wilcoxon_p_value, 3),
                     limit, note])
    context = {
        "title": "skintopo study summary", "subjects": long.subject.nunique(), "visits": [str(v) for v in dict.fromkeys(long.visit)],
        "statistics_rows": rows, "pictures": [(f"{readable_name(n)} per subject and visit", p) for n, p in _paired_plots(long)],
        "reports": sorted(reports.items()), "failures": list(failures.itertuples()),
    }
    return render_page("study.html", context, style="study.css")
