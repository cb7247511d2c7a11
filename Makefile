# ilcforce: `make help` lists the targets.
SHELL := /bin/bash
.DELETE_ON_ERROR:
.DEFAULT_GOAL := help

PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed
RESULTS ?= results
# every experiment file in experiments/ (a file with a [study] table is a study, run by `make studies`), but the
# tuned ones (*-tuned.toml, written by `make tune`): their gains are judged by their held-out studies
# (tuned-mc, serial2r-tuned-mc), never by a single run on seed 0; and the robots read from a model file
# (*-model.toml): their compiled chain kernels still run about 35x slower than the closed forms
# (docs/model.md#model-file), so they run on demand (`ilcforce compare -c experiments/serial2r-model.toml`);
# and the spatial arm (arm3): its evidence is its study over 20 held-out seeds (arm3-mc, every method with a
# law for three axes, SL-adapt included), not a single run on seed 0
EXPERIMENTS := $(filter-out %-tuned %-model arm3,$(patsubst experiments/%.toml,%,$(shell grep -L '^\[study\]' experiments/*.toml)))
# every registered method (ilcforce/controllers/__init__.py, then any installed plugin's: docs/plugins.md);
# evaluated only by targets that need it
METHODS = $(shell $(PY) -m ilcforce.controllers)
JOBS ?= $(shell nproc 2>/dev/null || echo 2)
# numba keeps compiled kernels here so that only the first run pays for compilation
export NUMBA_CACHE_DIR ?= $(CURDIR)/.venv/numba-cache

help: ## list the targets
	@grep -E '^[a-zA-Z_-]+:.*?## ' $(MAKEFILE_LIST) | awk 'BEGIN {FS = ":.*?## "}; {printf "  \033[36m%-16s\033[0m %s\n", $$1, $$2}'

$(STAMP): pyproject.toml
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet -e '.[test]'
	touch $@

SOURCES := $(shell find ilcforce -name '*.py' -o -name '*.mplstyle')

# the simulation kernels compiled ahead of time (ilcforce/compiled/aot.py): commands then run without numba
# in the process. Checked at every make (a fraction of a second): rebuilt when a kernel's source
# changed or the module is missing or damaged; a failed build is recorded and commands run through
# numba instead. Results never depend on it (same numbers either way), so stores only wait for it.
aot: $(STAMP)
	@$(PY) -m ilcforce.compiled.build
	@# bytecode as a regular install has it, also where PYTHONDONTWRITEBYTECODE is set (an editable
	@# install then never writes it, and every command compiled ilcforce's sources anew: about 40 ms)
	@$(PY) -m compileall -q ilcforce

install: $(STAMP) aot ## create .venv, install ilcforce with its test extras and compile its kernels

# TEST_WORKERS: pytest-xdist's worker processes (auto: one per core; 0 runs the tests in this process)
TEST_WORKERS ?= auto

test: $(STAMP) aot ## run the fast test suite (slow paper-level studies excluded) on every core
	$(PY) -m pytest -q -n $(TEST_WORKERS)

test-slow: $(STAMP) aot ## run only the slow paper-level regression studies
	$(PY) -m pytest -q -m slow

# BENCH_ARGS, e.g. --against ../old/.venv/bin/ilcforce (another tree's cold commands beside these)
bench: $(STAMP) aot ## print speed figures (medians over repeated runs)
	$(PY) -m benchmarks $(BENCH_ARGS)

STORES = $(foreach e,$(EXPERIMENTS),$(foreach m,$(METHODS),$(RESULTS)/$(e)/$(m).h5))
comma := ,
empty :=
space := $(empty) $(empty)

# a store is rebuilt when the code or its experiment file changes
.SECONDEXPANSION:
$(RESULTS)/%.h5: $(STAMP) $(SOURCES) experiments/$$(word 1,$$(subst /, ,$$*)).toml | aot
	$(VENV)/bin/ilcforce simulate --config experiments/$(word 1,$(subst /, ,$*)).toml \
	    --method $(word 2,$(subst /, ,$*)) --out $@ --overwrite

# `make stores`: one `ilcforce compare` per experiment runs every registered method at once (one
# worker process each, sharing the cores): one cold start per experiment instead of one per store.
# All of an experiment's stores are rerun when the code or its experiment file changes (the marker
# .stores records when they were made). A single store can still be made: make results/paper/c3.h5
$(RESULTS)/%/.stores: $(STAMP) $(SOURCES) experiments/%.toml | aot
	@rm -f $(foreach m,$(METHODS),$(RESULTS)/$*/$(m).h5)
	$(VENV)/bin/ilcforce compare --config experiments/$*.toml --results $(RESULTS) \
	    --methods $(subst $(space),$(comma),$(strip $(METHODS)))
	@test "$$(ls $(foreach m,$(METHODS),$(RESULTS)/$*/$(m).h5) | wc -l)" = "$(words $(METHODS))" || \
	    { echo "experiments/$*.toml: its experiment.name must be '$*' (the stores go to results/<name>/)"; exit 1; }
	touch $@

stores: $(STAMP) $$(foreach e,$$(EXPERIMENTS),$$(RESULTS)/$$(e)/.stores)

# Studies: every experiments/*.toml with a [study] table (its study.name must be the file's stem),
# all in one `ilcforce study` command on one local cluster (started once, its workers kept warm).
# A study resumes where it stopped; --replace-stale starts it over only if its settings or the
# simulation code changed (unchanged studies are skipped in seconds, so this always runs).
STUDY_FILES := $(shell grep -l '^\[study\]' experiments/*.toml 2>/dev/null)
# the paper's Monte Carlo first: the report leads with it
STUDY_FILES := $(filter experiments/paper-mc.toml,$(STUDY_FILES)) $(filter-out experiments/paper-mc.toml,$(STUDY_FILES))

studies: $(STAMP) aot ## run every study in experiments/ (on all cores, one after another, one cluster)
	$(VENV)/bin/ilcforce study $(STUDY_FILES) --results $(RESULTS) --replace-stale

calibrate: $(STAMP) aot ## fit noise.scale to Table 2 (experiments/calibration.toml) and write experiments/paper-calibrated.toml
	$(VENV)/bin/ilcforce study experiments/calibration.toml --results $(RESULTS) --replace-stale
	$(PY) -m ilcforce.report.calibration $(RESULTS)/studies/calibration.h5 --write experiments/paper-calibrated.toml

# the claim map with 20 seeds a cell (make reproduce runs experiments/claim-map.toml, 5 seeds a cell);
# the next `ilcforce report` reports it beside the 5-seed one
claim-map: $(STAMP) aot ## the claim map over noise level x sample time with 20 seeds a cell (about 10 minutes on 2 cores)
	$(VENV)/bin/ilcforce study experiments/full/claim-map-full.toml --results $(RESULTS) --replace-stale
	$(VENV)/bin/ilcforce report --results $(RESULTS) --out $(RESULTS)/report

reproduce: $(STAMP) aot ## run every experiment (every registered method, in parallel) and every study in experiments/, then write the report
	$(MAKE) --no-print-directory -j $(JOBS) -O stores
	$(MAKE) --no-print-directory studies
	$(VENV)/bin/ilcforce report --results $(RESULTS) --out $(RESULTS)/report
	@echo "report: $(RESULTS)/report/index.html (open it in a browser; the Markdown pages beside it: index.md)"

# The long runs (experiments/long/): every method over 1,000 iterations on 10 held-out seeds and the growth
# test checked against 300-iteration truth, and C3-robust taken apart (c3-robust-ablation.toml: 65 cells of 300
# iterations, about 17 minutes more; its own page docs/long-run/c3-robust-ablation.md, linked from long-run.md;
# c3-robust-leak-1000.toml, 4 cells of 1,000 iterations, about 3 minutes), and the tuned five-bar's NO-ILC
# against C3 and the robust variants at equal chattering (long-equal-chattering*.toml: 20 cells of 300
# iterations, about 2 minutes; its own page docs/long-run/equal-chattering-long.md, linked from long-run.md).
# Not part of `make reproduce` (about 30 minutes on 2 cores before the ablation); its
# summary page is committed as docs/long-run/long-run.md (dated, with the commit) and the findings cite it.
# `ilcforce report` writes the same pages into the report when these stores are in $(RESULTS)/studies/, and
# otherwise copies the committed ones in (docs/long-run/: its long-run/ folder, on the site's long runs page).
# the study files only (experiments/long/ also holds experiment files the studies run, e.g. fivebar-tuned-error-only.toml)
LONG_STUDIES := $(sort $(shell grep -l '^\[study\]' experiments/long/*.toml))

long: $(STAMP) aot ## run the long studies (1,000 iterations; the growth test's validation) and write docs/long-run/
	$(VENV)/bin/ilcforce study $(LONG_STUDIES) --results $(RESULTS) --replace-stale
	$(PY) -m ilcforce.report.long_run --results $(RESULTS) --out docs/long-run
	$(PY) -m ilcforce.theory.q_evidence --results $(RESULTS) --out docs/lifted

# The lifted check against the simulation (ilcforce/theory/): each learning method's predicted band growth
# beside the growth measured from 220-iteration runs with noise on held-out seeds, and the predicted
# boundedness beside docs/long-run/ (see docs/lifted/validation.md for the time it took)
lifted: $(STAMP) aot ## the lifted-system check against long runs on the five-bar and the 2R arm: writes docs/lifted/
	$(PY) -m ilcforce.theory.validation experiments/paper.toml experiments/serial2r.toml --out docs/lifted

# The contact model cross-checked (ilcforce/crosscheck/): C1, C2, C3, C2-robust and C3-robust on the 2R arm and the
# spatial arm from their model files, ilcforce's plant beside MuJoCo's with its own soft contact (three contact
# variants) for 20 iterations on seed 0, and the matched variant on seeds 1 and 2. One process; the page states the
# time it took (30.5 minutes here, on 2 shared cores).
crosscheck: $(STAMP) aot ## MuJoCo as the plant, its own contact against a plane, beside ilcforce's: writes docs/crosscheck.md
	$(PY) -m ilcforce.crosscheck.page --experiments experiments/serial2r-model.toml,experiments/arm3.toml \
		--out docs/crosscheck.md --iters 20 --seed 0 --extra-seeds 1,2 --save $(RESULTS)/crosscheck/rows.pkl

findings: $(STAMP) ## copy the report's generated findings (results/report/findings.md) into docs/findings.md
	$(PY) -m ilcforce.report.readme update docs/findings.md $(RESULTS)/report/findings.md

check-findings: $(STAMP) ## fail when docs/findings.md differs from the report's findings (run after make reproduce)
	$(PY) -m ilcforce.report.readme check docs/findings.md $(RESULTS)/report/findings.md

readme-findings: findings
check-readme: check-findings

# Tuning is not part of `make reproduce`: its results are committed as the experiment files
# experiments/*-tuned.toml (each stating the tuning file, the budget and what each method ships) and the pages
# docs/tuning/<name>/ (every search's convergence, every front re-evaluated on held-out seeds: pareto.csv,
# fronts.png, convergence.png), which `ilcforce report` copies into the report when no tuning store is there.
# `tune -o` never replaces a file unasked (and --overwrite would also discard the stored trials), so each
# tuned file is written beside the results, then moved over the committed one on success.
TUNINGS := fivebar serial2r arm3

tune: $(STAMP) aot ## tune each tuning file's methods (error and chattering, stable over 60 iterations) on every robot (experiments/tuning/); writes experiments/*-tuned.toml and docs/tuning/
	@times=""; for robot in $(TUNINGS); do \
	  rm -f $(RESULTS)/$$robot-tuned.toml && start=$$(date +%s) && \
	  $(VENV)/bin/ilcforce tune experiments/tuning/$$robot-tune.toml --results $(RESULTS) -o $(RESULTS)/$$robot-tuned.toml && \
	  mv $(RESULTS)/$$robot-tuned.toml experiments/$$robot-tuned.toml || exit 1; \
	  times="$$times $$robot-tune=$$(( $$(date +%s) - start ))"; \
	done; $(PY) -m ilcforce.report.tuning --results $(RESULTS) --out docs/tuning $$times

clean: ## remove generated results, caches and the virtual environment
	rm -rf $(RESULTS)/*/ $(VENV) .pytest_cache build *.egg-info ilcforce/_kernels_aot*
	find . -name __pycache__ -type d -prune -exec rm -rf {} +

.PHONY: help aot install test test-slow bench stores studies calibrate claim-map reproduce long lifted crosscheck findings check-findings readme-findings check-readme tune clean
