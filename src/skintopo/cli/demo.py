"""``skintopo demo``: simulate a forehead, measure it, compare with the truth."""

from __future__ import annotations

import time
from pathlib import Path

from skintopo.cli import options as shared


def run(args):
    import numpy as np

    from skintopo.acquisition import load_acquisition
    from skintopo.evaluation import evaluate_height, wrinkle_max_depths
    from skintopo.outputs import check_output_folder, staged_output_folder, write_json
    from skintopo.pipeline import (
        HeightOptions,
        MeasureOptions,
        acquisition_chromophores,
        acquisition_height,
        acquisition_summary,
        measure_height,
    )
    from skintopo.report import cross_section_pngs
    from skintopo.results import HeightOutputs, run_header, write_measurement
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
        shared.say(args, f"simulated {args.preset}, {args.skin} skin, {args.size}x{args.size} px at 20 um ({time.perf_counter() - started:.1f} s)")
        acquisition = load_acquisition(staging / "acquisition")
        made = acquisition_height(acquisition, options, shared.band_progress(args), shared.step_progress(args, desc="physics"))
        heights = {band: result.height for band, result in made.bands.items()} | {"algorithm": made.height}
        true_depths = wrinkle_max_depths(surface.height, surface.wrinkle_labels)
        evaluations = {
            name: evaluate_height(height, surface.height, wrinkle_labels=surface.wrinkle_labels, register=False,
                                  reference_wrinkle_depths=true_depths)
            for name, height in heights.items()
        }
        result_folder = staging / "result"
        result_folder.mkdir()
        for band, result in made.bands.items():
            shared.write_band_outputs(result_folder / band, result)
        source = {"input": "simulated", "kind": "acquisition", "preset": args.preset, "skin": args.skin, "seed": args.seed,
                  "height": made.description}
        chromophores, source["chromophores"] = acquisition_chromophores(acquisition, made.bands, options)
        early = HeightOutputs(result_folder)  # height.x3p and the report's height views, made while the wrinkles are measured
        measurement = measure_height(made.height, options, albedo=made.albedo, source=source, progress=shared.step_progress(args),
                                     chromophores=chromophores, alongside=early)
        write_measurement(result_folder, measurement, title=f"skintopo demo: simulated {args.preset}, {args.skin} skin",
                          evaluations=evaluations, cross_sections=cross_section_pngs(heights, surface.height, surface.wrinkle_labels),
                          early=early)
        segmentation = measurement.segmentation  # the wrinkles of the report (the correction segments its own height)
        summary = run_header(
            "demo", acquisition=acquisition_summary(acquisition), preset=args.preset, skin=args.skin, seed=args.seed,
            segmentation=segmentation_quality(segmentation.mask, surface.wrinkle_labels > 0)
            | {"wrinkles_found": len(measurement.wrinkles.wrinkles), "wrinkles_true": len(spec.wrinkles)},
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


def add_parser(commands):
    demo = commands.add_parser("demo", help="simulate a forehead capture, reconstruct and correct it, compare with the truth")
    demo.add_argument("-o", "--out", type=Path, default=Path("demo-out"), help="output folder (default demo-out)")
    demo.add_argument("--preset", default="forehead-moderate", choices=["forehead-low", "forehead-moderate", "forehead-high"],
                      help="wrinkle state of the simulated forehead (default forehead-moderate)")
    demo.add_argument("--skin", choices=["light", "dark"], default="light", help="skin albedo preset (default light)")
    demo.add_argument("--size", type=shared.size, default=256, help="field size in pixels at 20 um (default 256)")
    demo.add_argument("--seed", type=int, default=0, help="random seed of the surface and the sensor noise (default 0)")
    shared.add_output_switches(demo)
    demo.set_defaults(handler=run)
