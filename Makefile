# `make demo` and `make test` each do all set-up on a fresh machine.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed

.PHONY: all env build demo test test-slow bench clean

all: demo

# virtual environment with the pinned dependencies (requirements.lock) and the project, editable
$(STAMP): pyproject.toml requirements.lock
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install -q --upgrade pip
	$(BIN)/pip install -q -c requirements.lock -e '.[dask,cosim,test,replay,bench]'
	touch $@

env: $(STAMP)

# incremental (orchestration/build.py): rebuilds only what changed, by content; about a second
# when nothing did
build: $(STAMP)
	$(BIN)/flexfusion build

demo: build
	$(BIN)/flexfusion run orchestration/scenarios/flagship.toml --out results/flagship --force
	$(BIN)/flexfusion plot results/flagship

test: $(STAMP)          # the tests build every FMU themselves (tests/conftest.py), with the kernels `flexfusion build` compiled
	$(BIN)/pytest -q

test-slow: $(STAMP)
	$(BIN)/pytest -q -m slow

bench: build
	for b in benchmarks/*.py; do echo "== $$b"; $(BIN)/python $$b || exit 1; done

clean:
	rm -rf dist build results .pytest_cache
