"""``skintopo synth``: a simulated acquisition with ground truth."""

from __future__ import annotations

import argparse
import time
from dataclasses import replace
from pathlib import Path

from skintopo.cli import options as shared
from skintopo.defaults import CALIBRATION_TARGETS, DEFAULT_SKIN_OPTICS
from skintopo.errors import SkinTopoError


def run(args):
    from skintopo.outputs import check_output_folder
    from skintopo.synth import (PRESETS, Effects, default_settings, make_surface, optics_profile, preset_spec, simulate_acquisition,
                                write_synthetic_acquisition)

    if args.target is not None and args.device is not None:
        from skintopo.synth.nearfield import write_device_targets

        check_output_folder(args.out, overwrite=args.overwrite)
        write_device_targets(args.out, _device(args), seed=args.seed, overwrite=args.overwrite)
        shared.say(args, f"wrote {Path(args.out).resolve()}: a chrome sphere at two places (place_1/, place_2/) and a flat "
                         "target (flat/) through the device, design.json to calibrate, the true device in ground_truth.json")
        return 0
    if args.target is not None:
        from skintopo.synth.targets import write_sphere_target

        check_output_folder(args.out, overwrite=args.overwrite)
        lights = default_settings().lights
        write_sphere_target(args.out, args.target, lights, shape=(args.size, args.size), seed=args.seed, overwrite=args.overwrite)
        shared.say(args, f"wrote {Path(args.out).resolve()}: {args.target} under {len(lights)} lights (sphere_1.png, ...; "
                         "the true lights in ground_truth.json)")
        return 0
    if args.preset not in PRESETS:
        raise SkinTopoError(f"unknown preset {args.preset!r}; choose from {list(PRESETS)}")
    check_output_folder(args.out, overwrite=args.overwrite)
    device = _device(args)
    if device is None:
        spec = preset_spec(args.preset, size_px=args.size, pixel_um=args.pixel_um)
    else:  # the camera's size and its pixel footprint on the skin
        spec = preset_spec(args.preset, size_px=device.camera.size_px, pixel_um=device.pixel_um)
    factors = dict(args.treat)
    unknown = sorted(i for i in factors if not 1 <= i <= len(spec.wrinkles))
    if unknown:
        raise SkinTopoError(f"--treat: the preset {args.preset} has wrinkles 1..{len(spec.wrinkles)}, not {unknown}")
    wrinkles = tuple(replace(w, depth_um=w.depth_um * factors.get(i, 1.0)) for i, w in enumerate(spec.wrinkles, start=1))
    spec = replace(spec, wrinkles=wrinkles, shift_um=args.shift_um)
    effects = Effects(
        shadows=not args.no_shadows,
        interreflection=not args.no_interreflection,
        bounces=1 if args.single_bounce else None,
        specular=not args.no_specular,
        translucency=not args.no_translucency,
        albedo_variation=not args.no_albedo_variation,
    )
    settings = default_settings(skin=args.skin, optics=optics_profile(args.optics), effects=effects, noise=args.noise,
                                saturate=args.saturate)
    started = time.perf_counter()
    capture_seed = args.seed if args.capture_seed is None else args.capture_seed
    if device is None:
        surface = make_surface(spec, seed=args.seed)
        bands, info = simulate_acquisition(surface, settings, seed=capture_seed,
                                           progress=lambda bands: shared.progress(bands, quiet=args.quiet, desc="render", total=3))
    else:
        from skintopo.synth.nearfield import camera_grid_surface, device_surface, simulate_device_acquisition

        rendered = device_surface(spec, device, seed=args.seed)
        images, info = simulate_device_acquisition(rendered, device, settings, seed=capture_seed)
        surface = camera_grid_surface(rendered, device)
        bands = {band: (stack, device.central_directions()) for band, stack in images.items()}
    write_synthetic_acquisition(args.out, surface, bands, settings=settings, seed=args.seed, info=info, overwrite=args.overwrite,
                                capture_seed=capture_seed, manifest=not args.no_manifest, device=device)
    shared.say(
        args,
        f"wrote {Path(args.out).resolve()}: preset {args.preset}, {args.skin} skin ({args.optics} optics), {spec.size_px[1]}x{spec.size_px[0]} px "
        f"at {spec.pixel_um:g} um, {len(spec.wrinkles)} wrinkle(s), {time.perf_counter() - started:.1f} s"
        + ("" if device is None else f", through the device ({len(device.leds)} near-field LEDs, perspective camera)"),
    )
    return 0


def _device(args):
    """The device of ``--device``: ``paper`` (a paper-like device with a camera of --size
    pixels) or a device file; None without the option."""
    if args.device is None:
        return None
    from skintopo.device import paper_device, read_device

    return paper_device(size_px=args.size) if args.device == "paper" else read_device(args.device)


def _pair(text):
    try:
        x, y = (float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} must look like X,Y (micrometres)") from None
    return x, y


def _treatment(text):
    try:
        wrinkle, factor = text.split("=")
        wrinkle, factor = int(wrinkle), float(factor)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} must look like ID=FACTOR, e.g. 2=0.7") from None
    if not factor > 0:
        raise argparse.ArgumentTypeError(f"{text!r}: the depth factor must be positive")
    return wrinkle, factor


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
    synth.add_argument("--shift-um", type=_pair, default=(0.0, 0.0), metavar="X,Y",
                       help="the field sees the same skin displaced by X, Y micrometres (x right, y up): a later visit")
    synth.add_argument("--treat", type=_treatment, action="append", default=[], metavar="ID=FACTOR",
                       help="multiply the depth of wrinkle ID (1 = the top one) by FACTOR, e.g. 2=0.7: a treated visit (repeatable)")
    synth.add_argument("--noise", type=shared.non_negative_float, default=1.0, help="sensor noise level, 0 = none, 1 = default camera")
    synth.add_argument("--saturate", action="store_true", help="expose so that specular highlights clip")
    synth.add_argument("--no-manifest", action="store_true",
                       help="write the images without acquisition.json, as a camera would (then 'skintopo init' makes it)")
    synth.add_argument("--target", choices=CALIBRATION_TARGETS,
                       help="instead of skin: a calibration target under the same lights, sphere_1.png, ... for 'skintopo calibrate "
                       "lights'; with --device: the chrome sphere at two places and a flat target for 'skintopo calibrate leds'")
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
    shared.add_output_switches(synth)
    synth.set_defaults(handler=run)
