"""The ``skintopo`` command line: a thin layer over the Python API.

Errors caused by the input (:class:`~skintopo.errors.SkinTopoError`) are printed as one
clear message, exit status 2, without a traceback.
"""

from __future__ import annotations

import argparse
import base64
import hashlib
import platform
import sys
import time
from pathlib import Path

import numpy as np

from skintopo import __version__
from skintopo.acquisition import BANDS, DEFAULT_SATURATION, MANIFEST_NAME, load_acquisition
from skintopo.errors import SkinTopoError
from skintopo.height import AUTO, DEFAULT_INTEGRATOR, INTEGRATORS
from skintopo.normals import DEFAULT_SHADOW_FRACTION, SOLVERS
from skintopo.outputs import check_output_folder, staged_output_folder, write_json, write_json_atomic, write_label_image
from skintopo.reconstruct import SPECULAR_FREE, band_statistics, reconstruct_band
from skintopo.segmentation import DEFAULT_CUTOFF_UM, DEFAULT_MIN_DEPTH_UM, DEFAULT_MIN_LENGTH_UM, DEFAULT_SHORT_CUTOFF_UM


def _number_type(convert, accept, requirement):
    """An argparse type: ``convert`` the text, then require ``accept(value)``."""

    def parse(text):
        try:
            value = convert(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
        if not (np.isfinite(value) and accept(value)):
            raise argparse.ArgumentTypeError(f"must be {requirement}, got {text}")
        return value

    return parse


_positive_float = _number_type(float, lambda v: v > 0, "a positive number")
_non_negative_float = _number_type(float, lambda v: v >= 0, "zero or positive")
_fraction = _number_type(float, lambda v: 0 <= v < 1, "in [0, 1)")
_size = _number_type(int, lambda v: v >= 16, "at least 16 pixels")


def _progress(iterable, *, quiet, desc, total=None):
    from tqdm import tqdm

    return tqdm(iterable, desc=desc, total=total, disable=quiet, unit="band", file=sys.stderr, leave=False)


def _say(args, message):
    if not args.quiet:
        print(message)


def _acquisition_fingerprint(acquisition):
    """SHA-256 over the manifest (or DiLiGenT lists) so a summary identifies its input
    without recording the folder's path, which may name the person."""
    digest = hashlib.sha256()
    source = acquisition.source
    for name in (MANIFEST_NAME, "filenames.txt", "light_directions.txt", "light_intensities.txt"):
        if (source / name).is_file():
            digest.update((source / name).read_bytes())
    return digest.hexdigest()


def _add_acquisition_options(parser):
    parser.add_argument("acquisition", type=Path, help="acquisition folder (acquisition.json or DiLiGenT layout)")
    parser.add_argument(
        "--pixel-um", type=_positive_float, default=None, help="pixel size in micrometres for folders without one (DiLiGenT; default 1)"
    )
    parser.add_argument(
        "--saturation", type=_fraction, default=DEFAULT_SATURATION,
        help=f"fraction of full scale at or above which a pixel is saturated and left out (default {DEFAULT_SATURATION})",
    )
    parser.add_argument("--solver", choices=SOLVERS, default="least-squares",
                        help="photometric stereo solver: least-squares (default) or robust (outlier rejection)")
    parser.add_argument(
        "--shadow-fraction", type=_fraction, default=DEFAULT_SHADOW_FRACTION,
        help="observations below this fraction of a pixel's brightest are taken as shadow and left out "
        f"(default {DEFAULT_SHADOW_FRACTION})",
    )


def _load(args, bands):
    acquisition = load_acquisition(args.acquisition, pixel_um=args.pixel_um, bands=bands, saturation=args.saturation)
    if acquisition.pixel_um_assumed:
        _say(args, f"note: {args.acquisition} has no pixel size; assuming 1 um per pixel (give --pixel-um)")
    return acquisition


def _acquisition_summary(acquisition):
    return {
        "name": acquisition.source.name,
        "sha256": _acquisition_fingerprint(acquisition),
        "layout": acquisition.layout,
        "shape": list(acquisition.shape),
        "pixel_um": acquisition.pixel_um,
        "pixel_um_assumed": acquisition.pixel_um_assumed,
        "bands": {b: len(acquisition.bands[b].files) for b in acquisition.bands},
    }


def _summary(command, args, acquisition=None, **extra):
    summary = {"skintopo_version": __version__, "command": command, "python": platform.python_version()}
    if acquisition is not None:
        summary["acquisition"] = _acquisition_summary(acquisition)
    summary.update(extra)
    return summary


def _reconstruct_all(args, acquisition, bands=None):
    return {
        band: reconstruct_band(acquisition, band, integrator=args.integrator, shadow_fraction=args.shadow_fraction, solver=args.solver)
        for band in _progress(bands or list(acquisition.bands), quiet=args.quiet, desc="reconstruct")
    }


def _write_band_outputs(folder, result):
    folder.mkdir()
    np.save(folder / "normals.npy", result.stereo.normals.astype(np.float32))
    np.save(folder / "albedo.npy", result.stereo.albedo.astype(np.float32))
    result.height.save(folder / "height.x3p")


def cmd_reconstruct(args):
    derived = args.band == SPECULAR_FREE
    bands = None if args.band == "all" else (["red", "green", "blue"] if derived else [args.band])
    check_output_folder(args.out, overwrite=args.overwrite, inputs=[args.acquisition])
    started = time.perf_counter()
    acquisition = _load(args, bands)
    seconds_load = time.perf_counter() - started
    results = _reconstruct_all(args, acquisition, [SPECULAR_FREE] if derived else None)
    summary = _summary(
        "reconstruct", args, acquisition,
        options={"integrator": args.integrator, "saturation": args.saturation, "shadow_fraction": args.shadow_fraction, "solver": args.solver},
        units={"height": "um", "normals": "unit vector, camera frame (x right, y up, z toward camera)"},
        seconds_load=seconds_load,
        bands={band: band_statistics(result) for band, result in results.items()},
    )
    with staged_output_folder(args.out, overwrite=args.overwrite, inputs=[args.acquisition]) as staging:
        for band, result in results.items():
            _write_band_outputs(staging / band, result)
        summary["seconds_total"] = time.perf_counter() - started
        write_json(staging / "summary.json", summary)

    if not args.quiet:
        print(f"{'band':<13} {'valid %':>8} {'lights':>6} {'residual':>9} {'range um':>9}")
        for band, stats in summary["bands"].items():
            print(
                f"{band:<13} {100 * stats['valid_fraction']:8.1f} {stats['median_lights_used']:6.0f} "
                f"{stats['mean_residual']:9.4f} {stats['height_range_um']:9.2f}"
            )
        print(f"wrote {Path(args.out).resolve()}")
    return 0


def _segmentation_options(args):
    return {
        "cutoff_um": args.cutoff_um,
        "short_cutoff_um": args.short_cutoff_um,
        "min_depth_um": args.min_depth_um,
        "min_length_um": args.min_length_um,
    }


def cmd_correct(args):
    from skintopo.correction import REQUIRED_BANDS, spectral_correction

    check_output_folder(args.out, overwrite=args.overwrite, inputs=[args.acquisition])
    started = time.perf_counter()
    acquisition = _load(args, None)
    missing = [b for b in REQUIRED_BANDS if b not in acquisition.bands]
    if missing:
        raise SkinTopoError(
            f"{args.acquisition}: the spectral correction needs red, green and blue images; missing {missing} "
            f"(the acquisition has {sorted(acquisition.bands)})"
        )
    results = _reconstruct_all(args, acquisition)
    correction = spectral_correction(
        {band: results[band].stereo.normals for band in REQUIRED_BANDS}, acquisition.pixel_um,
        method=args.method, integrator=args.integrator, mask=acquisition.mask, **_segmentation_options(args),
    )
    summary = _summary(
        "correct", args, acquisition,
        options={
            "integrator": args.integrator, "saturation": args.saturation, "shadow_fraction": args.shadow_fraction,
            "method": args.method, "segmentation": correction.segmentation.parameters,
        },
        wrinkles_found=correction.segmentation.count,
        wrinkle_area_fraction=float(correction.segmentation.mask.mean()),
        bands={band: band_statistics(result) for band, result in results.items()},
    )
    with staged_output_folder(args.out, overwrite=args.overwrite, inputs=[args.acquisition]) as staging:
        correction.height.save(staging / "height.x3p")
        write_label_image(staging / "wrinkles.png", correction.segmentation.labels)
        for band, result in results.items():
            _write_band_outputs(staging / band, result)
        summary["seconds_total"] = time.perf_counter() - started
        write_json(staging / "summary.json", summary)
    _say(args, f"{correction.segmentation.count} wrinkle(s) segmented; corrected height ({args.method}) in {Path(args.out).resolve() / 'height.x3p'}")
    return 0


def cmd_evaluate(args):
    from skintopo.evaluation import evaluate_height
    from skintopo.heightmap import HeightMap

    output = Path(args.out)
    if output.exists() and not args.overwrite:
        raise SkinTopoError(f"{output}: exists; use --overwrite to replace it")
    result = HeightMap.load(args.result, pixel_um=args.pixel_um)
    reference = HeightMap.load(args.reference, pixel_um=args.pixel_um)
    labels = None
    if args.wrinkles is not None:
        from skintopo.acquisition import read_image

        labels = read_image(args.wrinkles)
        if labels.shape != reference.shape:
            raise SkinTopoError(f"{args.wrinkles}: wrinkle image size {labels.shape} differs from the reference {reference.shape}")
    report = evaluate_height(result, reference, wrinkle_labels=labels, register=not args.no_register)
    report = {"result": Path(args.result).name, "reference": Path(args.reference).name, "units": "um, degrees", **report}
    write_json_atomic(output, report)
    if not args.quiet:
        for key, value in report.items():
            if isinstance(value, float):
                print(f"{key:<34} {value:12.4f}")
            elif isinstance(value, list) and value and isinstance(value[0], float):
                print(f"{key:<34} " + " ".join(f"{v:.3f}" for v in value))
        print(f"wrote {output.resolve()}")
    return 0


def cmd_paper_tables(args):
    from skintopo.paper import paper_tables

    check_output_folder(args.out, overwrite=args.overwrite)
    with staged_output_folder(args.out, overwrite=args.overwrite) as staging:
        _, text = paper_tables(staging, size_px=args.size, pixel_um=args.pixel_um,
                               progress=None if args.quiet else lambda s: print(f"subject {s.number} done", file=sys.stderr))
    _say(args, text + f"\n\nwrote {Path(args.out).resolve()}")
    return 0


def cmd_demo(args):
    from skintopo.correction import spectral_correction
    from skintopo.evaluation import evaluate_height
    from skintopo.segmentation import segmentation_quality
    from skintopo.synth import default_settings, make_surface, preset_spec, simulate_acquisition, write_synthetic_acquisition

    check_output_folder(args.out, overwrite=args.overwrite)
    started = time.perf_counter()
    with staged_output_folder(args.out, overwrite=args.overwrite) as staging:
        spec = preset_spec(args.preset, size_px=args.size, pixel_um=20.0)
        surface = make_surface(spec, seed=args.seed)
        settings = default_settings(skin=args.skin)
        bands, info = simulate_acquisition(surface, settings, seed=args.seed)
        write_synthetic_acquisition(staging / "acquisition", surface, bands, settings=settings, seed=args.seed, info=info)
        _say(args, f"simulated {args.preset}, {args.skin} skin, {args.size}x{args.size} px at 20 um ({time.perf_counter() - started:.1f} s)")
        args.acquisition, args.pixel_um, args.saturation = staging / "acquisition", None, DEFAULT_SATURATION
        args.shadow_fraction, args.integrator, args.solver = DEFAULT_SHADOW_FRACTION, DEFAULT_INTEGRATOR, "least-squares"
        acquisition = _load(args, None)
        results = _reconstruct_all(args, acquisition)
        correction = spectral_correction({b: results[b].stereo.normals for b in ("red", "green", "blue")}, acquisition.pixel_um)
        heights = {band: result.height for band, result in results.items()} | {"algorithm": correction.height}
        evaluations = {
            name: evaluate_height(height, surface.height, wrinkle_labels=surface.wrinkle_labels, register=False)
            for name, height in heights.items()
        }
        result_folder = staging / "result"
        result_folder.mkdir()
        for band, result in results.items():
            _write_band_outputs(result_folder / band, result)
        args.region, args.level, args.p, args.q = [], 1, 10.0, 80.0
        args.cutoff_um, args.short_cutoff_um, args.min_depth_um, args.min_length_um = (
            DEFAULT_CUTOFF_UM, DEFAULT_SHORT_CUTOFF_UM, DEFAULT_MIN_DEPTH_UM, DEFAULT_MIN_LENGTH_UM)
        source = {"input": "simulated", "kind": "acquisition", "preset": args.preset, "skin": args.skin, "seed": args.seed,
                  "height": "spectral correction (paper)"}
        from skintopo.report import cross_section_pngs

        figures = cross_section_pngs(heights, surface.height, surface.wrinkle_labels)
        _write_measurements(result_folder, args, correction.height, results["red"].stereo.albedo, source,
                            title=f"skintopo demo: simulated {args.preset}, {args.skin} skin", evaluations=evaluations, cross_sections=figures)
        summary = _summary(
            "demo", args, acquisition, preset=args.preset, skin=args.skin, seed=args.seed,
            segmentation=segmentation_quality(correction.segmentation.mask, surface.wrinkle_labels > 0)
            | {"wrinkles_found": correction.segmentation.count, "wrinkles_true": len(spec.wrinkles)},
            evaluation=evaluations,
        )
        summary["seconds_total"] = time.perf_counter() - started
        write_json(staging / "summary.json", summary)
    if not args.quiet:
        print(f"\n{'height map':<10} {'RMS error um':>12} {'in wrinkles':>12} {'L2 normal':>10} {'depth error %':>14}")
        for name, e in evaluations.items():
            print(
                f"{name:<10} {e['rms_height_error_um']:12.2f} {e['rms_height_error_in_wrinkles_um']:12.2f} "
                f"{e['l2_normal_error']:10.4f} {100 * np.mean(e['wrinkle_depth_error_relative']):14.1f}"
            )
        seg = summary["segmentation"]
        print(f"\nwrinkles segmented: {seg['wrinkles_found']} of {seg['wrinkles_true']} (IoU {seg['iou']:.2f} with the true half-depth regions)")
        print(f"report: {(Path(args.out) / 'result' / 'report.html').resolve()}")
        print(f"wrote {Path(args.out).resolve()} in {summary['seconds_total']:.1f} s")
    return 0


def _parse_region(text):
    try:
        name, box = text.split("=", 1)
        x0, y0, x1, y1 = (float(v) for v in box.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"region {text!r} must look like NAME=x0,y0,x1,y1 (micrometres)") from None
    if not (x1 > x0 and y1 > y0):
        raise argparse.ArgumentTypeError(f"region {text!r}: need x1 > x0 and y1 > y0")
    return name, (x0, y0, x1, y1)


def _crop(height, box, name):
    from skintopo.heightmap import HeightMap

    dy, dx = height.spacing
    x0, y0, x1, y1 = box
    c0, c1 = int(round(x0 / dx)), int(round(x1 / dx)) + 1
    r0, r1 = int(round(y0 / dy)), int(round(y1 / dy)) + 1
    rows, columns = height.shape
    if c0 < 0 or r0 < 0 or c1 > columns or r1 > rows:
        raise SkinTopoError(f"region {name!r} ({box} um) lies outside the map ({(columns - 1) * dx:g} x {(rows - 1) * dy:g} um)")
    return HeightMap(height.z[r0:r1, c0:c1], height.spacing, height.mask[r0:r1, c0:c1])


def _measured_height(args):
    """The height map to measure and its albedo: a height file as it is, or an acquisition
    run through the paper's method (corrected height when red, green and blue are present,
    else white or the only band)."""
    path = Path(args.input)
    if path.is_file():
        return _load_height_input(path, args.pixel_um), None, {"input": path.name, "kind": "height map"}
    from skintopo.correction import REQUIRED_BANDS, spectral_correction

    args.acquisition = path
    acquisition = _load(args, None)
    results = _reconstruct_all(args, acquisition)
    albedo_band = "red" if "red" in results else next(iter(results))
    albedo = results[albedo_band].stereo.albedo
    source = {"input": path.name, "kind": "acquisition", "acquisition": _acquisition_summary(acquisition)}
    if all(b in results for b in REQUIRED_BANDS):
        correction = spectral_correction({b: results[b].stereo.normals for b in REQUIRED_BANDS}, acquisition.pixel_um,
                                         mask=acquisition.mask, integrator=args.integrator, **_segmentation_options(args))
        return correction.height, albedo, source | {"height": "spectral correction (paper)"}
    band = "white" if "white" in results else next(iter(results))
    return results[band].height, albedo, source | {"height": f"{band} band"}


def _write_measurements(staging, args, height, albedo, source, *, title, evaluations=None, cross_sections=()):
    """Texture, fractal and wrinkle measures of ``height`` into ``staging``, with the report."""
    import csv

    from skintopo.report import build_report
    from skintopo.segmentation import segment_wrinkles
    from skintopo.texture import finite_or_none, measure_texture
    from skintopo.wrinkles import measure_wrinkles

    regions = {"field": height} | {name: _crop(height, box, name) for name, box in args.region}
    fractal_results = []
    measured = {}
    for name, region in regions.items():
        measured[name] = measure_texture(region, level_order=args.level, p=args.p, q=args.q,
                                         fractal_results=fractal_results if name == "field" else None)
    rows = [
        {"region": name, "name": p.name, "value": finite_or_none(p.value), "unit": p.unit, "reference": p.reference}
        for name, parameters in measured.items()
        for p in parameters
    ]
    segmentation = segment_wrinkles(height, **_segmentation_options(args))
    wrinkles = measure_wrinkles(height, segmentation)
    settings = {"source": source, "level_order": args.level, "p": args.p, "q": args.q, "segmentation": segmentation.parameters,
                "solver": args.solver, "integrator": args.integrator, "skintopo_version": __version__}
    summary = _summary("measure", args, source=source, options=settings, units="um unless stated",
                       wrinkle_totals=wrinkles.totals, evaluation=evaluations)
    write_json(staging / "parameters.json", {"summary": summary, "parameters": rows})
    with open(staging / "parameters.csv", "w", newline="", encoding="utf-8") as stream:
        writer = csv.DictWriter(stream, fieldnames=["region", "name", "value", "unit", "reference"])
        writer.writeheader()
        writer.writerows(rows)
    _write_wrinkle_files(staging, wrinkles, segmentation)
    height.save(staging / "height.x3p")
    if albedo is not None:  # kept so that `compare` can carry it to the baseline grid
        np.save(staging / "albedo.npy", np.asarray(albedo, dtype=np.float32))
    write_json(staging / "summary.json", summary)
    report = build_report(title=title, height=height, albedo=albedo, parameters=measured["field"], fractal_results=fractal_results,
                          wrinkles=wrinkles, evaluations=evaluations, settings=settings, cross_sections=cross_sections)
    (staging / "report.html").write_text(report, encoding="utf-8")
    return rows, wrinkles


def cmd_measure(args):
    check_output_folder(args.out, overwrite=args.overwrite, inputs=[args.input])
    started = time.perf_counter()
    height, albedo, source = _measured_height(args)
    with staged_output_folder(args.out, overwrite=args.overwrite, inputs=[args.input]) as staging:
        rows, wrinkles = _write_measurements(staging, args, height, albedo, source, title=f"skintopo: {Path(args.input).name}")
    if not args.quiet:
        print(f"{'region':<10} {'parameter':<24} {'value':>14} unit")
        for row in rows:
            value = "NaN" if row["value"] is None else f"{row['value']:14.5g}"
            print(f"{row['region']:<10} {row['name']:<24} {value:>14} {row['unit']}")
        print(f"{wrinkles.totals['count']} wrinkle(s); report: {(Path(args.out) / 'report.html').resolve()}")
        print(f"wrote {Path(args.out).resolve()} in {time.perf_counter() - started:.1f} s")
    return 0


def cmd_synth(args):
    from skintopo.synth import PRESETS, Effects, default_settings, make_surface, preset_spec, simulate_acquisition, write_synthetic_acquisition

    if args.preset not in PRESETS:
        raise SkinTopoError(f"unknown preset {args.preset!r}; choose from {list(PRESETS)}")
    check_output_folder(args.out, overwrite=args.overwrite)
    spec = preset_spec(args.preset, size_px=args.size, pixel_um=args.pixel_um)
    effects = Effects(
        shadows=not args.no_shadows,
        interreflection=not args.no_interreflection,
        bounces=1 if args.single_bounce else None,
        specular=not args.no_specular,
        translucency=not args.no_translucency,
        albedo_variation=not args.no_albedo_variation,
    )
    settings = default_settings(skin=args.skin, effects=effects, noise=args.noise, saturate=args.saturate)
    started = time.perf_counter()
    surface = make_surface(spec, seed=args.seed)
    bands, info = simulate_acquisition(surface, settings, seed=args.seed)
    write_synthetic_acquisition(args.out, surface, bands, settings=settings, seed=args.seed, info=info, overwrite=args.overwrite)
    _say(
        args,
        f"wrote {Path(args.out).resolve()}: preset {args.preset}, {args.skin} skin, {spec.size_px[1]}x{spec.size_px[0]} px "
        f"at {spec.pixel_um:g} um, {len(spec.wrinkles)} wrinkle(s), {time.perf_counter() - started:.1f} s",
    )
    return 0


def _load_albedo_beside(path):
    """The albedo.npy a result folder holds (the output of measure), or None."""
    path = Path(path)
    if path.is_dir() and (path / "albedo.npy").is_file():
        try:
            return np.load(path / "albedo.npy")
        except (OSError, ValueError) as error:
            raise SkinTopoError(f"{path / 'albedo.npy'}: not a readable NumPy array ({error})") from None
    return None


def _load_height_input(path, pixel_um):
    """A height map file, or a result folder holding height.x3p."""
    from skintopo.heightmap import HeightMap

    path = Path(path)
    if path.is_dir():
        if not (path / "height.x3p").is_file():
            raise SkinTopoError(f"{path}: a folder given as a height map must hold height.x3p (the output of correct or measure)")
        path = path / "height.x3p"
    return HeightMap.load(path, pixel_um=pixel_um)


def _write_wrinkle_files(folder, measures, segmentation):
    """wrinkles.json (measures, totals, segmentation settings), wrinkles.csv and the id image."""
    import csv
    from dataclasses import asdict, fields

    from skintopo.wrinkles import Wrinkle

    data = measures.as_dict() | {"segmentation": segmentation.parameters, "units": "lengths in mm, depths in um, volume mm3"}
    write_json(folder / "wrinkles.json", data)
    with open(folder / "wrinkles.csv", "w", newline="", encoding="utf-8") as stream:
        writer = csv.DictWriter(stream, fieldnames=[f.name for f in fields(Wrinkle)])
        writer.writeheader()
        writer.writerows(asdict(w) for w in measures.wrinkles)
    write_label_image(folder / "wrinkles.png", measures.labels)


def cmd_wrinkles(args):
    from skintopo.report import wrinkle_overlay_png
    from skintopo.segmentation import segment_wrinkles
    from skintopo.wrinkles import measure_wrinkles

    check_output_folder(args.out, overwrite=args.overwrite, inputs=[args.input])
    height = _load_height_input(args.input, args.pixel_um)
    segmentation = segment_wrinkles(height, **_segmentation_options(args))
    measures = measure_wrinkles(height, segmentation)
    with staged_output_folder(args.out, overwrite=args.overwrite, inputs=[args.input]) as staging:
        _write_wrinkle_files(staging, measures, segmentation)
        (staging / "wrinkles_overlay.png").write_bytes(base64.b64decode(wrinkle_overlay_png(height, measures)))
    if not args.quiet:
        if not measures.wrinkles:
            print("no wrinkles found (deeper than the minimum depth and longer than the minimum length)")
        for w in measures.wrinkles:
            print(f"wrinkle {w.id}: length {w.length_mm:.2f} mm, max depth {w.max_depth_um:.1f} um, mean depth {w.mean_depth_um:.1f} um, "
                  f"width {w.mean_width_mm:.3f} mm, volume {w.volume_mm3:.4f} mm3, severity {w.severity:.2f}")
        t = measures.totals
        print(f"total: {t['count']} wrinkle(s), {t['total_length_mm']:.2f} mm, area fraction {100 * t['area_fraction']:.1f}%")
        print(f"wrote {Path(args.out).resolve()}")
    return 0


def cmd_compare(args):
    import csv

    from skintopo.compare import compare_visits, detection_limits
    from skintopo.heightmap import HeightMap
    from skintopo.texture import finite_or_none

    inputs = [args.baseline, args.follow_up] + ([args.repeat] if args.repeat else [])
    check_output_folder(args.out, overwrite=args.overwrite, inputs=inputs)
    baseline = _load_height_input(args.baseline, args.pixel_um)
    follow_up = _load_height_input(args.follow_up, args.pixel_um)
    options = _segmentation_options(args)
    albedos = _load_albedo_beside(args.baseline), _load_albedo_beside(args.follow_up)
    comparison = compare_visits(baseline, follow_up, allow_scale=args.allow_scale, segmentation_options=options,
                                baseline_albedo=albedos[0], follow_up_albedo=albedos[1])
    limits = detection_limits(compare_visits(baseline, _load_height_input(args.repeat, args.pixel_um), segmentation_options=options)) if args.repeat else {}
    rows = []
    for name, record in comparison.texture.items():
        rows.append({"parameter": name, **record, "detection_limit": limits.get(name)})
    for name, record in comparison.totals.items():
        rows.append({"parameter": f"wrinkles.{name}", **record, "detection_limit": None})
    for wrinkle_id, record in comparison.wrinkles.items():
        for name, change in record.items():
            if isinstance(change, dict):
                rows.append({"parameter": f"wrinkle{wrinkle_id}.{name}", **change, "detection_limit": limits.get(f"wrinkle{wrinkle_id}.{name}")})
    for row in rows:
        limit = row["detection_limit"]
        row["detectable"] = None if limit is None else bool(abs(row["change"]) > limit)
        for key in ("baseline", "follow_up", "change", "change_percent", "detection_limit"):
            row[key] = finite_or_none(None if row[key] is None else float(row[key]))
    registration = comparison.registration
    summary = _summary("compare", args, baseline=Path(args.baseline).name, follow_up=Path(args.follow_up).name,
                       repeat=Path(args.repeat).name if args.repeat else None,
                       registration={"shift_px": list(registration.shift_px), "rotation_deg": registration.rotation_deg,
                                     "scale": registration.scale, "residual_misalignment_px": registration.residual_px,
                                     "albedo_residual_misalignment_px": comparison.albedo_residual_px},
                       wrinkle_matches={str(k): v["follow_up_id"] for k, v in comparison.wrinkles.items()},
                       units="um, mm, mm3, %; change = follow-up - baseline")
    with staged_output_folder(args.out, overwrite=args.overwrite, inputs=inputs) as staging:
        HeightMap(comparison.difference, baseline.spacing).save(staging / "difference.x3p")
        if comparison.aligned_albedo is not None:
            np.save(staging / "follow_up_albedo_registered.npy", comparison.aligned_albedo.astype(np.float32))
        write_json(staging / "changes.json", {"summary": summary, "changes": rows})
        with open(staging / "changes.csv", "w", newline="", encoding="utf-8") as stream:
            writer = csv.DictWriter(stream, fieldnames=["parameter", "baseline", "follow_up", "change", "change_percent", "detection_limit", "detectable"])
            writer.writeheader()
            writer.writerows(rows)
    if not args.quiet:
        print(f"registration: shift ({registration.shift_px[0]:+.2f}, {registration.shift_px[1]:+.2f}) px, rotation {registration.rotation_deg:+.3f} deg, "
              f"residual misalignment {registration.residual_px:.3f} px")
        if comparison.albedo_residual_px is not None:
            print(f"albedo carried by the same transform: residual misalignment {comparison.albedo_residual_px:.3f} px")
        if not comparison.wrinkles:
            print("no wrinkles in the baseline: texture changes only")
        for wrinkle_id, record in comparison.wrinkles.items():
            if record["follow_up_id"] is None:
                print(f"wrinkle {wrinkle_id}: not found in the follow-up")
            else:
                depth = record["max_depth_um"]
                print(f"wrinkle {wrinkle_id} -> {record['follow_up_id']}: max depth {depth['baseline']:.1f} -> {depth['follow_up']:.1f} um ({depth['change_percent']:+.1f}%)")
        print(f"wrote {Path(args.out).resolve()}")
    return 0


def cmd_batch(args):
    from tqdm import tqdm

    from skintopo.batch import read_study, run_study

    total = len(read_study(args.study))  # validates before anything runs
    bar = tqdm(total=total, desc="batch", unit="item", file=sys.stderr, disable=args.quiet)

    def progress(item, status):
        bar.update(1)
        bar.set_postfix_str(f"{item.subject} {item.region} {item.visit}: {status}")

    counts, tables = run_study(args.study, args.out, workers=args.workers, scheduler=args.scheduler, progress=progress)
    bar.close()
    _say(args, f"computed {counts['computed']}, skipped (already done) {counts['skipped']}, failed {counts['failed']}; "
               f"tables in {Path(args.out).resolve()} (results.csv, results.parquet, changes.csv, failures.csv, summary.html)")
    return 0


def cmd_calibrate_lights(args):
    from skintopo.calibration import calibrate_lights

    output = Path(args.out)
    if output.exists() and not args.overwrite:
        raise SkinTopoError(f"{output}: exists; use --overwrite to replace it")
    result = calibrate_lights(args.images, mask=args.mask, method="matte" if args.matte else "chrome")
    result["note"] = "copy each 'light' (and 'intensity') into the matching image entries of acquisition.json"
    write_json_atomic(output, result)
    if not args.quiet:
        for entry in result["lights"]:
            x, y, z = entry["light"]
            print(f"{entry['file']:<30} light ({x:+.4f}, {y:+.4f}, {z:+.4f})" + (f"  intensity {entry['intensity']:.3f}" if "intensity" in entry else ""))
        print(f"wrote {output.resolve()}")
    return 0


def _add_output_switches(parser):
    """--overwrite and -q/--quiet, which every command that writes an output folder takes."""
    parser.add_argument("--overwrite", action="store_true", help="replace a non-empty output folder")
    parser.add_argument("-q", "--quiet", action="store_true", help="no progress bar, tables or messages (errors still go to stderr)")


def _add_segmentation_options(parser):
    parser.add_argument("--cutoff-um", type=_positive_float, default=DEFAULT_CUTOFF_UM,
                        help=f"lambda_c of the segmentation band-pass (default {DEFAULT_CUTOFF_UM:g})")
    parser.add_argument("--short-cutoff-um", type=_positive_float, default=DEFAULT_SHORT_CUTOFF_UM,
                        help=f"lambda_s (default {DEFAULT_SHORT_CUTOFF_UM:g})")
    parser.add_argument("--min-depth-um", type=_positive_float, default=DEFAULT_MIN_DEPTH_UM,
                        help=f"shallowest wrinkle (default {DEFAULT_MIN_DEPTH_UM:g})")
    parser.add_argument("--min-length-um", type=_positive_float, default=DEFAULT_MIN_LENGTH_UM,
                        help=f"shortest wrinkle (default {DEFAULT_MIN_LENGTH_UM:g})")


def build_parser():
    parser = argparse.ArgumentParser(prog="skintopo", description="3D skin topography by multispectral photometric stereo.")
    parser.add_argument("--version", action="version", version=f"skintopo {__version__}")
    commands = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    reconstruct = commands.add_parser("reconstruct", help="normals, albedo and height map for each band of an acquisition")
    _add_acquisition_options(reconstruct)
    reconstruct.add_argument("-o", "--out", type=Path, required=True, help="output folder (created; must be empty or new)")
    reconstruct.add_argument("--band", choices=[*BANDS, SPECULAR_FREE, "all"], default="all",
                             help="band to process (default all present); specular-free = SUV projection of red, green, blue")
    reconstruct.add_argument("--integrator", choices=[AUTO, *sorted(INTEGRATORS)], default=DEFAULT_INTEGRATOR,
        help="normal integration (default auto: dct-poisson on a fully valid field, else least-squares over the valid pixels)")
    _add_output_switches(reconstruct)
    reconstruct.set_defaults(handler=cmd_reconstruct)

    correct = commands.add_parser("correct", help="the paper's method: per-band reconstruction, wrinkle segmentation, spectral correction")
    _add_acquisition_options(correct)
    correct.add_argument("-o", "--out", type=Path, required=True, help="output folder")
    correct.add_argument("--method", choices=["paper", "feathered"], default="paper", help="correction variant (default paper)")
    correct.add_argument("--integrator", choices=[AUTO, *sorted(INTEGRATORS)], default=DEFAULT_INTEGRATOR)
    _add_segmentation_options(correct)
    _add_output_switches(correct)
    correct.set_defaults(handler=cmd_correct)

    evaluate = commands.add_parser("evaluate", help="accuracy of a height map against a reference (ground truth, replica)")
    evaluate.add_argument("result", type=Path, help="height map (.x3p or .npy)")
    evaluate.add_argument("reference", type=Path, help="reference height map (.x3p or .npy)")
    evaluate.add_argument("-o", "--out", type=Path, default=Path("evaluation.json"), help="JSON file to write (default evaluation.json)")
    evaluate.add_argument("--wrinkles", type=Path, help="wrinkle label image (ground_truth/wrinkles.png) for in-wrinkle errors and depths")
    evaluate.add_argument("--pixel-um", type=_positive_float, help="pixel size for .npy maps")
    evaluate.add_argument("--no-register", action="store_true", help="do not search for a sub-pixel translation")
    _add_output_switches(evaluate)
    evaluate.set_defaults(handler=cmd_evaluate)

    demo = commands.add_parser("demo", help="simulate a forehead capture, reconstruct and correct it, compare with the truth")
    demo.add_argument("-o", "--out", type=Path, default=Path("demo-out"), help="output folder (default demo-out)")
    demo.add_argument("--preset", default="forehead-moderate", choices=["forehead-low", "forehead-moderate", "forehead-high"])
    demo.add_argument("--skin", choices=["light", "dark"], default="light")
    demo.add_argument("--size", type=_size, default=256, help="field size in pixels at 20 um (default 256)")
    demo.add_argument("--seed", type=int, default=0)
    _add_output_switches(demo)
    demo.set_defaults(handler=cmd_demo)

    measure = commands.add_parser("measure", help="surface texture (ISO 25178-2), volume and fractal parameters of a height map or acquisition")
    measure.add_argument("input", type=Path, help="height map (.x3p, .npy) or acquisition folder")
    measure.add_argument("-o", "--out", type=Path, required=True, help="output folder (parameters.json, parameters.csv)")
    measure.add_argument("--pixel-um", type=_positive_float, help="pixel size for .npy maps and DiLiGenT folders")
    measure.add_argument("--level", type=int, default=1, help="order of the least-squares form removed first (default 1: plane)")
    measure.add_argument("--p", type=float, default=10.0, help="material ratio p of Vmp/Vmc/Vvc (default 10 %%)")
    measure.add_argument("--q", type=float, default=80.0, help="material ratio q of Vmc/Vvc/Vvv (default 80 %%)")
    measure.add_argument("--region", type=_parse_region, action="append", default=[], help="extra region NAME=x0,y0,x1,y1 in um (repeatable)")
    _add_output_switches(measure)
    measure.add_argument("--solver", choices=SOLVERS, default="least-squares", help="photometric stereo solver (acquisitions)")
    measure.add_argument("--integrator", choices=[AUTO, *sorted(INTEGRATORS)], default=DEFAULT_INTEGRATOR, help="normal integration (acquisitions)")
    _add_segmentation_options(measure)
    measure.set_defaults(handler=cmd_measure, saturation=DEFAULT_SATURATION, shadow_fraction=DEFAULT_SHADOW_FRACTION)

    wrinkles = commands.add_parser("wrinkles", help="per-wrinkle measures: length, depth, width, volume, severity")
    wrinkles.add_argument("input", type=Path, help="height map (.x3p, .npy) or an output folder holding height.x3p")
    wrinkles.add_argument("-o", "--out", type=Path, required=True, help="output folder (wrinkles.csv, wrinkles.json, wrinkles_overlay.png)")
    wrinkles.add_argument("--pixel-um", type=_positive_float, help="pixel size for .npy maps")
    _add_segmentation_options(wrinkles)
    _add_output_switches(wrinkles)
    wrinkles.set_defaults(handler=cmd_wrinkles)

    compare = commands.add_parser("compare", help="before/after: register two visits, difference map, change of every parameter")
    compare.add_argument("baseline", type=Path, help="baseline height map (.x3p, .npy) or result folder with height.x3p")
    compare.add_argument("follow_up", type=Path, metavar="after", help="follow-up height map or result folder")
    compare.add_argument("-o", "--out", type=Path, required=True, help="output folder (difference.x3p, changes.csv, changes.json)")
    compare.add_argument("--repeat", type=Path, help="a second baseline capture of the unchanged skin: gives detection limits")
    compare.add_argument("--allow-scale", action="store_true", help="also fit a small scale change")
    compare.add_argument("--pixel-um", type=_positive_float, help="pixel size for .npy maps")
    _add_segmentation_options(compare)
    _add_output_switches(compare)
    compare.set_defaults(handler=cmd_compare)

    batch = commands.add_parser("batch", help="a whole study: measure every acquisition, compare follow-ups, one table")
    batch.add_argument("study", type=Path, help="study CSV: subject, visit, region, acquisition[, baseline]")
    batch.add_argument("-o", "--out", type=Path, required=True, help="study output folder (reused: finished items are skipped)")
    batch.add_argument("--workers", type=int, default=2, help="local worker processes (default 2)")
    batch.add_argument("--scheduler", help="address of a running Dask scheduler (tcp://host:8786) to run on instead")
    batch.add_argument("-q", "--quiet", action="store_true")
    batch.set_defaults(handler=cmd_batch)

    calibrate = commands.add_parser("calibrate", help="device calibration")
    calibrate_commands = calibrate.add_subparsers(dest="what", required=True, metavar="WHAT")
    lights = calibrate_commands.add_parser("lights", help="light directions from a chrome (or matte white) sphere")
    lights.add_argument("images", type=Path, nargs="+", help="one sphere image per light, in light order")
    lights.add_argument("--mask", type=Path, help="sphere mask (default: found automatically)")
    lights.add_argument("--matte", action="store_true", help="a matte white sphere: directions and relative intensities by least squares")
    lights.add_argument("-o", "--out", type=Path, required=True, help="lights.json to write")
    _add_output_switches(lights)
    lights.set_defaults(handler=cmd_calibrate_lights)

    tables = commands.add_parser("paper-tables", help="the paper's Tables 1-2 and Figures 3 and 5 on four simulated subjects")
    tables.add_argument("-o", "--out", type=Path, required=True)
    tables.add_argument("--size", type=_size, default=256, help="field size in pixels (default 256)")
    tables.add_argument("--pixel-um", type=_positive_float, default=20.0)
    _add_output_switches(tables)
    tables.set_defaults(handler=cmd_paper_tables)

    synth = commands.add_parser("synth", help="simulate a skin acquisition with exact ground truth")
    synth.add_argument("-o", "--out", type=Path, required=True, help="output acquisition folder")
    synth.add_argument("--preset", default="forehead-moderate", help="flat-microrelief, forehead-low, forehead-moderate (default), forehead-high")
    synth.add_argument("--skin", choices=["light", "dark"], default="light", help="albedo preset (default light)")
    synth.add_argument("--size", type=_size, default=256, help="field size in pixels (square, default 256)")
    synth.add_argument("--pixel-um", type=_positive_float, default=20.0, help="pixel size in micrometres (default 20)")
    synth.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    synth.add_argument("--noise", type=_non_negative_float, default=1.0, help="sensor noise level, 0 = none, 1 = default camera")
    synth.add_argument("--saturate", action="store_true", help="expose so that specular highlights clip")
    synth.add_argument("--no-interreflection", action="store_true")
    synth.add_argument("--single-bounce", action="store_true", help="one interreflection bounce instead of converged radiosity")
    synth.add_argument("--no-specular", action="store_true")
    synth.add_argument("--no-translucency", action="store_true")
    synth.add_argument("--no-shadows", action="store_true")
    synth.add_argument("--no-albedo-variation", action="store_true")
    _add_output_switches(synth)
    synth.set_defaults(handler=cmd_synth)
    return parser


def main(argv=None):
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return args.handler(args)
    except SkinTopoError as exc:
        print(f"skintopo {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"skintopo {args.command}: interrupted; no output written", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
