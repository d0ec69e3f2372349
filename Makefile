# Two entry points for a fresh machine with only python3 and make:
#   make demo   - create .venv, install tendonkit, run the main job
#   make test   - same set-up, then lint (ruff), type checks (mypy) and the whole test suite
# For the edit loop:
#   make check  - lint, type checks and the fast tier (no slow co-simulation, no real data)
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed-stamp

.PHONY: demo test check lint typecheck pytest pytest-fast bench clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e ".[dev]"
	touch $(STAMP)

demo: $(STAMP)
	$(BIN)/tendonkit demo --out demo-report

test: $(STAMP) lint typecheck pytest

check: $(STAMP) lint typecheck pytest-fast

lint: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .

typecheck: $(STAMP)
	$(BIN)/mypy toolkit plugins fmu

# Both cores (pytest-xdist), one BLAS thread per worker (two workers with two BLAS threads each
# oversubscribe a 2-core machine); every test is safe in parallel (tmp_path, atomic caches).
# --dist loadgroup: a module marked xdist_group runs on one worker, so its session-scoped
# fixtures (the demo run, built FMUs) are built once instead of once per worker.
ONE_THREAD := OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 MKL_NUM_THREADS=1
pytest: $(STAMP)
	$(ONE_THREAD) $(BIN)/python -m pytest -q -n auto --dist loadgroup --durations=15

pytest-fast: $(STAMP)
	$(ONE_THREAD) $(BIN)/python -m pytest -q -n auto --dist loadgroup -m "not slow and not real_data"

bench: $(STAMP)
	$(BIN)/python -m pip install --quiet -r benchmarks/requirements.txt
	$(BIN)/python benchmarks/bench_identify.py

clean:
	rm -rf $(VENV) build *.egg-info demo-report .pytest_cache .mypy_cache .ruff_cache
