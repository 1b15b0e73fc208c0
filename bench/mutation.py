"""Mutation testing of the core modules with mutmut (PyPI), each module against its own fast tests.

Run with ``make mutate`` (or ``python bench/mutation.py [--all] [--update] [MODULE ...]``; ``--update``
runs only the modules named and rewrites the results of all from what mutmut kept). For each module,
``build/mutation/MODULE/`` gets a copy of ``src/`` and ``tests/`` and a ``pyproject.toml`` that
tells mutmut to mutate that module only and to run the module's test folders without the slow
tests; mutmut keeps its results there, so a second run retests only what changed.

By default a fixed fifth of the mutants is run (mutmut's mutants numbered ..0 and ..5 within
each function: every function with five or more mutants is sampled, the same mutants on every
run): `make mutate` took 34 minutes on 2 cores (the eleven modules 30 minutes, 11 of them for
batch, whose fast tests run a small study); ``--all`` runs every mutant (several hours). The
score of a sample is given with its 95% Wilson interval.

Mutation score = killed / (killed + survived + no test + suspicious), after the mutants judged
equivalent (``bench/mutation_equivalent.toml``: a mutant that no input can tell from the
original, with the reason) are set aside; a timed-out mutant counts as killed (it changed the
behaviour: the tests would hang). Written: ``bench/results/mutation.json`` (counts per module,
score, time) and ``bench/results/mutation-survivors.md`` (every surviving mutant's diff,
equivalent ones with their reason).

mutmut is run as a separate program from a virtual environment that has the project's
dependencies but not skintopo itself (mutmut puts its mutated copy first on the import path; an
editable install of the original would otherwise be what the tests import).
"""

import argparse
import fnmatch
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import time
import tomllib
from pathlib import Path

from _results import write_result

ROOT = Path(__file__).resolve().parent.parent
WORK = ROOT / "build" / "mutation"
TIMEOUT_MULTIPLIER = 3.0  # mutmut's timeout_multiplier (see _prepare)

# module -> (the files mutmut mutates, the tests run against them: the module's own folder, and
# for acquisition the two files that test its DiLiGenT reader and its folder inference, for batch
# the study tests (its study.csv reader) and the command's tests of a study's validation)
CORE_MODULES = {
    "normals": ("src/skintopo/normals.py", ["tests/normals"]),
    "height": ("src/skintopo/height.py", ["tests/height"]),
    "filters": ("src/skintopo/filters.py", ["tests/filters"]),
    "correction": ("src/skintopo/correction.py", ["tests/correction"]),
    "segmentation": ("src/skintopo/segmentation.py", ["tests/segmentation"]),
    "wrinkles": ("src/skintopo/wrinkles.py", ["tests/wrinkles"]),
    "compare": ("src/skintopo/compare.py", ["tests/compare"]),
    "texture": ("src/skintopo/texture/*", ["tests/texture"]),
    "acquisition": ("src/skintopo/acquisition/*", ["tests/acquisition", "tests/normals/test_diligent.py", "tests/cli/test_init.py"]),
    "formats": ("src/skintopo/formats.py", ["tests/formats"]),
    "batch": ("src/skintopo/batch.py", ["tests/batch", "tests/study", "tests/cli/test_batch.py"]),
}

# Run inside a module's work folder: every mutant's status and, unless killed, its diff.
_LIST_MUTANTS = """
import json
from mutmut.configuration import config
from mutmut.mutation.data import SourceFileMutationData
from mutmut.mutation.diff_apply import get_diff_for_mutant
from mutmut.stats import status_by_exit_code
from mutmut.utils.file_utils import walk_mutatable_files
rows = []
for path in walk_mutatable_files():
    data = SourceFileMutationData(path=path)
    data.load()
    for name, code in data.exit_code_by_key.items():
        status = status_by_exit_code[code]
        diff = "" if status in ("killed", "timeout") else get_diff_for_mutant(name, path=path)
        rows.append({"name": name, "status": status, "diff": diff})
print(json.dumps(rows))
"""


def _mutmut_python():
    """The Python of build/mutation/.venv: the project's dependencies and mutmut, not skintopo."""
    venv = WORK / ".venv"
    python = venv / "bin" / "python"
    if not python.exists():
        subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True)
        subprocess.run([str(python), "-m", "pip", "install", "--quiet", "--upgrade", "pip"], check=True)
        subprocess.run([str(python), "-m", "pip", "install", "--quiet", "-c", str(ROOT / "constraints.txt"),
                        f"{ROOT}[test]", "mutmut==3.8.1"], check=True)
        subprocess.run([str(python), "-m", "pip", "uninstall", "--quiet", "--yes", "skintopo"], check=True)
    return python


def _prepare(module):
    """build/mutation/MODULE with today's src/ and tests/ and mutmut's settings for the module."""
    pattern, test_folders = CORE_MODULES[module]
    folder = WORK / module
    folder.mkdir(parents=True, exist_ok=True)
    ignore = shutil.ignore_patterns("__pycache__", "*.pyc")
    for part in ("src", "tests"):
        shutil.rmtree(folder / part, ignore_errors=True)
        shutil.copytree(ROOT / part, folder / part, ignore=ignore)  # copy2: mtimes kept, so mutmut reuses results
    shutil.copy2(ROOT / "README.md", folder)  # a test reads the README's manifest example
    shared = ROOT.parent / "shared"  # the tests look for ../shared beside the repository (here: beside mutants/)
    if shared.is_dir() and not (folder / "shared").exists():
        (folder / "shared").symlink_to(shared)
    # mutmut maps each test to the functions it calls once, when it first sees the test's name;
    # a test extended later keeps its old map (and misses mutants it kills): map them all anew
    (folder / "mutants" / "mutmut-stats.json").unlink(missing_ok=True)
    pytest_options = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["pytest"]["ini_options"]
    selection = [*test_folders, "-m", "not slow", "-p", "no:cacheprovider"]
    (folder / "pyproject.toml").write_text(
        "[tool.pytest.ini_options]\n"
        f"markers = {json.dumps(pytest_options['markers'])}\n\n"
        "[tool.mutmut]\n"
        'source_paths = ["src/"]\n'
        'also_copy = ["README.md"]\n'
        f"only_mutate = {json.dumps([pattern])}\n"
        f"pytest_add_cli_args_test_selection = {json.dumps(selection)}\n"
        # A mutant that loops for ever (a read loop whose end sentinel is changed) is stopped
        # after 2 x TIMEOUT_MULTIPLIER times its tests' time in CPU seconds (mutmut's default
        # multiplier 15 let one such batch mutant run for 13 minutes).
        f"timeout_multiplier = {TIMEOUT_MULTIPLIER}\n")
    return folder


def _equivalent_mutants():
    """The judgements of bench/mutation_equivalent.toml: a function (function, original line,
    mutated line) -> reason or None, from single mutants and from rules (a regular expression
    "pattern": a mutant is covered when the two lines differ only inside its matches, i.e.
    are equal once the matches are removed from both)."""
    judged = tomllib.loads((ROOT / "bench" / "mutation_equivalent.toml").read_text())
    single = {(e["function"], e["original"].strip(), e["mutant"].strip()): e["reason"] for e in judged.get("equivalent", [])}
    rules = [(re.compile(rule["pattern"]), rule["reason"]) for rule in judged.get("rule", [])]

    def reason(function, original, mutant):
        if (function, original, mutant) in single:
            return single[function, original, mutant]
        return next((text for pattern, text in rules
                     if pattern.search(original) and _without(pattern, original) == _without(pattern, mutant)), None)
    return reason


def _without(pattern, line):
    """The line without the pattern's matches, blanks and trailing commas."""
    return re.sub(r"\s+", "", pattern.sub("", line)).replace(",)", ")")


def _changed_lines(diff):
    """The first removed and added lines of a unified diff (mutmut changes one expression)."""
    lines = diff.splitlines()[2:]
    removed = next((line[1:].strip() for line in lines if line.startswith("-")), "")
    added = next((line[1:].strip() for line in lines if line.startswith("+")), "")
    return removed, added


def _function(name):
    """skintopo.filters.x_level__mutmut_3 -> skintopo.filters.level (class methods: Class.method)."""
    qualified = name.rsplit("__mutmut_", 1)[0]
    module, _, function = qualified.rpartition(".")
    function = function.replace("ǁ", ".").lstrip(".")
    return f"{module}.{function[2:] if function.startswith('x_') else function}"


SAMPLE = ["*__mutmut_*0", "*__mutmut_*5"]  # mutmut's fnmatch patterns for the fixed fifth


def wilson_interval(successes, n, z=1.959964):
    """95% Wilson score interval of a proportion (Wilson 1927)."""
    if n == 0:
        return float("nan"), float("nan")
    p = successes / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * ((p * (1 - p) / n + z * z / (4 * n * n)) ** 0.5) / (1 + z * z / n)
    return centre - half, centre + half


def run_module(python, module, sample=True):
    """Mutate one module and run its tests against the mutants (mutmut keeps the results in the
    module's folder); the seconds it took."""
    folder = _prepare(module)
    start = time.perf_counter()
    with open(folder / "mutmut.log", "w") as log:
        # its own process group, ended with this script (an interrupt or SIGTERM leaves no mutmut workers behind)
        mutmut = subprocess.Popen([str(python), "-m", "mutmut", "run", "--max-children", str(os.cpu_count() or 2),
                                   *(SAMPLE if sample else [])], cwd=folder, stdout=log, stderr=subprocess.STDOUT,
                                  start_new_session=True)
        try:
            if mutmut.wait():
                raise SystemExit(f"mutmut failed on {module}: see {folder / 'mutmut.log'}")
        finally:
            if mutmut.poll() is None:
                os.killpg(mutmut.pid, signal.SIGKILL)
                mutmut.wait()
    return time.perf_counter() - start


def tally_module(python, module, equivalent, seconds, sample=True):
    """A module's counts and surviving mutants from the results mutmut kept in its folder."""
    listing = subprocess.run([str(python), "-c", _LIST_MUTANTS], cwd=WORK / module, capture_output=True, text=True,
                             check=True)
    counts = {"killed": 0, "timeout": 0, "survived": 0, "no tests": 0, "suspicious": 0, "equivalent": 0}
    survivors = []
    for row in json.loads(listing.stdout):
        status = row["status"]
        if sample and not any(fnmatch.fnmatch(row["name"], pattern) for pattern in SAMPLE):
            continue
        if status not in ("killed", "timeout"):
            function = _function(row["name"])
            reason = equivalent(function, *_changed_lines(row["diff"]))
            if reason is not None:
                status = "equivalent"
            survivors.append({**row, "function": function, "status": status, "reason": reason})
        counts[status] = counts.get(status, 0) + 1
    return {"module": module, **counts, **_score(counts), "seconds": round(seconds, 1)}, survivors


def _score(counts):
    """Killed (timeouts included) over every mutant judged, equivalent ones set aside, with its 95% interval."""
    detected = counts["killed"] + counts["timeout"]
    judged = detected + counts["survived"] + counts["no tests"] + counts["suspicious"]
    return {"score": detected / judged if judged else float("nan"), "score_95": list(wilson_interval(detected, judged))}


def _write_survivors(survivors_by_module):
    lines = ["# Surviving mutants", "",
             "Written by `bench/mutation.py` (`make mutate`). A mutant judged equivalent carries its reason;",
             "every other one is a change that the module's fast tests do not notice.", ""]
    for module, survivors in survivors_by_module.items():
        lines += [f"## {module} ({len(survivors)})", ""]
        for row in survivors:
            reason = f": equivalent, {row['reason']}" if row["status"] == "equivalent" else ""
            lines += [f"### `{row['name']}` ({row['status']}{reason})", "", "```diff", row["diff"], "```", ""]
    (ROOT / "bench" / "results" / "mutation-survivors.md").write_text("\n".join(lines))


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--all", action="store_true", help="every mutant, not the fixed fifth (several hours)")
    parser.add_argument("--update", action="store_true",
                        help="run only the modules named, and rewrite the results of every module from the kept ones")
    parser.add_argument("modules", nargs="*", help=f"modules to mutate (default: all of {', '.join(CORE_MODULES)})")
    args = parser.parse_args(argv)
    unknown = sorted(set(args.modules) - set(CORE_MODULES))
    if unknown:
        parser.error(f"not a core module: {', '.join(unknown)}")
    modules = args.modules or list(CORE_MODULES)
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(143))  # SIGTERM unwinds like an interrupt: mutmut is stopped too
    python = _mutmut_python()
    equivalent = _equivalent_mutants()
    results = ROOT / "bench" / "results" / "mutation.json"
    previous = {row["module"]: row["seconds"] for row in json.loads(results.read_text())["modules"]} if args.update else {}
    seconds = {}
    for module in modules:
        seconds[module] = run_module(python, module, sample=not args.all)
        print(f"{module}: {seconds[module]:.0f} s", flush=True)
    reported = list(CORE_MODULES) if args.update or modules == list(CORE_MODULES) else modules
    rows, survivors_by_module = [], {}
    for module in reported:
        row, survivors_by_module[module] = tally_module(python, module, equivalent, seconds.get(module, previous.get(module, float("nan"))),
                                                        sample=not args.all)
        print(json.dumps(row), flush=True)
        rows.append(row)
    total = {key: sum(row[key] for row in rows) for key in rows[0] if key not in ("module", "score", "score_95", "seconds")}
    result = {"tool": "mutmut 3.8.1", "command": "make mutate" + (" (bench/mutation.py --all)" if args.all else ""),
              "mutants": "all" if args.all else "the fixed fifth numbered ..0 and ..5 in each function", "modules": rows,
              "total": {**total, **_score(total), "seconds": round(sum(row["seconds"] for row in rows), 1)}}
    if reported == list(CORE_MODULES):
        _write_survivors(survivors_by_module)
        write_result("mutation", result)
    else:
        print(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()
