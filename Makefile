# Two commands do all the set-up on a fresh machine: `make run` and `make test`.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed-stamp

.PHONY: run test lint bench replay clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --disable-pip-version-check -e '.[dev]'
	touch $(STAMP)

run: $(STAMP)
	$(BIN)/warden run

replay: $(STAMP)
	$(BIN)/warden replay manifests/scenarios/seed_stale_chunk.json --pretty

test: $(STAMP)
	$(BIN)/pytest -q

lint: $(STAMP)
	$(BIN)/ruff check .

bench: $(STAMP)
	$(BIN)/python bench/admission.py
	$(BIN)/python bench/loop.py
	$(BIN)/python bench/e2e.py
	$(BIN)/python bench/kinematics.py
	$(BIN)/python bench/drivers.py

clean:
	rm -rf $(VENV) build *.egg-info .pytest_cache .hypothesis
