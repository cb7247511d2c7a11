# ilcforce: `make help` lists the targets.
SHELL := /bin/bash
.DELETE_ON_ERROR:
.DEFAULT_GOAL := help

PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed
RESULTS ?= results
# every experiment file in experiments/ (a file with a [study] table is a study, run by `make studies`)
EXPERIMENTS := $(patsubst experiments/%.toml,%,$(shell grep -L '^\[study\]' experiments/*.toml))
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
	@# bytecode as a regular install has it (an editable one under PYTHONDONTWRITEBYTECODE never writes it)
	$(PY) -m compileall -q ilcforce
	$(PY) -m ilcforce.bench

STORES = $(foreach e,$(EXPERIMENTS),$(foreach m,$(METHODS),$(RESULTS)/$(e)/$(m).h5))

SOURCES := $(shell find ilcforce -name '*.py' -o -name '*.mplstyle')

# a store is rebuilt when the code or its experiment file changes
.SECONDEXPANSION:
$(RESULTS)/%.h5: $(STAMP) $(SOURCES) experiments/$$(word 1,$$(subst /, ,$$*)).toml
	$(VENV)/bin/ilcforce simulate --config experiments/$(word 1,$(subst /, ,$*)).toml \
	    --method $(word 2,$(subst /, ,$*)) --out $@ --overwrite

stores: $(STAMP) $$(STORES)

# Studies: every experiments/*.toml with a [study] table (its study.name must be the file's stem).
# A study resumes where it stopped; --replace-stale starts it over only if its settings or the
# simulation code changed (unchanged cells are kept, so a rerun after a report-only change is quick).
STUDY_FILES := $(shell grep -l '^\[study\]' experiments/*.toml 2>/dev/null)
STUDIES := $(patsubst experiments/%.toml,%,$(STUDY_FILES))
STUDY_STORES := $(foreach s,$(STUDIES),$(RESULTS)/studies/$(s).h5)
.PRECIOUS: $(RESULTS)/studies/%.h5
$(RESULTS)/studies/%.h5: $(STAMP) $(SOURCES) experiments/%.toml $(wildcard experiments/*.toml)
	$(VENV)/bin/ilcforce study experiments/$*.toml --results $(RESULTS) --replace-stale
	touch $@

studies: $(STUDY_STORES) ## run every study in experiments/ (all cores each, one after another)

reproduce: $(STAMP) ## run every experiment (every registered method, in parallel) and every study in experiments/, then write the report
	$(MAKE) --no-print-directory -j $(JOBS) -O stores
	$(MAKE) --no-print-directory studies
	$(VENV)/bin/ilcforce report --results $(RESULTS) --out $(RESULTS)/report
	@echo "report: $(RESULTS)/report/index.md"

readme-findings: $(STAMP) ## copy the report's generated findings (results/report/findings.md) into README.md
	$(PY) -m ilcforce.report.readme update README.md $(RESULTS)/report/findings.md

check-readme: $(STAMP) ## fail when README.md's findings differ from the report's (run after make reproduce)
	$(PY) -m ilcforce.report.readme check README.md $(RESULTS)/report/findings.md

clean: ## remove generated results, caches and the virtual environment
	rm -rf $(RESULTS)/*/ $(VENV) .pytest_cache build *.egg-info
	find . -name __pycache__ -type d -prune -exec rm -rf {} +

.PHONY: help install test test-slow bench stores studies reproduce readme-findings check-readme clean
