"""Studies: Monte Carlo over seeds and parameter sweeps, run on Dask, stored by one writer.

Python API::

    from ilcforce.study import load_study, run_study, read_study, tidy_metrics
    study = load_study("experiments/paper-mc.toml")
    run_study(study, "results", workers=2)
    frame = tidy_metrics("results/studies/paper-mc.h5")   # same table as `ilcforce export`

Modules: :mod:`~ilcforce.study.spec` (the study file), :mod:`~ilcforce.study.cell` (one cell, the
worker's job), :mod:`~ilcforce.study.runner` (the driver, Dask), :mod:`~ilcforce.store.study` (the
study store, in the store package: only the store touches h5py), :mod:`~ilcforce.study.tidy` (reading, export).
"""

from ilcforce.study.dask_run import StudyRunError
from ilcforce.study.runner import run_study, store_path
from ilcforce.study.spec import Cell, Setting, Study, StudyError, build_study, load_study
from ilcforce.store.study import StudyStoreError
from ilcforce.study.tidy import ExportError, StudyResults, export, read_study, tidy_metrics

__all__ = ["Cell", "ExportError", "Setting", "Study", "StudyError", "StudyResults", "StudyRunError",
           "StudyStoreError", "build_study", "export", "load_study", "read_study", "run_study", "store_path",
           "tidy_metrics"]
