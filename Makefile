# The two commands of the README. Each sets up what is missing (a .venv with the project
# installed) and is quick when everything is already there.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: run test lint bench browser clean

$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --disable-pip-version-check -e '.[dev]'
	touch $(STAMP)

run: $(STAMP)
	$(BIN)/fleet run

test: $(STAMP) browser
	$(BIN)/python -m pytest -q

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
	rm -rf $(VENV) runs .pytest_cache
