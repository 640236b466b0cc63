# Two commands do all set-up on a fresh machine (see README.md):
#   make demo   reproduce the paper's Section 5 (both scenarios, both controllers): figures + table
#   make test   run the whole test suite (slow tests included; installs the dev, check, rl and marl extras,
#               and the ray and benchmarl extras in venvs of their own, .venv-ray and .venv-benchmarl)
PYTHON ?= python3
VENV   ?= .venv
PY     := $(VENV)/bin/python
RAYVENV ?= .venv-ray
RAYPY  := $(RAYVENV)/bin/python
BMVENV ?= .venv-benchmarl
BMPY   := $(BMVENV)/bin/python
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

# BenchMARL pins TorchRL < 0.12 (the main venv has the newest) and pulls torchvision, whose newest wheel
# would replace torch: its own venv, with the torchvision of torch 2.13 installed first
$(BMVENV)/.benchmarl: pyproject.toml
	test -x $(BMPY) || $(PYTHON) -m venv $(BMVENV)
	$(BMPY) -m pip install --quiet --upgrade pip
	$(BMPY) -m pip install --quiet torch==2.13.0 torchvision==0.28.0
	$(BMPY) -m pip install --quiet -e ".[benchmarl,dev]"
	touch $@

demo: $(VENV)/.core
	$(PY) -m pan1_env paper --out $(OUT)

test: $(VENV)/.dev $(RAYVENV)/.ray $(BMVENV)/.benchmarl
	$(PY) -m ruff check .
	PAN1_REQUIRE_MARL=1 $(PY) -m pytest -q -n 2 --durations=15 tests
	PAN1_REQUIRE_RAY=1 $(RAYPY) -m pytest -q -p no:cacheprovider tests/test_rllib.py
	PAN1_REQUIRE_BENCHMARL=1 $(BMPY) -m pytest -q -p no:cacheprovider tests/test_benchmarl.py

lint: $(VENV)/.dev
	$(PY) -m ruff check .

clean:
	rm -rf $(VENV) $(RAYVENV) $(BMVENV) runs .pytest_cache .ruff_cache
