# ilcforce: `make help` lists the targets.
SHELL := /bin/bash
.DELETE_ON_ERROR:
.DEFAULT_GOAL := help

PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed
RESULTS ?= results
EXPERIMENTS := paper noise-free realistic ts-1ms long-run
# every registered method (ilcforce/controllers/__init__.py); evaluated only by targets that need it
METHODS = $(shell $(PY) -m ilcforce.controllers)
JOBS ?= $(shell nproc 2>/dev/null || echo 2)
# numba keeps compiled kernels here so that only the first run pays for compilation
export NUMBA_CACHE_DIR ?= $(CURDIR)/.venv/numba-cache

help: ## list the targets
	@grep -E '^[a-zA-Z_-]+:.*?## ' $(MAKEFILE_LIST) | awk 'BEGIN {FS = ":.*?## "}; {printf "  \033[36m%-12s\033[0m %s\n", $$1, $$2}'

$(STAMP): pyproject.toml
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet -e '.[test]'
	touch $@

install: $(STAMP) ## create .venv and install ilcforce with its test extras

test: $(STAMP) ## run the fast test suite (slow paper-level studies excluded)
	$(PY) -m pytest -q

test-slow: $(STAMP) ## run only the slow paper-level regression studies
	$(PY) -m pytest -q -m slow

bench: $(STAMP) ## print speed figures (medians over repeated runs)
	$(PY) -m ilcforce.bench

STORES = $(foreach e,$(EXPERIMENTS),$(foreach m,$(METHODS),$(RESULTS)/$(e)/$(m).h5))

SOURCES := $(shell find ilcforce -name '*.py' -o -name '*.mplstyle')

# a store is rebuilt when the code or its experiment file changes
.SECONDEXPANSION:
$(RESULTS)/%.h5: $(STAMP) $(SOURCES) experiments/$$(word 1,$$(subst /, ,$$*)).toml
	$(VENV)/bin/ilcforce simulate --config experiments/$(word 1,$(subst /, ,$*)).toml \
	    --method $(word 2,$(subst /, ,$*)) --out $@ --overwrite

stores: $(STAMP) $$(STORES)

reproduce: $(STAMP) ## run every experiment in experiments/ for every registered method (in parallel), then write the report
	$(MAKE) --no-print-directory -j $(JOBS) -O stores
	$(VENV)/bin/ilcforce report --results $(RESULTS) --out $(RESULTS)/report
	@echo "report: $(RESULTS)/report/index.md"

clean: ## remove generated results, caches and the virtual environment
	rm -rf $(RESULTS)/*/ $(VENV) .pytest_cache build *.egg-info
	find . -name __pycache__ -type d -prune -exec rm -rf {} +

.PHONY: help install test test-slow bench stores reproduce clean
