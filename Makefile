# Two commands bootstrap everything: `make demo` and `make test`. Both create .venv on first use.
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
export MUJOCO_GL ?= egl
export PYOPENGL_PLATFORM ?= egl
# Compiled bytecode and pytest's rewritten test modules are cached in __pycache__ (an empty value
# switches Python's PYTHONDONTWRITEBYTECODE off): without the cache each xdist worker and every
# `sim2real` child process a test starts compiles the project's modules again (~10 s a worker).
export PYTHONDONTWRITEBYTECODE =

.PHONY: venv demo test test-slow test-all bench lint format firmware firmware-test avr-deps docs docs-serve clean

# The AVR firmware's toolchain and simulator (Debian packages). `make test` installs them when
# missing and it runs as root (CI does); otherwise the AVR tests skip with a one-line reason.
AVR_PACKAGES := gcc-avr avr-libc arduino-core-avr simavr libsimavr-dev libsimavrparts1
AVR_READY := command -v avr-g++ >/dev/null && command -v avr-size >/dev/null \
	&& [ -f /usr/share/arduino/hardware/arduino/avr/cores/arduino/Arduino.h ] \
	&& [ -f /usr/include/simavr/sim_avr.h ]

venv: $(STAMP)

$(STAMP): pyproject.toml constraints.txt
	$(PY) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet -c constraints.txt -e '.[all,dev,docs]'
	touch $(STAMP)

demo: $(STAMP)
	$(BIN)/sim2real demo

test: $(STAMP) avr-deps
	$(BIN)/python -m pytest -n 2 --timeout 600 -q --durations=15

avr-deps:
	@if $(AVR_READY); then :; \
	elif [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null; then \
		echo "installing the AVR toolchain: $(AVR_PACKAGES)"; \
		apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq $(AVR_PACKAGES) >/dev/null; \
	else \
		echo "note: no AVR toolchain and not root: the AVR firmware tests will skip (sudo make avr-deps)"; \
	fi

# The sketch for the ATmega328P and its size report (flash, RAM; budget 75 %), then the harness.
firmware: $(STAMP) avr-deps
	$(MAKE) -C hardware/firmware/arm3 avr sim
	$(BIN)/python -m hardware.firmware.avr

# The tests marked slow (end-to-end demo, adapt, lean installs): CI runs them after `make test`.
test-slow: $(STAMP) avr-deps
	$(BIN)/python -m pytest -n 2 --timeout 3600 -q -m slow --durations=15

test-all: $(STAMP)
	$(BIN)/python -m pytest -n 2 --timeout 3600 -q -m ''

bench: $(STAMP)
	@for f in bench/*.py; do echo "# $$f"; $(BIN)/python $$f || exit 1; done

lint: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .
	$(BIN)/mypy
	$(BIN)/lint-imports  # the layers' import contracts ([tool.importlinter] in pyproject.toml)

format: $(STAMP)
	$(BIN)/ruff format .
	$(BIN)/ruff check --fix .

# The documentation site (mkdocs.yml): the benchmark pages from bench/records first, then a
# strict build (a dead link or a page missing from the nav fails). Offline once the docs extra is
# installed (make venv installs it; an older .venv gets it here).
docs: $(STAMP)
	@$(BIN)/python -c "import mkdocs, material, mkdocstrings" 2>/dev/null || \
		$(BIN)/pip install --quiet -c constraints.txt -e '.[docs]'
	$(BIN)/python bench/pages.py
	NO_MKDOCS_2_WARNING=1 $(BIN)/mkdocs build --strict --quiet

docs-serve: docs
	NO_MKDOCS_2_WARNING=1 $(BIN)/mkdocs serve

clean:
	rm -rf $(VENV) .cache build site *.egg-info
