"""``skintopo correct``: the paper's spectral correction, or the physically based height."""

from __future__ import annotations

import time
from pathlib import Path

from skintopo.cli import options as shared
from skintopo.defaults import CORRECTION_METHODS, DEFAULT_CORRECTION_METHOD, PHYSICS


def run(args):
    from skintopo.outputs import check_output_folder, staged_output_folder, write_json, write_label_image
    from skintopo.pipeline import HeightOptions, MeasureOptions, acquisition_height, acquisition_summary
    from skintopo.reconstruct import band_statistics
    from skintopo.results import run_header
    from skintopo.segmentation import segment_wrinkles

    check_output_folder(args.out, overwrite=args.overwrite, inputs=[args.acquisition])
    started = time.perf_counter()
    acquisition = shared.load(args, None, "correct")
    options = MeasureOptions(reconstruction=shared.reconstruction_options(args), height=HeightOptions(args.method, args.physics_kernels),
                             segmentation=shared.segmentation_options(args))
    made = acquisition_height(acquisition, options, shared.band_progress(args), shared.step_progress(args, desc="physics"))
    segmentation = made.correction.segmentation if made.correction else segment_wrinkles(made.height, **options.segmentation.as_kwargs())
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
            shared.write_band_outputs(staging / band, result)
        if made.physics is not None:
            write_json(staging / "physics.json", made.physics.as_dict())
        summary["seconds_total"] = time.perf_counter() - started
        write_json(staging / "summary.json", summary)
    note = made.physics.convergence_note() if made.physics is not None else None
    if note:
        shared.say(args, f"warning: {note}; see physics.json")
    shared.say(args, f"{segmentation.count} wrinkle(s) segmented; height: {made.description}, in {Path(args.out).resolve() / 'height.x3p'}")
    return 0


def add_parser(commands):
    correct = commands.add_parser("correct", help="per-band reconstruction and the corrected height: the paper's spectral correction "
                                                  "(paper, feathered) or the physically based height (physics)")
    shared.add_acquisition_options(correct)
    correct.add_argument("-o", "--out", type=Path, required=True, help="output folder")
    correct.add_argument("--method", choices=(*CORRECTION_METHODS, PHYSICS), default=DEFAULT_CORRECTION_METHOD,
                         help=f"paper or feathered (the paper's spectral correction), or physics (inverts scattering, "
                              f"interreflection and highlights; writes physics.json); default {DEFAULT_CORRECTION_METHOD}")
    shared.add_physics_kernels_option(correct)
    shared.add_segmentation_options(correct)
    shared.add_output_switches(correct)
    correct.set_defaults(handler=run)
