"""Study-scale batch: local processes and a Dask LocalCluster, failures, interruption."""

import os
import signal
import subprocess
import sys
import time

import pandas as pd
import pytest

from skintopo.batch import read_study, run_study
from skintopo.errors import SkinTopoError
from skintopo.synth import Effects, default_settings, make_surface, preset_spec, simulate_acquisition, write_synthetic_acquisition


@pytest.fixture(scope="module")
def study(tmp_path_factory):
    """2 subjects x 3 visits of simulated skin (small, quick), one acquisition corrupt."""
    import dataclasses

    root = tmp_path_factory.mktemp("study")
    rows = ["subject,visit,region,acquisition"]
    for subject, seed in (("S01", 1), ("S02", 2)):
        for visit, (shift, depth_factor) in enumerate((((0, 0), 1.0), ((20.0, -10.0), 0.9), ((-15.0, 25.0), 0.8)), start=1):
            spec = preset_spec("forehead-moderate", size_px=128)
            wrinkles = tuple(dataclasses.replace(w, depth_um=w.depth_um * depth_factor) for w in spec.wrinkles)
            surface = make_surface(dataclasses.replace(spec, shift_um=shift, wrinkles=wrinkles), seed=seed)
            settings = default_settings(effects=Effects(interreflection=False))
            bands, info = simulate_acquisition(surface, settings, seed=10 * seed + visit)
            folder = root / f"{subject}_v{visit}"
            write_synthetic_acquisition(folder, surface, bands, settings=settings, seed=seed, info=info)
            rows.append(f"{subject},V{visit},forehead,{folder.name}")
    (root / "S02_v3" / "red_01.png").write_bytes(b"\\x89PNG broken")  # the corrupt one
    (root / "study.csv").write_text("\n".join(rows) + "\n")
    return root / "study.csv"


def tables(out):
    return {name: pd.read_csv(out / name) for name in ("results.csv", "changes.csv", "failures.csv")}


@pytest.fixture(scope="module")
def local_run(study, tmp_path_factory):
    out = tmp_path_factory.mktemp("local")
    counts, _, _ = run_study(study, out, workers=2)
    return out, counts


@pytest.mark.slow
def test_local_processes(local_run):
    out, counts = local_run
    assert counts == {"computed": 8, "skipped": 0, "failed": 1}  # 5 of 6 measures (S02 V3 is corrupt) + 3 compares
    t = tables(out)
    assert len(t["results.csv"]) == 5 and set(t["results.csv"].subject) == {"S01", "S02"}
    failures = t["failures.csv"]
    assert len(failures) == 1 and failures.iloc[0].visit == "V3" and "red_01.png" in failures.iloc[0].error
    assert set(t["changes.csv"].visit) == {"V2", "V3"} and len(t["changes.csv"][t["changes.csv"].subject == "S02"].visit.unique()) == 1
    assert (out / "results.parquet").stat().st_size > 0 and (out / "summary.html").stat().st_size > 10_000
    depth = t["changes.csv"]
    s01 = depth[(depth.subject == "S01") & (depth.parameter == "wrinkles.mean_depth_um")]
    print(s01[["visit", "change_percent"]])
    assert (s01.change_percent < 0).all()  # the wrinkles were made shallower at every visit


@pytest.mark.slow
def test_dask_local_cluster_gives_identical_tables(study, local_run, tmp_path):
    distributed = pytest.importorskip("distributed")
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster:
        counts, _, _ = run_study(study, tmp_path / "dask", scheduler=cluster.scheduler_address)
    assert counts == local_run[1]
    for name, table in tables(tmp_path / "dask").items():
        pd.testing.assert_frame_equal(table, tables(local_run[0])[name])


@pytest.mark.slow
def test_interrupted_batch_resumes_without_recomputing(study, local_run, tmp_path):
    out = tmp_path / "interrupted"
    process = subprocess.Popen([sys.executable, "-m", "skintopo.cli", "batch", str(study), "-o", str(out), "--workers", "1", "-q"],
                               start_new_session=True)
    deadline = time.time() + 120
    while time.time() < deadline and len(list(out.glob("items/*/*/*/batch.json"))) < 2:
        time.sleep(0.2)
    os.killpg(process.pid, signal.SIGINT)  # Ctrl-C, to the whole process group as a terminal would
    process.wait(timeout=60)
    finished = len(list(out.glob("items/*/*/*/batch.json")))
    assert 2 <= finished < 5
    assert not list(out.glob("items/**/.*.partial"))  # nothing half-written
    counts, _, _ = run_study(study, out, workers=2)
    assert counts["skipped"] == finished and counts["computed"] + counts["skipped"] == 8
    for name, table in tables(out).items():
        pd.testing.assert_frame_equal(table, tables(local_run[0])[name])


def test_study_validation_reports_every_problem(tmp_path):
    (tmp_path / "a").mkdir()
    (tmp_path / "study.csv").write_text("subject,visit,region,acquisition,baseline\nS1,V1,fh,a,\nS1,V1,fh,a,\nS2,V2,fh,missing,V1\n,V3,fh,a,\n")
    with pytest.raises(SkinTopoError) as error:
        read_study(tmp_path / "study.csv")
    message = str(error.value)
    assert "4 problem(s)" in message and "listed twice" in message and "'missing' not found" in message
    assert "empty subject" in message and "baseline visit 'V1' of subject S2" in message
