"""Pores against exact geometry: a closed-form bowl, simulated fields with pores of known
size and depth among wrinkles and microrelief furrows, and fields with no pore at all."""

from dataclasses import replace

import numpy as np
import pytest

from skintopo.heightmap import HeightMap
from skintopo.pores import measure_pores
from skintopo.synth import make_surface, preset_spec
from skintopo.synth.surfaces import Pore, SurfaceSpec, place_pores


def test_one_bowl_on_a_plane_has_its_closed_form_measures():
    """A paraboloid pore of opening radius r = 150 um and depth d = 60 um on a flat field at
    5 um pixels: depth d; opening area pi r^2 (1 - edge / d), where the bowl is deeper than
    the 0.5 um edge level, within 2% (pixel counting); volume below the rim pi r^2 d / 2
    within 2%; one pore, round."""
    spec = SurfaceSpec(size_px=(160, 160), pixel_um=5.0, microrelief=False, form_radius_mm=None, pores=(Pore((10.0, -20.0), 150.0, 60.0),))
    surface = make_surface(spec, seed=0)
    measures = measure_pores(surface.height)
    assert len(measures.pores) == 1
    pore = measures.pores[0]
    area_um2 = np.pi * 150.0**2
    assert pore.depth_um == pytest.approx(60.0, rel=0.005)
    assert pore.area_mm2 * 1e6 == pytest.approx(area_um2 * (1 - 0.5 / 60.0), rel=0.02)
    assert pore.volume_mm3 * 1e9 == pytest.approx(area_um2 * 60.0 / 2, rel=0.02)
    assert pore.roundness > 0.95
    assert (pore.column * 5.0 - 79.5 * 5.0, 79.5 * 5.0 - pore.row * 5.0) == pytest.approx((10.0, -20.0), abs=5.0)
    assert measures.totals["count_per_cm2"] == pytest.approx(1 / (0.8 * 0.8 / 100))


@pytest.mark.slow
@pytest.mark.parametrize("seed", [1, 2, 3, 4])
def test_pores_of_known_geometry_among_wrinkles_and_furrows(seed):
    """Each field (10 um pixels, 512 px, the four presets in turn; microrelief plates of
    0.7 mm so that 0.5 mm pores fit on them) holds 6 pores of 0.05-0.5 mm openings and
    30-150 um depth on its plateaus: every pore is found once and nothing else is (count
    exact); depth and opening area within 10% (bench_colour_pores over 20 fields: 120 of
    120, the worst area -9.0%, a 5-pixel opening)."""
    preset = ("forehead-low", "forehead-moderate", "forehead-high", "flat-microrelief")[seed % 4]
    spec = replace(preset_spec(preset, size_px=512, pixel_um=10.0), plate_um=700.0)
    spec = place_pores(spec, seed, 6, radius_um=(25.0, 250.0), depth_um=(30.0, 150.0))
    surface = make_surface(spec, seed=seed)
    measures = measure_pores(surface.height)
    assert len(measures.pores) == 6
    for pore in measures.pores:
        ids = surface.pore_labels[measures.labels == pore.id]
        true_id = int(np.bincount(ids).argmax())
        assert true_id > 0 and (ids == true_id).mean() > 0.9
        truth = spec.pores[true_id - 1]
        assert pore.depth_um == pytest.approx(truth.depth_um, rel=0.10)
        assert pore.area_mm2 == pytest.approx(np.pi * truth.radius_um**2 * 1e-6, rel=0.10)


@pytest.mark.slow
@pytest.mark.parametrize("preset", ["flat-microrelief", "forehead-low", "forehead-moderate", "forehead-high"])
def test_no_wrinkle_or_furrow_is_a_pore(preset):
    """Wrinkles, microrelief furrows (0.4 mm plates, where short furrow segments meet) and
    roughness, no pore: none is found, at 20 um and at 10 um pixels."""
    for pixel, size in ((20.0, 384), (10.0, 512)):
        surface = make_surface(preset_spec(preset, size_px=size, pixel_um=pixel), seed=5)
        assert measure_pores(surface.height).pores == (), (preset, pixel)


def test_masked_points_are_neither_pores_nor_field():
    """A pore under the mask is not measured, and the density counts only the measured area."""
    spec = SurfaceSpec(size_px=(100, 100), pixel_um=10.0, microrelief=False, form_radius_mm=None,
                       pores=(Pore((-200.0, 0.0), 100.0, 50.0), Pore((250.0, 0.0), 100.0, 50.0)))
    z = make_surface(spec, seed=0).height.z
    mask = np.ones(z.shape, bool)
    mask[:, 50:] = False
    measures = measure_pores(HeightMap(z, 10.0, mask))
    assert len(measures.pores) == 1 and measures.pores[0].column < 50
    assert measures.field_area_mm2 == pytest.approx(0.5)


def test_fine_maps_are_binned_so_that_the_closings_stay_short():
    """The same bowl on 1 um pixels (a 0.6 mm segment would be 600 pixels long): found on the
    map averaged over 5 x 5 blocks (recorded), with the same measures within 3% and its
    label and centre on the map's own grid."""
    spec = SurfaceSpec(size_px=(800, 800), pixel_um=1.0, microrelief=False, form_radius_mm=None, pores=(Pore((10.0, -20.0), 150.0, 60.0),))
    surface = make_surface(spec, seed=0)
    measures = measure_pores(surface.height)
    assert measures.parameters["binning"] == 5 and len(measures.pores) == 1
    pore = measures.pores[0]
    assert pore.depth_um == pytest.approx(60.0, rel=0.03)
    assert pore.area_mm2 * 1e6 == pytest.approx(np.pi * 150.0**2 * (1 - 0.5 / 60.0), rel=0.03)
    assert measures.labels.shape == (800, 800) and (measures.labels == 1).sum() * 1e-6 == pytest.approx(pore.area_mm2, rel=0.05)
    assert (pore.column - 399.5, 399.5 - pore.row) == pytest.approx((10.0, -20.0), abs=5.0)
