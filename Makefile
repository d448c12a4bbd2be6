# jaxgrasp: `make test` and `make bench` set everything up on a fresh clone.
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
export JAXGRASP_CACHE_DIR ?= $(CURDIR)/.cache/jax

.PHONY: install test test-all lint bench assets clean

$(STAMP): pyproject.toml
	$(PY) -m venv $(VENV)
	$(BIN)/pip install --upgrade pip
	$(BIN)/pip install -e ".[dev,arviz]"
	touch $(STAMP)

install: $(STAMP)

test: $(STAMP)
	$(BIN)/python -m pytest -m "not slow" -q -n auto --maxprocesses 4 --dist worksteal

test-all: $(STAMP)
	$(BIN)/python -m pytest -q -n auto --maxprocesses 4 --dist worksteal

lint: $(STAMP)
	$(BIN)/ruff check jaxgrasp tests benchmarks

bench: $(STAMP)
	$(BIN)/python -m jaxgrasp.bench $(ARGS)

assets: $(STAMP)
	$(BIN)/python -m jaxgrasp.objects.generate

clean:
	rm -rf $(VENV) .cache .pytest_cache
