"""Study-scale batch: every acquisition of a study measured, every follow-up compared with its
baseline, on local processes or a Dask cluster, resumable, with one tidy table.

Study file (CSV): columns ``subject``, ``visit``, ``region``, ``acquisition`` (folder,
relative to the study file), optional ``baseline`` (the visit to compare with; default: the
subject's first listed visit of that region). All rows are validated before anything runs.

Each item runs the same code as ``skintopo measure`` (and ``skintopo compare``), into
``OUT/items/<subject>/<region>/<visit>/`` (``OUT/changes/...``), written to a temporary
folder and renamed into place when complete, then stamped with ``batch.json`` holding the
item's fingerprint: SHA-256 over the settings and the name, size and content of every input
file. A rerun skips items whose stamp matches and redoes missing, failed or changed ones; an
interrupted run leaves no half-written item. One failing item is recorded in
``failures.csv`` and never stops the others.
"""

from __future__ import annotations

import csv
import hashlib
import json
import re
import shutil
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from skintopo.errors import SkinTopoError

STAMP = "batch.json"
_SAFE = re.compile(r"[^A-Za-z0-9_.-]+")


@dataclass(frozen=True)
class StudyItem:
    subject: str
    visit: str
    region: str
    acquisition: Path
    baseline: str | None  # the baseline visit of a follow-up, None for a baseline

    @property
    def key(self):
        return tuple(_SAFE.sub("_", part) for part in (self.subject, self.region, self.visit))


def read_study(path):
    """Parse and validate a study CSV; every problem is reported at once."""
    path = Path(path)
    if not path.is_file():
        raise SkinTopoError(f"{path}: no such study file")
    with open(path, newline="", encoding="utf-8") as stream:
        rows = list(csv.DictReader(stream))
    problems = []
    required = ("subject", "visit", "region", "acquisition")
    columns = set(rows[0]) if rows else set()
    missing = [c for c in required if c not in columns]
    if not rows or missing:
        raise SkinTopoError(f"{path}: the study needs the columns {list(required)} (missing {missing or 'all rows'})")
    items, seen, first_visit = [], set(), {}
    for number, row in enumerate(rows, start=2):  # line 1 is the header
        values = {c: (row.get(c) or "").strip() for c in (*required, "baseline")}
        empty = [c for c in required if not values[c]]
        if empty:
            problems.append(f"{path.name}: line {number}: empty {', '.join(empty)}")
            continue
        folder = (path.parent / values["acquisition"]).resolve()
        if not folder.is_dir():
            problems.append(f"{path.name}: line {number}: acquisition folder {values['acquisition']!r} not found")
        key = (values["subject"], values["region"], values["visit"])
        if key in seen:
            problems.append(f"{path.name}: line {number}: subject {key[0]} region {key[1]} visit {key[2]} listed twice")
        seen.add(key)
        first_visit.setdefault((values["subject"], values["region"]), values["visit"])
        items.append((number, values, folder))
    study = []
    for number, values, folder in items:
        group = (values["subject"], values["region"])
        baseline = values["baseline"] or first_visit[group]
        if (values["subject"], values["region"], baseline) not in seen:
            problems.append(f"{path.name}: line {number}: baseline visit {baseline!r} of subject {group[0]} region {group[1]} is not in the study")
        study.append(StudyItem(values["subject"], values["visit"], values["region"], folder, None if baseline == values["visit"] else baseline))
    if problems:
        raise SkinTopoError(f"{path}: {len(problems)} problem(s) in the study:\n" + "\n".join(f"  - {p}" for p in problems))
    return study


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
    marker = Path(folder) / STAMP
    try:
        return json.loads(marker.read_text())["fingerprint"] == stamp
    except (OSError, ValueError, KeyError):
        return False


def run_task(kind, inputs, out, stamp, extra):
    """One item, in a worker process: ``skintopo measure`` or ``compare`` into ``out``, then
    the stamp. Returns (status, message); never raises for a bad input."""
    from skintopo.cli import build_parser

    out = Path(out)
    arguments = [kind, *map(str, inputs), "-o", str(out), "-q", "--overwrite", *extra]
    try:
        args = build_parser().parse_args(arguments)
        args.handler(args)
        (out / STAMP).write_text(json.dumps({"fingerprint": stamp, "finished": time.time()}) + "\n")
        return "done", ""
    except SkinTopoError as exc:
        return "failed", str(exc)
    except Exception as exc:  # noqa: BLE001 - a study must go on; the error is recorded
        return "failed", f"{exc.__class__.__name__}: {exc}"


class LocalRunner:
    """Local worker processes (concurrent.futures)."""

    def __init__(self, workers):
        from concurrent.futures import ProcessPoolExecutor

        self.pool = ProcessPoolExecutor(max_workers=workers)

    def submit(self, *args):
        return self.pool.submit(run_task, *args)

    def as_completed(self, futures):
        from concurrent.futures import as_completed

        return as_completed(futures)

    def close(self):
        self.pool.shutdown(cancel_futures=True)


class DaskRunner:
    """An existing Dask distributed cluster, by scheduler address."""

    def __init__(self, address):
        from distributed import Client

        self.client = Client(address)

    def submit(self, *args):
        return self.client.submit(run_task, *args, pure=False)

    def as_completed(self, futures):
        from distributed import as_completed

        return as_completed(futures)

    def close(self):
        self.client.close()


def _run(runner, tasks, progress):
    """Run (item, kind, inputs, out, stamp, extra) tasks; return {out: (status, message)}."""
    futures = {runner.submit(kind, inputs, out, stamp, extra): (item, out) for item, kind, inputs, out, stamp, extra in tasks}
    results = {}
    for future in runner.as_completed(list(futures)):
        item, out = futures[future]
        results[out] = future.result()
        if progress:
            progress(item, results[out][0])
    return results


def run_study(study_path, out, *, workers=1, scheduler=None, progress=None):
    """Measure and compare a whole study into ``out``. Returns counts and the tables' paths."""
    study = read_study(study_path)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    for leftover in out.glob("*/**/.*.partial"):  # staging folders of a run that was killed
        shutil.rmtree(leftover, ignore_errors=True)
    settings = {"measure": [], "compare": [], "version": 1}
    runner = DaskRunner(scheduler) if scheduler else LocalRunner(workers)
    counts = {"computed": 0, "skipped": 0, "failed": 0}
    failures = []
    try:
        measure_tasks = []
        for item in study:
            folder = out.joinpath("items", *item.key)
            stamp = fingerprint([item.acquisition], settings | {"kind": "measure"})
            if _finished(folder, stamp):
                counts["skipped"] += 1
                continue
            measure_tasks.append((item, "measure", [item.acquisition], folder, stamp, settings["measure"]))
        outcomes = _run(runner, measure_tasks, progress)
        compare_tasks = []
        by_key = {(i.subject, i.region, i.visit): i for i in study}
        for item in study:
            if item.baseline is None:
                continue
            base = out.joinpath("items", *by_key[(item.subject, item.region, item.baseline)].key)
            follow = out.joinpath("items", *item.key)
            if not ((base / "height.x3p").is_file() and (follow / "height.x3p").is_file()):
                continue  # a failed measurement: recorded there
            folder = out.joinpath("changes", *item.key)
            stamp = fingerprint([base / "height.x3p", follow / "height.x3p"], settings | {"kind": "compare"})
            if _finished(folder, stamp):
                counts["skipped"] += 1
                continue
            compare_tasks.append((item, "compare", [base / "height.x3p", follow / "height.x3p"], folder, stamp, settings["compare"]))
        outcomes.update(_run(runner, compare_tasks, progress))
    finally:
        runner.close()
    for task in (*measure_tasks, *compare_tasks):
        status, message = outcomes[task[3]]
        counts["computed" if status == "done" else "failed"] += 1
        if status != "done":
            shutil.rmtree(task[3], ignore_errors=True)  # no partial item left behind
            failures.append({"subject": task[0].subject, "visit": task[0].visit, "region": task[0].region, "step": task[1], "error": message})
    tables = write_tables(study, out, failures)
    return counts, tables


def _parameters(folder):
    data = json.loads((folder / "parameters.json").read_text())
    values = {f"{p['name']}" if p["region"] == "field" else f"{p['region']}.{p['name']}": p["value"] for p in data["parameters"]}
    units = {f"{p['name']}" if p["region"] == "field" else f"{p['region']}.{p['name']}": p["unit"] for p in data["parameters"]}
    totals = json.loads((folder / "wrinkles.json").read_text())["totals"]
    for name, unit in (("count", ""), ("total_length_mm", "mm"), ("mean_depth_um", "um"), ("area_fraction", "")):
        values[f"wrinkles.{name}"], units[f"wrinkles.{name}"] = totals[name], unit
    return values, units


def write_tables(study, out, failures):
    """results.csv (wide), results_long.csv, results.parquet, changes.csv, failures.csv and
    summary.html from the finished items."""
    import pandas as pd

    long_rows, change_rows = [], []
    for item in study:
        folder = out.joinpath("items", *item.key)
        if (folder / STAMP).is_file():
            values, units = _parameters(folder)
            long_rows += [{"subject": item.subject, "visit": item.visit, "region": item.region, "parameter": name,
                           "value": value, "unit": units[name]} for name, value in values.items()]
        changes = out.joinpath("changes", *item.key)
        if (changes / STAMP).is_file():
            for row in json.loads((changes / "changes.json").read_text())["changes"]:
                change_rows.append({"subject": item.subject, "region": item.region, "baseline_visit": item.baseline, "visit": item.visit,
                                    **{k: row[k] for k in ("parameter", "baseline", "follow_up", "change", "change_percent")}})
    long = pd.DataFrame(long_rows, columns=["subject", "visit", "region", "parameter", "value", "unit"])
    wide = long.pivot_table(index=["subject", "visit", "region"], columns="parameter", values="value", aggfunc="first").reset_index()
    wide.columns.name = None
    long = long.sort_values(["subject", "region", "visit", "parameter"]).reset_index(drop=True)
    wide = wide.sort_values(["subject", "region", "visit"]).reset_index(drop=True)
    changes = pd.DataFrame(change_rows, columns=["subject", "region", "baseline_visit", "visit", "parameter", "baseline", "follow_up", "change", "change_percent"])
    changes = changes.sort_values(["subject", "region", "visit", "parameter"]).reset_index(drop=True)
    failure_table = pd.DataFrame(failures, columns=["subject", "visit", "region", "step", "error"]).sort_values(["subject", "visit", "region", "step"])
    paths = {name: out / name for name in ("results.csv", "results_long.csv", "results.parquet", "changes.csv", "failures.csv", "summary.html")}
    from skintopo.formats import atomic_write

    atomic_write(paths["results.csv"], lambda tmp: wide.to_csv(tmp, index=False))
    atomic_write(paths["results_long.csv"], lambda tmp: long.to_csv(tmp, index=False))
    atomic_write(paths["results.parquet"], lambda tmp: long.to_parquet(tmp, index=False))
    atomic_write(paths["changes.csv"], lambda tmp: changes.to_csv(tmp, index=False))
    atomic_write(paths["failures.csv"], lambda tmp: failure_table.to_csv(tmp, index=False))
    atomic_write(paths["summary.html"], lambda tmp: Path(tmp).write_text(_summary_html(long, changes, failure_table), encoding="utf-8"))
    return paths


def _summary_html(long, changes, failures):
    """Study summary: distributions of key parameters per visit, change per subject."""
    import base64
    import html
    import io

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    key = ["Sa", "Sq", "Vvv", "wrinkles.mean_depth_um"]
    figure, axes = plt.subplots(1, len(key), figsize=(4 * len(key), 3.5))
    for axis, name in zip(np.atleast_1d(axes), key):
        subset = long[long.parameter == name]
        visits = sorted(subset.visit.unique())
        axis.boxplot([subset[subset.visit == v].value.dropna().astype(float) for v in visits], tick_labels=visits)
        axis.set(title=name, xlabel="visit")
    figure.tight_layout()
    buffer = io.BytesIO()
    figure.savefig(buffer, format="png", dpi=90)
    plt.close(figure)
    picture = base64.b64encode(buffer.getvalue()).decode("ascii")
    depth = changes[changes.parameter.str.endswith(".max_depth_um")] if len(changes) else changes
    rows = "".join(
        "<tr>" + "".join(f"<td>{html.escape(str(v))}</td>" for v in (r.subject, r.region, r.baseline_visit, r.visit, r.parameter, f"{r.change_percent:+.1f}%"))
        + "</tr>" for r in depth.itertuples()
    )
    failed = "".join(f"<li>{html.escape(f'{r.subject} {r.visit} {r.region} ({r.step}): {r.error}')}</li>" for r in failures.itertuples())
    return (
        "<!DOCTYPE html><html lang=en><head><meta charset=utf-8>"
        "<meta http-equiv='Content-Security-Policy' content=\"default-src 'none'; img-src data:; style-src 'unsafe-inline'\">"
        "<title>skintopo study summary</title><style>body{font-family:sans-serif;margin:2em} td{border:1px solid #ccc;padding:2px 6px}</style>"
        f"</head><body><h1>Study summary</h1><h2>Parameters per visit</h2><img alt='distributions' src='data:image/png;base64,{picture}'>"
        f"<h2>Wrinkle depth change per subject</h2><table><tr><th>subject</th><th>region</th><th>baseline</th><th>visit</th><th>wrinkle</th><th>change</th></tr>{rows}</table>"
        f"<h2>Failures</h2><ul>{failed or '<li>none</li>'}</ul></body></html>"
    )
