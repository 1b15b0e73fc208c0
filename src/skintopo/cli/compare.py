"""``skintopo compare``: two visits registered and compared."""

from __future__ import annotations

import sys
from pathlib import Path

from skintopo.cli import options as shared
from skintopo.defaults import DEFAULT_DETECTION_CONFIDENCE


def run(args):
    from skintopo.outputs import check_output_folder, staged_output_folder
    from skintopo.pipeline import compare_results
    from skintopo.results import write_comparison

    inputs = [args.baseline, args.follow_up, *args.repeat]
    check_output_folder(args.out, overwrite=args.overwrite, inputs=inputs)
    result = compare_results(args.baseline, args.follow_up, repeat=args.repeat, pixel_um=args.pixel_um, allow_scale=args.allow_scale,
                             confidence=args.confidence / 100, segmentation=shared.segmentation_options(args), wrinkles=shared.wrinkle_options(args),
                             pores=shared.pore_options(args),
                             progress=shared.step_progress(args, desc="compare"))
    comparison, registration = result.comparison, result.comparison.registration
    with staged_output_folder(args.out, overwrite=args.overwrite, inputs=inputs) as staging:
        write_comparison(staging, comparison, result.rows, result.summary, result.spacing)
    for warning in result.warnings:
        print(f"warning: {warning}", file=sys.stderr)
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


def add_parser(commands):
    compare = commands.add_parser("compare", help="before/after: register two visits, difference map, change of every parameter")
    compare.add_argument("baseline", type=Path, help=f"baseline height map ({shared.HEIGHT_MAPS}) or result folder with height.x3p")
    compare.add_argument("follow_up", type=Path, metavar="after", help="follow-up height map or result folder")
    compare.add_argument("-o", "--out", type=Path, required=True, help="output folder (difference.x3p, changes.csv, changes.json)")
    compare.add_argument("--repeat", type=Path, action="append", default=[],
                         help="a repeat capture of the unchanged baseline skin (repeatable): gives detection limits; "
                         "one repeat gives wide limits, five or more are recommended")
    compare.add_argument("--confidence", type=shared.percent_confidence, default=100 * DEFAULT_DETECTION_CONFIDENCE,
                         help=f"confidence of the detection limits, %% (default {100 * DEFAULT_DETECTION_CONFIDENCE:g}; "
                         "95 is ISO 5725-6's repeatability limit)")
    compare.add_argument("--allow-scale", action="store_true", help="also fit a small scale change")
    compare.add_argument("--pixel-um", type=shared.positive_float, help="pixel size for .npy maps")
    shared.add_segmentation_options(compare)
    shared.add_wrinkle_options(compare)
    shared.add_pore_options(compare)
    shared.add_output_switches(compare)
    compare.set_defaults(handler=run)
