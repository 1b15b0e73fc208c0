"""``skintopo init``: an acquisition manifest from a folder of images and the calibrated lights."""

from __future__ import annotations

import json
from pathlib import Path

from skintopo.cli import options as shared
from skintopo.errors import SkinTopoError


def run(args):
    from skintopo.acquisition.manifest import manifest_for_folder, write_manifest

    try:
        lights = json.loads(Path(args.lights).read_text(encoding="utf-8"))["lights"]
    except (OSError, ValueError, KeyError, TypeError) as error:
        raise SkinTopoError(f"{args.lights}: not a lights file of 'skintopo calibrate lights' ({error.__class__.__name__}: {error})") from None
    manifest = manifest_for_folder(args.folder, lights, args.pixel_um, pattern=args.pattern, mask=args.mask)
    acquisition = write_manifest(args.folder, manifest, overwrite=args.overwrite)
    shared.say(args, f"wrote {(Path(args.folder) / 'acquisition.json').resolve()}: bands "
                     + ", ".join(f"{band} ({len(images.files)} images)" for band, images in acquisition.bands.items())
                     + f", {acquisition.shape[1]} x {acquisition.shape[0]} px of {acquisition.pixel_um:g} um")
    return 0


def add_parser(commands):
    init = commands.add_parser("init", help="write acquisition.json for a folder of images, with the lights from 'calibrate lights'")
    init.add_argument("folder", type=Path, help="folder of images named like red_1.png, green_1.png, ... (see --pattern)")
    init.add_argument("--lights", type=Path, required=True, help="lights.json written by 'skintopo calibrate lights' (light order)")
    init.add_argument("--pixel-um", type=shared.positive_float, required=True, help="pixel size in micrometres on the skin")
    init.add_argument("--pattern", default="{band}_{index}",
                      help="file names without suffix: {band} = red/green/blue/white, {index} = the light's number (default {band}_{index})")
    init.add_argument("--mask", type=Path, help="a mask image in the folder (non-zero = skin to measure)")
    shared.add_output_switches(init)
    init.set_defaults(handler=run)
