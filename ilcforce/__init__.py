"""ilcforce: iterative learning control experiments for hybrid force/position control.

What a notebook imports (each loaded on first use, so ``import ilcforce`` costs nothing)::

    import ilcforce
    run = ilcforce.open("results/paper/c3.h5")          # a stored run: .metrics, .iteration(j), .config
    frame = ilcforce.tidy_metrics("results/studies/paper-mc.h5")   # one row per (setting, seed, method, j)
    study = ilcforce.read_study("results/studies/paper-mc.h5")
    config = ilcforce.load_config("experiments/paper.toml", {"c3.eta": 2.0})
    summary = ilcforce.run_method(config, "c3", "results/mine/c3.h5")
    ilcforce.METHODS["c3"].title, ilcforce.PLANTS["serial2r"]

docs/api.md describes each name.
"""

from __future__ import annotations

import importlib

__version__ = "0.1.0"

#: public name -> (module, attribute), imported when first asked for
_PUBLIC = {
    "open": ("ilcforce.store.run", "open_run"),  # ilcforce.open(path) -> Run, as open() reads a file
    "load_config": ("ilcforce.config_load", "load_config"),
    "default_config": ("ilcforce.config_load", "default_config"),
    "Config": ("ilcforce.config", "Config"),
    "ConfigError": ("ilcforce.config", "ConfigError"),
    "METHODS": ("ilcforce.controllers", "REGISTRY"),
    "PLANTS": ("ilcforce.plants", "MODELS"),
    "load_model": ("ilcforce.plants.model_file", "load_model"),  # a robot from a URDF or MJCF file
    "ModelFileError": ("ilcforce.plants.model_file", "ModelFileError"),
    "run_method": ("ilcforce.experiment", "api_run_method"),  # refusals name overwrite=True, not --overwrite
    "simulate_iterations": ("ilcforce.experiment", "simulate_iterations"),
    "iteration_metrics": ("ilcforce.metrics", "iteration_metrics"),
    "analyze": ("ilcforce.theory.lifted", "analyze"),  # the lifted-system check of a learning law
    "Run": ("ilcforce.store.run", "Run"),
    "StoreError": ("ilcforce.store", "StoreError"),
    "validate": ("ilcforce.store", "validate"),
    "load_study": ("ilcforce.study", "load_study"),
    "run_study": ("ilcforce.study", "run_study"),
    "read_study": ("ilcforce.study", "read_study"),
    "tidy_metrics": ("ilcforce.study", "tidy_metrics"),
    "export": ("ilcforce.study", "export"),
}

__all__ = ["__version__", *_PUBLIC]


def __getattr__(name: str):
    if name in _PUBLIC:
        module, attribute = _PUBLIC[name]
        value = getattr(importlib.import_module(module), attribute)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'ilcforce' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(__all__)
