# `make demo` and `make test` work on a fresh machine with Python 3.11: each creates (or reuses)
# the local virtual environment .venv, installs the package and what it needs (at the versions
# of constraints.txt, with which the README's figures were measured), then runs.
PYTHON ?= python3
VENV ?= .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed

.PHONY: demo test test-latest bench mutate docs clean

$(STAMP): pyproject.toml constraints.txt
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -c constraints.txt -e '.[test,docs]'
	touch $(STAMP)

demo: $(STAMP)
	$(VENV)/bin/skintopo demo -o demo-out --overwrite

test: $(STAMP)
	$(PY) -m pytest -q

# the newest versions PyPI serves, in a separate environment: shows drift from constraints.txt
test-latest:
	$(PYTHON) -m venv .venv-latest
	.venv-latest/bin/python -m pip install --quiet --upgrade pip
	.venv-latest/bin/python -m pip install --quiet --upgrade -e '.[test]'
	.venv-latest/bin/python -m pytest -q

docs: $(STAMP)
	$(VENV)/bin/mkdocs build --quiet --strict

bench: $(STAMP)
	for script in bench/bench_*.py; do $(PY) $$script || exit 1; done

# mutation testing: issue 25's seven planted bugs, then mutmut over the core modules (34 min on 2 cores):
# bench/results/mutation*.{json,md}
mutate: $(STAMP)
	$(PY) bench/mutation_blind_spots.py
	$(PY) bench/mutation.py

clean:
	rm -rf $(VENV) .venv-latest demo-out build
