# zenoh-perception: every target sets itself up from a bare machine with Python 3.11+.
#   make run    create .venv when missing, install, start the service (peer mode)
#   make test   same set-up, then lint, type check and the whole test suite
#   make demo   synthetic camera + service + echo in one process
#   make bench  the generator benchmark against OpenCV's default (docs/benchmarks.md)
#   make flood | soak | fuzz | stalls   the project's stress tools (tools/README.md)

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
# one pytest worker per core; the tests of one bench run share a worker (tests/bench/conftest.py)
PYTEST_ARGS ?= -n auto --dist loadgroup

.PHONY: venv run demo echo test lint typecheck pytest bench flood soak fuzz stalls exit-stress system-tools clean

$(STAMP): pyproject.toml bench/pyproject.toml
	@test -n "$(PYTHON)" || { echo "error: Python 3.11+ not found (set PYTHON=...)" >&2; exit 1; }
	@test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[dev]' -e ./bench
	@touch $(STAMP)

venv: $(STAMP)

run: venv
	$(BIN)/zenoh-perception run --settings $(SETTINGS) $(ARGS)

demo: venv
	$(BIN)/zenoh-perception demo --settings $(SETTINGS) $(ARGS)

echo: venv
	$(BIN)/zenoh-perception echo $(ARGS)

# System tools the tests use: Debian's docker-compose validates docker-compose.yml (no Docker
# engine runs here) and openssl makes the certificates of the TLS tests. Installed when missing.
SYSTEM_TOOLS := docker-compose openssl
system-tools:
	@missing=""; for t in $(SYSTEM_TOOLS); do command -v $$t >/dev/null 2>&1 || missing="$$missing $$t"; done; \
	if [ -n "$$missing" ]; then \
		echo "installing Debian packages:$$missing"; \
		SUDO=$$( [ "$$(id -u)" = 0 ] || echo sudo ); \
		$$SUDO apt-get -o DPkg::Lock::Timeout=600 update -qq && DEBIAN_FRONTEND=noninteractive $$SUDO apt-get -o DPkg::Lock::Timeout=600 install -y -qq $$missing >/dev/null; \
	fi

lint: venv
	$(BIN)/ruff check zenoh_perception bench tools tests corpus
	$(BIN)/ruff format --check zenoh_perception bench tools tests corpus

typecheck: venv
	$(BIN)/mypy

pytest: venv system-tools
	$(BIN)/pytest $(PYTEST_ARGS)

test: lint typecheck pytest

bench: venv
	$(BIN)/zenoh-perception bench $(ARGS)

# The stress tools are not installed with the package: each runs from this folder.
flood soak fuzz stalls: venv
	$(BIN)/python -m tools.$@ $(ARGS)

exit-stress: venv
	$(BIN)/python -m tools.exit_stress $(ARGS)

clean:
	rm -rf $(VENV) .mypy_cache .ruff_cache .pytest_cache .hypothesis *.egg-info
