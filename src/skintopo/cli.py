"""The ``skintopo`` command line: a thin layer over the Python API.

Errors caused by the input (:class:`~skintopo.errors.SkinTopoError`) are printed as one
clear message, exit status 2, without a traceback.
"""

from __future__ import annotations

import argparse
import base64
import sys
import time
from dataclasses import asdict
from pathlib import Path

import numpy as np

from skintopo import __version__
from skintopo.acquisition import BANDS, DEFAULT_SATURATION, load_acquisition
from skintopo.batch import DEFAULT_SCHEDULER_TIMEOUT_S
from skintopo.correction import DEFAULT_METHOD as DEFAULT_CORRECTION_METHOD
from skintopo.correction import METHODS as CORRECTION_METHODS
from skintopo.errors import SkinTopoError
from skintopo.height import AUTO, DEFAULT_INTEGRATOR, INTEGRATORS
from skintopo.normals import DEFAULT_SHADOW_FRACTION, DEFAULT_SOLVER, SOLVERS
from skintopo.outputs import check_output_file, check_output_folder, staged_output_folder, write_json, write_json_atomic
from skintopo.pipeline import (
    HEIGHT_METHODS,
    HeightOptions,
    MeasureOptions,
    ReconstructionOptions,
    SegmentationOptions,
    TextureOptions,
    acquisition_summary,
    reconstruct_bands,
)
from skintopo.reconstruct import DEFAULT_HIGHLIGHTS, HIGHLIGHT_MODES, SPECULAR_FREE, band_statistics
from skintopo.results import load_albedo_beside, load_height_input, run_header
from skintopo.segmentation import DEFAULT_CUTOFF_UM, DEFAULT_MIN_DEPTH_UM, DEFAULT_MIN_LENGTH_UM, DEFAULT_SHORT_CUTOFF_UM
from skintopo.texture import DEFAULT_P, DEFAULT_Q


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
_positive_int = _number_type(int, lambda v: v >= 1, "1 or more")
_non_negative_int = _number_type(int, lambda v: v >= 0, "0 or more")


def _progress(iterable, *, quiet, desc, total=None):
    from tqdm import tqdm

    return tqdm(iterable, desc=desc, total=total, disable=quiet, unit="band", file=sys.stderr, leave=False)


def _say(args, message):
    if not args.quiet:
        print(message)


def _add_acquisition_options(parser):
    parser.add_argument("acquisition", type=Path, help="acquisition folder (acquisition.json or DiLiGenT layout)")
    _add_reconstruction_options(parser)


def _add_reconstruction_options(parser):
    """Options of the acquisition -> normals -> height stages (``ReconstructionOptions``)."""
    parser.add_argument(
        "--pixel-um", type=_positive_float, default=None, help="pixel size in micrometres for inputs without one (DiLiGenT folders, .npy maps; default 1)"
    )
    parser.add_argument(
        "--saturation", type=_fraction, default=DEFAULT_SATURATION,
        help=f"fraction of full scale at or above which a pixel is saturated and left out (default {DEFAULT_SATURATION})",
    )
    parser.add_argument("--solver", choices=SOLVERS, default=DEFAULT_SOLVER,
                        help=f"photometric stereo solver: least-squares or robust (outlier rejection); default {DEFAULT_SOLVER}")
    parser.add_argument(
        "--shadow-fraction", type=_fraction, default=DEFAULT_SHADOW_FRACTION,
        help="observations below this fraction of the pixel's albedo (from a first fit) are taken as shadow and left out "
        f"(default {DEFAULT_SHADOW_FRACTION})",
    )
    parser.add_argument("--highlights", choices=HIGHLIGHT_MODES, default=DEFAULT_HIGHLIGHTS,
                        help="none (default): fit every observation the shadow and saturation rules keep; cross-band: leave out the "
                        "highlights found from red, green and blue together (helps opaque shiny surfaces and blue; see the docs)")
    parser.add_argument("--integrator", choices=[AUTO, *sorted(INTEGRATORS)], default=DEFAULT_INTEGRATOR,
        help="normal integration (default auto: dct-poisson on a fully valid field, else least-squares over the valid pixels)")


def _reconstruction_options(args):
    return ReconstructionOptions(pixel_um=args.pixel_um, saturation=args.saturation, shadow_fraction=args.shadow_fraction,
                                 solver=args.solver, integrator=args.integrator, highlights=args.highlights)


def _measure_options(args, method=None):
    return MeasureOptions(
        reconstruction=_reconstruction_options(args),
        height=HeightOptions(method or args.method),
        segmentation=_segmentation_options(args),
        texture=TextureOptions(level_order=args.level, p=args.p, q=args.q),
        regions=tuple(args.region),
    )


def _load(args, bands):
    acquisition = load_acquisition(args.acquisition, pixel_um=args.pixel_um, bands=bands, saturation=args.saturation)
    if acquisition.pixel_um_assumed:
        _say(args, f"note: {args.acquisition} has no pixel size; assuming 1 um per pixel (give --pixel-um)")
    return acquisition


def _band_progress(args):
    return lambda bands: _progress(bands, quiet=args.quiet, desc="reconstruct")


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
    options = _reconstruction_options(args)
    results = reconstruct_bands(acquisition, options, [SPECULAR_FREE] if derived else None, _band_progress(args))
    summary = run_header(
        "reconstruct", acquisition=acquisition_summary(acquisition), options=asdict(options),
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
    return SegmentationOptions(cutoff_um=args.cutoff_um, short_cutoff_um=args.short_cutoff_um, min_depth_um=args.min_depth_um,
                               min_length_um=args.min_length_um)


def cmd_correct(args):
    from skintopo.outputs import write_label_image
    from skintopo.pipeline import acquisition_height

    check_output_folder(args.out, overwrite=args.overwrite, inputs=[args.acquisition])
    started = time.perf_counter()
    acquisition = _load(args, None)
    options = MeasureOptions(reconstruction=_reconstruction_options(args), height=HeightOptions(args.method),
                             segmentation=_segmentation_options(args))
    made = acquisition_height(acquisition, options, _band_progress(args))
    segmentation = made.correction.segmentation
    summary = run_header(
        "correct", acquisition=acquisition_summary(acquisition),
        options=options.as_dict() | {"segmentation_parameters": segmentation.parameters},
        height=made.description,
        wrinkles_found=segmentation.count,
        wrinkle_area_fraction=float(segmentation.mask.mean()),
        bands={band: band_statistics(result) for band, result in made.bands.items()},
    )
    with staged_output_folder(args.out, overwrite=args.overwrite, inputs=[args.acquisition]) as staging:
        made.height.save(staging / "height.x3p")
        write_label_image(staging / "wrinkles.png", segmentation.labels)
        for band, result in made.bands.items():
            _write_band_outputs(staging / band, result)
        summary["seconds_total"] = time.perf_counter() - started
        write_json(staging / "summary.json", summary)
    _say(args, f"{segmentation.count} wrinkle(s) segmented; height: {made.description}, in {Path(args.out).resolve() / 'height.x3p'}")
    return 0


def cmd_evaluate(args):
    from skintopo.evaluation import evaluate_height
    from skintopo.heightmap import HeightMap

    inputs = [args.result, args.reference] + ([args.wrinkles] if args.wrinkles else [])
    check_output_file(args.out, overwrite=args.overwrite, inputs=inputs)
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
    write_json_atomic(args.out, report)
    if not args.quiet:
        for key, value in report.items():
            if isinstance(value, float):
                print(f"{key:<34} {value:12.4f}")
            elif isinstance(value, list) and value and isinstance(value[0], float):
                print(f"{key:<34} " + " ".join(f"{v:.3f}" for v in value))
        print(f"wrote {Path(args.out).resolve()}")
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
    from skintopo.evaluation import evaluate_height
    from skintopo.pipeline import acquisition_height, measure_height
    from skintopo.report import cross_section_pngs
    from skintopo.results import write_measurement
    from skintopo.segmentation import segmentation_quality
    from skintopo.synth import default_settings, make_surface, preset_spec, simulate_acquisition, write_synthetic_acquisition

    check_output_folder(args.out, overwrite=args.overwrite)
    started = time.perf_counter()
    options = MeasureOptions(height=HeightOptions("paper"))
    with staged_output_folder(args.out, overwrite=args.overwrite) as staging:
        spec = preset_spec(args.preset, size_px=args.size, pixel_um=20.0)
        surface = make_surface(spec, seed=args.seed)
        settings = default_settings(skin=args.skin)
        bands, info = simulate_acquisition(surface, settings, seed=args.seed)
        write_synthetic_acquisition(staging / "acquisition", surface, bands, settings=settings, seed=args.seed, info=info)
        _say(args, f"simulated {args.preset}, {args.skin} skin, {args.size}x{args.size} px at 20 um ({time.perf_counter() - started:.1f} s)")
        acquisition = load_acquisition(staging / "acquisition")
        made = acquisition_height(acquisition, options, _band_progress(args))
        heights = {band: result.height for band, result in made.bands.items()} | {"algorithm": made.height}
        evaluations = {
            name: evaluate_height(height, surface.height, wrinkle_labels=surface.wrinkle_labels, register=False)
            for name, height in heights.items()
        }
        result_folder = staging / "result"
        result_folder.mkdir()
        for band, result in made.bands.items():
            _write_band_outputs(result_folder / band, result)
        source = {"input": "simulated", "kind": "acquisition", "preset": args.preset, "skin": args.skin, "seed": args.seed,
                  "height": made.description}
        measurement = measure_height(made.height, options, albedo=made.albedo, source=source)
        write_measurement(result_folder, measurement, title=f"skintopo demo: simulated {args.preset}, {args.skin} skin",
                          evaluations=evaluations, cross_sections=cross_section_pngs(heights, surface.height, surface.wrinkle_labels))
        segmentation = made.correction.segmentation
        summary = run_header(
            "demo", acquisition=acquisition_summary(acquisition), preset=args.preset, skin=args.skin, seed=args.seed,
            segmentation=segmentation_quality(segmentation.mask, surface.wrinkle_labels > 0)
            | {"wrinkles_found": segmentation.count, "wrinkles_true": len(spec.wrinkles)},
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
        print(f"measured height: {made.description}; report: {(Path(args.out) / 'result' / 'report.html').resolve()}")
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


def cmd_measure(args):
    from skintopo.pipeline import measure_acquisition, measure_height
    from skintopo.results import write_measurement

    check_output_folder(args.out, overwrite=args.overwrite, inputs=[args.input])
    started = time.perf_counter()
    options = _measure_options(args)
    path = Path(args.input)
    if path.is_dir() and not (path / "height.x3p").is_file():
        measurement = measure_acquisition(path, options, _band_progress(args), on_note=lambda note: _say(args, f"note: {note}"))
    else:
        source = {"input": path.name, "kind": "height map", "height": "as given"}
        measurement = measure_height(load_height_input(path, args.pixel_um), options, albedo=load_albedo_beside(path), source=source)
    with staged_output_folder(args.out, overwrite=args.overwrite, inputs=[args.input]) as staging:
        write_measurement(staging, measurement, title=f"skintopo: {path.name}")
    if not args.quiet:
        print(f"{'region':<10} {'parameter':<24} {'value':>14} unit")
        for row in measurement.parameter_rows():
            value = "NaN" if row["value"] is None else f"{row['value']:14.5g}"
            print(f"{row['region']:<10} {row['name']:<24} {value:>14} {row['unit']}")
        print(f"measured height: {measurement.source['height']}")
        print(f"{measurement.wrinkles.totals['count']} wrinkle(s); report: {(Path(args.out) / 'report.html').resolve()}")
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


def cmd_wrinkles(args):
    from skintopo.report import wrinkle_overlay_png
    from skintopo.results import write_wrinkle_files
    from skintopo.segmentation import segment_wrinkles
    from skintopo.wrinkles import measure_wrinkles

    check_output_folder(args.out, overwrite=args.overwrite, inputs=[args.input])
    height = load_height_input(args.input, args.pixel_um)
    segmentation = segment_wrinkles(height, **_segmentation_options(args).as_kwargs())
    measures = measure_wrinkles(height, segmentation)
    with staged_output_folder(args.out, overwrite=args.overwrite, inputs=[args.input]) as staging:
        write_wrinkle_files(staging, measures, segmentation)
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
    from skintopo.pipeline import compare_results
    from skintopo.results import write_comparison

    inputs = [args.baseline, args.follow_up] + ([args.repeat] if args.repeat else [])
    check_output_folder(args.out, overwrite=args.overwrite, inputs=inputs)
    result = compare_results(args.baseline, args.follow_up, repeat=args.repeat, pixel_um=args.pixel_um, allow_scale=args.allow_scale,
                             segmentation=_segmentation_options(args))
    comparison, registration = result.comparison, result.comparison.registration
    with staged_output_folder(args.out, overwrite=args.overwrite, inputs=inputs) as staging:
        write_comparison(staging, comparison, result.rows, result.summary, result.spacing)
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

    from skintopo.batch import BatchInterrupted, read_study, run_study

    total = len(read_study(args.study))  # validates before anything runs
    bar = tqdm(desc="batch", unit="item", file=sys.stderr, disable=args.quiet)  # total grows with the compares

    def progress(item, step, status):
        bar.update(1)
        bar.set_postfix_str(f"{item.subject} {item.region} {item.visit} {step}: {status}")

    try:
        counts, _, failures = run_study(args.study, args.out, options=_measure_options(args), workers=args.workers, scheduler=args.scheduler,
                                        scheduler_timeout=args.scheduler_timeout, force=args.force, progress=progress)
    except BatchInterrupted as stop:
        bar.close()
        c = stop.counts
        print(f"skintopo batch: interrupted: {c['computed']} item(s) finished this run and are complete, {c['skipped']} were already done, "
              f"unfinished items left nothing; run the same command again to finish (tables not updated)", file=sys.stderr)
        return 128 + int(stop.signal_number)
    bar.close()
    for failure in failures:
        print(f"failed: {failure['subject']} {failure['visit']} {failure['region']} ({failure['step']}): "
              f"{' '.join(line.strip() for line in failure['error'].splitlines())}", file=sys.stderr)
    _say(args, f"{total} acquisition(s): computed {counts['computed']}, skipped (already done) {counts['skipped']}, failed {counts['failed']}; "
               f"tables in {Path(args.out).resolve()} (results.csv, changes.csv, statistics.csv, summary.html)")
    return 1 if failures else 0


def cmd_calibrate_lights(args):
    from skintopo.calibration import calibrate_lights

    check_output_file(args.out, overwrite=args.overwrite, inputs=[*args.images, *([args.mask] if args.mask else [])])
    output = Path(args.out)
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


def _add_measure_options(parser):
    """Every option of ``MeasureOptions``: reconstruction, height method, texture, regions, segmentation."""
    _add_reconstruction_options(parser)
    parser.add_argument("--method", choices=HEIGHT_METHODS, default=HeightOptions().method,
                        help="height measured from an acquisition: auto (default: the paper's correction when red, green and blue "
                        "are present, else white, else the only band), paper, feathered, or one band")
    parser.add_argument("--level", type=_non_negative_int, default=TextureOptions().level_order,
                        help="order of the least-squares form removed first (default 1: plane)")
    parser.add_argument("--p", type=float, default=DEFAULT_P, help=f"material ratio p of Vmp/Vmc/Vvc (default {DEFAULT_P:g} %%)")
    parser.add_argument("--q", type=float, default=DEFAULT_Q, help=f"material ratio q of Vmc/Vvc/Vvv (default {DEFAULT_Q:g} %%)")
    parser.add_argument("--region", type=_parse_region, action="append", default=[],
                        help="extra region NAME=x0,y0,x1,y1 in um from the top-left corner (pixel edges; repeatable)")
    _add_segmentation_options(parser)


def build_parser():
    parser = argparse.ArgumentParser(prog="skintopo", description="3D skin topography by multispectral photometric stereo.")
    parser.add_argument("--version", action="version", version=f"skintopo {__version__}")
    commands = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    reconstruct = commands.add_parser("reconstruct", help="normals, albedo and height map for each band of an acquisition")
    _add_acquisition_options(reconstruct)
    reconstruct.add_argument("-o", "--out", type=Path, required=True, help="output folder (created; must be empty or new)")
    reconstruct.add_argument("--band", choices=[*BANDS, SPECULAR_FREE, "all"], default="all",
                             help="band to process (default all present); specular-free = SUV projection of red, green, blue")
    _add_output_switches(reconstruct)
    reconstruct.set_defaults(handler=cmd_reconstruct)

    correct = commands.add_parser("correct", help="the paper's method: per-band reconstruction, wrinkle segmentation, spectral correction")
    _add_acquisition_options(correct)
    correct.add_argument("-o", "--out", type=Path, required=True, help="output folder")
    correct.add_argument("--method", choices=CORRECTION_METHODS, default=DEFAULT_CORRECTION_METHOD,
                         help=f"correction variant (default {DEFAULT_CORRECTION_METHOD})")
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
    _add_measure_options(measure)
    _add_output_switches(measure)
    measure.set_defaults(handler=cmd_measure)

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

    batch = commands.add_parser("batch", help="a whole study: measure every acquisition, compare follow-ups, statistics, one table")
    batch.add_argument("study", type=Path, help="study CSV: subject, visit, region, acquisition[, baseline][, repeat]")
    batch.add_argument("-o", "--out", type=Path, required=True,
                       help="study output folder, new or from an earlier run of the same study (finished items are skipped)")
    batch.add_argument("--workers", type=_positive_int, default=2, help="local worker processes (default 2)")
    batch.add_argument("--scheduler", help="address of a running Dask scheduler (tcp://host:8786) to run on instead")
    batch.add_argument("--scheduler-timeout", type=_positive_float, default=DEFAULT_SCHEDULER_TIMEOUT_S,
                       help=f"seconds to wait for the scheduler (default {DEFAULT_SCHEDULER_TIMEOUT_S:g})")
    batch.add_argument("--force", action="store_true", help="recompute every item, even those whose inputs and options are unchanged")
    _add_measure_options(batch)
    batch.add_argument("-q", "--quiet", action="store_true", help="no progress bar or summary line (failures still go to stderr)")
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
