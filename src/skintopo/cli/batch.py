"""``skintopo batch``: a whole study."""

from __future__ import annotations

import sys
from pathlib import Path

from skintopo.cli import options as shared
from skintopo.defaults import DEFAULT_SCHEDULER_TIMEOUT_S


def run(args):
    from skintopo.batch import BatchInterrupted, read_study, run_study

    total = len(read_study(args.study))  # validates before anything runs
    bar = shared.bar(quiet=args.quiet, desc="batch", unit="item", leave=True)  # total grows with the compares

    def progress(item, step, status):
        bar.update(1)
        bar.set_postfix_str(f"{item.subject} {item.region} {item.visit} {step}: {status}")

    try:
        counts, _, failures = run_study(args.study, args.out, options=shared.measure_options(args), workers=args.workers, scheduler=args.scheduler,
                                        scheduler_timeout=args.scheduler_timeout, force=args.force, progress=progress)
    except BatchInterrupted as stop:
        bar.close()
        c = stop.counts
        print(f"skintopo batch: interrupted: {c['computed']} item(s) finished this run and are complete, {c['skipped']} were already done, "
              f"unfinished items left nothing; run the same command again to finish (tables not updated)", file=sys.stderr)
        return 128 + int(stop.signal_number)
    bar.close()
    for failure in failures:
        print(f"failed: {failure['subject']} {failure['visit']} {failure['region']} ({failure['step']}): "
              f"{' '.join(line.strip() for line in failure['error'].splitlines())}", file=sys.stderr)
    shared.say(args, f"{total} acquisition(s): computed {counts['computed']}, skipped (already done) {counts['skipped']}, failed {counts['failed']}; "
               f"tables in {Path(args.out).resolve()} (results.csv, changes.csv, statistics.csv, summary.html)")
    return 1 if failures else 0


def add_parser(commands):
    batch = commands.add_parser("batch", help="a whole study: measure every acquisition, compare follow-ups, statistics, one table")
    batch.add_argument("study", type=Path, help="study CSV: subject, visit, region, acquisition[, baseline][, repeat]")
    batch.add_argument("-o", "--out", type=Path, required=True,
                       help="study output folder, new or from an earlier run of the same study (finished items are skipped)")
    batch.add_argument("--workers", type=shared.positive_int, default=2, help="local worker processes (default 2)")
    batch.add_argument("--scheduler", help="address of a running Dask scheduler (tcp://host:8786) to run on instead")
    batch.add_argument("--scheduler-timeout", type=shared.positive_float, default=DEFAULT_SCHEDULER_TIMEOUT_S,
                       help=f"seconds to wait for the scheduler (default {DEFAULT_SCHEDULER_TIMEOUT_S:g})")
    batch.add_argument("--force", action="store_true", help="recompute every item, even those whose inputs and options are unchanged")
    shared.add_measure_options(batch)
    batch.add_argument("-q", "--quiet", action="store_true", help="no progress bar or summary line (failures still go to stderr)")
    batch.set_defaults(handler=run)
