# The two commands of the README: `make demo` (the main job) and `make test`.
# Both set up .venv on first use. torch==2.13.0 is installed first, on its own: the CPU build
# is on disk here, and any other torch requirement would pull gigabytes of CUDA packages.

PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.prosplat-setup

.PHONY: setup demo test test-all bench addon lint format clean

setup: $(STAMP)

$(STAMP): pyproject.toml Makefile
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet torch==2.13.0
	$(PY) -m pip install --quiet -e ".[blender,test,bench,lora]"
	$(PY) -m prosplat.metrics.lpips_weights
	touch $(STAMP)

demo: $(STAMP)
	$(PY) -m prosplat demo

test: $(STAMP)
	$(PY) -m ruff check .
	$(PY) -m pytest

test-all: $(STAMP)
	$(PY) -m pytest -m "slow or not slow"

bench: $(STAMP)
	$(PY) benchmarks/render.py

addon: $(STAMP)
	$(PY) scripts/build_addon.py

lint: $(STAMP)
	$(PY) -m ruff check .
	$(PY) -m ruff format --check .

clean:
	rm -rf $(VENV) out .pytest_cache
