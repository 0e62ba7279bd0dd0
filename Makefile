# Everything a fresh machine with python3 and make needs: `make demo` and `make test`.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
BASE_STAMP := $(VENV)/.installed-base
TEST_STAMP := $(VENV)/.installed-test
DOCS_STAMP := $(VENV)/.installed-docs

.PHONY: demo test test-fast bench docs install clean

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip

$(BASE_STAMP): pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install --quiet -e .
	touch $@

$(TEST_STAMP): pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install --quiet -e ".[test]"
	touch $(BASE_STAMP) $@

$(DOCS_STAMP): pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install --quiet -e ".[docs]"
	touch $(BASE_STAMP) $@

install: $(BASE_STAMP)

demo: $(BASE_STAMP)
	$(BIN)/python -m hbjax demo --out demo_output --force

test: $(TEST_STAMP)
	$(BIN)/python -m pytest -q -p no:cacheprovider -n 2 --dist loadfile --durations=25 tests

test-fast: $(TEST_STAMP)
	$(BIN)/python -m pytest -q -p no:cacheprovider -m "not slow" tests

bench: $(TEST_STAMP)
	cd benchmarks && ../$(BIN)/python simulate.py
	cd benchmarks && ../$(BIN)/python refine.py
	cd benchmarks && ../$(BIN)/python monte_carlo.py
	cd benchmarks && ../$(BIN)/python diagnose.py
	cd benchmarks && ../$(BIN)/python against_earlier.py f15f477 c7c563c

# The documentation site (mkdocs.yml): guides from docs/, API pages from the docstrings.
docs: $(DOCS_STAMP)
	NO_MKDOCS_2_WARNING=1 $(BIN)/python -m mkdocs build --strict --site-dir site

clean:
	rm -rf $(VENV) demo_output site
