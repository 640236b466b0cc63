# Two commands do all set-up on a fresh machine (see README.md):
#   make demo   reproduce the paper's Section 5 (both scenarios, both controllers): figures + table
#   make test   run the whole test suite (slow tests included; installs the dev, check and rl extras)
PYTHON ?= python3
VENV   ?= .venv
PY     := $(VENV)/bin/python
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
	$(PY) -m pip install --quiet -e ".[dev,check,rl]"
	touch $@

demo: $(VENV)/.core
	$(PY) -m pan1_env paper --out $(OUT)

test: $(VENV)/.dev
	$(PY) -m ruff check .
	$(PY) -m pytest -q --durations=15 tests

lint: $(VENV)/.dev
	$(PY) -m ruff check .

clean:
	rm -rf $(VENV) runs .pytest_cache .ruff_cache
