"""Tuning: every method's gains searched for error and chattering, stable over a long horizon, on Dask.

Python API::

    from ilcforce.tune import load_tuning, run_tuning
    tuning = load_tuning("experiments/tuning/serial2r-tune.toml")
    summary = run_tuning(tuning, "results", workers=2)   # results/tuning/<name>/, tuned.toml
    summary.chosen["c2-robust"]                          # its shipped point on the held-out seeds, or None

Modules: :mod:`~ilcforce.tune.spec` (the tuning file), :mod:`~ilcforce.tune.objectives` (what a trial
scores), :mod:`~ilcforce.tune.trial` (a trial's cells and record), :mod:`~ilcforce.tune.check` (the stability
check), :mod:`~ilcforce.tune.search` (one method's Optuna study and its extent), :mod:`~ilcforce.tune.front`
(fronts, hypervolume, convergence), :mod:`~ilcforce.tune.heldout` (the held-out re-evaluation, the cap, the
choice), :mod:`~ilcforce.tune.output` (the tuned experiment file), :mod:`~ilcforce.tune.runner` (the driver:
rounds of cells on the study engine); :mod:`ilcforce.store.tuning` (sealed JSON records, resumable, checked
by :func:`~ilcforce.tune.runner.validate_tuning`); the ``ilcforce tune`` command is :mod:`ilcforce.cli.tune`.
"""

from ilcforce.tune.runner import TuneProgress, TuneSummary, run_tuning, tuning_dir, validate_tuning
from ilcforce.tune.spec import Tuning, TuneError, build_tuning, load_tuning
from ilcforce.store.tuning import TuningStoreError, is_tuning_store

__all__ = ["TuneError", "TuneProgress", "TuneSummary", "Tuning", "TuningStoreError", "build_tuning",
           "is_tuning_store", "load_tuning", "run_tuning", "tuning_dir", "validate_tuning"]
