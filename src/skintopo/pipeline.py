"""The measurement as one pipeline, with its options kept beside its result.

acquisition -> normals per band -> height (a band, the spectral correction or the physically
based height) -> texture, fractal, wrinkle and pore measures; beside the height, melanin and
haemoglobin maps from the bands' albedo. The command line, the batch, the demo and a notebook all call
these functions; each stage also stays usable alone.

Options are frozen dataclasses holding the library's defaults, so a result records exactly
the settings that made it (``MeasureOptions.as_dict``), and a study can fingerprint them:

>>> options = MeasureOptions(height=HeightOptions(method="blue"))    # doctest: +SKIP
>>> measurement = measure_acquisition("capture/", options)          # doctest: +SKIP
>>> measurement.parameter_rows()[0]                                  # doctest: +SKIP
{'region': 'field', 'name': 'Sq', 'value': 31.2, 'unit': 'um', ...}
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict, dataclass, field, fields, replace
from pathlib import Path

import numpy as np

from skintopo.acquisition import DEFAULT_SATURATION, load_acquisition
from skintopo.chromophores import RGB, ChromophoreMaps, chromophore_maps, reference_albedo
from skintopo.correction import REQUIRED_BANDS, CorrectionResult, spectral_correction
from skintopo.defaults import (
    AUTO_HEIGHT,
    CORRECTION_METHODS,
    DEFAULT_COLOUR_SMOOTHING_UM,
    DEFAULT_DETECTION_CONFIDENCE,
    DEFAULT_LEVEL_ORDER,
    DEFAULT_PORE_EDGE_UM,
    DEFAULT_PORE_MAX_OPENING_UM,
    DEFAULT_PORE_MIN_DEPTH_UM,
    DEFAULT_PORE_MIN_OPENING_UM,
    HEIGHT_METHODS,
    PHYSICS,
)
from skintopo.errors import SkinTopoError
from skintopo.height import DEFAULT_INTEGRATOR
from skintopo.heightmap import HeightMap
from skintopo.normals import DEFAULT_SHADOW_FRACTION, DEFAULT_SOLVER, checked_specular_colour
from skintopo.optics import optics_profile
from skintopo.physics import PhysicsResult, near_field_physics_height, physics_height
from skintopo.pores import PoreMeasures, measure_pores
from skintopo.reconstruct import DEFAULT_HIGHLIGHTS, SPECULAR_FREE, reconstruct_band, rgb_share_lights, specular_separation
from skintopo.segmentation import (
    DEFAULT_CUTOFF_UM,
    DEFAULT_MIN_DEPTH_UM,
    DEFAULT_MIN_LENGTH_UM,
    DEFAULT_SHORT_CUTOFF_UM,
    DEFAULT_STRAIGHT_VALLEY_UM,
    WrinkleSegmentation,
    segment_wrinkles,
)
from skintopo.texture import DEFAULT_P, DEFAULT_Q, blas_threads, finite_or_none, measure_texture
from skintopo.wrinkles import (
    DEFAULT_ALONG_CLOSING_UM,
    DEFAULT_DEPTH_SHORT_CUTOFF_UM,
    DEFAULT_DEPTH_WINDOW_UM,
    DEFAULT_FURROW_CLOSING_UM,
    WrinkleMeasures,
    measure_wrinkles,
)


@dataclass(frozen=True)
class ReconstructionOptions:
    """How an acquisition becomes normals and heights (see :func:`skintopo.reconstruct.reconstruct_band`).

    ``highlights``: ``"none"`` fits every observation the shadow and saturation rules keep;
    ``"cross-band"`` leaves out the highlights found from red, green and blue together
    (:func:`skintopo.normals.separate_specular`). ``specular_colour``: for ``"cross-band"``,
    the surface reflection's relative strength in red, green and blue (e.g. measured as the
    difference of a parallel- and a cross-polarised capture of the skin); None (default) is
    white, the neutral-interface assumption. It cannot be estimated from the capture itself
    (docs/method.md).

    ``pixel_um`` is used only for folders without a pixel size (DiLiGenT), where it defaults to 1.
    """

    pixel_um: float | None = None
    saturation: float = DEFAULT_SATURATION
    shadow_fraction: float = DEFAULT_SHADOW_FRACTION
    solver: str = DEFAULT_SOLVER
    integrator: str = DEFAULT_INTEGRATOR
    highlights: str = DEFAULT_HIGHLIGHTS
    specular_colour: tuple | None = None

    def __post_init__(self):
        if self.specular_colour is None:
            return
        if self.highlights != "cross-band":
            raise SkinTopoError(f"a specular colour applies to cross-band highlights only (highlights is {self.highlights!r})")
        # a JSON list becomes a tuple
        object.__setattr__(self, "specular_colour", checked_specular_colour(self.specular_colour))


@dataclass(frozen=True)
class HeightOptions:
    """Which height map is measured.

    ``method``: ``"auto"`` (the paper's spectral correction when red, green and blue are
    present, else the white band, else the only band), ``"paper"`` or ``"feathered"`` (the
    spectral correction, :mod:`skintopo.correction`), ``"physics"`` (the physically based
    height, :mod:`skintopo.physics`), or one band: ``red``, ``green``,
    ``blue``, ``white``, ``specular-free``. ``physics_kernels``: for ``"physics"``, known
    scattering kernels: a diffusion-profile file (``.json``, from ``skintopo calibrate
    skin``: :func:`skintopo.calibration.diffusion_profile_from_edge`) or the name of a
    skin-optics profile (:mod:`skintopo.optics`) whose diffusion profiles are taken; None
    (default) estimates them from the capture.
    """

    method: str = AUTO_HEIGHT
    physics_kernels: str | None = None

    def __post_init__(self):
        if self.method not in HEIGHT_METHODS:
            raise SkinTopoError(f"unknown height method {self.method!r}; choose from {list(HEIGHT_METHODS)}")
        self.kernels()  # a clear error for an unknown profile or a bad file

    def kernels(self):
        """band -> diffusion profile of ``physics_kernels``, or None."""
        name = self.physics_kernels
        if name is None:
            return None
        if str(name).lower().endswith(".json"):
            from skintopo.calibration import read_diffusion_profiles

            return read_diffusion_profiles(name)
        return optics_profile(name).scattering


@dataclass(frozen=True)
class SegmentationOptions:
    """Wrinkle segmentation settings (:func:`skintopo.segmentation.segment_wrinkles`), micrometres."""

    cutoff_um: float = DEFAULT_CUTOFF_UM
    short_cutoff_um: float = DEFAULT_SHORT_CUTOFF_UM
    min_depth_um: float = DEFAULT_MIN_DEPTH_UM
    min_length_um: float = DEFAULT_MIN_LENGTH_UM
    straight_valley_um: float = DEFAULT_STRAIGHT_VALLEY_UM

    def as_kwargs(self):
        return asdict(self)


@dataclass(frozen=True)
class WrinkleOptions:
    """Wrinkle measure settings (:func:`skintopo.wrinkles.measure_wrinkles`), micrometres:
    the closing segments that fill the furrows around a wrinkle and bridge those crossing it,
    the stretch of centre line whose mean depth is the max depth, and the depth's S-filter
    (0 = none, the default: any S-filter fills the floor of narrow wrinkles)."""

    furrow_closing_um: float = DEFAULT_FURROW_CLOSING_UM
    along_closing_um: float = DEFAULT_ALONG_CLOSING_UM
    depth_window_um: float = DEFAULT_DEPTH_WINDOW_UM
    short_cutoff_um: float = DEFAULT_DEPTH_SHORT_CUTOFF_UM

    def as_kwargs(self):
        return asdict(self)


@dataclass(frozen=True)
class PoreOptions:
    """Pore settings (:func:`skintopo.pores.measure_pores`), micrometres."""

    max_opening_um: float = DEFAULT_PORE_MAX_OPENING_UM
    min_opening_um: float = DEFAULT_PORE_MIN_OPENING_UM
    min_depth_um: float = DEFAULT_PORE_MIN_DEPTH_UM
    edge_um: float = DEFAULT_PORE_EDGE_UM

    def __post_init__(self):
        if not (0 < self.min_opening_um < self.max_opening_um and self.min_depth_um > self.edge_um > 0):
            raise SkinTopoError(f"pore settings need 0 < min opening < max opening and 0 < edge < min depth, got {asdict(self)}")

    def as_kwargs(self):
        return asdict(self)


@dataclass(frozen=True)
class ColourOptions:
    """Melanin and haemoglobin maps (:func:`skintopo.chromophores.chromophore_maps`): the
    Gaussian (sigma, um) the optical densities are smoothed with."""

    smoothing_um: float = DEFAULT_COLOUR_SMOOTHING_UM


@dataclass(frozen=True)
class TextureOptions:
    """Surface texture settings (:func:`skintopo.texture.measure_texture`): the order of the
    least-squares form removed first and the material ratios p, q (%) of the volume parameters."""

    level_order: int | None = DEFAULT_LEVEL_ORDER
    p: float = DEFAULT_P
    q: float = DEFAULT_Q

    def __post_init__(self):
        if self.level_order is not None and self.level_order < 0:
            raise SkinTopoError(f"the form removal order must be 0 or more (1 = plane), got {self.level_order}")
        if not (0 <= self.p < self.q <= 100):
            raise SkinTopoError(f"material ratios must satisfy 0 <= p < q <= 100 (%), got p = {self.p:g}, q = {self.q:g}")


@dataclass(frozen=True)
class MeasureOptions:
    """Every option that changes a number of ``skintopo measure``.

    ``regions``: extra rectangles ``((name, (x0, y0, x1, y1)), ...)`` in micrometres, pixel
    edges from the map's top-left corner, measured beside the whole field.
    """

    reconstruction: ReconstructionOptions = field(default_factory=ReconstructionOptions)
    height: HeightOptions = field(default_factory=HeightOptions)
    segmentation: SegmentationOptions = field(default_factory=SegmentationOptions)
    texture: TextureOptions = field(default_factory=TextureOptions)
    regions: tuple = ()
    wrinkles: WrinkleOptions = field(default_factory=WrinkleOptions)
    pores: PoreOptions = field(default_factory=PoreOptions)
    colour: ColourOptions = field(default_factory=ColourOptions)

    def as_dict(self):
        """Plain JSON-ready dict (the form stored in results and study fingerprints)."""
        data = asdict(self)
        data["regions"] = [[name, list(box)] for name, box in self.regions]
        return data

    @classmethod
    def from_dict(cls, data):
        """Inverse of :meth:`as_dict`."""
        kinds = {"reconstruction": ReconstructionOptions, "height": HeightOptions, "segmentation": SegmentationOptions,
                 "texture": TextureOptions, "wrinkles": WrinkleOptions, "pores": PoreOptions, "colour": ColourOptions}
        unknown = set(data) - {f.name for f in fields(cls)}
        if unknown:
            raise SkinTopoError(f"unknown measure options {sorted(unknown)}")
        values = {name: kinds[name](**data[name]) for name in kinds if name in data}
        values["regions"] = tuple((name, tuple(box)) for name, box in data.get("regions", ()))
        return cls(**values)


def region_slices(height: HeightMap, box, name):
    """(rows, columns) slices of ``box = (x0, y0, x1, y1)`` micrometres, measured as pixel
    edges from the map's top-left corner (the map spans columns x spacing by rows x spacing);
    a :class:`SkinTopoError` when it lies outside the map or is under 2 x 2 pixels."""
    dy, dx = height.spacing
    x0, y0, x1, y1 = box
    c0, c1 = int(round(x0 / dx)), int(round(x1 / dx))
    r0, r1 = int(round(y0 / dy)), int(round(y1 / dy))
    rows, columns = height.shape
    if c0 < 0 or r0 < 0 or c1 > columns or r1 > rows:
        raise SkinTopoError(f"region {name!r} ({box} um) lies outside the map ({columns * dx:g} x {rows * dy:g} um)")
    if c1 - c0 < 2 or r1 - r0 < 2:
        raise SkinTopoError(f"region {name!r} ({box} um) is smaller than 2 x 2 pixels of {dx:g} x {dy:g} um")
    return slice(r0, r1), slice(c0, c1)


def crop_region(height: HeightMap, box, name):
    """The part of ``height`` inside ``box`` (:func:`region_slices`)."""
    window = region_slices(height, box, name)
    return HeightMap(height.z[window], height.spacing, height.mask[window])


# Memory each command needs per pixel beyond the acquisition's float32 images (bytes), for
# the guard of load_acquisition: peaks measured on a 20-megapixel acquisition (4472 x 4472,
# 16 images, default options; each process's own peak, bench/results/scale.json of 2026-12-06):
# reconstruct 5.20 GiB, correct 7.44 GiB, measure 6.23 GiB (report included), i.e. 199, 319
# and 254 bytes a pixel beyond the images and a 0.3 GiB baseline, rounded up.
PROCESSING_BYTES_PER_PIXEL = {"reconstruct": 210, "correct": 330, "measure": 260}


def reconstruct_bands(acquisition, options: ReconstructionOptions = ReconstructionOptions(), bands=None, progress=iter, integrate=True,
                      separation=None):
    """Normals, albedo and height of each band (default: every band present; ``integrate=False``:
    no height, see :func:`skintopo.reconstruct.reconstruct_band`).

    ``progress`` wraps the iteration over bands (e.g. a tqdm bar). ``separation``: the
    acquisition's :func:`~skintopo.reconstruct.specular_separation`, when already made."""
    if options.highlights == "cross-band" and separation is None:  # once for every band
        separation = specular_separation(acquisition, options.specular_colour)
    results = {}
    for band in progress(list(bands or acquisition.bands)):
        # with a device, each band starts from the first band's depth (the same skin at the same distance)
        start = next(iter(results.values()), None) if acquisition.device is not None else None
        results[band] = reconstruct_band(acquisition, band, integrator=options.integrator, shadow_fraction=options.shadow_fraction,
                                         solver=options.solver, highlights=options.highlights, separation=separation, start=start,
                                         integrate=integrate)
    return results


@dataclass(frozen=True, eq=False)
class AcquisitionHeight:
    """The height map chosen by :class:`HeightOptions`, with what made it.

    ``description`` names it (e.g. ``"spectral correction (paper)"``, ``"blue band"``);
    ``albedo`` is the red band's (else the first band's) albedo on the same grid.
    """

    height: HeightMap
    albedo: np.ndarray
    description: str
    bands: dict  # band -> BandReconstruction
    correction: CorrectionResult | None
    physics: PhysicsResult | None = None


def _resolved_method(method, present):
    if method != AUTO_HEIGHT:
        return method
    if all(b in present for b in REQUIRED_BANDS):
        return "paper"
    return "white" if "white" in present else next(iter(present))


def acquisition_height(acquisition, options: MeasureOptions = MeasureOptions(), progress=iter, step_progress=iter, *,
                       every_band=True) -> AcquisitionHeight:
    """Reconstruct the bands ``options.height`` needs and return the height to measure.
    ``progress`` wraps the iteration over the bands, ``step_progress`` that over the physics
    height's iterations. ``every_band`` (as ``correct`` and ``demo`` report them): the
    spectral correction, the physics height and the automatic choice reconstruct and
    integrate every band of the acquisition; False: only the bands the height is made from,
    and not integrated when the method integrates their normals itself (``measure``: at 20
    megapixels this saves a band's reconstruction and four integrations, about 36 bytes a pixel
    a band)."""
    method = _resolved_method(options.height.method, acquisition.bands)
    spectral = method in CORRECTION_METHODS
    needed = REQUIRED_BANDS if spectral or method in (SPECULAR_FREE, PHYSICS) else (method,)
    missing = [b for b in needed if b not in acquisition.bands]
    if missing:
        what = f"the spectral correction ({method})" if spectral else f"the height method {method!r}"
        raise SkinTopoError(f"{acquisition.source}: {what} needs {', '.join(needed[:-1]) + ' and ' + needed[-1] if len(needed) > 1 else needed[0]} "
                            f"images; missing {missing} (the acquisition has {sorted(acquisition.bands)})")
    if method == PHYSICS and not rgb_share_lights(acquisition):
        raise SkinTopoError(f"{acquisition.source}: the physics height needs red, green and blue images taken under the same lights, "
                            "in the same order")
    # the spectral correction reports every band beside its own height (``skintopo correct``)
    derived = spectral or method == PHYSICS  # heights made from the bands' normals or images, not from one band's height
    if every_band and (derived or options.height.method == AUTO_HEIGHT):
        wanted = list(acquisition.bands)
    else:
        wanted = list(REQUIRED_BANDS) if derived else [method]
    reconstruction = options.reconstruction
    separation = specular_separation(acquisition, reconstruction.specular_colour) if reconstruction.highlights == "cross-band" else None
    results = reconstruct_bands(acquisition, reconstruction, wanted, progress, integrate=every_band or not derived, separation=separation)
    albedo_band = "red" if "red" in results else next(iter(results))
    albedo = results[albedo_band].stereo.albedo
    if spectral:
        # with a device the bands live on the skin-plane grid, where the camera's mask does not apply
        mask = acquisition.mask if acquisition.device is None else np.logical_and.reduce([results[b].height.mask for b in REQUIRED_BANDS])
        correction = spectral_correction({b: results[b].stereo.normals for b in REQUIRED_BANDS}, acquisition.pixel_um, method=method,
                                         mask=mask, integrator=options.reconstruction.integrator,
                                         **options.segmentation.as_kwargs())
        return AcquisitionHeight(correction.height, albedo, f"spectral correction ({method})", results, correction)
    if method == PHYSICS:
        physics = _physics(acquisition, options, results, step_progress, separation)
        inverted = "scattering, interreflection and highlights inverted" if physics.components["highlights"] else \
            "scattering and interreflection inverted, highlights separated cross-band"
        lights = ", near-field LEDs" if acquisition.device else ""
        return AcquisitionHeight(physics.height, albedo, f"physics ({inverted}{lights})", results, None, physics)
    return AcquisitionHeight(results[method].height, albedo, f"{method} band", results, None)


def _physics(acquisition, options: MeasureOptions, results, progress, separation) -> PhysicsResult:
    """The physics height of ``acquisition`` (:mod:`skintopo.physics`). Under distant lights
    it models the highlights itself (``--highlights`` does not apply). With a device the
    bands' near-field reconstructions ``results`` are reused, and ``--highlights cross-band``
    gives it the separated diffuse images and no highlight lobe of its own (on the simulated
    paper-like device's shiny forehead, 21.9 against 106.5 um after form with its own lobe:
    Method and validation, "The physics height through the device"); ``separation``: that of
    the bands' reconstructions."""
    images = {band: acquisition.bands[band].images for band in REQUIRED_BANDS}
    common = {"mask": acquisition.mask, "kernels": options.height.kernels(), "integrator": options.reconstruction.integrator,
              "progress": progress}
    if acquisition.device is None:
        return physics_height(images, acquisition.bands["red"].lights, acquisition.pixel_um, solver=options.reconstruction.solver, **common)
    separated = options.reconstruction.highlights == "cross-band"
    if separated:
        images = {band: values - separation.band_specular(band) for band, values in images.items()}
    device = acquisition.device
    device = replace(device, leds=tuple(device.led(name) for name in acquisition.bands["red"].leds))
    solved = {band: results[band].near_field for band in REQUIRED_BANDS}
    return near_field_physics_height(images, device, highlights=not separated, solved=solved, **common)


@dataclass(frozen=True, eq=False)
class Measurement:
    """Everything ``skintopo measure`` computes, with the options and source that made it.

    ``texture`` maps a region name (``"field"`` first) to its list of
    :class:`skintopo.texture.Parameter`; ``fractal_results`` holds the whole field's
    estimators with their log-log points. ``chromophores``: melanin and haemoglobin maps
    (from an acquisition with red, green and blue albedo; else None, and
    ``source["chromophores"]`` says why).
    """

    height: HeightMap
    albedo: np.ndarray | None
    source: dict
    options: MeasureOptions
    texture: dict
    fractal_results: tuple
    segmentation: WrinkleSegmentation
    wrinkles: WrinkleMeasures
    pores: PoreMeasures | None = None
    chromophores: ChromophoreMaps | None = None

    def region_masks(self):
        """{name: boolean mask on the height's grid} of ``options.regions`` (the field is all)."""
        masks = {}
        for name, box in self.options.regions:
            masks[name] = np.zeros(self.height.shape, bool)
            masks[name][region_slices(self.height, box, name)] = True
        return masks

    def parameter_rows(self):
        """One dict per (region, parameter): region, name, value (None for NaN), unit, reference."""
        return [
            {"region": region, "name": p.name, "value": finite_or_none(p.value), "unit": p.unit, "reference": p.reference}
            for region, parameters in self.texture.items()
            for p in parameters
        ]


def measure_height(height: HeightMap, options: MeasureOptions = MeasureOptions(), *, albedo=None, source=None, progress=iter,
                   chromophores=None, alongside=None) -> Measurement:
    """Texture and fractal parameters (whole field and each region), wrinkle and pore
    measures of ``height``; ``chromophores`` (melanin and haemoglobin maps) are kept with
    them. ``progress`` wraps the iteration over the steps (each a name; e.g. a tqdm bar).

    ``alongside``: a callable of the height map, run on this thread once the texture and
    pores are measured, while the worker thread still segments or measures the wrinkles
    (the longer of the two); work that needs only the height fills that wait (``skintopo
    measure`` writes ``height.x3p`` and makes the report's height views there:
    :class:`skintopo.results.HeightOutputs`)."""
    regions = {"field": height} | {name: crop_region(height, box, name) for name, box in options.regions}
    texture_options = {"level_order": options.texture.level_order, "p": options.texture.p, "q": options.texture.q}
    texture, fractal_results = {}, ()
    # The wrinkles are segmented and measured in a worker thread while the texture is measured
    # here: the two share nothing, and both spend their time in NumPy/SciPy loops that
    # release the GIL (a 1024^2 forehead: 1.76 s one after the other, 1.52 s side by side, medians of 3).
    # BLAS is held to one thread meanwhile (its idle workers spin and take a core; 1024^2
    # forehead, whole process: 2.02 -> 1.99 s median of 6 interleaved runs, best 2.00 -> 1.94 s).
    with blas_threads(1), ThreadPoolExecutor(max_workers=1) as pool:
        segmenting = pool.submit(segment_wrinkles, height, **options.segmentation.as_kwargs())
        measuring = pool.submit(lambda: measure_wrinkles(height, segmenting.result(), **options.wrinkles.as_kwargs()))
        for step in progress([*(f"texture: {name}" for name in regions), "pores", "wrinkle segmentation", "wrinkle measures"]):
            if step == "texture: field":  # its estimators' log-log points go to the report's plot
                texture["field"], fractal_results = measure_texture(height, **texture_options, return_fractal=True)
            elif step.startswith("texture: "):
                name = step.removeprefix("texture: ")
                texture[name] = measure_texture(regions[name], **texture_options)
            elif step == "pores":  # here while the worker segments; both use two threads, so on two cores it still adds
                # about 0.65 s to a 1024^2 map (bench_measure)
                pores = measure_pores(height, **options.pores.as_kwargs())
            elif step == "wrinkle segmentation":
                if alongside is not None:
                    alongside(height)
                segmentation = segmenting.result()
            else:
                wrinkles = measuring.result()
    return Measurement(height, albedo, dict(source or {}), options, texture, fractal_results, segmentation, wrinkles, pores, chromophores)


def acquisition_chromophores(acquisition, bands, options: MeasureOptions = MeasureOptions()):
    """(:class:`~skintopo.chromophores.ChromophoreMaps` or None, note): the melanin and
    haemoglobin maps from the red, green and blue albedo of ``bands`` (band ->
    BandReconstruction, on the height's grid), absolute when the acquisition has a white
    reference; None with the reason when a band is missing."""
    albedo = {b: bands[b].stereo.albedo for b in RGB if b in bands}
    return colour_maps(albedo, acquisition.pixel_um, options, white_reference_of(acquisition, options), str(acquisition.source))


def white_reference_of(acquisition, options: MeasureOptions = MeasureOptions()):
    """(the white reference's median albedo per band, its reflectance per band) of
    ``acquisition``, or None when it has no white reference."""
    if acquisition.white_reference is None:
        return None
    return reference_albedo(acquisition, shadow_fraction=options.reconstruction.shadow_fraction), acquisition.white_reference.reflectance


def colour_maps(albedo, pixel_um, options: MeasureOptions = MeasureOptions(), reference=None, source="the acquisition"):
    """The second half of :func:`acquisition_chromophores`, from the albedo maps (band ->
    map) and :func:`white_reference_of` (so that the images can be let go first). An
    unphysical reflectance is an error with a white reference (the capture's own reference
    contradicts it); without one (the albedo in the lights' intensity units) the maps are
    left out with the reason, and the topography is still measured."""
    missing = [b for b in RGB if b not in albedo]
    if missing:
        return None, f"not measured: the height was made without the {', '.join(missing)} band(s)"
    measured, reflectance = reference if reference is not None else (None, None)
    try:
        maps = chromophore_maps(albedo, pixel_um=pixel_um, smoothing_um=options.colour.smoothing_um, reference_albedo=measured,
                                reference_reflectance=reflectance, source=source)
    except SkinTopoError as error:
        if reference is not None:  # the capture's own reference says the reflectance is unphysical: an input to fix
            raise
        # without a reference the albedo's scale is the lights' intensity units: no colour, but the topography is measured
        return None, f"not measured: {error}"
    return maps, f"melanin and haemoglobin indices ({maps.reflectance} reflectance)"


def measure_acquisition(path, options: MeasureOptions = MeasureOptions(), progress=iter, on_note=None, step_progress=iter,
                        alongside=None) -> Measurement:
    """Load an acquisition folder, make the height ``options.height`` asks for and measure it.

    ``progress`` wraps the iteration over the bands, ``step_progress`` that over the measure's
    steps (:func:`measure_height`, which runs ``alongside``); ``on_note`` receives notes meant
    for the user (e.g. an assumed pixel size)."""
    acquisition = load_acquisition(path, pixel_um=options.reconstruction.pixel_um, saturation=options.reconstruction.saturation,
                                   bytes_per_pixel=PROCESSING_BYTES_PER_PIXEL["measure"])
    if acquisition.pixel_um_assumed and on_note is not None:
        on_note(f"{Path(path).name} has no pixel size; assuming 1 um per pixel (give --pixel-um)")
    made = acquisition_height(acquisition, options, progress, step_progress, every_band=False)
    source = {"input": acquisition.source.name, "kind": "acquisition", "acquisition": acquisition_summary(acquisition),
              "height": made.description}
    if made.physics is not None:
        source["physics"] = made.physics.as_dict()  # kernels, highlight lobe, convergence: kept with the result
        note = made.physics.convergence_note()
        if note and on_note is not None:
            on_note(note)
    height, albedo, pixel_um, name = made.height, made.albedo, acquisition.pixel_um, str(acquisition.source)
    band_albedo = {b: made.bands[b].stereo.albedo for b in RGB if b in made.bands}
    reference = white_reference_of(acquisition, options)
    # the images and the bands' normals and albedos (about 170 bytes a pixel with 16 images)
    # are not needed to measure the height: let them go first
    del acquisition, made
    colour = []

    def colour_then_alongside(height):
        # the melanin and haemoglobin maps need only the albedo: made in the measure's wait for
        # the wrinkles (1000 x 1000: 0.1 s off the whole measure), before the caller's work
        colour.extend(colour_maps(band_albedo, pixel_um, options, reference, name))
        band_albedo.clear()
        if alongside is not None:
            alongside(height)

    measurement = measure_height(height, options, albedo=albedo, source=source, progress=step_progress, alongside=colour_then_alongside)
    chromophores, source["chromophores"] = colour
    return replace(measurement, source=dict(source), chromophores=chromophores)


def acquisition_summary(acquisition):
    """What identifies an acquisition in a result without its path (which may name the
    person): the folder's name, a SHA-256 of its manifest (or DiLiGenT lists), layout, size."""
    import hashlib

    from skintopo.acquisition import MANIFEST_NAME

    digest = hashlib.sha256()
    for name in (MANIFEST_NAME, "filenames.txt", "light_directions.txt", "light_intensities.txt"):
        if (acquisition.source / name).is_file():
            digest.update((acquisition.source / name).read_bytes())
    return {
        "name": acquisition.source.name,
        "sha256": digest.hexdigest(),
        "layout": acquisition.layout,
        "shape": list(acquisition.shape),
        "pixel_um": acquisition.pixel_um,
        "pixel_um_assumed": acquisition.pixel_um_assumed,
        "bands": {b: len(acquisition.bands[b].files) for b in acquisition.bands},
    }


@dataclass(frozen=True, eq=False)
class CompareResult:
    """Output of :func:`compare_results`: the comparison, its rows (see
    :func:`skintopo.results.comparison_rows`), a summary, the baseline's pixel spacing and
    warnings about the detection limits."""

    comparison: object
    rows: list
    summary: dict
    spacing: tuple
    warnings: tuple = ()


def compare_results(baseline, follow_up, *, repeat=(), pixel_um=None, allow_scale=False, confidence=DEFAULT_DETECTION_CONFIDENCE,
                    segmentation: SegmentationOptions = SegmentationOptions(),
                    wrinkles: WrinkleOptions = WrinkleOptions(), pores: PoreOptions = PoreOptions(), progress=iter) -> CompareResult:
    """Compare two visits given as height files or result folders (see :mod:`skintopo.compare`).

    ``repeat``: repeat captures of the unchanged baseline skin (one path or several), each
    compared with the baseline as the follow-up is, give detection limits
    (:func:`skintopo.compare.detection_limits` at ``confidence``). The albedo of result
    folders is carried by the same registration, and so are their melanin and haemoglobin
    maps (compared over the overlap). ``progress`` wraps the iteration over the
    comparisons (named "follow-up", "repeat 1", ...)."""
    from skintopo.compare import compare_visits, detection_limits
    from skintopo.results import comparison_rows, load_albedo_beside, load_colour_beside, load_height_input, run_header

    before, before_colour = load_height_input(baseline, pixel_um), load_colour_beside(baseline)
    options, wrinkle_options = segmentation.as_kwargs(), wrinkles.as_kwargs()
    repeats = [repeat] if isinstance(repeat, (str, Path)) else list(repeat or ())
    others = {"follow-up": follow_up} | {f"repeat {k}": path for k, path in enumerate(repeats, start=1)}

    def compared(path, **extra):
        return compare_visits(before, load_height_input(path, pixel_um), segmentation_options=options, wrinkle_options=wrinkle_options,
                              pore_options=pores.as_kwargs(), baseline_colour=before_colour, follow_up_colour=load_colour_beside(path),
                              **extra)

    comparisons = {}
    for name in progress(list(others)):
        if name == "follow-up":  # registered allowing a scale if asked; its albedo is carried along
            comparisons[name] = compared(follow_up, allow_scale=allow_scale, baseline_albedo=load_albedo_beside(baseline),
                                         follow_up_albedo=load_albedo_beside(follow_up))
        else:
            comparisons[name] = compared(others[name])
    comparison = comparisons.pop("follow-up")
    limits = detection_limits(list(comparisons.values()), confidence=confidence) if comparisons else None
    registration = comparison.registration
    summary = run_header("compare", baseline=Path(baseline).name, follow_up=Path(follow_up).name,
                         repeats=[Path(path).name for path in repeats],
                         detection_limits=limits.as_dict() if limits else None,
                         options={"allow_scale": allow_scale, "segmentation": options, "wrinkles": wrinkle_options,
                                  "pores": pores.as_kwargs()},
                         registration={"shift_px": list(registration.shift_px), "rotation_deg": registration.rotation_deg,
                                       "scale": registration.scale, "residual_misalignment_px": registration.residual_px,
                                       "albedo_residual_misalignment_px": comparison.albedo_residual_px},
                         wrinkle_matches={str(k): v["follow_up_id"] for k, v in comparison.wrinkles.items()},
                         units="um, mm, mm3, %; change = follow-up - baseline")
    return CompareResult(comparison, comparison_rows(comparison, limits.limits if limits else None), summary, before.spacing,
                         limits.warnings if limits else ())
