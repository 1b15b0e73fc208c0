"""Study-scale batch: every acquisition of a study measured, every follow-up compared with its
baseline, on local processes or a Dask cluster, resumable, with one tidy table and the
statistics a trial reports.

Study file (CSV): columns ``subject``, ``visit``, ``region``, ``acquisition`` (folder,
relative to the study file), optional ``baseline`` (the visit to compare with; default: the
subject's first listed visit of that region) and optional ``repeat`` (a second capture of
the same skin at the same visit: gives the detection limits). All rows are validated before
anything runs.

Each item calls the library (:func:`skintopo.pipeline.measure_acquisition`,
:func:`skintopo.pipeline.compare_results`) into ``OUT/items/<subject>/<region>/<visit>/``
(``OUT/changes/...``, ``OUT/repeats/...``), written to a staging folder that holds the
item's stamp ``batch.json`` and is renamed into place when complete. The stamp's
fingerprint is a SHA-256 over the skintopo version, every option that changes a number
(:meth:`skintopo.pipeline.MeasureOptions.as_dict`) and the name, size and content of every
input file; a rerun skips items whose stamp matches and redoes missing, failed or changed
ones (``force`` redoes all). One failing item is recorded in ``failures.csv`` and never
stops the others.

Safety: the output folder may not hold or lie inside any input; one run at a time holds
its lock (``OUT/.lock``). SIGINT and SIGTERM stop the workers at once (they never outlive
the run, even one killed with SIGKILL: each worker exits when its parent dies), finished
items stay complete, unfinished ones leave nothing, and a rerun finishes the rest. Paths
in the outputs are relative to the study file.
"""

from __future__ import annotations

import csv
import hashlib
import json
import os
import re
import shutil
import signal
import threading
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

from skintopo import __version__
from skintopo.defaults import DEFAULT_SCHEDULER_TIMEOUT_S
from skintopo.errors import SkinTopoError
from skintopo.pipeline import MeasureOptions

STAMP = "batch.json"
LOCK = ".lock"
_SAFE = re.compile(r"[^A-Za-z0-9_.-]+")
REPEAT_SUFFIX = "~repeat"


@dataclass(frozen=True)
class StudyItem:
    subject: str
    visit: str
    region: str
    acquisition: Path
    baseline: str | None  # the baseline visit of a follow-up, None for a baseline
    repeat: Path | None = None  # a repeat capture of this visit's skin

    @property
    def key(self):
        return tuple(_SAFE.sub("_", part) for part in (self.subject, self.region, self.visit))

    @property
    def repeat_key(self):
        return (*self.key[:2], self.key[2] + REPEAT_SUFFIX)


def read_study(path):
    """Parse and validate a study CSV; every problem is reported at once."""
    path = Path(path)
    if not path.is_file():
        raise SkinTopoError(f"{path}: no such study file")
    try:
        with open(path, newline="", encoding="utf-8") as stream:
            reader = csv.DictReader(stream)
            rows = list(reader)
            columns = reader.fieldnames or []
    except (UnicodeDecodeError, csv.Error) as error:
        raise SkinTopoError(f"{path}: not a readable CSV file ({error})") from None
    problems = []
    required = ("subject", "visit", "region", "acquisition")
    missing = [c for c in required if c not in columns]
    if missing:
        raise SkinTopoError(f"{path}: the study needs the columns {list(required)} (missing {missing})")
    if not rows:
        raise SkinTopoError(f"{path}: the study lists no acquisition (a header line only)")
    items, seen, first_visit = [], set(), {}
    for number, row in enumerate(rows, start=2):  # line 1 is the header
        values = {c: (row.get(c) or "").strip() for c in (*required, "baseline", "repeat")}
        empty = [c for c in required if not values[c]]
        if empty:
            problems.append(f"{path.name}: line {number}: empty {', '.join(empty)}")
            continue
        folders = {}
        for column in ("acquisition", "repeat"):
            if values[column]:
                folders[column] = (path.parent / values[column]).resolve()
                if not folders[column].is_dir():
                    problems.append(f"{path.name}: line {number}: {column} folder {values[column]!r} not found")
        key = (values["subject"], values["region"], values["visit"])
        if key in seen:
            problems.append(f"{path.name}: line {number}: subject {key[0]} region {key[1]} visit {key[2]} listed twice")
        seen.add(key)
        first_visit.setdefault((values["subject"], values["region"]), values["visit"])
        items.append((number, values, folders))
    study = []
    for number, values, folders in items:
        group = (values["subject"], values["region"])
        baseline = values["baseline"] or first_visit[group]
        if (values["subject"], values["region"], baseline) not in seen:
            problems.append(f"{path.name}: line {number}: baseline visit {baseline!r} of subject {group[0]} region {group[1]} is not in the study")
        study.append(StudyItem(values["subject"], values["visit"], values["region"], folders.get("acquisition"),
                               None if baseline == values["visit"] else baseline, folders.get("repeat")))
    if problems:
        raise SkinTopoError(f"{path}: {len(problems)} problem(s) in the study:\n" + "\n".join(f"  - {p}" for p in problems))
    return study


def check_study_output(study_path, study, out):
    """The output folder may not be the study file's folder, hold an input, or lie inside an
    acquisition folder (results must never mix with inputs)."""
    out = Path(out).resolve()
    study_path = Path(study_path).resolve()
    if out == study_path.parent or study_path.is_relative_to(out):
        raise SkinTopoError(f"{out}: the output folder holds the study file {study_path.name}; choose a new folder for -o")
    for item in study:
        for folder in filter(None, (item.acquisition, item.repeat)):
            if out.is_relative_to(folder) or folder.is_relative_to(out):
                raise SkinTopoError(f"{out}: the output folder overlaps the acquisition folder {folder.name} "
                                    f"(subject {item.subject}, visit {item.visit}); choose another -o")
    if out.exists() and not out.is_dir():
        raise SkinTopoError(f"{out}: exists and is not a folder")


def fingerprint(paths, settings):
    """SHA-256 over the settings and the name, size and content of every file under ``paths``."""
    digest = hashlib.sha256(json.dumps(settings, sort_keys=True).encode())
    for root in paths:
        root = Path(root)
        files = sorted(p for p in (root.rglob("*") if root.is_dir() else [root]) if p.is_file())
        for file in files:
            digest.update(f"{file.relative_to(root.parent)}:{file.stat().st_size}:".encode())
            with open(file, "rb") as stream:
                for block in iter(lambda: stream.read(1 << 20), b""):
                    digest.update(block)
    return digest.hexdigest()


def _finished(folder, stamp):
    try:
        return json.loads((Path(folder) / STAMP).read_text())["fingerprint"] == stamp
    except (OSError, ValueError, KeyError):
        return False


def run_task(kind, inputs, out, stamp, options):
    """One item, in a worker: measure an acquisition (``kind`` "measure") or compare two
    result folders ("compare") into ``out`` (staged, with its stamp inside). Returns
    ("done", "") or ("failed", message); never raises for a bad input."""
    from skintopo.outputs import staged_output_folder
    from skintopo.pipeline import compare_results, measure_acquisition
    from skintopo.results import write_comparison, write_measurement

    options = MeasureOptions.from_dict(options)
    try:
        if kind == "measure":
            result = measure_acquisition(inputs[0], options)
        elif kind == "compare":
            result = compare_results(*inputs, segmentation=options.segmentation, wrinkles=options.wrinkles, pores=options.pores)
        else:
            raise ValueError(f"unknown kind of item {kind!r} (measure or compare)")
        with staged_output_folder(out, overwrite=True) as staging:
            if kind == "measure":
                write_measurement(staging, result, title=f"skintopo: {Path(inputs[0]).name}")
            else:
                write_comparison(staging, result.comparison, result.rows, result.summary, result.spacing)
            (staging / STAMP).write_text(json.dumps({"fingerprint": stamp, "skintopo_version": __version__}) + "\n")
        return "done", ""
    except SkinTopoError as exc:
        return "failed", str(exc)
    except Exception as exc:  # noqa: BLE001 - a study must go on; the error is recorded
        return "failed", f"{exc.__class__.__name__}: {exc}"


def _worker_start(parent, blas_threads):
    """In each local worker: leave Ctrl-C to the parent (which stops the workers itself), and
    exit when the parent (pid ``parent``) dies, however it died: Linux's parent-death signal,
    and a watch of the parent's pid where that is not available. With several workers, BLAS
    keeps to ``blas_threads`` per worker: OpenBLAS's idle threads spin and would take the
    cores the other workers need."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    if blas_threads is not None:
        from threadpoolctl import threadpool_limits

        threadpool_limits(limits=blas_threads, user_api="blas")
    try:
        import ctypes

        ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG = 1
    except (OSError, AttributeError):
        pass
    if os.getppid() != parent:  # the parent died before the signal was armed
        os._exit(1)

    def watch():
        while True:
            threading.Event().wait(0.5)
            if os.getppid() != parent:
                os._exit(1)

    threading.Thread(target=watch, daemon=True).start()


class LocalRunner:
    """Local worker processes (concurrent.futures, spawned: a clean interpreter each)."""

    def __init__(self, workers):
        import multiprocessing
        from concurrent.futures import ProcessPoolExecutor

        if not isinstance(workers, int) or workers < 1:
            raise SkinTopoError(f"--workers must be 1 or more, got {workers}")
        self.pool = ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context("spawn"),
                                        initializer=_worker_start, initargs=(os.getpid(), 1 if workers > 1 else None))

    def submit(self, *args):
        return self.pool.submit(run_task, *args)

    def as_completed(self, futures):
        from concurrent.futures import as_completed

        return as_completed(futures)

    def close(self, interrupted=False):
        if interrupted:  # stop now: unfinished items are redone by the next run
            for process in list((getattr(self.pool, "_processes", None) or {}).values()):
                process.kill()
        self.pool.shutdown(wait=True, cancel_futures=True)  # a second call does nothing


class DaskRunner:
    """An existing Dask distributed cluster, by scheduler address. A worker lost in the
    middle of an item makes the scheduler run that item again elsewhere; the item's staging
    folder makes the result appear once."""

    def __init__(self, address, timeout=DEFAULT_SCHEDULER_TIMEOUT_S):
        try:
            from distributed import Client
        except ImportError:
            raise SkinTopoError("--scheduler needs the 'distributed' package: pip install 'skintopo[cluster]'") from None
        try:
            self.client = Client(address, timeout=f"{timeout}s")
        except (OSError, TimeoutError, ValueError) as error:
            raise SkinTopoError(f"cannot reach the Dask scheduler at {address} within {timeout:g} s "
                                f"({error.__class__.__name__}); is it running? (--scheduler-timeout to wait longer)") from None

    def submit(self, *args):
        return self.client.submit(run_task, *args, pure=False)

    def as_completed(self, futures):
        from distributed import as_completed

        return as_completed(futures)

    def close(self, interrupted=False):
        self.client.close()  # a second call does nothing


class BatchInterrupted(KeyboardInterrupt):
    """A study stopped by SIGINT or SIGTERM; ``counts`` says what was done."""

    def __init__(self, signal_number, counts):
        super().__init__(signal_number)
        self.signal_number = signal_number
        self.counts = counts


@contextmanager
def _interruptible():
    """SIGTERM behaves as Ctrl-C while a study runs (main thread only)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def stop(number, _frame):
        raise KeyboardInterrupt(number)

    previous = signal.signal(signal.SIGTERM, stop)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


@contextmanager
def _locked(out):
    """Hold ``out/.lock`` for the run; a second run on the same folder fails at once."""
    import fcntl

    handle = open(Path(out) / LOCK, "a+")
    try:
        fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        handle.close()
        raise SkinTopoError(f"{out}: another skintopo batch is writing this study folder; wait for it or choose another -o") from None
    try:
        yield
    finally:
        handle.close()


def _remove_staging_leftovers(out):
    for leftover in Path(out).glob("*/**/.*.partial"):  # staging folders of a run that was killed
        shutil.rmtree(leftover, ignore_errors=True)


@dataclass
class _Task:
    item: StudyItem
    kind: str  # measure, compare, repeat
    inputs: list
    out: Path
    stamp: str


def _relative(message, roots):
    for root, name in roots:
        message = message.replace(str(root) + os.sep, name).replace(str(root), name or ".")
    return message


def run_study(study_path, out, *, options: MeasureOptions = MeasureOptions(), workers=1, scheduler=None,
              scheduler_timeout=DEFAULT_SCHEDULER_TIMEOUT_S, force=False, progress=None):
    """Measure and compare a whole study into ``out``.

    Returns ``(counts, tables, failures)``: counts of computed, skipped and failed items,
    the tables' paths, and one record per failed item. Raises :class:`BatchInterrupted`
    on SIGINT / SIGTERM after stopping the workers, and :class:`SkinTopoError` (with nothing
    written) for a bad study, output folder, worker count or unreachable scheduler.
    """
    study = read_study(study_path)
    check_study_output(study_path, study, out)
    out = Path(out).resolve()
    settings = {"skintopo_version": __version__, "options": options.as_dict()}
    runner = DaskRunner(scheduler, scheduler_timeout) if scheduler else LocalRunner(workers)
    counts = {"computed": 0, "skipped": 0, "failed": 0}
    failures, interrupted = [], None
    roots = [(Path(study_path).resolve().parent, ""), (out, "")]
    try:
        out.mkdir(parents=True, exist_ok=True)
        with _locked(out), _interruptible():
            _remove_staging_leftovers(out)
            try:
                stages = (_measure_tasks, _compare_tasks)
                for make_tasks in stages:
                    tasks = make_tasks(study, out, settings)
                    pending = []
                    for task in tasks:
                        if not force and _finished(task.out, task.stamp):
                            counts["skipped"] += 1
                        else:
                            pending.append(task)
                    for task, (status, message) in _run(runner, pending, settings["options"], progress):
                        if status == "done":
                            counts["computed"] += 1
                            continue
                        counts["failed"] += 1
                        shutil.rmtree(task.out, ignore_errors=True)  # no stale result stays beside a failure
                        failures.append({"subject": task.item.subject, "visit": task.item.visit, "region": task.item.region,
                                         "step": task.kind, "error": _relative(message, roots)})
            except KeyboardInterrupt as stop:
                interrupted = stop.args[0] if stop.args else signal.SIGINT
            finally:
                runner.close(interrupted=interrupted is not None)
                _remove_staging_leftovers(out)
            if interrupted is not None:
                raise BatchInterrupted(interrupted, counts)
            tables = write_tables(study, out, failures, options=options)
    finally:
        runner.close()
    return counts, tables, failures


def _measure_tasks(study, out, settings):
    tasks = []
    for item in study:
        for acquisition, key, kind in ((item.acquisition, item.key, "measure"), (item.repeat, item.repeat_key, "measure")):
            if acquisition is not None:
                stamp = fingerprint([acquisition], settings | {"kind": kind})
                tasks.append(_Task(item, kind, [acquisition], out.joinpath("items", *key), stamp))
    return tasks


def _compare_tasks(study, out, settings):
    """Follow-up vs baseline (``changes/``) and visit vs its repeat capture (``repeats/``),
    where both measures exist."""
    by_key = {(i.subject, i.region, i.visit): i for i in study}
    pairs = []
    for item in study:
        if item.baseline is not None:
            base = by_key[(item.subject, item.region, item.baseline)]
            pairs.append((item, "compare", out.joinpath("items", *base.key), out.joinpath("items", *item.key), out.joinpath("changes", *item.key)))
        if item.repeat is not None:
            pairs.append((item, "repeat", out.joinpath("items", *item.key), out.joinpath("items", *item.repeat_key), out.joinpath("repeats", *item.key)))
    tasks = []
    for item, kind, before, after, folder in pairs:
        inputs = [before / "height.x3p", after / "height.x3p"]
        if all((p.parent / STAMP).is_file() for p in inputs):
            tasks.append(_Task(item, kind, [before, after], folder, fingerprint(inputs, settings | {"kind": "compare"})))
        else:  # a measure failed (recorded there): an earlier comparison of these visits is stale
            shutil.rmtree(folder, ignore_errors=True)
    return tasks


def _run(runner, tasks, options, progress):
    """Yield (task, (status, message)) as the tasks finish."""
    futures = {runner.submit("measure" if task.kind == "measure" else "compare", task.inputs, task.out, task.stamp, options): task
               for task in tasks}
    for future in runner.as_completed(list(futures)):
        task = futures[future]
        try:
            outcome = future.result()
        except Exception as exc:  # noqa: BLE001 - a worker lost for good (killed, out of memory): recorded, the study goes on
            outcome = ("failed", f"the worker running this item was lost ({exc.__class__.__name__}: {exc})")
        if progress:
            progress(task.item, task.kind, outcome[0])
        yield task, outcome


def write_tables(study, out, failures, *, options=None):
    """results.csv (wide), results_long.csv, results.parquet, changes.csv, statistics.csv,
    failures.csv, summary.json and summary.html from the finished items."""
    import pandas as pd

    from skintopo.formats import atomic_write
    from skintopo.results import read_change_rows, read_measurement_values
    from skintopo.study import study_statistics, summary_html

    long_rows, change_rows, repeat_rows = [], [], []
    for item in study:
        folder = out.joinpath("items", *item.key)
        if (folder / STAMP).is_file():
            values, units = read_measurement_values(folder)
            long_rows += [{"subject": item.subject, "visit": item.visit, "region": item.region, "parameter": name,
                           "value": value, "unit": units[name]} for name, value in values.items()]
        for kind, rows, base_visit in (("changes", change_rows, item.baseline), ("repeats", repeat_rows, item.visit)):
            changes = out.joinpath(kind, *item.key)
            if (changes / STAMP).is_file():
                rows += [{"subject": item.subject, "region": item.region, "baseline_visit": base_visit, "visit": item.visit,
                          **{k: row[k] for k in ("parameter", "baseline", "follow_up", "change", "change_percent")}}
                         for row in read_change_rows(changes)]
    long = pd.DataFrame(long_rows, columns=["subject", "visit", "region", "parameter", "value", "unit"])
    # pivot, not pivot_table: a parameter that is NaN at every visit keeps its column
    wide = long.pivot(index=["subject", "visit", "region"], columns="parameter", values="value").reset_index()
    wide.columns.name = None
    long = long.sort_values(["subject", "region", "visit", "parameter"]).reset_index(drop=True)
    wide = wide.sort_values(["subject", "region", "visit"]).reset_index(drop=True)
    change_columns = ["subject", "region", "baseline_visit", "visit", "parameter", "baseline", "follow_up", "change", "change_percent"]
    changes = pd.DataFrame(change_rows, columns=change_columns).sort_values(["subject", "region", "visit", "parameter"]).reset_index(drop=True)
    repeats = pd.DataFrame(repeat_rows, columns=change_columns)
    units = dict(zip(long.parameter, long.unit))
    visits = {key: set(group.subject) for key, group in long.groupby(["region", "visit"])}
    statistics = study_statistics(changes, repeats, units, visits)
    failure_table = pd.DataFrame(failures, columns=["subject", "visit", "region", "step", "error"]).sort_values(["subject", "visit", "region", "step"])
    reports = {(i.subject, i.region, i.visit): "/".join(("items", *i.key, "report.html")) for i in study
               if (out.joinpath("items", *i.key) / STAMP).is_file()}
    summary = {"skintopo_version": __version__, "items": len(study), "measured": len(reports), "failed": len(failures),
               "options": options.as_dict() if options is not None else None,
               "detection_limit": "ISO 5725-6 repeatability limit r = 2.8 s_r, s_r pooled over the study's repeat pairs"}
    paths = {name: out / name for name in ("results.csv", "results_long.csv", "results.parquet", "changes.csv", "statistics.csv",
                                           "failures.csv", "summary.json", "summary.html")}
    atomic_write(paths["results.csv"], lambda tmp: wide.to_csv(tmp, index=False))
    atomic_write(paths["results_long.csv"], lambda tmp: long.to_csv(tmp, index=False))
    atomic_write(paths["results.parquet"], lambda tmp: long.to_parquet(tmp, index=False))
    atomic_write(paths["changes.csv"], lambda tmp: changes.to_csv(tmp, index=False))
    atomic_write(paths["statistics.csv"], lambda tmp: statistics.to_csv(tmp, index=False))
    atomic_write(paths["failures.csv"], lambda tmp: failure_table.to_csv(tmp, index=False))
    atomic_write(paths["summary.json"], lambda tmp: Path(tmp).write_text(json.dumps(summary, indent=2) + "\n", encoding="utf-8"))
    page = summary_html(long, changes, statistics, failure_table, reports)
    atomic_write(paths["summary.html"], lambda tmp: Path(tmp).write_text(page, encoding="utf-8"))
    return paths
