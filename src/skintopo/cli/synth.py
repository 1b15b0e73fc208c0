"""``skintopo synth``: a simulated acquisition with ground truth."""

from __future__ import annotations

import time
from pathlib import Path

from skintopo.cli import options as shared
from skintopo.defaults import CALIBRATION_TARGETS, DEFAULT_SKIN_OPTICS
from skintopo.errors import SkinTopoError


def run(args):
    from skintopo.outputs import check_output_folder
    from skintopo.synth import (
        PRESETS,
        Effects,
        another_visit,
        default_settings,
        optics_profile,
        preset_spec,
        simulate_to_folder,
        write_calibration_target,
    )
    from skintopo.synth.render import Pigmentation
    from skintopo.synth.surfaces import place_pores

    if args.target is not None:
        check_output_folder(args.out, overwrite=args.overwrite)
        written = write_calibration_target(args.out, args.target, device=_device(args), size_px=args.size, pixel_um=args.pixel_um,
                                           optics=args.optics, skin=args.skin, seed=args.seed, overwrite=args.overwrite)
        shared.say(args, f"wrote {Path(args.out).resolve()}: {written}")
        return 0
    if args.preset not in PRESETS:
        raise SkinTopoError(f"unknown preset {args.preset!r}; choose from {list(PRESETS)}")
    check_output_folder(args.out, overwrite=args.overwrite)
    device = _device(args)
    size, pixel = (args.size, args.pixel_um) if device is None else (device.camera.size_px, device.pixel_um)  # the device's footprint
    try:
        spec = another_visit(preset_spec(args.preset, size_px=size, pixel_um=pixel), depth_factors=dict(args.treat), shift_um=args.shift_um)
    except SkinTopoError as error:
        raise SkinTopoError(f"--treat: preset {args.preset}: {error}") from None
    if args.pores:
        spec = place_pores(spec, args.seed, args.pores)
    if device is not None and args.white_reference is not None:
        raise SkinTopoError("--white-reference: not with --device (a white reference box is for distant-light captures)")
    effects = Effects(shadows=not args.no_shadows, interreflection=not args.no_interreflection, bounces=1 if args.single_bounce else None,
                      specular=not args.no_specular, translucency=not args.no_translucency, albedo_variation=not args.no_albedo_variation)
    settings = default_settings(skin=args.skin, optics=optics_profile(args.optics), effects=effects, noise=args.noise, saturate=args.saturate,
                                pigmentation=Pigmentation(seed=args.seed) if args.pigmentation else None, white_reference=args.white_reference)
    started = time.perf_counter()
    simulate_to_folder(args.out, spec, settings, seed=args.seed, capture_seed=args.capture_seed, device=device, manifest=not args.no_manifest,
                       overwrite=args.overwrite, progress=lambda bands: shared.progress(bands, quiet=args.quiet, desc="render", total=3))
    shared.say(args, f"wrote {Path(args.out).resolve()}: preset {args.preset}, {args.skin} skin ({args.optics} optics), {spec.size_px[1]}x"
                     f"{spec.size_px[0]} px at {spec.pixel_um:g} um, {len(spec.wrinkles)} wrinkle(s), {time.perf_counter() - started:.1f} s"
                     + ("" if device is None else f", through the device ({len(device.leds)} near-field LEDs, perspective camera)"))
    return 0


def _device(args):
    """The device of ``--device``: ``paper`` (a paper-like device with a camera of --size
    pixels) or a device file; None without the option."""
    if args.device is None:
        return None
    from skintopo.device import paper_device, read_device

    return paper_device(size_px=args.size) if args.device == "paper" else read_device(args.device)


def add_parser(commands):
    synth = commands.add_parser("synth", help="simulate a skin acquisition with exact ground truth")
    synth.add_argument("-o", "--out", type=Path, required=True, help="output acquisition folder")
    synth.add_argument("--preset", default="forehead-moderate", help="flat-microrelief, forehead-low, forehead-moderate (default), forehead-high")
    synth.add_argument("--skin", choices=["light", "dark"], default="light", help="albedo preset (default light)")
    synth.add_argument("--optics", default=DEFAULT_SKIN_OPTICS, metavar="PROFILE",
                       help="skin-optics profile (albedo, subsurface scattering, surface reflection): default-v1 (default), "
                       "literature, paper-calibrated; see the method docs")
    synth.add_argument("--size", type=shared.size, default=256, help="field size in pixels (square, default 256)")
    synth.add_argument("--pixel-um", type=shared.positive_float, default=20.0, help="pixel size in micrometres (default 20)")
    synth.add_argument("--seed", type=int, default=0, help="random seed of the skin (default 0): the same seed is the same skin")
    synth.add_argument("--capture-seed", type=int, help="random seed of the sensor noise (default: --seed); another value is "
                       "a repeat capture of the same skin")
    synth.add_argument("--shift-um", type=shared.coordinate_pair, default=(0.0, 0.0), metavar="X,Y",
                       help="the field sees the same skin displaced by X, Y micrometres (x right, y up): a later visit")
    synth.add_argument("--treat", type=shared.depth_treatment, action="append", default=[], metavar="ID=FACTOR",
                       help="multiply the depth of wrinkle ID (1 = the top one) by FACTOR, e.g. 2=0.7: a treated visit (repeatable)")
    synth.add_argument("--noise", type=shared.non_negative_float, default=1.0, help="sensor noise level, 0 = none, 1 = default camera")
    synth.add_argument("--saturate", action="store_true", help="expose so that specular highlights clip")
    synth.add_argument("--no-manifest", action="store_true",
                       help="write the images without acquisition.json, as a camera would (then 'skintopo init' makes it)")
    synth.add_argument("--target", choices=CALIBRATION_TARGETS,
                       help="instead of skin: a calibration target under the same lights, sphere_1.png, ... for 'skintopo calibrate "
                       "lights'; with --device: the chrome sphere at two places and a flat target for 'skintopo calibrate leds'; "
                       "skin-edge: a black mask's straight edge on skin of --optics/--skin, for 'skintopo calibrate skin'")
    synth.add_argument("--device", metavar="paper|DEVICE.JSON",
                       help="render through a device: near-field LEDs and a perspective camera (paper: the paper-like device "
                       "with a camera of --size pixels over 65 mm; or a device file); the pixel size is then the device's "
                       "footprint on the skin and --pixel-um is not used")
    synth.add_argument("--no-interreflection", action="store_true", help="no light bouncing between skin points (wrinkles)")
    synth.add_argument("--single-bounce", action="store_true", help="one interreflection bounce instead of converged radiosity")
    synth.add_argument("--no-specular", action="store_true", help="no surface (specular) reflection")
    synth.add_argument("--no-translucency", action="store_true", help="no subsurface scattering (opaque skin)")
    synth.add_argument("--no-shadows", action="store_true", help="no cast shadows")
    synth.add_argument("--no-albedo-variation", action="store_true", help="uniform albedo instead of a mild spatial variation")
    synth.add_argument("--pigmentation", action="store_true",
                       help="albedo made from melanin and haemoglobin maps (spots, a reddened patch), written as ground_truth/melanin.npy, "
                            "haemoglobin.npy")
    synth.add_argument("--white-reference", type=shared.unit_fraction, metavar="R",
                       help="a flat white target of reflectance R in (0, 1] in the top-left tenth of the field (in the manifest, out of the mask)")
    synth.add_argument("--pores", type=shared.non_negative_int, default=0, metavar="N",
                       help="N pores (openings 0.05-0.5 mm, 20-120 um deep) on the skin's plateaus, in ground_truth/pores.png")
    shared.add_output_switches(synth)
    synth.set_defaults(handler=run)
