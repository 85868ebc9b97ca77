# gelcell: two commands do everything on a fresh Debian 12 machine.
#   make run   - install what is missing, run the shear-flow baseline with a cell
#   make test  - install what is missing, run the test suite (serial + 2 MPI ranks)
#   make lint  - the linter (ruff, installed into .venv; settings in pyproject.toml)
#   make benchmark - performance tables (benchmarks/performance.py; BENCHMARK_ARGS="--sizes 1 0.5")

VENV      := .venv
PY        := $(VENV)/bin/python
STAMP     := $(VENV)/.gelcell-installed
RUN_OUT   ?= results/shear-baseline
export OMPI_ALLOW_RUN_AS_ROOT := 1
export OMPI_ALLOW_RUN_AS_ROOT_CONFIRM := 1
export OMPI_MCA_rmaps_base_oversubscribe := 1
export OMPI_MCA_mpi_yield_when_idle := 1
export MPLBACKEND := Agg

.PHONY: all setup run test test-serial test-mpi lint benchmark clean

all: test

# byte-compile the packages: with PYTHONDONTWRITEBYTECODE set (as on some CI images) every process
# would otherwise compile them again (~0.2 s per command); up-to-date files are skipped
setup: $(STAMP)
	@$(PY) -m compileall -q -j 0 coupling fluid gel cell gelcell femtools

$(STAMP): pyproject.toml scripts/ensure-system-packages $(wildcard */__init__.py)
	./scripts/ensure-system-packages
	test -x $(PY) || /usr/bin/python3 -m venv --system-site-packages $(VENV)
	$(PY) -m pip install --no-build-isolation --no-deps -q -e .
	touch $(STAMP)

run: setup
	$(VENV)/bin/gelcell run shear --compare-no-cell --out $(RUN_OUT)

# the serial suite on every core (pytest-xdist; a file's tests stay in one worker, which shares its fixtures)
test: setup
	$(PY) -m pytest -q -ra --durations=15 -n auto --dist loadfile
	./scripts/pytest-2-ranks

RUFF      := $(VENV)/bin/ruff
RUFF_VERSION := 0.17.6

lint: setup
	test -x $(RUFF) && $(RUFF) --version | grep -q " $(RUFF_VERSION)$$" || $(PY) -m pip install -q "ruff==$(RUFF_VERSION)"
	$(RUFF) check .

# performance tables of the shear baseline (timings printed, never asserted), then the timing tests
benchmark: setup
	$(PY) benchmarks/performance.py $(BENCHMARK_ARGS)
	$(PY) -m pytest -q -s -m benchmark

clean:
	rm -rf $(VENV) results .pytest_cache
