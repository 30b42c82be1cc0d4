# pg_node: `make train` runs the main job, `make test` runs every test.
# Both create (or reuse) .venv and install the pinned dependencies from requirements.lock;
# when nothing changed, the install step is skipped.

PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
LOCK_HASH := $(shell cat requirements.lock setup.py | sha1sum | cut -c1-12)
STAMP := $(VENV)/.installed-$(LOCK_HASH)
# uv installs the lock: the same packages as pip, in 41 s against 119 s here (parallel
# downloads and unpacking; measured in two fresh venvs, pip freeze equal). It compiles the
# bytecode at install (--compile-bytecode, 14 s more): where PYTHONDONTWRITEBYTECODE is set,
# as on this CI machine, Python never writes it, and every process of the suite compiled
# torch._dynamo, sympy and matplotlib again (5 CPU seconds each: 1,647 against 1,105 CPU s).
UV_VERSION := 0.13.9

# ament_index look-ups (message packages, pg_node's share dir) search the venv prefix.
export AMENT_PREFIX_PATH := $(abspath $(VENV))
export PYTHONPATH := $(abspath .)
export PYTHONUNBUFFERED := 1

ARGS ?=
PYTEST_ARGS ?=
# make test runs the tests in TEST_JOBS processes (pytest-xdist), a file per process at a time,
# each in DDS domains of its own (test/conftest.py); TEST_JOBS=0 runs them in this process.
# Three on two cores: the end-to-end tests wait on DDS and on real time, and a third process
# fills those waits (681 s against 790 s with two, the same CPU; docs/testing.md).
TEST_JOBS ?= 3

.PHONY: all venv train test test-fast lint bench bench-quick bench-sim profile variance lock clean

all: test

venv: $(STAMP)

# Debian packages: libosmesa6 lets MuJoCo render offscreen (python -m pg_node render).
SYSTEM_PACKAGES := libosmesa6

# Keyed on the content of requirements.lock and setup.py (in the stamp's name), not on
# their dates: a fresh clone or a checkout gives them new dates, and nothing to install.
$(STAMP):
	@for pkg in $(SYSTEM_PACKAGES); do dpkg -s $$pkg >/dev/null 2>&1 || missing="$$missing $$pkg"; done; \
	if [ -n "$$missing" ]; then \
	  echo "Installing Debian packages:$$missing"; \
	  SUDO=$$( [ "$$(id -u)" = 0 ] || echo sudo ); \
	  $$SUDO apt-get update -qq && $$SUDO apt-get install -y -qq --no-install-recommends $$missing >/dev/null; \
	fi
	@test -x $(PY) || $(PYTHON) -m venv $(VENV)
	@$(PY) -m pip install --quiet --disable-pip-version-check --upgrade pip==26.3 uv==$(UV_VERSION)
	@echo "Installing pinned dependencies into $(VENV) (first run: about a minute, 6 GB)"
	@$(PY) -m uv pip install --quiet --compile-bytecode --python $(PY) -r requirements.lock
	@echo "Installing pg_node itself into $(VENV) (editable: $(VENV)/bin/sim_node runs this checkout)"
	@# PYTHONWARNINGS: without it setuptools prints a 10-line banner about editable installs
	@PYTHONWARNINGS=ignore $(PY) -m pip install --quiet --disable-pip-version-check --no-deps \
	  --no-build-isolation -e . >/dev/null
	@rm -f $(VENV)/.installed-*
	@touch $@

train: $(STAMP)
	$(PY) -m pg_node train $(ARGS)

# pg_node's own bytecode, for the same reason (compileall redoes only the changed files)
COMPILE := $(PY) -m compileall -q pg_node test

test: $(STAMP)
	@$(COMPILE)
	$(PY) -m pytest -n $(TEST_JOBS) --dist loadfile $(PYTEST_ARGS)

test-fast: $(STAMP)
	@$(COMPILE)
	$(PY) -m pytest -n $(TEST_JOBS) --dist loadfile -m "not slow" $(PYTEST_ARGS)

lint: $(STAMP)
	$(PY) -m pytest test/test_flake8.py test/test_pep257.py

variance: $(STAMP)
	$(PY) -m pg_node variance $(ARGS)

# the benchmarks are the repository's bench package (not installed); they write docs/results/
bench: $(STAMP)
	$(PY) -m bench $(ARGS)

bench-quick: $(STAMP)
	$(PY) -m bench --quick --out /tmp/pg_node_bench $(ARGS)

bench-sim: $(STAMP)
	$(PY) bench/bench_sim.py $(ARGS)

profile: $(STAMP)
	$(PY) -m bench --only profile --report PROFILE.md $(ARGS)

# Regenerate requirements.lock after editing requirements.in.
lock:
	@test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --disable-pip-version-check -r requirements.in
	$(PY) scripts/freeze_lock.py requirements.lock

clean:
	rm -rf build install log .pytest_cache
