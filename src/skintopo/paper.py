"""The paper's Tables 1 and 2 and Figures 3 and 5, reproduced on simulated subjects.

Four subjects, as in the paper two light-skinned (1, 4) and two darker-skinned (2, 3), in
different wrinkle states. For each: simulate the acquisition (all effects on), reconstruct
red, green, blue and white, run the spectral correction (the paper's algorithm and the
feathered variant), and evaluate every height map against the ground truth.
"""

from __future__ import annotations

import base64
import csv
import json
import time
from dataclasses import dataclass

import numpy as np

from skintopo.correction import spectral_correction
from skintopo.defaults import DEFAULT_SKIN_OPTICS, DEFAULT_SOLVER
from skintopo.evaluation import evaluate_height, wrinkle_max_depths
from skintopo.height import integrate_normals
from skintopo.normals import photometric_stereo
from skintopo.report import cross_section_pngs
from skintopo.segmentation import segmentation_quality
from skintopo.synth import default_settings, make_surface, optics_profile, preset_spec, simulate_acquisition


@dataclass(frozen=True)
class Subject:
    number: int
    skin: str
    preset: str
    seed: int


SUBJECTS = (
    Subject(1, "light", "forehead-high", 11),
    Subject(2, "dark", "forehead-moderate", 12),
    Subject(3, "dark", "forehead-low", 13),
    Subject(4, "light", "forehead-moderate", 14),
)
COLUMNS = ("red", "green", "blue", "white", "algorithm", "algorithm-feathered")


def run_subject(subject: Subject, *, size_px=256, pixel_um=20.0, optics=DEFAULT_SKIN_OPTICS, solver=DEFAULT_SOLVER):
    """Simulate, reconstruct, correct and evaluate one subject. Returns a dict.

    ``optics`` is a skin-optics profile or its name (:mod:`skintopo.optics`); ``solver``
    the photometric-stereo solver (the paper's is least squares).
    """
    started = time.perf_counter()
    surface = make_surface(preset_spec(subject.preset, size_px=size_px, pixel_um=pixel_um), seed=subject.seed)
    settings = default_settings(skin=subject.skin, optics=optics_profile(optics))
    bands, _ = simulate_acquisition(surface, settings, seed=subject.seed + 1000)
    normals, heights = {}, {}
    for band in ("red", "green", "blue", "white"):
        stereo = photometric_stereo(*bands[band], solver=solver)
        normals[band] = stereo.normals
        heights[band] = integrate_normals(stereo.normals, pixel_um, mask=stereo.valid)
    paper = spectral_correction(normals, pixel_um, method="paper")
    heights["algorithm"] = paper.height
    heights["algorithm-feathered"] = spectral_correction(normals, pixel_um, method="feathered", segmentation=paper.segmentation).height
    true_depths = wrinkle_max_depths(surface.height, surface.wrinkle_labels)
    evaluations = {
        name: evaluate_height(height, surface.height, wrinkle_labels=surface.wrinkle_labels, register=False,
                              reference_wrinkle_depths=true_depths)
        for name, height in heights.items()
    }
    return {
        "subject": subject,
        "surface": surface,
        "heights": heights,
        "evaluations": evaluations,
        "segmentation": segmentation_quality(paper.segmentation.mask, surface.wrinkle_labels > 0),
        "wrinkles_found": paper.segmentation.count,
        "seconds": time.perf_counter() - started,
    }


def _table(results, key):
    return [[f"Subject {r['subject'].number}"] + [r["evaluations"][c][key] for c in COLUMNS] for r in results]


def _write_table(folder, name, title, rows, digits):
    header = ["", *COLUMNS]
    with open(folder / f"{name}.csv", "w", newline="", encoding="utf-8") as stream:
        writer = csv.writer(stream)
        writer.writerow(header)
        writer.writerows(rows)
    lines = [f"**{title}**", "", "| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for row in rows:
        lines.append("| " + " | ".join([row[0]] + [f"{v:.{digits}f}" for v in row[1:]]) + " |")
    (folder / f"{name}.md").write_text("\n".join(lines) + "\n", encoding="utf-8")
    return "\n".join(lines)


def _figures(folder, result):
    surface = result["surface"]
    figure3, figure5 = cross_section_pngs(result["heights"], surface.height, surface.wrinkle_labels, title=f"Subject {result['subject'].number}: ")
    (folder / "figure3_cross_section_per_band.png").write_bytes(base64.b64decode(figure3))
    (folder / "figure5_algorithm_vs_truth.png").write_bytes(base64.b64decode(figure5))


def paper_tables(folder, *, size_px=256, pixel_um=20.0, optics=DEFAULT_SKIN_OPTICS, progress=None):
    """Run all subjects and write Table 1, Table 2, the wrinkle-depth table, the figures and
    ``optics.json`` (the skin-optics profile, with its sources) into ``folder``. Returns the
    per-subject results and the tables as Markdown."""
    optics = optics_profile(optics)
    (folder / "optics.json").write_text(json.dumps(optics.describe(), indent=2) + "\n", encoding="utf-8")
    results = []
    for subject in SUBJECTS:
        results.append(run_subject(subject, size_px=size_px, pixel_um=pixel_um, optics=optics))
        if progress:
            progress(subject)
    text = [
        _write_table(folder, "table1_rms_height_error", "Table 1. RMS height error (um)", _table(results, "rms_height_error_um"), 3),
        _write_table(folder, "table2_l2_normal_error", "Table 2. L2-norm normal error", _table(results, "l2_normal_error"), 4),
    ]
    depth_rows = [
        [f"Subject {r['subject'].number}"] + [float(np.mean(r["evaluations"][c]["wrinkle_depth_error_relative"])) * 100 for c in COLUMNS]
        for r in results
    ]
    text.append(_write_table(folder, "table_wrinkle_depth_error", "Mean relative error of wrinkle maximum depth (%)", depth_rows, 1))
    _figures(folder, results[0])
    return results, "\n\n".join(text)
