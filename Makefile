# Two commands do all set-up on a fresh machine (see README.md):
#   make demo   reproduce the paper's Section 5 (both scenarios, both controllers): figures + table
#   make test   run the whole test suite (slow tests included; installs the dev, check and rl extras,
#               and the ray extra in a venv of its own, .venv-ray, for the RLlib test)
PYTHON ?= python3
VENV   ?= .venv
PY     := $(VENV)/bin/python
RAYVENV ?= .venv-ray
RAYPY  := $(RAYVENV)/bin/python
OUT    ?= runs/paper

.PHONY: demo test lint clean

$(VENV)/.core: pyproject.toml
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e .
	touch $@

# torch first, from the local CPU build: otherwise stable-baselines3 pulls the CUDA wheels
$(VENV)/.dev: $(VENV)/.core
	$(PY) -m pip install --quiet torch==2.13.0
	$(PY) -m pip install --quiet -e ".[dev,check,rl,marl]"
	touch $@

# Ray RLlib pins gymnasium 1.2.2: its own venv keeps the main one on the newest gymnasium
$(RAYVENV)/.ray: pyproject.toml
	test -x $(RAYPY) || $(PYTHON) -m venv $(RAYVENV)
	$(RAYPY) -m pip install --quiet --upgrade pip
	$(RAYPY) -m pip install --quiet torch==2.13.0
	$(RAYPY) -m pip install --quiet -e ".[ray,dev]"
	touch $@

demo: $(VENV)/.core
	$(PY) -m pan1_env paper --out $(OUT)

test: $(VENV)/.dev $(RAYVENV)/.ray
	$(PY) -m ruff check .
	PAN1_REQUIRE_MARL=1 $(PY) -m pytest -q -n 2 --durations=15 tests
	PAN1_REQUIRE_RAY=1 $(RAYPY) -m pytest -q -p no:cacheprovider tests/test_rllib.py

lint: $(VENV)/.dev
	$(PY) -m ruff check .

clean:
	rm -rf $(VENV) $(RAYVENV) runs .pytest_cache .ruff_cache
