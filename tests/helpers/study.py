"""A simulated study on disk: acquisitions of a few subjects over visits, and study.csv."""

import dataclasses
from concurrent.futures import Future

import skintopo.batch
from skintopo.synth import Effects, default_settings, make_surface, preset_spec, simulate_acquisition, write_synthetic_acquisition


def write_study(root, subjects, *, size_px=96, depth_factors=(1.0, 0.9, 0.8), repeat_first=False):
    """``subjects`` x visits of simulated skin (wrinkles made shallower at each visit, the
    field shifted a little), written as acquisitions beside ``study.csv``."""
    root.mkdir(parents=True, exist_ok=True)
    rows = ["subject,visit,region,acquisition" + (",repeat" if repeat_first else "")]
    for number, subject in enumerate(subjects):
        for visit, factor in enumerate(depth_factors, start=1):
            spec = preset_spec("forehead-moderate", size_px=size_px)
            wrinkles = tuple(dataclasses.replace(w, depth_um=w.depth_um * factor) for w in spec.wrinkles)
            surface = make_surface(dataclasses.replace(spec, shift_um=(12.0 * visit, -7.0 * visit), wrinkles=wrinkles), seed=number + 1)
            settings = default_settings(effects=Effects(interreflection=False))
            folders = [f"{subject}_v{visit}"] + ([f"{subject}_v{visit}_repeat"] if repeat_first and visit == 1 else [])
            for capture, folder in enumerate(folders):  # a repeat capture: the same skin, new sensor noise
                bands, info = simulate_acquisition(surface, settings, seed=100 * number + 10 * visit + capture)
                write_synthetic_acquisition(root / folder, surface, bands, settings=settings, seed=number + 1, info=info)
            repeat = ("," + (folders[1] if len(folders) > 1 else "")) if repeat_first else ""
            rows.append(f"{subject},V{visit},forehead,{folders[0]}{repeat}")
    (root / "study.csv").write_text("\n".join(rows) + "\n")
    return root / "study.csv"


class InProcessRunner:
    """Runs each study item at once in the test's own process, as a worker runs it
    (:func:`skintopo.batch.run_task`), in place of the local process pool: the items' code is
    then seen by tools that follow this process only (mutation testing's coverage)."""

    def submit(self, *args):
        future = Future()
        future.set_result(skintopo.batch.run_task(*args))
        return future

    def as_completed(self, futures):
        return iter(futures)

    def close(self, interrupted=False):
        pass
