# endocam: every target creates .venv and installs what it needs, so a fresh clone needs nothing else.
SHELL := /bin/bash
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed
SYSSTAMP := $(VENV)/.system-deps
export MUJOCO_GL ?= egl
export PYOPENGL_PLATFORM ?= egl
# uv installs no bytecode (.pyc); with PYTHONDONTWRITEBYTECODE set (as on this machine) every
# process would compile numpy, scipy, numba, MuJoCo, ... from source on each import (~4 s of CPU
# per process, and `make test` starts dozens). Unset, the first process to import a module writes
# its .pyc and every later one loads it.
unexport PYTHONDONTWRITEBYTECODE

.PHONY: demo test lint typecheck unit kernels kernel-tests no-kernel-tests bench system-deps clean

$(SYSSTAMP):
	@./.ci/system-deps
	@mkdir -p $(VENV) && touch $(SYSSTAMP)

# uv installs the same packages from PyPI as pip, ~8x faster (parallel downloads; measured on a
# fresh clone: 21 s against 2 min 51 s), which keeps a fresh clone's `make test` inside its budget.
$(STAMP): pyproject.toml $(SYSSTAMP)
	@test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q uv
	$(PY) -m uv pip install -q --python $(PY) -e ".[study,dev]"
	@touch $(STAMP)

system-deps: $(SYSSTAMP)

demo: $(STAMP)
	$(VENV)/bin/endocam demo --out out/demo

lint: $(STAMP)
	$(VENV)/bin/ruff check .
	$(VENV)/bin/ruff format --check .
	$(VENV)/bin/mypy

# Two workers on the two cores (pytest-xdist; worksteal evens out the slow study and sweep tests).
unit: $(STAMP)
	$(VENV)/bin/pytest -n 2 --dist worksteal

# numba compiles each kernel in the first process that calls it: without a compile step both
# test workers, and every process a test starts (pool workers, Ray, the CLI), compile the same
# kernels. `make test` runs two chains side by side on the two cores: `endocam compile` (one
# process, so no kernel is compiled twice) and then the suite's kernel tests on two xdist
# workers; lint and then the test modules that call no kernel (marked `no_kernels`;
# tests/conftest.py fails one that does). The second chain's log is printed when it ends.
NO_KERNEL_TESTS := $(shell grep -l '^pytestmark = pytest.mark.no_kernels' tests/test_*.py)
NO_KERNEL_LOG := .venv/no-kernel-tests.log

kernels: $(STAMP)
	@$(VENV)/bin/endocam compile

kernel-tests: kernels
	@$(VENV)/bin/pytest -n 2 --dist worksteal $(addprefix --ignore=,$(NO_KERNEL_TESTS))

no-kernel-tests: lint
	@ENDOCAM_TESTS_NO_KERNELS=1 $(VENV)/bin/pytest -p no:xdist $(NO_KERNEL_TESTS) \
		> $(NO_KERNEL_LOG) 2>&1; status=$$?; cat $(NO_KERNEL_LOG); exit $$status

test: $(STAMP)
	@$(MAKE) --no-print-directory -j2 kernel-tests no-kernel-tests

bench: $(STAMP)
	$(VENV)/bin/pytest bench/bench_*.py --benchmark-enable --benchmark-only -p no:cacheprovider -o addopts=""

clean:
	rm -rf $(VENV) out .pytest_cache .mypy_cache .ruff_cache
