"""``skintopo calibrate lights``: light directions from spheres; ``skintopo calibrate leds``: a
device's near-field LEDs from a chrome sphere at two or more places and a flat target;
``skintopo calibrate skin``: skin's diffusion profile per band from a black mask's edge;
``skintopo calibrate highlight``: the surface reflection's colour from a parallel- and a
cross-polarised capture."""

from __future__ import annotations

from pathlib import Path

from skintopo.cli import options as shared
from skintopo.errors import SkinTopoError


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


def run_leds(args):
    from skintopo.calibration import calibrate_device, folder_images, read_grey_images
    from skintopo.device import read_device, write_device
    from skintopo.outputs import check_output_file

    design = read_device(args.device)
    places = [folder_images(place) for place in args.place]
    flat = folder_images(args.flat) if args.flat else None
    check_output_file(args.out, overwrite=args.overwrite, inputs=[args.device, *[p for paths in places for p in paths], *(flat or [])])
    for place, paths in zip(args.place, places):
        if len(paths) != len(design.leds):
            raise SkinTopoError(f"{place}: {len(paths)} images for the {len(design.leds)} LEDs of {args.device}: one per LED, in LED order")
    device, details = calibrate_device(design.camera, design.working_distance_mm, [read_grey_images(paths)[0] for paths in places],
                                       args.sphere_radius_mm, flat_images=read_grey_images(flat)[0] if flat else None,
                                       flat_depth_mm=args.flat_depth_mm, names=[led.name for led in design.leds])
    output = Path(args.out)
    write_device(output, device)
    if not args.quiet:
        for led, miss in zip(device.leds, details["ray_miss_rms_mm"]):
            x, y, z = led.position_mm
            print(f"{led.name:<10} at ({x:+8.2f}, {y:+8.2f}, {z:+8.2f}) mm, mu {led.mu:.2f}, rays miss by {miss:.2f} mm RMS")
        print(f"wrote {output.resolve()}")
    return 0


def run_skin(args):
    from skintopo.calibration import (
        diffusion_profile_from_edge,
        read_grey_images,
        write_diffusion_profiles,
    )
    from skintopo.optics import BANDS
    from skintopo.outputs import check_output_file

    paths = {band: getattr(args, band) or args.folder / f"edge_{band}.png" for band in BANDS}
    check_output_file(args.out, overwrite=args.overwrite, inputs=list(paths.values()))
    profiles, records = {}, {}
    for band, path in paths.items():
        image = read_grey_images([path])[0][0]
        profiles[band], records[band] = diffusion_profile_from_edge(image, args.pixel_um, name=str(path))
    write_diffusion_profiles(args.out, profiles, pixel_um=args.pixel_um, records=records,
                             source={band: str(path) for band, path in paths.items()})
    if not args.quiet:
        for band, profile in profiles.items():
            transfer = ", ".join(f"{profile.transfer(f / 1000):.2f} at {f:g}" for f in (0.5, 1, 2, 4))
            print(f"{band:<6} re-emerging where it entered {profile.weights[0] if profile.sigmas_um[0] == 0 else 0:.2f}; "
                  f"transfer {transfer} cycles/mm; misfit {records[band]['rms_misfit_relative']:.2%}")
        print(f"wrote {Path(args.out).resolve()} (give it to --physics-kernels)")
    return 0


def run_highlight(args):
    from skintopo.acquisition import load_acquisition
    from skintopo.calibration import specular_colour_from_polarised, write_specular_colour
    from skintopo.outputs import check_output_file

    check_output_file(args.out, overwrite=args.overwrite, inputs=[args.parallel, args.crossed])
    parallel, crossed = (load_acquisition(path, bands=("red", "green", "blue")) for path in (args.parallel, args.crossed))
    colour, record = specular_colour_from_polarised(parallel, crossed)
    write_specular_colour(args.out, colour, record=record, source={"parallel": str(args.parallel), "crossed": str(args.crossed)})
    if not args.quiet:
        print(f"surface reflection colour (red, green, blue; mean 1): {colour[0]:.4f}, {colour[1]:.4f}, {colour[2]:.4f} "
              f"from {record['observations']} observations (where it is strongest, "
              f"{record['specular_share_of_parallel_light']:.1%} of the parallel capture's light)")
        print(f"wrote {Path(args.out).resolve()} (give it to --specular-colour with --highlights cross-band)")
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
    leds = calibrate_commands.add_parser("leds", help="near-field LED positions (chrome sphere at two or more places), "
                                         "their axes, fall-off mu and intensities (flat matte target): writes a device file")
    leds.add_argument("device", type=Path, help="device file with the camera and the working distance (its LED positions: the "
                      "design values, replaced; its LED names and order are kept)")
    leds.add_argument("--place", type=Path, action="append", required=True, metavar="FOLDER",
                      help="a folder of chrome-sphere images, one per LED in LED order (file names sorted); give two or more")
    leds.add_argument("--sphere-radius-mm", type=shared.positive_float, required=True, help="the chrome sphere's radius in mm")
    leds.add_argument("--flat", type=Path, metavar="FOLDER", help="a folder of flat matte target images, one per LED, "
                      "corrected for the camera's vignetting: LED axes, mu and relative intensities (default: aimed at the "
                      "field centre, mu 1, equal)")
    leds.add_argument("--flat-depth-mm", type=shared.positive_float, help="distance of the flat target along the optical axis "
                      "(default: the working distance)")
    leds.add_argument("-o", "--out", type=Path, required=True, help="device file to write")
    shared.add_output_switches(leds)
    leds.set_defaults(handler=run_leds)
    skin = calibrate_commands.add_parser("skin", help="skin's diffusion profile per band (the physics height's scattering kernels) "
                                         "from images of a black mask's straight edge laid on the skin: writes a file for --physics-kernels")
    skin.add_argument("folder", type=Path, nargs="?", default=Path("."),
                      help="folder with edge_red.png, edge_green.png, edge_blue.png (linear images, all LEDs on, crossed polarisers)")
    for band in ("red", "green", "blue"):
        skin.add_argument(f"--{band}", type=Path, help=f"the {band} image, if not FOLDER/edge_{band}.png")
    skin.add_argument("--pixel-um", type=shared.positive_float, required=True, help="pixel size on the skin in micrometres")
    skin.add_argument("-o", "--out", type=Path, required=True, help="diffusion-profile file to write (JSON)")
    shared.add_output_switches(skin)
    skin.set_defaults(handler=run_skin)
    highlight = calibrate_commands.add_parser("highlight", help="the surface reflection's colour (for --specular-colour) from two "
                                              "captures of the same skin, through parallel and through crossed polarisers")
    highlight.add_argument("parallel", type=Path, help="acquisition through parallel polarisers (surface reflection passes)")
    highlight.add_argument("crossed", type=Path, help="acquisition of the same skin, lights, exposure and pose through crossed "
                           "polarisers (surface reflection blocked)")
    highlight.add_argument("-o", "--out", type=Path, required=True, help="specular-colour file to write (JSON)")
    shared.add_output_switches(highlight)
    highlight.set_defaults(handler=run_highlight)
