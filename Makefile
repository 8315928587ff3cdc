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

.PHONY: venv demo test lint bench clean gl

venv: $(STAMP)

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --upgrade pip >/dev/null
	$(PY) -m pip install torch==2.13.0
	$(PY) -m pip install -e '.[dev,deploy,ray,gpu,rsl_rl,viewer]'
	touch $(STAMP)

demo: venv gl
	$(PY) -m legoh_rl.demo

# Off-screen OpenGL for MuJoCo's renderer (the evaluation video). Installs Mesa's EGL when it
# is missing and we may (root with apt); otherwise the demo runs and skips the video.
gl:
	@if ldconfig -p 2>/dev/null | grep -q 'libEGL.so.1'; then :; \
	elif [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null; then \
	  echo "installing Mesa EGL for off-screen rendering"; \
	  apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq libegl1 libgl1-mesa-dri >/dev/null; \
	else echo "note: no libEGL found; the demo will skip its video (install libegl1 + libgl1-mesa-dri)"; fi

test: venv
	$(PY) -m pytest -q --durations=25 tests

lint: venv
	$(VENV)/bin/ruff check legoh_rl recipes tests benchmarks

clean:
	rm -rf $(VENV) outputs wandb .pytest_cache
