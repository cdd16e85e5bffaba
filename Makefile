# The two commands of the README: `make demo` (the main job) and `make test`.
# Both set up .venv on first use. torch==2.13.0 is installed first, on its own: the CPU build
# is on disk here, and any other torch requirement would pull gigabytes of CUDA packages.

PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.prosplat-setup

.PHONY: setup demo test test-all bench addon lint format clean

setup: $(STAMP)

# Run-time requirements are held at addon/pins.py's versions (the set the add-on installs and
# the tests assert on), so a clean clone tests what was pinned, not whatever the index holds
# today. To move a pin: pip install -U it in .venv, then python scripts/pin_requirements.py.
CONSTRAINTS := $(VENV)/constraints.txt

$(STAMP): pyproject.toml Makefile addon/pins.py
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -c "import runpy; p = runpy.run_path('addon/pins.py'); \
		print(*(f'{n}=={v}' for n, v in p['PINS'] if n != 'torch'), sep='\n')" > $(CONSTRAINTS)
	$(PY) -m pip install --quiet torch==2.13.0
	$(PY) -m pip install --quiet -c $(CONSTRAINTS) -e ".[blender,test,bench,lora]"
	$(PY) -m prosplat.metrics.lpips_weights
	touch $(STAMP)

demo: $(STAMP)
	$(PY) -m prosplat demo

test: $(STAMP)
	$(PY) -m ruff check .
	$(PY) -m pytest

test-all: $(STAMP)
	$(PY) -m pytest -m "slow or not slow"

# The whole system's numbers (BENCHMARKS.md): renders the test and hard scenes once (skipped
# when present; ~10 min), then speed against error, the hard-case suite and the rasterizer.
HARD := textureless specular near_far thin_structures repeated_pattern inside_outside
SCENES := $(VENV)/bin/prosplat scenes render --size 64 --inputs 6 --targets 8 --samples 16

bench: $(STAMP)
	$(SCENES) --seed 950000 --count 6 --out data/test64 --workers 2
	seed=950100; for s in $(HARD); do \
		$(SCENES) --seed $$seed --count 1 --scene $$s --out data/hard64 --workers 1 || exit 1; \
		seed=$$((seed + 1)); \
	done
	$(VENV)/bin/prosplat bench points --data data/test64 data/hard64
	$(VENV)/bin/prosplat bench hard --data data/test64 data/hard64
	$(PY) benchmarks/render.py

addon: $(STAMP)
	$(PY) scripts/build_addon.py

lint: $(STAMP)
	$(PY) -m ruff check .
	$(PY) -m ruff format --check .

clean:
	rm -rf $(VENV) out .pytest_cache
