"""The ``skintopo`` command line: a thin layer over the Python API.

Errors caused by the input (:class:`~skintopo.errors.SkinTopoError`) are printed as one
clear message, exit status 2, without a traceback.
"""

from __future__ import annotations

import argparse
import hashlib
import platform
import sys
import time
from pathlib import Path

import numpy as np

from skintopo import __version__
from skintopo.acquisition import BANDS, DEFAULT_SATURATION, MANIFEST_NAME, load_acquisition
from skintopo.errors import SkinTopoError
from skintopo.height import AUTO, DEFAULT_INTEGRATOR, INTEGRATORS
from skintopo.normals import DEFAULT_SHADOW_FRACTION
from skintopo.outputs import check_output_folder, staged_output_folder, write_json
from skintopo.reconstruct import band_statistics, reconstruct_band


def _positive_float(text):
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not np.isfinite(value) or value <= 0:
        raise argparse.ArgumentTypeError(f"must be a positive number, got {text}")
    return value


def _fraction(text):
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not 0 <= value < 1:
        raise argparse.ArgumentTypeError(f"must be in [0, 1), got {text}")
    return value


def _progress(iterable, *, quiet, desc, total=None):
    from tqdm import tqdm

    return tqdm(iterable, desc=desc, total=total, disable=quiet, unit="band", file=sys.stderr, leave=False)


def _say(args, message):
    if not args.quiet:
        print(message)


def _acquisition_fingerprint(acquisition):
    """SHA-256 over the manifest (or DiLiGenT lists) so a summary identifies its input
    without recording the folder's path, which may name the person."""
    digest = hashlib.sha256()
    source = acquisition.source
    for name in (MANIFEST_NAME, "filenames.txt", "light_directions.txt", "light_intensities.txt"):
        if (source / name).is_file():
            digest.update((source / name).read_bytes())
    return digest.hexdigest()


def _add_acquisition_options(parser):
    parser.add_argument("acquisition", type=Path, help="acquisition folder (acquisition.json or DiLiGenT layout)")
    parser.add_argument(
        "--pixel-um", type=_positive_float, default=None, help="pixel size in micrometres for folders without one (DiLiGenT; default 1)"
    )
    parser.add_argument(
        "--saturation", type=_fraction, default=DEFAULT_SATURATION,
        help=f"fraction of full scale at or above which a pixel is saturated and left out (default {DEFAULT_SATURATION})",
    )
    parser.add_argument(
        "--shadow-fraction", type=_fraction, default=DEFAULT_SHADOW_FRACTION,
        help="observations below this fraction of a pixel's brightest are taken as shadow and left out "
        f"(default {DEFAULT_SHADOW_FRACTION})",
    )


def _load(args, bands):
    acquisition = load_acquisition(args.acquisition, pixel_um=args.pixel_um, bands=bands, saturation=args.saturation)
    if acquisition.pixel_um_assumed:
        _say(args, f"note: {args.acquisition} has no pixel size; assuming 1 um per pixel (give --pixel-um)")
    return acquisition


def cmd_reconstruct(args):
    bands = None if args.band == "all" else [args.band]
    check_output_folder(args.out, overwrite=args.overwrite, inputs=[args.acquisition])
    started = time.perf_counter()
    acquisition = _load(args, bands)
    seconds_load = time.perf_counter() - started
    results = {}
    for band in _progress(acquisition.bands, quiet=args.quiet, desc="reconstruct"):
        results[band] = reconstruct_band(acquisition, band, integrator=args.integrator, shadow_fraction=args.shadow_fraction)

    summary = {
        "skintopo_version": __version__,
        "command": "reconstruct",
        "python": platform.python_version(),
        "acquisition": {
            "name": acquisition.source.name,
            "sha256": _acquisition_fingerprint(acquisition),
            "layout": acquisition.layout,
            "shape": list(acquisition.shape),
            "pixel_um": acquisition.pixel_um,
            "pixel_um_assumed": acquisition.pixel_um_assumed,
            "bands": {b: len(acquisition.bands[b].files) for b in acquisition.bands},
        },
        "options": {
            "integrator": args.integrator,
            "saturation": args.saturation,
            "shadow_fraction": args.shadow_fraction,
        },
        "units": {"height": "um", "normals": "unit vector, camera frame (x right, y up, z toward camera)"},
        "seconds_load": seconds_load,
        "bands": {band: band_statistics(result) for band, result in results.items()},
    }
    with staged_output_folder(args.out, overwrite=args.overwrite, inputs=[args.acquisition]) as staging:
        for band, result in results.items():
            folder = staging / band
            folder.mkdir()
            np.save(folder / "normals.npy", result.stereo.normals.astype(np.float32))
            np.save(folder / "albedo.npy", result.stereo.albedo.astype(np.float32))
            result.height.save(folder / "height.x3p")
        summary["seconds_total"] = time.perf_counter() - started
        write_json(staging / "summary.json", summary)

    if not args.quiet:
        print(f"{'band':<6} {'valid %':>8} {'lights':>6} {'residual':>9} {'range um':>9}")
        for band, stats in summary["bands"].items():
            print(
                f"{band:<6} {100 * stats['valid_fraction']:8.1f} {stats['median_lights_used']:6.0f} "
                f"{stats['mean_residual']:9.4f} {stats['height_range_um']:9.2f}"
            )
        print(f"wrote {Path(args.out).resolve()}")
    return 0


def cmd_synth(args):
    from skintopo.synth import PRESETS, Effects, default_settings, make_surface, preset_spec, simulate_acquisition, write_synthetic_acquisition

    if args.preset not in PRESETS:
        raise SkinTopoError(f"unknown preset {args.preset!r}; choose from {list(PRESETS)}")
    check_output_folder(args.out, overwrite=args.overwrite)
    spec = preset_spec(args.preset, size_px=args.size, pixel_um=args.pixel_um)
    effects = Effects(
        shadows=not args.no_shadows,
        interreflection=not args.no_interreflection,
        bounces=1 if args.single_bounce else None,
        specular=not args.no_specular,
        translucency=not args.no_translucency,
        albedo_variation=not args.no_albedo_variation,
    )
    settings = default_settings(skin=args.skin, effects=effects, noise=args.noise, saturate=args.saturate)
    started = time.perf_counter()
    surface = make_surface(spec, seed=args.seed)
    bands, info = simulate_acquisition(surface, settings, seed=args.seed)
    write_synthetic_acquisition(args.out, surface, bands, settings=settings, seed=args.seed, info=info, overwrite=args.overwrite)
    _say(
        args,
        f"wrote {Path(args.out).resolve()}: preset {args.preset}, {args.skin} skin, {spec.size_px[1]}x{spec.size_px[0]} px "
        f"at {spec.pixel_um:g} um, {len(spec.wrinkles)} wrinkle(s), {time.perf_counter() - started:.1f} s",
    )
    return 0


def _size(text):
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a whole number of pixels") from None
    if value < 16:
        raise argparse.ArgumentTypeError(f"field size must be at least 16 pixels, got {value}")
    return value


def _non_negative_float(text):
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not np.isfinite(value) or value < 0:
        raise argparse.ArgumentTypeError(f"must be zero or positive, got {text}")
    return value


def build_parser():
    parser = argparse.ArgumentParser(prog="skintopo", description="3D skin topography by multispectral photometric stereo.")
    parser.add_argument("--version", action="version", version=f"skintopo {__version__}")
    commands = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    reconstruct = commands.add_parser("reconstruct", help="normals, albedo and height map for each band of an acquisition")
    _add_acquisition_options(reconstruct)
    reconstruct.add_argument("-o", "--out", type=Path, required=True, help="output folder (created; must be empty or new)")
    reconstruct.add_argument("--band", choices=[*BANDS, "all"], default="all", help="band to process (default all present)")
    reconstruct.add_argument("--integrator", choices=[AUTO, *sorted(INTEGRATORS)], default=DEFAULT_INTEGRATOR,
        help="normal integration (default auto: dct-poisson on a fully valid field, else least-squares over the valid pixels)")
    reconstruct.add_argument("--overwrite", action="store_true", help="replace a non-empty output folder")
    reconstruct.add_argument("-q", "--quiet", action="store_true", help="no progress bar or table")
    reconstruct.set_defaults(handler=cmd_reconstruct)

    synth = commands.add_parser("synth", help="simulate a skin acquisition with exact ground truth")
    synth.add_argument("-o", "--out", type=Path, required=True, help="output acquisition folder")
    synth.add_argument("--preset", default="forehead-moderate", help="flat-microrelief, forehead-low, forehead-moderate (default), forehead-high")
    synth.add_argument("--skin", choices=["light", "dark"], default="light", help="albedo preset (default light)")
    synth.add_argument("--size", type=_size, default=256, help="field size in pixels (square, default 256)")
    synth.add_argument("--pixel-um", type=_positive_float, default=20.0, help="pixel size in micrometres (default 20)")
    synth.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    synth.add_argument("--noise", type=_non_negative_float, default=1.0, help="sensor noise level, 0 = none, 1 = default camera")
    synth.add_argument("--saturate", action="store_true", help="expose so that specular highlights clip")
    synth.add_argument("--no-interreflection", action="store_true")
    synth.add_argument("--single-bounce", action="store_true", help="one interreflection bounce instead of converged radiosity")
    synth.add_argument("--no-specular", action="store_true")
    synth.add_argument("--no-translucency", action="store_true")
    synth.add_argument("--no-shadows", action="store_true")
    synth.add_argument("--no-albedo-variation", action="store_true")
    synth.add_argument("--overwrite", action="store_true", help="replace a non-empty output folder")
    synth.add_argument("-q", "--quiet", action="store_true")
    synth.set_defaults(handler=cmd_synth)
    return parser


def main(argv=None):
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return args.handler(args)
    except SkinTopoError as exc:
        print(f"skintopo {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"skintopo {args.command}: interrupted; no output written", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
