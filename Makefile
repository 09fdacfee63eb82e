# Two commands for a fresh machine: `make demo` and `make test`.
# Both create .venv when it is missing; the stamp files reinstall when pyproject.toml changes.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin

.PHONY: demo test bench clean datasets

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --upgrade pip setuptools wheel

$(VENV)/.installed: $(BIN)/python pyproject.toml
	$(BIN)/python -m pip install -e .
	touch $@

$(VENV)/.installed-test: $(BIN)/python pyproject.toml
	$(BIN)/python -m pip install -e ".[test]"
	touch $@ $(VENV)/.installed

demo: $(VENV)/.installed
	$(BIN)/lcmr-xr demo --output-dir demo-output --overwrite

# One BLAS/OpenMP thread: the kernels batch their own work, and threaded BLAS on tiny
# matrices is much slower on a loaded two-core machine.
THREADS := OPENBLAS_NUM_THREADS=1 OMP_NUM_THREADS=1 MKL_NUM_THREADS=1

test: $(VENV)/.installed-test
	$(THREADS) MPLBACKEND=Agg $(BIN)/python -m pytest

# Benchmarks run as users do: default thread settings, nothing exported (issue 12).
bench: $(VENV)/.installed-test  # the benchmarks compare against the tests' oracles
	for b in benchmarks/*.py; do $(BIN)/python $$b || exit 1; done

datasets: $(VENV)/.installed
	$(BIN)/python datasets/make_hdd_experiments.py

clean:
	rm -rf $(VENV) demo-output .pytest_cache
