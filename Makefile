# jaxgrasp: `make test` and `make bench` set everything up on a fresh clone.
SHELL := /bin/bash
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
export JAXGRASP_CACHE_DIR ?= $(CURDIR)/.cache/jax

.PHONY: install test test-all lint bench assets clean lock upgrade-check

# constraints.txt: the versions the tests last passed with (pyproject.toml keeps the ranges).
$(STAMP): pyproject.toml constraints.txt
	$(PY) -m venv $(VENV)
	$(BIN)/pip install --upgrade pip
	$(BIN)/pip install -c constraints.txt -e ".[dev,arviz]"
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

# After a green `make test`: record the installed versions as the tested ones.
LOCK_VENV ?= $(VENV)
lock:
	{ sed -n '/^#/p' constraints.txt; $(LOCK_VENV)/bin/pip freeze --exclude-editable; } \
		> constraints.tmp
	mv constraints.tmp constraints.txt

# The newest versions pyproject.toml allows, in a venv of their own: what changed, what breaks.
LATEST := .venv-latest
upgrade-check:
	rm -rf $(LATEST)
	$(PY) -m venv $(LATEST)
	$(LATEST)/bin/pip install --upgrade pip
	$(LATEST)/bin/pip install --upgrade -e ".[dev,arviz]"
	@$(LATEST)/bin/pip freeze --exclude-editable | diff <(grep -v '^#' constraints.txt) - \
		| sed -n 's/^> /newer: /p' || true
	JAXGRASP_UPGRADE_CHECK=1 $(LATEST)/bin/python -m pytest -m "not slow" -q -n auto --maxprocesses 4 --dist worksteal \
		&& echo "upgrade-check: they pass; adopt them with: make lock LOCK_VENV=$(LATEST)" \
		|| { echo "upgrade-check: the newest allowed versions FAIL (above); constraints.txt stays"; exit 1; }

clean:
	rm -rf $(VENV) $(LATEST) .cache .pytest_cache
