"""The result folder: what ``measure`` and ``compare`` write, and reading it back.

A measure result folder holds ``parameters.json`` / ``parameters.csv`` (every texture and
fractal parameter per region, with units and the standard's clause), ``wrinkles.json`` /
``wrinkles.csv`` / ``wrinkles.png`` (per-wrinkle measures and their label image),
``height.x3p`` (the measured height, metres inside the file per ISO 25178-72),
``albedo.npy`` (when measured from an acquisition), ``pores.json`` / ``pores.csv`` /
``pores.png`` (per-pore measures and their label image), ``chromophores.json``,
``melanin.npy`` and ``haemoglobin.npy`` (the melanin and haemoglobin indices, from an
acquisition with red, green and blue), ``summary.json`` (software version, source, options)
and ``report.html``. A compare folder holds ``changes.json`` /
``changes.csv``, ``difference.x3p`` and, when both visits had one, the registered albedo.
This module is the only one that knows these names; callers write into a staged folder
(:func:`skintopo.outputs.staged_output_folder`) so a folder appears complete or not at all.
"""

from __future__ import annotations

import csv
import json
import platform
from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict
from pathlib import Path

import numpy as np

from skintopo import __version__
from skintopo.errors import SkinTopoError
from skintopo.outputs import write_json, write_label_image
from skintopo.texture import finite_or_none

PARAMETER_COLUMNS = ("region", "name", "value", "unit", "reference")
CHANGE_COLUMNS = ("parameter", "baseline", "follow_up", "change", "change_percent", "detection_limit", "detectable")
WRINKLE_TOTAL_UNITS = {"count": "", "total_length_mm": "mm", "mean_depth_um": "um", "area_fraction": ""}
PORE_TOTAL_UNITS = {"count": "", "count_per_cm2": "1/cm2", "mean_area_mm2": "mm2", "mean_diameter_um": "um", "mean_depth_um": "um",
                    "total_volume_mm3": "mm3"}
CHROMOPHORE_UNITS = {"mean": "OD", "standard_deviation": "OD", "relative_variation": ""}  # each of chromophores.STATISTICS


def run_header(command, **extra):
    """The first entries of every summary: software version, command, Python version."""
    return {"skintopo_version": __version__, "command": command, "python": platform.python_version(), **extra}


def _write_csv(path, columns, rows):
    with open(path, "w", newline="", encoding="utf-8") as stream:
        writer = csv.DictWriter(stream, fieldnames=list(columns))
        writer.writeheader()
        writer.writerows(rows)


def write_wrinkle_files(folder, measures, segmentation):
    """wrinkles.json (measures, totals, segmentation settings), wrinkles.csv and the id image."""
    from skintopo.wrinkles import WRINKLE_COLUMNS

    folder = Path(folder)
    data = measures.as_dict() | {"segmentation": segmentation.parameters, "units": "lengths in mm, depths in um, volume mm3"}
    write_json(folder / "wrinkles.json", data)
    _write_csv(folder / "wrinkles.csv", list(WRINKLE_COLUMNS), (asdict(w) for w in measures.wrinkles))
    write_label_image(folder / "wrinkles.png", measures.labels)


def write_pore_files(folder, pores):
    """pores.json (totals, pores, settings), pores.csv and the id image pores.png."""
    from skintopo.pores import PORE_COLUMNS

    folder = Path(folder)
    write_json(folder / "pores.json", pores.as_dict())
    _write_csv(folder / "pores.csv", PORE_COLUMNS, (asdict(p) for p in pores.pores))
    write_label_image(folder / "pores.png", pores.labels)


def write_chromophore_files(folder, chromophores, statistics):
    """chromophores.json (model, sources, ``statistics`` per region), melanin.npy and haemoglobin.npy."""
    folder = Path(folder)
    write_json(folder / "chromophores.json", chromophores.as_dict(statistics=statistics))
    np.save(folder / "melanin.npy", chromophores.melanin)
    np.save(folder / "haemoglobin.npy", chromophores.haemoglobin)


def measurement_settings(measurement):
    """The settings recorded with a measurement (and shown in its report)."""
    return {"source": measurement.source, "options": measurement.options.as_dict(),
            "segmentation": measurement.segmentation.parameters, "skintopo_version": __version__}


def write_measurement(folder, measurement, *, title, command="measure", evaluations=None, cross_sections=(), early=None):
    """Write a :class:`skintopo.pipeline.Measurement` into ``folder`` (which must exist);
    ``early``: the :class:`HeightOutputs` of ``folder`` that already wrote ``height.x3p`` and
    made the report's height views of the measurement's height (e.g. alongside the measure:
    :func:`skintopo.pipeline.measure_height`)."""
    from skintopo.report import build_report

    folder = Path(folder)
    early = early if early is not None and early.height is measurement.height and early.folder == folder else None
    rows = measurement.parameter_rows()
    settings = measurement_settings(measurement)
    colour = None if measurement.chromophores is None else measurement.chromophores.statistics(measurement.region_masks())
    summary = run_header(command, source=measurement.source, options=settings["options"], segmentation=settings["segmentation"],
                         units="um unless stated", wrinkle_totals=measurement.wrinkles.totals,
                         pore_totals=None if measurement.pores is None else measurement.pores.totals,
                         chromophores=colour,
                         evaluation=evaluations)

    def data_files():
        if early is None:  # the height map's x3p, unless it was written early
            write_height_file(folder, measurement.height)
        write_json(folder / "parameters.json", {"summary": summary, "parameters": rows})
        _write_csv(folder / "parameters.csv", PARAMETER_COLUMNS, rows)
        write_wrinkle_files(folder, measurement.wrinkles, measurement.segmentation)
        if measurement.pores is not None:
            write_pore_files(folder, measurement.pores)
        if measurement.chromophores is not None:
            write_chromophore_files(folder, measurement.chromophores, colour)
        if measurement.albedo is not None:  # kept so that `compare` can carry it to the baseline grid
            np.save(folder / "albedo.npy", np.asarray(measurement.albedo, dtype=np.float32))
        write_json(folder / "summary.json", summary)

    # the data files are written on a thread of their own while the report is made here (zlib
    # and PNG encoding release the GIL; the x3p's compression is 0.14 s at 1024 x 1024)
    with ThreadPoolExecutor(max_workers=1) as pool:
        writing = pool.submit(data_files)
        boxes = dict(measurement.options.regions)
        report_regions = {name: (boxes[name], values) for name, values in measurement.texture.items() if name != "field"}
        report = build_report(title=title, height=measurement.height, albedo=measurement.albedo, parameters=measurement.texture["field"],
                              regions=report_regions, fractal_results=measurement.fractal_results, wrinkles=measurement.wrinkles,
                              evaluations=evaluations, settings=settings, cross_sections=cross_sections, pores=measurement.pores,
                              chromophores=measurement.chromophores, chromophore_statistics=colour,
                              views=None if early is None else early.views)
        (folder / "report.html").write_text(report, encoding="utf-8")
        writing.result()
    if not (folder / "height.x3p").is_file():
        raise SkinTopoError(f"{folder}: height.x3p was not written")
    return summary


def write_height_file(folder, height):
    """Write the measured height map as ``folder/height.x3p``, the file a result folder holds."""
    height.save(Path(folder) / "height.x3p")


class HeightOutputs:
    """What :func:`write_measurement` can do before the measures are done, from the height map
    alone: called with it, writes ``folder/height.x3p`` and makes the report's height views
    (:func:`skintopo.report.height_views`), kept here for :func:`write_measurement` (its
    ``early``). ``skintopo measure`` passes one as ``alongside`` to
    :func:`skintopo.pipeline.measure_height`, which runs it while the wrinkles are measured:
    zlib, the template's compilation and the shaded relief fill that wait (1024 x 1024: about
    0.25 s)."""

    def __init__(self, folder):
        self.folder, self.height, self.views = Path(folder), None, None

    def __call__(self, height):
        from skintopo.report import height_views

        write_height_file(self.folder, height)
        self.height, self.views = height, height_views(height)


def _read_json(path):
    try:
        return json.loads(Path(path).read_text(encoding="utf-8"))
    except (OSError, ValueError) as error:
        raise SkinTopoError(f"{path}: not a readable skintopo result ({error})") from None


def read_measurement_values(folder):
    """({name: value}, {name: unit}) of a measure result folder: field parameters by name,
    region parameters as ``region.name``, wrinkle totals as ``wrinkles.name``, pore totals as
    ``pores.name`` and the melanin and haemoglobin statistics as ``melanin.mean`` (field) or
    ``region.melanin.mean`` (when the folder has them)."""
    folder = Path(folder)
    values, units = {}, {}
    for p in _read_json(folder / "parameters.json")["parameters"]:
        name = p["name"] if p["region"] == "field" else f"{p['region']}.{p['name']}"
        values[name], units[name] = p["value"], p["unit"]
    for prefix, path, table in (("wrinkles", folder / "wrinkles.json", WRINKLE_TOTAL_UNITS), ("pores", folder / "pores.json", PORE_TOTAL_UNITS)):
        if path.is_file() or prefix == "wrinkles":
            totals = _read_json(path)["totals"]
            for name, unit in table.items():
                values[f"{prefix}.{name}"], units[f"{prefix}.{name}"] = finite_or_none(totals[name]), unit
    if (folder / "chromophores.json").is_file():
        for region, maps in _read_json(folder / "chromophores.json")["regions"].items():
            for chromophore, statistics in maps.items():
                for statistic in CHROMOPHORE_UNITS:
                    name = f"{chromophore}.{statistic}" if region == "field" else f"{region}.{chromophore}.{statistic}"
                    values[name], units[name] = statistics[statistic], CHROMOPHORE_UNITS[statistic]
    return values, units


def comparison_rows(comparison, limits=None):
    """One row per changed quantity of a :class:`skintopo.compare.Comparison`: texture
    parameters, wrinkle totals (``wrinkles.name``), pore totals (``pores.name``), colour
    statistics (``melanin.mean``, ...) and matched wrinkles (``wrinkleN.measure``), with the
    detection limit from repeat captures where they were given."""
    limits = limits or {}
    rows = [{"parameter": name, **record, "detection_limit": limits.get(name)} for name, record in comparison.texture.items()]
    rows += [{"parameter": f"wrinkles.{name}", **record, "detection_limit": limits.get(f"wrinkles.{name}")}
             for name, record in comparison.totals.items()]
    rows += [{"parameter": f"pores.{name}", **record, "detection_limit": limits.get(f"pores.{name}")} for name, record in comparison.pores.items()]
    rows += [{"parameter": name, **record, "detection_limit": limits.get(name)} for name, record in comparison.colour.items()]
    for wrinkle_id, record in comparison.wrinkles.items():
        for name, change in record.items():
            if isinstance(change, dict):
                rows.append({"parameter": f"wrinkle{wrinkle_id}.{name}", **change, "detection_limit": limits.get(f"wrinkle{wrinkle_id}.{name}")})
    for row in rows:
        limit = row["detection_limit"]
        row["detectable"] = None if limit is None else bool(abs(row["change"]) > limit)
        for key in ("baseline", "follow_up", "change", "change_percent", "detection_limit"):
            row[key] = finite_or_none(None if row[key] is None else float(row[key]))
    return rows


def write_comparison(folder, comparison, rows, summary, spacing):
    """difference.x3p (on the baseline grid of ``spacing`` um), the registered albedo (when
    there is one), changes.json and changes.csv."""
    from skintopo.heightmap import HeightMap

    folder = Path(folder)
    HeightMap(comparison.difference, spacing).save(folder / "difference.x3p")
    if comparison.aligned_albedo is not None:
        np.save(folder / "follow_up_albedo_registered.npy", comparison.aligned_albedo.astype(np.float32))
    write_json(folder / "changes.json", {"summary": summary, "changes": rows})
    _write_csv(folder / "changes.csv", CHANGE_COLUMNS, rows)


def read_change_rows(folder):
    """The rows of a compare result folder's changes.json."""
    return _read_json(Path(folder) / "changes.json")["changes"]


def load_height_input(path, pixel_um=None):
    """A height map file, or a result folder holding height.x3p (micrometres)."""
    from skintopo.heightmap import HeightMap

    path = Path(path)
    if path.is_dir():
        if not (path / "height.x3p").is_file():
            raise SkinTopoError(f"{path}: a folder given as a height map must hold height.x3p (the output of correct or measure)")
        path = path / "height.x3p"
    elif not path.exists():
        raise SkinTopoError(f"{path}: no such height map or folder")
    return HeightMap.load(path, pixel_um=pixel_um)


def _load_array_beside(path, name):
    path = Path(path)
    if path.is_dir() and (path / name).is_file():
        try:
            return np.load(path / name)
        except (OSError, ValueError) as error:
            raise SkinTopoError(f"{path / name}: not a readable NumPy array ({error})") from None
    return None


def load_albedo_beside(path):
    """The albedo.npy a result folder holds (the output of measure), or None."""
    return _load_array_beside(path, "albedo.npy")


def load_colour_beside(path):
    """{"melanin": map, "haemoglobin": map} from a result folder's melanin.npy and
    haemoglobin.npy (the output of measure from an acquisition), or None."""
    maps = {name: _load_array_beside(path, f"{name}.npy") for name in ("melanin", "haemoglobin")}
    return maps if all(value is not None for value in maps.values()) else None
