"""``skintopo calibrate lights``: light directions from spheres."""

from __future__ import annotations

from pathlib import Path

from skintopo.cli import options as shared


def run(args):
    from skintopo.calibration import calibrate_lights
    from skintopo.outputs import check_output_file, write_json_atomic

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


def add_parser(commands):
    calibrate = commands.add_parser("calibrate", help="device calibration")
    calibrate_commands = calibrate.add_subparsers(dest="what", required=True, metavar="WHAT")
    lights = calibrate_commands.add_parser("lights", help="light directions from a chrome (or matte white) sphere")
    lights.add_argument("images", type=Path, nargs="+", help="one sphere image per light, in light order")
    lights.add_argument("--mask", type=Path, help="sphere mask (default: found automatically)")
    lights.add_argument("--matte", action="store_true", help="a matte white sphere: directions and relative intensities by least squares")
    lights.add_argument("-o", "--out", type=Path, required=True, help="lights.json to write")
    shared.add_output_switches(lights)
    lights.set_defaults(handler=run)
