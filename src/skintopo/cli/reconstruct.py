"""``skintopo reconstruct``: normals, albedo and height map per band."""

from __future__ import annotations

import time
from dataclasses import asdict
from pathlib import Path

from skintopo.cli import options as shared
from skintopo.defaults import BANDS, SPECULAR_FREE


def run(args):
    from skintopo.outputs import check_output_folder, staged_output_folder, write_json
    from skintopo.pipeline import acquisition_summary, reconstruct_bands
    from skintopo.reconstruct import band_statistics
    from skintopo.results import run_header

    derived = args.band == SPECULAR_FREE
    wanted = None if args.band == "all" else [args.band]
    # the specular-free band and the cross-band highlights are made from red, green and blue,
    # whichever band is reconstructed
    rgb = derived or args.highlights == "cross-band"
    bands = None if wanted is None else [b for b in BANDS if b in wanted or (rgb and b in ("red", "green", "blue"))]
    check_output_folder(args.out, overwrite=args.overwrite, inputs=[args.acquisition])
    started = time.perf_counter()
    acquisition = shared.load(args, bands, "reconstruct")
    seconds_load = time.perf_counter() - started
    options = shared.reconstruction_options(args)
    results = reconstruct_bands(acquisition, options, wanted, shared.band_progress(args))
    summary = run_header(
        "reconstruct", acquisition=acquisition_summary(acquisition), options=asdict(options),
        units={"height": "um", "normals": "unit vector, camera frame (x right, y up, z toward camera)"},
        seconds_load=seconds_load,
        bands={band: band_statistics(result) for band, result in results.items()},
    )
    with staged_output_folder(args.out, overwrite=args.overwrite, inputs=[args.acquisition]) as staging:
        for band, result in results.items():
            shared.write_band_outputs(staging / band, result)
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


def add_parser(commands):
    reconstruct = commands.add_parser("reconstruct", help="normals, albedo and height map for each band of an acquisition")
    shared.add_acquisition_options(reconstruct)
    reconstruct.add_argument("-o", "--out", type=Path, required=True, help="output folder (created; must be empty or new)")
    reconstruct.add_argument("--band", choices=[*BANDS, SPECULAR_FREE, "all"], default="all",
                             help="band to process (default all present); specular-free = SUV projection of red, green, blue")
    shared.add_output_switches(reconstruct)
    reconstruct.set_defaults(handler=run)
