"""Study-scale batch runs: local processes and Dask, killed workers, signals, resumption and fingerprints."""

import fcntl
import hashlib
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

import skintopo.batch
from skintopo.batch import run_study
from skintopo.errors import SkinTopoError
from skintopo.pipeline import HeightOptions, MeasureOptions, SegmentationOptions, WrinkleOptions
from tests.helpers import browser
from tests.helpers.study import InProcessRunner, write_study

CLI = [sys.executable, "-m", "skintopo.cli"]


@pytest.fixture(scope="module")
def study(tmp_path_factory):
    """2 subjects x 3 visits at 128 px, one acquisition corrupt."""
    path = write_study(tmp_path_factory.mktemp("study"), ["S01", "S02"], size_px=128)
    (path.parent / "S02_v3" / "red_01.png").write_bytes(b"\\x89PNG broken")
    return path


@pytest.fixture(scope="module")
def twelve(tmp_path_factory):
    """4 subjects x 3 visits at 96 px: the fault-injection study."""
    return write_study(tmp_path_factory.mktemp("twelve"), ["A", "B", "C", "D"])


def tables(out):
    return {name: pd.read_csv(out / name) for name in ("results.csv", "changes.csv", "failures.csv")}


def descendants(pid):
    """Every process below ``pid`` (from /proc)."""
    found, queue = [], [pid]
    while queue:
        parent = queue.pop()
        for task in Path(f"/proc/{parent}/task").glob("*"):
            try:
                children = [int(c) for c in (task / "children").read_text().split()]
            except OSError:
                continue
            found += children
            queue += children
    return found


def assert_gone(pids, within=5.0):
    deadline = time.time() + within
    alive = list(pids)
    while alive and time.time() < deadline:
        alive = [p for p in alive if Path(f"/proc/{p}").exists() and "Z" not in _state(p)]
        time.sleep(0.1)
    assert not alive, f"orphan processes left: {alive}"


def _state(pid):
    try:
        return Path(f"/proc/{pid}/stat").read_text().split(")")[-1].split()[0]
    except OSError:
        return "Z"


def finished_results(out, pattern="items/*/*/*/batch.json"):
    """Stamps of published results; a stamp inside a staging folder (``.NAME.partial``) is not
    one yet (the item is written whole in staging, stamp included, then renamed)."""
    return [p for p in out.glob(pattern) if not any(part.startswith(".") for part in p.relative_to(out).parts)]


def assert_items_complete(out):
    """Every visible item folder is complete (stamped, with its files); staging folders aside."""
    for kind, needed in (("items", "parameters.json"), ("changes", "changes.json")):
        for folder in out.glob(f"{kind}/*/*/*"):
            if folder.name.startswith("."):
                continue
            assert (folder / "batch.json").is_file() and (folder / needed).is_file(), folder


@pytest.fixture(scope="module")
def local_run(study, tmp_path_factory):
    out = tmp_path_factory.mktemp("local") / "out"
    run = subprocess.run([*CLI, "batch", str(study), "-o", str(out), "--workers", "2"], capture_output=True, text=True, timeout=600)
    return out, run


@pytest.mark.slow
def test_local_processes(study, local_run):
    out, run = local_run
    assert run.returncode == 1, run.stderr  # one item failed: the exit status says so
    failed_lines = [line for line in run.stderr.splitlines() if line.startswith("failed:")]
    assert len(failed_lines) == 1 and failed_lines[0].startswith("failed: S02 V3 forehead (measure):") and "red_01.png" in failed_lines[0]
    assert "computed 8, skipped (already done) 0, failed 1" in run.stdout  # 5 of 6 measures + 3 compares
    t = tables(out)
    assert len(t["results.csv"]) == 5 and set(t["results.csv"].subject) == {"S01", "S02"}
    failures = t["failures.csv"]
    assert len(failures) == 1 and failures.iloc[0].visit == "V3" and "red_01.png" in failures.iloc[0].error
    assert set(t["changes.csv"].visit) == {"V2", "V3"} and len(t["changes.csv"][t["changes.csv"].subject == "S02"].visit.unique()) == 1
    assert (out / "results.parquet").stat().st_size > 0 and (out / "summary.html").stat().st_size > 10_000
    depth = t["changes.csv"]
    s01 = depth[(depth.subject == "S01") & (depth.parameter == "wrinkles.mean_depth_um")]
    assert (s01.change_percent < 0).all()  # the wrinkles were made shallower at every visit
    np.testing.assert_allclose(depth.change, depth.follow_up - depth.baseline, rtol=1e-12)
    np.testing.assert_allclose(depth.change_percent, 100 * depth.change / depth.baseline.abs(), rtol=1e-12)  # + = an increase
    for row in t["results.csv"].itertuples(index=False):  # every number of results.csv is its visit's measure
        item = json.loads((out / "items" / row.subject / row.region / row.visit / "parameters.json").read_text())
        expected = {p["name"]: p["value"] for p in item["parameters"] if p["region"] == "field"}
        expected.update({f"wrinkles.{k}": v for k, v in item["summary"]["wrinkle_totals"].items() if k != "mean_orientation_deg"})
        values = dict(zip(t["results.csv"].columns, row))
        for name, value in expected.items():
            assert values[name] == pytest.approx(value, rel=1e-12, nan_ok=True), (row.subject, row.visit, name)
    long = pd.read_csv(out / "results_long.csv").pivot(index=["subject", "visit", "region"], columns="parameter", values="value")
    wide = t["results.csv"].set_index(["subject", "visit", "region"])
    pd.testing.assert_frame_equal(long[wide.columns].sort_index(), wide.sort_index(), check_names=False, check_dtype=False)
    study_summary = json.loads((out / "summary.json").read_text())
    assert (study_summary["items"], study_summary["measured"], study_summary["failed"]) == (6, 5, 1)
    # privacy: no absolute path of the study (or of anything else under it) in any output
    root = str(study.parent)
    for file in out.rglob("*"):
        if file.is_file():
            assert root.encode() not in file.read_bytes(), file
    summary = json.loads((out / "summary.json").read_text())
    assert summary["options"]["height"]["method"] == "auto" and summary["skintopo_version"] == skintopo.batch.__version__


@pytest.mark.slow
def test_dask_local_cluster_gives_identical_tables(study, local_run, tmp_path):
    distributed = pytest.importorskip("distributed")
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster:
        counts, _, failures = run_study(study, tmp_path / "dask", scheduler=cluster.scheduler_address)
    assert counts == {"computed": 8, "skipped": 0, "failed": 1} and len(failures) == 1
    for name, table in tables(tmp_path / "dask").items():
        pd.testing.assert_frame_equal(table, tables(local_run[0])[name])


@pytest.mark.slow
def test_dask_worker_killed_mid_study_loses_and_duplicates_nothing(twelve, tmp_path):
    distributed = pytest.importorskip("distributed")
    reference = tmp_path / "reference"
    run_study(twelve, reference, workers=2)
    out = tmp_path / "dask"
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster:
        outcome = {}
        thread = threading.Thread(target=lambda: outcome.update(result=run_study(twelve, out, scheduler=cluster.scheduler_address)))
        thread.start()
        deadline = time.time() + 120
        while time.time() < deadline and not finished_results(out):
            time.sleep(0.05)
        with distributed.Client(cluster) as client:
            victim = next(iter(client.run(os.getpid).values()))
        os.kill(victim, signal.SIGKILL)  # in the middle of the study
        thread.join(timeout=300)
    counts, _, failures = outcome["result"]
    assert failures == [] and counts["failed"] == 0 and counts["computed"] == 20  # 12 measures + 8 compares, each once
    assert_items_complete(out)
    assert (out / "results.csv").read_bytes() == (reference / "results.csv").read_bytes()
    assert (out / "changes.csv").read_bytes() == (reference / "changes.csv").read_bytes()
    assert not list(out.glob("**/.*.partial"))


@pytest.mark.slow
def test_sigkill_at_random_moments_then_resume_gives_identical_results(twelve, tmp_path):
    reference = tmp_path / "reference"
    assert subprocess.run([*CLI, "batch", str(twelve), "-o", str(reference), "-q"], timeout=600).returncode == 0
    out = tmp_path / "killed"
    rng = np.random.default_rng(20261201)
    for _ in range(10):
        process = subprocess.Popen([*CLI, "batch", str(twelve), "-o", str(out), "-q"], stderr=subprocess.DEVNULL)
        time.sleep(rng.uniform(0.5, 5.0))
        children = descendants(process.pid)
        process.kill()  # SIGKILL: nothing in skintopo runs after it
        process.wait(timeout=30)
        assert_gone(children)
        assert_items_complete(out)
    assert subprocess.run([*CLI, "batch", str(twelve), "-o", str(out), "-q"], timeout=600).returncode == 0
    for name in ("results.csv", "changes.csv", "results_long.csv", "statistics.csv"):
        assert (out / name).read_bytes() == (reference / name).read_bytes(), name
    assert not list(out.glob("**/.*.partial"))


@pytest.mark.slow
def test_sigterm_stops_the_workers_at_once_and_a_rerun_finishes(twelve, tmp_path):
    out = tmp_path / "out"
    process = subprocess.Popen([*CLI, "batch", str(twelve), "-o", str(out), "-q"], stderr=subprocess.PIPE, text=True)
    deadline = time.time() + 120
    while time.time() < deadline and not finished_results(out):
        time.sleep(0.05)
    children = descendants(process.pid)
    assert children
    sent = time.time()
    process.send_signal(signal.SIGTERM)
    stderr = process.communicate(timeout=30)[1]
    assert time.time() - sent < 3.0  # no waiting for running items
    assert process.returncode == 128 + signal.SIGTERM and "interrupted" in stderr and "run the same command again" in stderr
    assert_gone(children)
    assert_items_complete(out)
    finished = len(finished_results(out))
    assert 1 <= finished < 12
    counts, _, _ = run_study(twelve, out, workers=2)
    assert counts["skipped"] == finished and counts["computed"] == 20 - finished


@pytest.mark.slow
def test_interrupted_batch_resumes_without_recomputing(study, local_run, tmp_path):
    out = tmp_path / "interrupted"
    process = subprocess.Popen([*CLI, "batch", str(study), "-o", str(out), "--workers", "1", "-q"], start_new_session=True,
                               stderr=subprocess.DEVNULL)
    deadline = time.time() + 120
    while time.time() < deadline and len(finished_results(out)) < 2:
        time.sleep(0.1)
    os.killpg(process.pid, signal.SIGINT)  # Ctrl-C, to the whole process group as a terminal would
    process.wait(timeout=60)
    # every finished result, measures (items/) and comparisons (changes/, repeats/): on a loaded
    # machine the run may get further than the first two measures before the signal lands
    finished = len(finished_results(out, "*/*/*/*/batch.json"))
    assert finished >= 2
    assert not list(out.glob("items/**/.*.partial"))  # nothing half-written
    counts, _, _ = run_study(study, out, workers=2)
    assert counts["skipped"] == finished and counts["computed"] + counts["skipped"] == 8
    for name, table in tables(out).items():
        pd.testing.assert_frame_equal(table, tables(local_run[0])[name])


@pytest.mark.slow
def test_fingerprint_recomputes_exactly_the_affected_items(tmp_path, monkeypatch):
    study_path = write_study(tmp_path / "study", ["S"], size_px=96)
    out = tmp_path / "out"

    def run(**options):
        counts, _, failures = run_study(study_path, out, workers=1, **options)
        assert failures == []
        return counts["computed"], counts["skipped"]

    assert run() == (5, 0)  # 3 measures + 2 compares
    assert run() == (0, 5)
    monkeypatch.setattr(skintopo.batch, "__version__", "99.0")  # an upgrade
    assert run() == (5, 0)
    assert run() == (0, 5)
    manifest = study_path.parent / "S_v3" / "acquisition.json"  # one byte changed, same size: that visit and its compare
    text = manifest.read_text()
    manifest.write_text(text.replace("synthetic skin", "synthetiC skin"))
    assert manifest.stat().st_size == len(text.encode())
    assert run() == (2, 3)
    (study_path.parent / "S_v2" / "red_01.png").write_bytes(b"broken")  # a visit that now fails: its stale compare goes too
    counts, _, failures = run_study(study_path, out, workers=1)
    assert counts == {"computed": 0, "skipped": 3, "failed": 1} and [f["visit"] for f in failures] == ["V2"]
    assert not (out / "changes" / "S" / "forehead" / "V2").exists() and not (out / "items" / "S" / "forehead" / "V2").exists()
    assert set(pd.read_csv(out / "changes.csv").visit) == {"V3"}
    shutil.rmtree(study_path.parent / "S_v2")
    shutil.copytree(study_path.parent / "S_v3", study_path.parent / "S_v2")
    assert run() == (2, 3)  # V2 measured again and compared
    assert run(options=MeasureOptions(segmentation=SegmentationOptions(min_depth_um=30.0))) == (5, 0)  # an option
    assert run(options=MeasureOptions(segmentation=SegmentationOptions(min_depth_um=30.0)), force=True) == (5, 0)


def test_fingerprint_is_the_sha256_of_settings_names_sizes_and_contents(tmp_path):
    visit = tmp_path / "visit"
    (visit / "sub").mkdir(parents=True)
    files = {"a.png": b"\x00\x01\x02", "sub/b.json": b'{"x": 1}'}
    for name, content in files.items():
        (visit / name).write_bytes(content)
    settings = {"band": "red", "cutoff_um": 250.0}
    direct = hashlib.sha256(json.dumps(settings, sort_keys=True).encode())  # the docstring's definition, summed directly
    for name in sorted(files):
        direct.update(f"visit/{name}:{len(files[name])}:".encode() + files[name])
    assert skintopo.batch.fingerprint([visit], settings) == direct.hexdigest()
    (visit / "a.png").write_bytes(b"\x00\x01\x03")  # one byte changed, same size
    assert skintopo.batch.fingerprint([visit], settings) != direct.hexdigest()
    (visit / "a.png").write_bytes(files["a.png"])
    assert skintopo.batch.fingerprint([visit], settings) == direct.hexdigest()
    assert skintopo.batch.fingerprint([visit], {**settings, "cutoff_um": 80.0}) != direct.hexdigest()


def test_unreachable_scheduler_is_a_clear_error_within_the_timeout(tmp_path):
    pytest.importorskip("distributed")
    study_path = tmp_path / "study.csv"
    (tmp_path / "a").mkdir()
    study_path.write_text("subject,visit,region,acquisition\nS1,V1,fh,a\n")
    with socket.socket() as sock:  # a port nobody listens on
        sock.bind(("127.0.0.1", 0))
        address = f"tcp://127.0.0.1:{sock.getsockname()[1]}"
    started = time.time()
    with pytest.raises(SkinTopoError, match=f"cannot reach the Dask scheduler at {address} within 1 s"):
        run_study(study_path, tmp_path / "out", scheduler=address, scheduler_timeout=1.0)
    assert time.time() - started < 8 and not (tmp_path / "out").exists()


def test_a_second_concurrent_run_on_the_same_folder_is_refused(tmp_path):
    study_path = tmp_path / "study" / "study.csv"
    (tmp_path / "study" / "a").mkdir(parents=True)
    study_path.write_text("subject,visit,region,acquisition\nS1,V1,fh,a\n")
    out = tmp_path / "out"
    out.mkdir()
    with open(out / ".lock", "a+") as held:
        fcntl.flock(held, fcntl.LOCK_EX | fcntl.LOCK_NB)  # as a running batch holds it
        with pytest.raises(SkinTopoError, match="another skintopo batch is writing"):
            run_study(study_path, out)


@pytest.mark.slow
def test_study_with_repeats_gives_detection_limits_and_a_readable_summary_page(tmp_path):
    study_path = write_study(tmp_path / "study", ["S1", "S2", "S3"], size_px=128, depth_factors=(1.0, 0.8), repeat_first=True)
    out = tmp_path / "out"
    counts, _, failures = run_study(study_path, out, workers=2)
    assert failures == [] and counts["computed"] == 6 + 3 + 3 + 3  # visits + repeats measured, 3 compares, 3 repeat pairs
    statistics = pd.read_csv(out / "statistics.csv")
    depth = statistics[statistics.parameter == "wrinkles.mean_depth_um"].iloc[0]
    assert depth.subjects == 3 and depth.repeat_pairs == 3 and depth.mean_change < 0 and np.isfinite(depth.detection_limit)
    assert depth.ci95_low < depth.mean_change < depth.ci95_high
    page = (out / "summary.html").read_text()
    assert "mean wrinkle depth" in page and "µm" in page and "items/S1/forehead/V1/report.html" in page
    assert "default-src 'none'" in page and "http://" not in page and "https://" not in page
    if browser.CHROMIUM is None:
        pytest.skip("no chromium on this machine (Debian package 'chromium'): summary page not rendered")
    for width in (1400, 390):
        shot = tmp_path / f"summary-{width}.png"
        stderr = browser.screenshot(out / "summary.html", shot, width, 2400, tmp_path / "profile")
        assert shot.is_file(), stderr
        import imagecodecs

        image = imagecodecs.imread(shot)[..., :3]
        # nothing cut off on the right: the last columns of the page are background only
        assert (image[:, -6:] >= 250).all(), f"content reaches the right edge at {width} px"
        if os.environ.get("SKINTOPO_KEEP_SCREENSHOTS"):
            shutil.copy(shot, Path(os.environ["SKINTOPO_KEEP_SCREENSHOTS"]) / shot.name)


def test_a_study_run_in_this_process(tmp_path, monkeypatch):
    """The whole study path in the fast tests, each item run in this interpreter as a worker
    runs it (``run_task``): V1 with a repeat capture, V2, and V3 whose acquisition is
    broken. Every table's columns and rows, the stamps against the documented fingerprint, the
    failure recorded with paths relative to the study, the summary, a rerun that skips
    everything, a changed acquisition and a corrupted result that recompute exactly their items,
    and a SIGTERM that stops the study with what was done."""
    monkeypatch.setattr(skintopo.batch, "LocalRunner", lambda workers: InProcessRunner())
    study_path = write_study(tmp_path / "study", ["S1"], size_px=64, depth_factors=(1.0, 0.8, 0.8), repeat_first=True)
    (study_path.parent / "S1_v3" / "red_01.png").write_bytes(b"broken")
    out = tmp_path / "results" / "trial" / "out"  # outside the study, two new folders deep
    options = MeasureOptions(height=HeightOptions(method="blue"), segmentation=SegmentationOptions(min_depth_um=8.0),
                             wrinkles=WrinkleOptions(depth_window_um=300.0))
    settings = {"skintopo_version": skintopo.batch.__version__, "options": options.as_dict()}
    seen = []

    def run(**extra):
        return run_study(study_path, out, options=options, progress=lambda item, kind, status: seen.append((item.visit, kind, status)),
                         **extra)

    counts, paths, failures = run()
    assert counts == {"computed": 5, "skipped": 0, "failed": 1}  # 4 measures (1 failed), 1 compare, 1 repeat pair
    assert sorted(seen) == [("V1", "measure", "done"), ("V1", "measure", "done"), ("V1", "repeat", "done"),
                            ("V2", "compare", "done"), ("V2", "measure", "done"), ("V3", "measure", "failed")]
    assert [(f["subject"], f["visit"], f["region"], f["step"]) for f in failures] == [("S1", "V3", "forehead", "measure")]
    error = failures[0]["error"]
    assert error.startswith("S1_v3/acquisition.json: 1 problem") and "- S1_v3/red_01.png: not a readable PNG" in error
    assert str(tmp_path) not in error
    assert sorted(paths) == ["changes.csv", "failures.csv", "results.csv", "results.parquet", "results_long.csv",
                             "statistics.csv", "summary.html", "summary.json"]
    # each stamp is the fingerprint of its inputs with the run's settings (the module's definition)
    items, measured = out / "items" / "S1" / "forehead", {}
    for visit, folder in (("V1", "S1_v1"), ("V1~repeat", "S1_v1_repeat"), ("V2", "S1_v2")):
        stamp = json.loads((items / visit / "batch.json").read_text())
        assert stamp == {"fingerprint": skintopo.batch.fingerprint([study_path.parent / folder], settings | {"kind": "measure"}),
                         "skintopo_version": skintopo.batch.__version__}
        summary = json.loads((items / visit / "summary.json").read_text())
        assert summary["source"]["height"] == "blue band" and summary["options"]["segmentation"]["min_depth_um"] == 8.0
        measured[visit] = summary
    for kind, before, after in (("changes", "V1", "V2"), ("repeats", "V1", "V1~repeat")):
        stamp = json.loads((out / kind / "S1" / "forehead" / after.split("~")[0] / "batch.json").read_text())["fingerprint"]
        inputs = [items / before / "height.x3p", items / after / "height.x3p"]
        assert stamp == skintopo.batch.fingerprint(inputs, settings | {"kind": "compare"})
        compared = json.loads((out / kind / "S1" / "forehead" / after.split("~")[0] / "changes.json").read_text())["summary"]["options"]
        assert compared["segmentation"]["min_depth_um"] == 8.0 and compared["wrinkles"]["depth_window_um"] == 300.0
    assert not (items / "V3").exists() and not (out / "changes" / "S1" / "forehead" / "V3").exists()

    long = pd.read_csv(out / "results_long.csv")
    assert list(long.columns) == ["subject", "visit", "region", "parameter", "value", "unit"]
    assert list(long.columns) == list(pd.read_parquet(out / "results.parquet").columns)
    # the same table (CSV reads a unitless "" back as NaN)
    pd.testing.assert_frame_equal(pd.read_parquet(out / "results.parquet"), long.fillna({"unit": ""}), check_dtype=False)
    assert set(long.visit) == {"V1", "V2"} and long.groupby("visit").size().nunique() == 1
    sa = long[long.parameter == "Sa"].set_index("visit")
    assert sa.unit.tolist() == ["um", "um"]
    results = pd.read_csv(out / "results.csv")
    assert list(results.columns[:3]) == ["subject", "visit", "region"] and list(results.visit) == ["V1", "V2"]
    assert set(results.columns[3:]) == set(long.parameter)
    for visit in ("V1", "V2"):  # results.csv is results_long.csv, one row per visit
        row = results[results.visit == visit].iloc[0]
        expected = long[long.visit == visit].set_index("parameter").value
        np.testing.assert_allclose(row[expected.index].to_numpy(float), expected.to_numpy(float), rtol=1e-12)
    changes = pd.read_csv(out / "changes.csv")
    assert list(changes.columns) == ["subject", "region", "baseline_visit", "visit", "parameter", "baseline", "follow_up",
                                     "change", "change_percent"]
    assert set(changes.visit) == {"V2"} and set(changes.baseline_visit) == {"V1"} and list(changes.parameter) == sorted(changes.parameter)
    np.testing.assert_allclose(changes.change, changes.follow_up - changes.baseline, rtol=1e-12)
    sa_change = changes[changes.parameter == "Sa"].iloc[0]  # the compare of the registered visits, not the difference of the fields
    assert sa_change.baseline == pytest.approx(sa.value["V1"], rel=0.2) and sa_change.follow_up == pytest.approx(sa.value["V2"], rel=0.2)
    statistics = pd.read_csv(out / "statistics.csv")
    assert list(statistics.columns[:4]) == ["region", "baseline_visit", "visit", "parameter"] and "Unnamed: 0" not in statistics.columns
    sa_statistics = statistics[statistics.parameter == "Sa"].iloc[0]
    assert (sa_statistics.subjects, sa_statistics.repeat_pairs) == (1, 1) and sa_statistics.mean_change == pytest.approx(sa_change.change)
    failure_table = pd.read_csv(out / "failures.csv")
    assert list(failure_table.columns) == ["subject", "visit", "region", "step", "error"]
    assert failure_table.iloc[0].tolist() == [failures[0][k] for k in ("subject", "visit", "region", "step", "error")]
    summary_text = (out / "summary.json").read_text()
    summary = json.loads(summary_text)
    assert len(summary_text.splitlines()) > 5  # indented for a reader
    assert {k: summary[k] for k in ("skintopo_version", "items", "measured", "failed", "options")} == {
        "skintopo_version": skintopo.batch.__version__, "items": 3, "measured": 2, "failed": 1, "options": options.as_dict()}
    assert summary["detection_limit"].startswith("ISO 5725-6 repeatability limit r = 2.8 s_r")
    page = (out / "summary.html").read_text()
    assert 'href="items/S1/forehead/V1/report.html"' in page and 'href="items/S1/forehead/V2/report.html"' in page

    seen.clear()
    assert run()[0] == {"computed": 0, "skipped": 5, "failed": 1}  # the broken visit is tried again
    (items / ".V2.partial").mkdir()  # a staging folder left by a killed run
    manifest = study_path.parent / "S1_v2" / "acquisition.json"  # one byte changed, same size
    manifest.write_text(manifest.read_text().replace("synthetic skin", "synthetiC skin"))
    assert run()[0] == {"computed": 2, "skipped": 3, "failed": 1}  # V2 and its compare
    assert not (items / ".V2.partial").exists()
    height = items / "V1~repeat" / "height.x3p"  # a result corrupted on disk: its comparison fails, naming it
    height.write_bytes(b"not an x3p file")
    counts, _, failures = run()
    assert counts == {"computed": 0, "skipped": 4, "failed": 2}
    repeat_failure = [f for f in failures if f["step"] == "repeat"][0]
    assert repeat_failure["error"].startswith("items/S1/forehead/V1~repeat/height.x3p: ")  # relative to the output folder
    assert not (out / "repeats" / "S1" / "forehead" / "V1").exists()  # no stale result beside a failure
    assert pd.read_csv(out / "statistics.csv").repeat_pairs.fillna(0).eq(0).all()

    seen.clear()
    with pytest.raises(skintopo.batch.BatchInterrupted) as stopped:  # SIGTERM as the first item finishes
        run_study(study_path, out, options=options, force=True, progress=lambda item, kind, status: os.kill(os.getpid(), signal.SIGTERM))
    assert stopped.value.signal_number == signal.SIGTERM and set(stopped.value.counts) == {"computed", "skipped", "failed"}
    assert_items_complete(out)
    assert not list(out.rglob("*.partial")) and not list(out.rglob(".*.partial"))


def test_a_local_worker_ignores_ctrl_c_keeps_to_its_blas_threads_and_dies_with_its_parent(monkeypatch):
    """``_worker_start`` run here (it runs in each worker): SIGINT ignored, BLAS limited, the
    kernel's parent-death signal armed as SIGKILL (read back with PR_GET_PDEATHSIG), and the
    watch thread exits when the parent pid changes."""
    import ctypes

    from threadpoolctl import threadpool_info, threadpool_limits

    blas = [i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"]
    previous_handler = signal.getsignal(signal.SIGINT)
    libc = ctypes.CDLL(None, use_errno=True)
    exits = []

    def fake_exit(status):
        exits.append(status)
        if threading.current_thread() is threading.main_thread():
            raise SystemExit
        threading.Event().wait()  # the watch thread stops here for good instead of ending this process

    monkeypatch.setattr(os, "_exit", fake_exit)
    try:
        skintopo.batch._worker_start(os.getppid(), 1)
        assert signal.getsignal(signal.SIGINT) is signal.SIG_IGN
        if blas:
            assert {i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"} == {1}
        armed = ctypes.c_int(-1)
        assert libc.prctl(2, ctypes.byref(armed)) == 0 and armed.value == signal.SIGKILL  # PR_GET_PDEATHSIG
        assert exits == []
        real_parent = os.getppid()
        monkeypatch.setattr(os, "getppid", lambda: real_parent + 1)  # the parent has died
        deadline = time.time() + 3
        while not exits and time.time() < deadline:
            time.sleep(0.05)
        assert exits == [1]
        with pytest.raises(SystemExit):  # a parent already gone at start: exit at once
            skintopo.batch._worker_start(real_parent, None)
    finally:
        signal.signal(signal.SIGINT, previous_handler)
        libc.prctl(1, 0)  # disarm the parent-death signal in this test process
        if blas:
            threadpool_limits(limits=max(blas), user_api="blas")


def test_local_runner_stops_its_workers_and_records_a_lost_worker(tmp_path):
    """Closing after an interruption kills a busy worker at once; closing normally waits
    for the workers to exit; a worker killed in the middle of an item is recorded as lost."""
    import multiprocessing

    runner = skintopo.batch.LocalRunner(1)
    busy = runner.pool.submit(time.sleep, 20)
    deadline = time.time() + 30
    while not multiprocessing.active_children() and time.time() < deadline:
        time.sleep(0.05)
    workers = [p.pid for p in multiprocessing.active_children()]
    started = time.time()
    runner.close(interrupted=True)
    assert time.time() - started < 5 and busy.done()
    assert_gone(workers)
    runner = skintopo.batch.LocalRunner(2)
    assert runner.pool.submit(os.getpid).result(timeout=60) != os.getpid()
    # each worker a clean interpreter (spawned, not forked: nothing of this process's modules)
    assert runner.pool.submit(eval, "__import__('sys').modules.get('tests.batch.test_batch') is None").result(timeout=60)
    blas = "[i['num_threads'] for i in __import__('threadpoolctl').threadpool_info() if i['user_api'] == 'blas']"
    assert set(runner.pool.submit(eval, blas).result(timeout=60)) == {1}  # one BLAS thread per worker when there are several
    runner.close()
    assert multiprocessing.active_children() == []

    study_path = tmp_path / "study" / "study.csv"
    (tmp_path / "study" / "a").mkdir(parents=True)
    study_path.write_text("subject,visit,region,acquisition\nS1,V1,fh,a\n")
    seen = []

    def kill_the_worker():
        deadline = time.time() + 30
        while not multiprocessing.active_children() and time.time() < deadline:
            time.sleep(0.01)
        for process in multiprocessing.active_children():
            os.kill(process.pid, signal.SIGKILL)

    killer = threading.Thread(target=kill_the_worker)
    killer.start()
    counts, _, failures = run_study(study_path, tmp_path / "out", progress=lambda item, kind, status: seen.append(status))
    killer.join()
    assert counts == {"computed": 0, "skipped": 0, "failed": 1} and seen == ["failed"]
    assert failures[0]["error"].startswith("the worker running this item was lost (BrokenProcessPool")
