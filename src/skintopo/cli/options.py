"""Option groups and helpers shared by the commands (one place, as rasterio's ``rio/options.py``)."""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

from skintopo.defaults import (
    AUTO_HEIGHT,
    AUTO_INTEGRATOR,
    DEFAULT_ALONG_CLOSING_UM,
    DEFAULT_COLOUR_SMOOTHING_UM,
    DEFAULT_CUTOFF_UM,
    DEFAULT_DEPTH_SHORT_CUTOFF_UM,
    DEFAULT_DEPTH_WINDOW_UM,
    DEFAULT_FURROW_CLOSING_UM,
    DEFAULT_HIGHLIGHTS,
    DEFAULT_INTEGRATOR,
    DEFAULT_LEVEL_ORDER,
    DEFAULT_MIN_DEPTH_UM,
    DEFAULT_MIN_LENGTH_UM,
    DEFAULT_P,
    DEFAULT_PORE_EDGE_UM,
    DEFAULT_PORE_MAX_OPENING_UM,
    DEFAULT_PORE_MIN_DEPTH_UM,
    DEFAULT_PORE_MIN_OPENING_UM,
    DEFAULT_Q,
    DEFAULT_SATURATION,
    DEFAULT_SHADOW_FRACTION,
    DEFAULT_SHORT_CUTOFF_UM,
    DEFAULT_SOLVER,
    DEFAULT_STRAIGHT_VALLEY_UM,
    HEIGHT_MAP_SUFFIXES,
    HEIGHT_METHODS,
    HIGHLIGHT_MODES,
    INTEGRATOR_NAMES,
    SOLVERS,
)

HEIGHT_MAPS = "/".join(HEIGHT_MAP_SUFFIXES)  # for help texts: the height map files that can be read

# The library (NumPy, SciPy) is imported inside the functions that use it, so that building
# the parser (``skintopo --help``) stays fast.


def number_type(convert, accept, requirement):
    """An argparse type: ``convert`` the text, then require ``accept(value)``."""

    def parse(text):
        try:
            value = convert(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
        if not (math.isfinite(value) and accept(value)):
            raise argparse.ArgumentTypeError(f"must be {requirement}, got {text}")
        return value

    return parse


positive_float = number_type(float, lambda v: v > 0, "a positive number")
non_negative_float = number_type(float, lambda v: v >= 0, "zero or positive")
fraction = number_type(float, lambda v: 0 <= v < 1, "in [0, 1)")
unit_fraction = number_type(float, lambda v: 0 < v <= 1, "in (0, 1]")
size = number_type(int, lambda v: v >= 16, "at least 16 pixels")
positive_int = number_type(int, lambda v: v >= 1, "1 or more")
non_negative_int = number_type(int, lambda v: v >= 0, "0 or more")
percent_confidence = number_type(float, lambda v: 50 < v < 100, "a percentage between 50 and 100")


def specular_colour(text):
    """An argparse type: three positive numbers ``R,G,B``, or a file of ``skintopo calibrate
    highlight``."""
    if "," not in text:
        from skintopo.calibration import read_specular_colour
        from skintopo.errors import SkinTopoError

        try:
            return read_specular_colour(text)
        except SkinTopoError as error:
            raise argparse.ArgumentTypeError(str(error)) from None
    parts = text.split(",")
    if len(parts) != 3:
        raise argparse.ArgumentTypeError(f"expected three numbers R,G,B, got {text!r}")
    return tuple(positive_float(part.strip()) for part in parts)


def bar(iterable=None, *, quiet, desc, unit, total=None, leave=False):
    """A tqdm progress bar on stderr (none with -q). Its size is the terminal's, or 100 x 24
    where the terminal reports none: tqdm draws nothing at all on a terminal of 0 rows (a
    pseudo-terminal whose size was never set, as some consoles and ``docker exec`` give)."""
    import shutil

    from tqdm import tqdm

    columns, lines = shutil.get_terminal_size((100, 24))
    return tqdm(iterable, desc=desc, total=total, disable=quiet, unit=unit, file=sys.stderr, leave=leave, ncols=columns, nrows=lines)


def progress(iterable, *, quiet, desc, total=None):
    # with -q, no bar and no tqdm to import (10 ms with multiprocessing, which it loads)
    return iterable if quiet else bar(iterable, quiet=quiet, desc=desc, unit="band", total=total)


def step_progress(args, desc="measure"):
    """A progress bar over named steps (``progress`` of :func:`skintopo.pipeline.measure_height`)
    that names the step running; on stderr, in a terminal or a pipe, none with -q."""
    if args.quiet:
        return iter

    def wrap(steps):
        steps_bar = bar(steps, quiet=args.quiet, desc=desc, unit="step")
        for step in steps_bar:
            steps_bar.set_postfix_str(step)
            yield step

    return wrap


def say(args, message):
    if not args.quiet:
        print(message)


def add_acquisition_options(parser):
    parser.add_argument("acquisition", type=Path, help="acquisition folder (acquisition.json or DiLiGenT layout)")
    add_reconstruction_options(parser)


def add_reconstruction_options(parser):
    """Options of the acquisition -> normals -> height stages (``ReconstructionOptions``)."""
    parser.add_argument(
        "--pixel-um", type=positive_float, default=None, help="pixel size in micrometres for inputs without one (DiLiGenT folders, .npy maps; default 1)"
    )
    parser.add_argument(
        "--saturation", type=fraction, default=DEFAULT_SATURATION,
        help=f"fraction of full scale at or above which a pixel is saturated and left out (default {DEFAULT_SATURATION})",
    )
    parser.add_argument("--solver", choices=SOLVERS, default=DEFAULT_SOLVER,
                        help=f"photometric stereo solver: least-squares or robust (outlier rejection; with --method physics, "
                        f"also inside its iteration); default {DEFAULT_SOLVER}")
    parser.add_argument(
        "--shadow-fraction", type=fraction, default=DEFAULT_SHADOW_FRACTION,
        help="observations below this fraction of the pixel's albedo (from a first fit) are taken as shadow and left out "
        f"(default {DEFAULT_SHADOW_FRACTION})",
    )
    parser.add_argument("--highlights", choices=HIGHLIGHT_MODES, default=DEFAULT_HIGHLIGHTS,
                        help="none (default): fit every observation the shadow and saturation rules keep; cross-band: leave out the "
                        "highlights found from red, green and blue together (helps opaque shiny surfaces and blue; see the docs)")
    parser.add_argument("--specular-colour", type=specular_colour, default=None, metavar="R,G,B|FILE",
                        help="with --highlights cross-band: the surface reflection's relative strength in red, green and blue, "
                        "or the file 'skintopo calibrate highlight' writes from a parallel- and a cross-polarised capture "
                        "(default white: 1,1,1)")
    parser.add_argument("--integrator", choices=[AUTO_INTEGRATOR, *sorted(INTEGRATOR_NAMES)], default=DEFAULT_INTEGRATOR,
        help="normal integration (default auto: dct-poisson on a fully valid field, else least-squares over the valid pixels)")


def reconstruction_options(args):
    from skintopo.pipeline import ReconstructionOptions

    return ReconstructionOptions(pixel_um=args.pixel_um, saturation=args.saturation, shadow_fraction=args.shadow_fraction,
                                 solver=args.solver, integrator=args.integrator, highlights=args.highlights,
                                 specular_colour=args.specular_colour)


def measure_options(args, method=None):
    from skintopo.pipeline import ColourOptions, HeightOptions, MeasureOptions, TextureOptions

    return MeasureOptions(
        reconstruction=reconstruction_options(args),
        height=HeightOptions(method or args.method, args.physics_kernels),
        segmentation=segmentation_options(args),
        texture=TextureOptions(level_order=args.level, p=args.p, q=args.q),
        regions=tuple(args.region),
        wrinkles=wrinkle_options(args),
        pores=pore_options(args),
        colour=ColourOptions(smoothing_um=args.colour_smoothing_um),
    )


def load(args, bands, command):
    """The acquisition of ``args``, refused when it will not fit in memory for ``command``."""
    from skintopo.acquisition import load_acquisition
    from skintopo.pipeline import PROCESSING_BYTES_PER_PIXEL

    acquisition = load_acquisition(args.acquisition, pixel_um=args.pixel_um, bands=bands, saturation=args.saturation,
                                   bytes_per_pixel=PROCESSING_BYTES_PER_PIXEL[command])
    if acquisition.pixel_um_assumed:
        say(args, f"note: {args.acquisition} has no pixel size; assuming 1 um per pixel (give --pixel-um)")
    return acquisition


def band_progress(args):
    return lambda bands: progress(bands, quiet=args.quiet, desc="reconstruct")


def write_band_outputs(folder, result):
    import numpy as np

    folder.mkdir()
    np.save(folder / "normals.npy", result.stereo.normals.astype(np.float32))
    np.save(folder / "albedo.npy", result.stereo.albedo.astype(np.float32))
    result.height.save(folder / "height.x3p")


def segmentation_options(args):
    from skintopo.pipeline import SegmentationOptions

    return SegmentationOptions(cutoff_um=args.cutoff_um, short_cutoff_um=args.short_cutoff_um, min_depth_um=args.min_depth_um,
                               min_length_um=args.min_length_um, straight_valley_um=args.straight_valley_um)


def wrinkle_options(args):
    from skintopo.pipeline import WrinkleOptions

    return WrinkleOptions(furrow_closing_um=args.furrow_closing_um, along_closing_um=args.along_closing_um,
                          depth_window_um=args.depth_window_um, short_cutoff_um=args.depth_short_cutoff_um)


def pore_options(args):
    from skintopo.pipeline import PoreOptions

    return PoreOptions(max_opening_um=args.pore_max_opening_um, min_opening_um=args.pore_min_opening_um, min_depth_um=args.pore_min_depth_um,
                       edge_um=args.pore_edge_um)


def parse_region(text):
    try:
        name, box = text.split("=", 1)
        x0, y0, x1, y1 = (float(v) for v in box.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"region {text!r} must look like NAME=x0,y0,x1,y1 (micrometres)") from None
    if not (x1 > x0 and y1 > y0):
        raise argparse.ArgumentTypeError(f"region {text!r}: need x1 > x0 and y1 > y0")
    return name, (x0, y0, x1, y1)


def add_output_switches(parser):
    """--overwrite and -q/--quiet, which every command that writes an output takes."""
    parser.add_argument("--overwrite", action="store_true", help="replace an earlier output (never an input)")
    parser.add_argument("-q", "--quiet", action="store_true", help="no progress bar, tables or messages (errors still go to stderr)")


def add_segmentation_options(parser):
    parser.add_argument("--cutoff-um", type=positive_float, default=DEFAULT_CUTOFF_UM,
                        help=f"lambda_c of the segmentation band-pass (default {DEFAULT_CUTOFF_UM:g})")
    parser.add_argument("--short-cutoff-um", type=positive_float, default=DEFAULT_SHORT_CUTOFF_UM,
                        help=f"lambda_s (default {DEFAULT_SHORT_CUTOFF_UM:g})")
    parser.add_argument("--min-depth-um", type=positive_float, default=DEFAULT_MIN_DEPTH_UM,
                        help=f"shallowest wrinkle (default {DEFAULT_MIN_DEPTH_UM:g})")
    parser.add_argument("--min-length-um", type=positive_float, default=DEFAULT_MIN_LENGTH_UM,
                        help=f"shortest wrinkle (default {DEFAULT_MIN_LENGTH_UM:g})")
    parser.add_argument("--straight-valley-um", type=non_negative_float, default=DEFAULT_STRAIGHT_VALLEY_UM,
                        help="also find wrinkles as valleys straight over this length, which the band-pass misses when they are "
                        f"narrow and shallow (default {DEFAULT_STRAIGHT_VALLEY_UM:g}; 0: the paper's band-pass alone)")


def add_wrinkle_options(parser):
    """The wrinkle measures' settings (docs/wrinkle-measures.md)."""
    parser.add_argument("--furrow-closing-um", type=positive_float, default=DEFAULT_FURROW_CLOSING_UM,
                        help=f"closing segment that fills the furrows around a wrinkle (default {DEFAULT_FURROW_CLOSING_UM:g})")
    parser.add_argument("--along-closing-um", type=positive_float, default=DEFAULT_ALONG_CLOSING_UM,
                        help=f"closing segment along a wrinkle that bridges crossing furrows (default {DEFAULT_ALONG_CLOSING_UM:g})")
    parser.add_argument("--depth-window-um", type=positive_float, default=DEFAULT_DEPTH_WINDOW_UM,
                        help=f"max depth = mean depth of the deepest stretch of centre line this long (default {DEFAULT_DEPTH_WINDOW_UM:g})")
    parser.add_argument("--depth-short-cutoff-um", type=non_negative_float, default=DEFAULT_DEPTH_SHORT_CUTOFF_UM,
                        help="S-filter of the height the wrinkle depths are read from (default 0: none; any S-filter makes "
                        "wrinkles narrower than about 4 x the cut-off read shallower)")


def add_pore_options(parser):
    """The pore measures' settings (skintopo.pores)."""
    parser.add_argument("--pore-max-opening-um", type=positive_float, default=DEFAULT_PORE_MAX_OPENING_UM,
                        help=f"largest pore opening (default {DEFAULT_PORE_MAX_OPENING_UM:g}; pits wider are not pores)")
    parser.add_argument("--pore-min-opening-um", type=positive_float, default=DEFAULT_PORE_MIN_OPENING_UM,
                        help=f"smallest pore opening (default {DEFAULT_PORE_MIN_OPENING_UM:g})")
    parser.add_argument("--pore-min-depth-um", type=positive_float, default=DEFAULT_PORE_MIN_DEPTH_UM,
                        help=f"a pore is at least this deep below its rim (default {DEFAULT_PORE_MIN_DEPTH_UM:g})")
    parser.add_argument("--pore-edge-um", type=positive_float, default=DEFAULT_PORE_EDGE_UM,
                        help=f"a pore's opening is where it is deeper than this (default {DEFAULT_PORE_EDGE_UM:g})")


def add_physics_kernels_option(parser):
    parser.add_argument("--physics-kernels", metavar="FILE.json|PROFILE", default=None,
                        help="physics only: known scattering kernels instead of estimating them from the capture: a diffusion-profile "
                        "file from 'skintopo calibrate skin', or a skin-optics profile's diffusion profiles (literature, "
                        "paper-calibrated, default-v1)")


def add_measure_options(parser):
    """Every option of ``MeasureOptions``: reconstruction, height method, texture, regions, segmentation."""
    add_reconstruction_options(parser)
    parser.add_argument("--method", choices=HEIGHT_METHODS, default=AUTO_HEIGHT,
                        help="height measured from an acquisition: auto (default: the paper's correction when red, green and blue "
                        "are present, else white, else the only band), paper, feathered, physics (inverts scattering, interreflection "
                        "and highlights; at least 5 mm of field recommended), or one band")
    add_physics_kernels_option(parser)
    parser.add_argument("--level", type=non_negative_int, default=DEFAULT_LEVEL_ORDER,
                        help="order of the least-squares form removed first (default 1: plane)")
    parser.add_argument("--p", type=float, default=DEFAULT_P, help=f"material ratio p of Vmp/Vmc/Vvc (default {DEFAULT_P:g} %%)")
    parser.add_argument("--q", type=float, default=DEFAULT_Q, help=f"material ratio q of Vmc/Vvc/Vvv (default {DEFAULT_Q:g} %%)")
    parser.add_argument("--region", type=parse_region, action="append", default=[],
                        help="extra region NAME=x0,y0,x1,y1 in um from the top-left corner (pixel edges; repeatable)")
    add_segmentation_options(parser)
    add_wrinkle_options(parser)
    add_pore_options(parser)
    parser.add_argument("--colour-smoothing-um", type=non_negative_float, default=DEFAULT_COLOUR_SMOOTHING_UM,
                        help="melanin and haemoglobin maps: sigma of the Gaussian on the optical densities before the inversion "
                        f"(default {DEFAULT_COLOUR_SMOOTHING_UM:g}; 0: per pixel)")


def coordinate_pair(text):
    """X,Y in micrometres."""
    try:
        x, y = (float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} must look like X,Y (micrometres)") from None
    return x, y


def depth_treatment(text):
    """ID=FACTOR: wrinkle ID made FACTOR times as deep."""
    try:
        wrinkle, factor = text.split("=")
        wrinkle, factor = int(wrinkle), float(factor)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} must look like ID=FACTOR, e.g. 2=0.7") from None
    if not factor > 0:
        raise argparse.ArgumentTypeError(f"{text!r}: the depth factor must be positive")
    return wrinkle, factor
