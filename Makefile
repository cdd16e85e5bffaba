# The two commands of the README: `make demo` (the main job) and `make test`.
# Both set up .venv on first use. torch==2.13.0 is installed first, on its own: the CPU build
# is on disk here, and any other torch requirement would pull gigabytes of CUDA packages.

PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.prosplat-setup

.PHONY: setup setup-blender demo test test-addon test-all bench addon lint format clean

setup: $(STAMP)

# Run-time requirements are held at addon/core/pins.py's versions (the set the add-on installs and
# the tests assert on), so a clean clone tests what was pinned, not whatever the index holds
# today. To move a pin: pip install -U it in .venv, then python scripts/pin_requirements.py.
CONSTRAINTS := $(VENV)/constraints.txt

$(STAMP): pyproject.toml Makefile addon/core/pins.py
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -c "import runpy; p = runpy.run_path('addon/core/pins.py'); \
		print(*(f'{n}=={v}' for n, v in p['PINS'] if n != 'torch'), sep='\n')" > $(CONSTRAINTS)
	$(PY) -m pip install --quiet torch==2.13.0
	$(PY) -m pip install --quiet -c $(CONSTRAINTS) -e ".[blender,test,bench,lora]"
	$(PY) -m prosplat.metrics.lpips_weights
	touch $(STAMP)

# The add-on on the Blender artists run today: Blender 5.1 and later bundle Python 3.13 and
# numpy 2, so a second venv holds bpy $(BPY) (PyPI's Blender-as-a-module) on Python 3.13, with
# the pinned set. PyPI has no CPU build of torch for 3.13, so its CUDA build comes (about 3 GB,
# a minute here; it runs on the CPU); its triton is removed, as the CPU build Install
# Requirements gives artists has none, and importing triton after an EEVEE render crashes.
# Another Blender: make test-addon BPY=5.2.3.
BPY      ?= 5.3.0
PYTHON313 ?= $(firstword $(wildcard $(HOME)/.pyenv/versions/3.13*/bin/python3.13) \
                         $(shell command -v python3.13 2>/dev/null))
VENV_BPY := .venv-bpy$(BPY)
PY_BPY   := $(VENV_BPY)/bin/python
STAMP_BPY := $(VENV_BPY)/.prosplat-setup

setup-blender: $(STAMP_BPY)

$(STAMP_BPY): $(STAMP)
	@test -n "$(PYTHON313)" || { echo "no Python 3.13 found: make PYTHON313=/path/to/python3.13"; exit 1; }
	test -x $(PY_BPY) || $(PYTHON313) -m venv $(VENV_BPY)
	$(PY_BPY) -m pip install --quiet --upgrade pip
	$(PY_BPY) -m pip install --quiet torch==$$($(PY) -c "import runpy; print(runpy.run_path('addon/core/pins.py')['TORCH_VERSION'])")
	$(PY_BPY) -m pip install --quiet -c $(CONSTRAINTS) bpy==$(BPY) -e ".[test]"
	$(PY_BPY) -m pip uninstall --quiet --yes triton
	touch $(STAMP_BPY)

# Tests run on every core (pytest-xdist), a file per worker at a time: an add-on test file's
# tests share one Blender's state. `make test JOBS=0` runs them in this one process.
JOBS   ?= auto
XDIST  := -n $(JOBS) --dist loadfile

demo: $(STAMP)
	$(PY) -m prosplat demo

test: $(STAMP) $(STAMP_BPY)
	$(PY) -m ruff check .
	$(PY) -m pytest $(XDIST)
	$(PY_BPY) -m pytest $(XDIST) tests/addon

# The add-on's tests alone, on bpy $(BPY) (Python 3.13)
test-addon: $(STAMP_BPY)
	$(PY_BPY) -m pytest $(XDIST) tests/addon

test-all: $(STAMP)
	$(PY) -m pytest $(XDIST) -m "slow or not slow"

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
