"""``skintopo evaluate``: a height map against a reference."""

from __future__ import annotations

from pathlib import Path

from skintopo.cli import options as shared
from skintopo.errors import SkinTopoError


def run(args):
    from skintopo.evaluation import evaluate_height
    from skintopo.heightmap import HeightMap
    from skintopo.outputs import check_output_file, write_json_atomic

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


def add_parser(commands):
    evaluate = commands.add_parser("evaluate", help="accuracy of a height map against a reference (ground truth, replica)")
    evaluate.add_argument("result", type=Path, help=f"height map ({shared.HEIGHT_MAPS})")
    evaluate.add_argument("reference", type=Path, help=f"reference height map ({shared.HEIGHT_MAPS})")
    evaluate.add_argument("-o", "--out", type=Path, default=Path("evaluation.json"), help="JSON file to write (default evaluation.json)")
    evaluate.add_argument("--wrinkles", type=Path, help="wrinkle label image (ground_truth/wrinkles.png) for in-wrinkle errors and depths")
    evaluate.add_argument("--pixel-um", type=shared.positive_float, help="pixel size for .npy maps")
    evaluate.add_argument("--no-register", action="store_true", help="do not search for a sub-pixel translation")
    shared.add_output_switches(evaluate)
    evaluate.set_defaults(handler=run)
