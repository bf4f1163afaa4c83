# zenoh-perception: every target sets itself up from a bare machine with Python 3.11+.
#   make run    create .venv when missing, install, start the service (peer mode)
#   make test   same set-up, then lint, type check and the whole test suite
#   make demo   synthetic camera + service + echo in one process
#   make bench  the detector benchmark (baseline vs. project), README table figures

SHELL := /bin/bash
VENV ?= .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
# The first Python >= 3.11 on PATH, unless PYTHON is given.
PYTHON ?= $(shell for p in python3.13 python3.12 python3.11 python3; do \
	command -v $$p >/dev/null 2>&1 && $$p -c 'import sys; sys.exit(sys.version_info < (3, 11))' 2>/dev/null \
	&& { echo $$p; break; }; done)
SETTINGS ?= config/perception.toml
ARGS ?=
PYTEST_ARGS ?=

.PHONY: venv run demo echo test lint typecheck pytest bench tools clean

$(STAMP): pyproject.toml
	@test -n "$(PYTHON)" || { echo "error: Python 3.11+ not found (set PYTHON=...)" >&2; exit 1; }
	@test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[dev]'
	@touch $(STAMP)

venv: $(STAMP)

run: venv
	$(BIN)/zenoh-perception run --settings $(SETTINGS) $(ARGS)

demo: venv
	$(BIN)/zenoh-perception demo --settings $(SETTINGS) $(ARGS)

echo: venv
	$(BIN)/zenoh-perception echo $(ARGS)

# Debian's docker-compose validates docker-compose.yml (no Docker engine runs here).
tools:
	@command -v docker-compose >/dev/null 2>&1 || { \
		echo "installing Debian's docker-compose to validate docker-compose.yml"; \
		SUDO=$$( [ "$$(id -u)" = 0 ] || echo sudo ); \
		$$SUDO apt-get update -qq && DEBIAN_FRONTEND=noninteractive $$SUDO apt-get install -y -qq docker-compose >/dev/null; }

lint: venv
	$(BIN)/ruff check zenoh_perception tests
	$(BIN)/ruff format --check zenoh_perception tests

typecheck: venv
	$(BIN)/mypy

pytest: venv tools
	$(BIN)/pytest $(PYTEST_ARGS)

test: lint typecheck pytest

bench: venv
	$(BIN)/zenoh-perception bench $(ARGS)

clean:
	rm -rf $(VENV) .mypy_cache .ruff_cache .pytest_cache .hypothesis *.egg-info
