# Two commands on a fresh machine: `make run` and `make test` (see README).
# `make run` builds a light venv (.venv-run: bonefit[service], what the API and workers need);
# `make test` and the other targets build the development venv (.venv: bonefit[dev]).
PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
RUN_VENV ?= .venv-run
RUN_STAMP := $(RUN_VENV)/.installed

.PHONY: run test lint typecheck pytest bench clean install

$(STAMP): pyproject.toml
	@echo "make: creating $(VENV) with bonefit[dev] (service, client and the test tools)..."
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --progress-bar off -e ".[dev]"
	touch $(STAMP)

$(RUN_STAMP): pyproject.toml
	@echo "make run: creating $(RUN_VENV) with bonefit[service] (the API and workers only)..."
	$(PYTHON) -m venv $(RUN_VENV)
	$(RUN_VENV)/bin/pip install --quiet --upgrade pip
	$(RUN_VENV)/bin/pip install --progress-bar off -e ".[service]"
	touch $(RUN_STAMP)
	@echo "make run: $(RUN_VENV) ready ($$(du -sh $(RUN_VENV) | cut -f1))"

install: $(STAMP)

run: $(RUN_STAMP)
	$(RUN_VENV)/bin/bonefit serve

test: $(STAMP) lint typecheck pytest

lint: $(STAMP)
	$(BIN)/ruff check bonefit estimation service tests benchmarks

typecheck: $(STAMP)
	$(BIN)/mypy

pytest: $(STAMP)
	$(BIN)/pytest

bench: $(STAMP)
	for b in benchmarks/*.py; do $(BIN)/python $$b || exit 1; done

clean:
	rm -rf $(VENV) $(RUN_VENV) bonefit-data .mypy_cache .ruff_cache .pytest_cache
