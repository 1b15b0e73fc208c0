"""``skintopo wrinkles``: per-wrinkle measures and an overlay."""

from __future__ import annotations

import base64
from pathlib import Path

from skintopo.cli import options as shared


def run(args):
    from skintopo.outputs import check_output_folder, staged_output_folder
    from skintopo.report import wrinkle_overlay_png
    from skintopo.results import load_height_input, write_wrinkle_files
    from skintopo.segmentation import segment_wrinkles
    from skintopo.wrinkles import measure_wrinkles

    check_output_folder(args.out, overwrite=args.overwrite, inputs=[args.input])
    height = load_height_input(args.input, args.pixel_um)
    for step in shared.step_progress(args, desc="wrinkles")(["segmentation", "measures"]):
        if step == "segmentation":
            segmentation = segment_wrinkles(height, **shared.segmentation_options(args).as_kwargs())
        else:
            measures = measure_wrinkles(height, segmentation, **shared.wrinkle_options(args).as_kwargs())
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


def add_parser(commands):
    wrinkles = commands.add_parser("wrinkles", help="per-wrinkle measures: length, depth, width, volume, severity")
    wrinkles.add_argument("input", type=Path, help=f"height map ({shared.HEIGHT_MAPS}) or an output folder holding height.x3p")
    wrinkles.add_argument("-o", "--out", type=Path, required=True, help="output folder (wrinkles.csv, wrinkles.json, wrinkles_overlay.png)")
    wrinkles.add_argument("--pixel-um", type=shared.positive_float, help="pixel size for .npy maps")
    shared.add_segmentation_options(wrinkles)
    shared.add_wrinkle_options(wrinkles)
    shared.add_output_switches(wrinkles)
    wrinkles.set_defaults(handler=run)
