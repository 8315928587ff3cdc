# The README's two commands: `make demo` (main job) and `make test` (test suite).
# Both create or refresh the local virtual environment first.
PYTHON ?= python3
VENV   ?= .venv
PY      = $(VENV)/bin/python
STAMP   = $(VENV)/.installed

# Offline robot models: use ../shared/robots when it is there and the user set nothing.
ifeq ($(origin MENAGERIE_ROOT), undefined)
  ifneq ($(wildcard ../shared/robots/unitree_h1),)
    export MENAGERIE_ROOT := $(abspath ../shared/robots)
  endif
endif
export WANDB_MODE ?= offline
export MUJOCO_GL ?= egl

.PHONY: venv demo test lint bench clean

venv: $(STAMP)

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --upgrade pip >/dev/null
	$(PY) -m pip install torch==2.13.0
	$(PY) -m pip install -e '.[dev]'
	touch $(STAMP)

demo: venv
	$(PY) -m legoh_rl.demo

test: venv
	$(PY) -m pytest -q tests

lint: venv
	$(VENV)/bin/ruff check legoh_rl recipes tests benchmarks

clean:
	rm -rf $(VENV) outputs wandb .pytest_cache
