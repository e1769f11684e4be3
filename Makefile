# Two commands for a fresh machine: `make demo` and `make test`.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
OUT    ?= out

.PHONY: demo test test-slow bench docs lint clean

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip

$(VENV)/.installed: pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install --quiet -e .
	touch $@

$(VENV)/.installed-test: pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install --quiet -e ".[test]"
	touch $@ $(VENV)/.installed

## demo: simulate the paper's large room, calibrate it, write plots and a report into out/
demo: $(VENV)/.installed
	$(BIN)/python -m bayescal demo --out $(OUT) --force

## test: the default test suite (a few minutes on 2 cores), one pytest worker per core
## (TEST_WORKERS=0 for a single process); a file's tests share a worker, so its
## module fixtures are built once, and BLAS runs one thread per worker
TEST_WORKERS ?= auto
test: $(VENV)/.installed-test
	OPENBLAS_NUM_THREADS=1 OMP_NUM_THREADS=1 MKL_NUM_THREADS=1 \
	    $(BIN)/python -m pytest -q -n $(TEST_WORKERS) --dist loadfile

$(VENV)/.installed-slow: pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install --quiet -e ".[test,nuts]"
	touch $@ $(VENV)/.installed-test $(VENV)/.installed

## test-slow: the long statistical validation (coverage, SBC, Monte-Carlo re-fits, NUTS)
test-slow: $(VENV)/.installed-slow
	$(BIN)/python -m pytest -q -m slow

# the docs build in a virtualenv of their own, with the docs extra alone: a missing
# dependency of the docs cannot hide behind the test extras
DOCS_VENV := .venv-docs

$(DOCS_VENV)/bin/python:
	$(PYTHON) -m venv $(DOCS_VENV)
	$(DOCS_VENV)/bin/python -m pip install --quiet --upgrade pip

$(DOCS_VENV)/.installed: pyproject.toml | $(DOCS_VENV)/bin/python
	$(DOCS_VENV)/bin/python -m pip install --quiet -e ".[docs]"
	touch $@

## docs: the HTML site into docs/_build/html (API reference, tutorials run at build time);
## warnings are errors; its own virtualenv (.venv-docs), so it works before `make test`.
## BAYESCAL_DOCS_QUICK=1 runs the tutorials on fewer points (CI).
docs: $(DOCS_VENV)/.installed
	MPLBACKEND=agg $(DOCS_VENV)/bin/python -m sphinx -b html -W --keep-going docs docs/_build/html

## bench: timings written to docs/performance.md (~25 min; the sampler rows include N = 20 000)
bench: $(VENV)/.installed
	$(BIN)/python studies/benchmark.py --large-n 20000 --out docs/performance.md

lint: $(VENV)/.installed-test
	$(BIN)/python -m pip install --quiet ruff
	$(BIN)/ruff check bayescal tests studies docs/conf.py docs/tutorials

clean:
	rm -rf $(VENV) $(DOCS_VENV) $(OUT) .pytest_cache build *.egg-info docs/_build docs/api docs/auto_tutorials
