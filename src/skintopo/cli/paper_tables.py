"""``skintopo paper-tables``: the paper's tables on simulated subjects."""

from __future__ import annotations

import sys
from pathlib import Path

from skintopo.cli import options as shared
from skintopo.defaults import DEFAULT_SKIN_OPTICS


def run(args):
    from skintopo.outputs import check_output_folder, staged_output_folder
    from skintopo.paper import paper_tables
    from skintopo.synth import optics_profile

    optics = optics_profile(args.optics)
    check_output_folder(args.out, overwrite=args.overwrite)
    with staged_output_folder(args.out, overwrite=args.overwrite) as staging:
        _, text = paper_tables(staging, size_px=args.size, pixel_um=args.pixel_um, optics=optics,
                               progress=None if args.quiet else lambda s: print(f"subject {s.number} done", file=sys.stderr))
    shared.say(args, f"skin optics: {optics.name}\n\n" + text + f"\n\nwrote {Path(args.out).resolve()}")
    return 0


def add_parser(commands):
    tables = commands.add_parser("paper-tables", help="the paper's Tables 1-2 and Figures 3 and 5 on four simulated subjects")
    tables.add_argument("-o", "--out", type=Path, required=True, help="output folder (tables as CSV and Markdown, figures as PNG)")
    tables.add_argument("--size", type=shared.size, default=256, help="field size in pixels (default 256)")
    tables.add_argument("--pixel-um", type=shared.positive_float, default=20.0, help="pixel size of the simulated fields in micrometres (default 20)")
    tables.add_argument("--optics", default=DEFAULT_SKIN_OPTICS, metavar="PROFILE",
                        help="skin-optics profile of the simulated subjects: default-v1 (default), literature, paper-calibrated")
    shared.add_output_switches(tables)
    tables.set_defaults(handler=run)
