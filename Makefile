# Two commands do all the set-up on a fresh machine: `make run` and `make test`.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed-stamp

.PHONY: run test test-fast lint bench replay clean fuzz mutants sidecar-lerobot interop

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --disable-pip-version-check -e '.[dev]'
	touch $(STAMP)

run: $(STAMP)
	$(BIN)/warden run

replay: $(STAMP)
	$(BIN)/warden replay manifests/scenarios/seed_stale_chunk.json --pretty

# Two sets (tests/conftest.py, WARDEN_TEST_SET): the in-process tests on both cores at once
# (pytest-xdist), then the wall-clock ones (cells, devices, links, services) alone, so that
# nothing else competes with their control loops. Both run; either failing fails the target.
# `$(BIN)/pytest -q` runs every test in one process.
test: $(STAMP)
	@WARDEN_TEST_SET=in-process $(BIN)/pytest -q -n 2; in_process=$$?; \
	WARDEN_TEST_SET=wall-clock $(BIN)/pytest -q; wall_clock=$$?; \
	exit $$(( in_process || wall_clock ))

# The developer loop: the core, link, kinematics, plant and fuzz tests (no cell, emulator or
# driver; 1545 tests, 145 s of CPU, less the 22 s tests/scenarios saved by replaying each scenario
# once for the tests that read its log); `make test` runs them too, with everything else.
FAST_TESTS := tests/core tests/runtime tests/scenarios tests/wire tests/kinematics tests/plant \
	tests/fuzz tests/sidecars tests/export tests/test_layers.py

test-fast: $(STAMP)
	$(BIN)/pytest -q -m "not slow" $(FAST_TESTS)

# The LeRobot sidecar's own venv (grpcio, NumPy, msgspec, websockets: sidecars/lerobot/
# requirements.lock) under build/; prints its Python: `<python> -m sidecars.lerobot CONFIG`.
sidecar-lerobot: $(STAMP)
	$(BIN)/python -m tools.venvs lerobot-sidecar

# The simulated cell driven by LeRobot's own PolicyServer (0.4.4, a random ACT) through the
# sidecar: builds the LeRobot venv (torch from LEROBOT_WHEELS, /opt/wheels by default; about a
# minute and 1.8 GB) and reports what warden did (tests/interop/lerobot/interop.py).
interop: $(STAMP)
	$(BIN)/python -m tests.interop.lerobot.interop

lint: $(STAMP)
	$(BIN)/ruff check .

bench: $(STAMP)
	$(BIN)/python bench/admission.py
	$(BIN)/python bench/loop.py
	$(BIN)/python bench/e2e.py
	$(BIN)/python bench/kinematics.py
	$(BIN)/python bench/drivers.py
	$(BIN)/python bench/cells.py
	$(BIN)/python bench/flood.py
	$(BIN)/python bench/link_loss.py
	$(BIN)/python bench/camera_latency.py

# Coverage-guided fuzzing of the wire decoder, the scenario loader and the manifest loader
# (tests/fuzz): FUZZ_SECONDS per target with atheris, then the hypothesis fuzz and property tests
# at FUZZ_SCALE times their `make test` size. Crashes land in build/fuzz/<target>/.
FUZZ_SECONDS ?= 60
FUZZ_SCALE ?= 20
FUZZ_TARGETS := wire_frame wire_chunk scenario manifest

fuzz: $(STAMP)
	@if $(BIN)/pip install --quiet --disable-pip-version-check -e '.[dev,fuzz]'; then \
		for target in $(FUZZ_TARGETS); do \
			echo "== atheris: $$target ($(FUZZ_SECONDS) s)"; \
			$(BIN)/python -m tests.fuzz.atheris_fuzz $$target -max_total_time=$(FUZZ_SECONDS) \
				-timeout=20 -rss_limit_mb=2048 -print_final_stats=1 || exit 1; \
		done; \
	else \
		echo "atheris does not install here: running the hypothesis fuzzers only"; \
	fi
	WARDEN_FUZZ_SCALE=$(FUZZ_SCALE) $(BIN)/pytest -q tests/fuzz --hypothesis-show-statistics

# Mutation testing (mutmut, pinned in the `mutants` extra) of the safety-critical modules that
# pyproject.toml's [tool.mutmut] names, each mutant against the in-process tests that reach it;
# prints the counts per module and the survivors. Not part of `make test`: the whole set takes
# hours on two cores. MUTANTS narrows it to mutant names (globs), e.g. MUTANTS='kernel.signing.*';
# MUTANT_CHILDREN caps the parallel test runs (mutmut's default: one per core). A run that could
# not start (a test failing while mutmut collects its stats, or without mutants) fails here
# rather than printing an earlier run's results; one stopped early keeps the mutants it ran.
MUTANTS ?=
MUTANT_CHILDREN ?=

mutants: $(STAMP)
	$(BIN)/pip install --quiet --disable-pip-version-check -e '.[dev,mutants]'
	$(BIN)/mutmut run $(if $(MUTANT_CHILDREN),--max-children $(MUTANT_CHILDREN)) $(MUTANTS)
	@echo "== counts per module"
	@$(BIN)/python -m tools.mutant_counts mutants
	@echo "== survivors (mutmut show <name> prints one)"
	@$(BIN)/mutmut results

clean:
	rm -rf $(VENV) build *.egg-info .pytest_cache .hypothesis mutants
