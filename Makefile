# The two commands of the README. Each sets up what is missing (a .venv holding exactly the
# versions in requirements.lock, and the project) and is quick when everything is already there.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
PIP := $(BIN)/python -m pip --disable-pip-version-check

# The lock: exact versions, with hashes, of everything the project, its tests and its build
# install, for every platform and Python >= 3.11 (docs/dependencies.md). `make lock` refreshes
# it after pyproject.toml changes; `make upgrade` moves everything to the newest releases.
LOCK := requirements.lock
# Locked beyond pyproject's dependencies: the build backend (the project installs without build
# isolation, so nothing unlocked is fetched) and the HiGHS we chose by measurement.
LOCK_INPUTS := setuptools>=68 highspy==1.16.0
UV_VERSION := 0.13.9
TOOLS := .venv-tools
UV := $(TOOLS)/bin/uv
LATEST := .venv-latest

.PHONY: run test test-latest lock upgrade lint bench browser clean

# A changed lock or pyproject rebuilds .venv from nothing, so it never holds anything else.
$(STAMP): pyproject.toml $(LOCK)
	rm -rf $(VENV)
	$(PYTHON) -m venv $(VENV)
	$(PIP) install --quiet --require-hashes --no-deps -r $(LOCK)
	$(PIP) install --quiet --no-deps --no-build-isolation -e .
	$(PIP) check
	$(BIN)/python scripts/check_lock.py $(LOCK)
	touch $(STAMP)

run: $(STAMP)
	$(BIN)/fleet run

test: $(STAMP) browser
	$(BIN)/python -m pytest -q

# The suite on the newest releases of every dependency (what `pip install` gives a user), in
# an environment of its own, made anew each time.
test-latest: browser
	rm -rf $(LATEST)
	$(PYTHON) -m venv $(LATEST)
	$(LATEST)/bin/python -m pip --disable-pip-version-check install --quiet --upgrade pip
	$(LATEST)/bin/python -m pip --disable-pip-version-check install --quiet --upgrade \
		--upgrade-strategy eager -e '.[dev]'
	@$(LATEST)/bin/python -c "import importlib.metadata as m; \
		print('newest:', ', '.join(f'{p} {m.version(p)}' for p in ('highspy', 'pyomo', \
		'numpy', 'simpy', 'shapely', 'networkx', 'pyzmq', 'matplotlib', 'distributed')))"
	$(LATEST)/bin/python -m pytest -q -p no:cacheprovider

$(UV):
	$(PYTHON) -m venv $(TOOLS)
	$(TOOLS)/bin/python -m pip --disable-pip-version-check install --quiet uv==$(UV_VERSION)

# One resolution for every platform and Python >= 3.11, from pyproject.toml and LOCK_INPUTS.
COMPILE = printf '%s\n' $(foreach r,$(LOCK_INPUTS),'$(r)') | $(UV) pip compile pyproject.toml - \
	--extra dev --universal --python-version 3.11 --generate-hashes --quiet -o $(LOCK)

# Re-resolve after pyproject.toml changed, keeping every locked version that still fits.
lock: $(UV)
	$(COMPILE)

# Every package to its newest release that pyproject and LOCK_INPUTS allow; then `make test`.
upgrade: $(UV)
	$(COMPILE) --upgrade

# The replay page is tested in a real headless Chromium (Debian's package): install it when it
# is missing and apt-get can (as root, or through sudo without a password prompt). If it cannot,
# the browser test skips, or fails when CI is set.
SUDO := $(shell [ "$$(id -u)" = 0 ] || echo sudo -n)
browser:
	@command -v chromium >/dev/null 2>&1 || command -v chromium-browser >/dev/null 2>&1 || \
	! command -v apt-get >/dev/null 2>&1 || { \
		echo "installing Debian's chromium for the replay's browser test"; \
		$(SUDO) apt-get update -qq && \
		DEBIAN_FRONTEND=noninteractive $(SUDO) apt-get install -y -qq chromium >/dev/null || \
		echo "could not install chromium: the replay's browser test will skip (fail under CI)"; }

lint: $(STAMP)
	$(BIN)/ruff check fleet plugins tests scripts

bench: $(STAMP)
	$(BIN)/python scripts/bench_engine.py

clean:
	rm -rf $(VENV) $(LATEST) $(TOOLS) runs .pytest_cache
