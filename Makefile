# Two commands do all set-up on a fresh machine (see README.md):
#   make demo   reproduce the paper's Section 5 (both scenarios, both controllers): figures + table
#   make test   run the whole test suite (slow tests included; installs the dev, check, rl and marl extras,
#               and the ray and benchmarl extras together in a venv of their own, .venv-pinned)
PYTHON ?= python3
VENV   ?= .venv
PY     := $(VENV)/bin/python
PINVENV ?= .venv-pinned
PINPY  := $(PINVENV)/bin/python
OUT    ?= runs/paper
# pip's wheel cache would keep a second copy of every download on a machine whose disk may be small
export PIP_NO_CACHE_DIR := 1

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

# Ray RLlib pins gymnasium 1.2.2 and BenchMARL pins TorchRL < 0.12: one venv holds both, so the main venv keeps
# the newest of each and a fresh machine unpacks torch twice, not three times (disk, not time, is what runs out).
# BenchMARL pulls torchvision, whose newest wheel would replace torch: the torchvision of torch 2.13 goes in first.
$(PINVENV)/.pinned: pyproject.toml
	test -x $(PINPY) || $(PYTHON) -m venv $(PINVENV)
	$(PINPY) -m pip install --quiet --upgrade pip
	$(PINPY) -m pip install --quiet torch==2.13.0 torchvision==0.28.0
	$(PINPY) -m pip install --quiet -e ".[ray,benchmarl,dev]"
	touch $@

demo: $(VENV)/.core
	$(PY) -m pan1_env paper --out $(OUT)

test: $(VENV)/.dev $(PINVENV)/.pinned
	$(PY) -m ruff check .
	PAN1_REQUIRE_MARL=1 $(PY) -m pytest -q -n 2 --durations=15 tests
	PAN1_REQUIRE_RAY=1 PAN1_REQUIRE_BENCHMARL=1 $(PINPY) -m pytest -q -p no:cacheprovider \
		tests/test_rllib.py tests/test_benchmarl.py

lint: $(VENV)/.dev
	$(PY) -m ruff check .

# .venv-ray and .venv-benchmarl: the separate venvs of older checkouts
clean:
	rm -rf $(VENV) $(PINVENV) .venv-ray .venv-benchmarl runs .pytest_cache .ruff_cache
