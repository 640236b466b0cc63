# Two commands do all set-up on a fresh machine (see README.md):
#   make demo   reproduce the paper's Section 5 (both scenarios, both controllers): figures + table
#   make test   run the whole test suite (slow tests included) in .venv, which holds every extra
#               (dev, check, rl, marl, benchmarl, ray, suite): one venv, torch unpacked once
PYTHON ?= python3
VENV   ?= .venv
PY     := $(VENV)/bin/python
OUT    ?= runs/paper
# pip's wheel cache would keep a second copy of every download on a machine whose disk may be small
export PIP_NO_CACHE_DIR := 1

.PHONY: demo test lint venv clean

$(VENV)/.core: pyproject.toml
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e .
	touch $@

# torch first, from the local CPU build, with the torchvision built for it: otherwise stable-baselines3 pulls
# the CUDA wheels, and BenchMARL's torchvision would replace torch. BenchMARL pins TorchRL < 0.12 and RLlib
# Gymnasium 1.2.2: the extras' pins (pyproject.toml) keep both, and pan1_env.marl supports that TorchRL.
$(VENV)/.dev: $(VENV)/.core
	$(PY) -m pip install --quiet torch==2.13.0 torchvision==0.28.0
	$(PY) -m pip install --quiet -e ".[dev,check,rl,marl,benchmarl,ray,suite]"
	touch $@

venv: $(VENV)/.dev

demo: $(VENV)/.core
	$(PY) -m pan1_env paper --out $(OUT)

test: $(VENV)/.dev
	$(PY) -m ruff check .
	PAN1_REQUIRE_MARL=1 PAN1_REQUIRE_RAY=1 PAN1_REQUIRE_BENCHMARL=1 $(PY) -m pytest -q -n 2 --durations=15 tests

lint: $(VENV)/.dev
	$(PY) -m ruff check .

# .venv-pinned, .venv-ray and .venv-benchmarl: the separate venvs of older checkouts
clean:
	rm -rf $(VENV) .venv-pinned .venv-ray .venv-benchmarl runs .pytest_cache .ruff_cache
