"""``skintopo measure``: every texture, fractal, wrinkle and pore measure, the melanin and
haemoglobin maps, with the report."""

from __future__ import annotations

import time
from pathlib import Path

from skintopo.cli import options as shared


def run(args):
    import numpy as np

    from skintopo.outputs import check_output_folder, staged_output_folder
    from skintopo.pipeline import measure_acquisition, measure_height
    from skintopo.results import HeightOutputs, load_albedo_beside, load_height_input, write_measurement

    check_output_folder(args.out, overwrite=args.overwrite, inputs=[args.input])
    started = time.perf_counter()
    options = shared.measure_options(args)
    path = Path(args.input)
    with staged_output_folder(args.out, overwrite=args.overwrite, inputs=[args.input]) as staging:
        alongside = HeightOutputs(staging)  # height.x3p and the report's height views, made while the wrinkles are measured
        if path.is_dir() and not (path / "height.x3p").is_file():
            measurement = measure_acquisition(path, options, shared.band_progress(args), on_note=lambda note: shared.say(args, f"note: {note}"),
                                              step_progress=shared.step_progress(args), alongside=alongside)
        else:
            source = {"input": path.name, "kind": "height map", "height": "as given"}
            measurement = measure_height(load_height_input(path, args.pixel_um), options, albedo=load_albedo_beside(path), source=source,
                                         progress=shared.step_progress(args), alongside=alongside)
        for _ in shared.step_progress(args, desc="write")(["report and tables"]):
            write_measurement(staging, measurement, title=f"skintopo: {path.name}", early=alongside)
    if not args.quiet:
        print(f"{'region':<10} {'parameter':<24} {'value':>14} unit")
        for row in measurement.parameter_rows():
            value = "NaN" if row["value"] is None else f"{row['value']:14.5g}"
            print(f"{row['region']:<10} {row['name']:<24} {value:>14} {row['unit']}")
        print(f"measured height: {measurement.source['height']}")
        pores = measurement.pores.totals
        print(f"{measurement.wrinkles.totals['count']} wrinkle(s), {pores['count']} pore(s) ({pores['count_per_cm2']:.1f} per cm2)")
        colour = measurement.chromophores
        if colour is not None:
            print(f"melanin index {np.nanmean(colour.melanin):.4f}, haemoglobin index {np.nanmean(colour.haemoglobin):.4f} "
                  f"(optical density at 523 nm, {colour.reflectance} reflectance)")
        else:
            print(f"melanin and haemoglobin: {measurement.source.get('chromophores', 'not measured: no acquisition')}")
        print(f"report: {(Path(args.out) / 'report.html').resolve()}")
        print(f"wrote {Path(args.out).resolve()} in {time.perf_counter() - started:.1f} s")
    return 0


def add_parser(commands):
    measure = commands.add_parser("measure", help="surface texture (ISO 25178-2), volume and fractal parameters of a height map or acquisition")
    measure.add_argument("input", type=Path, help=f"height map ({shared.HEIGHT_MAPS}), acquisition folder or result folder")
    measure.add_argument("-o", "--out", type=Path, required=True, help="output folder (parameters.json, parameters.csv)")
    shared.add_measure_options(measure)
    shared.add_output_switches(measure)
    measure.set_defaults(handler=run)
