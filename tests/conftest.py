"""Shared fixtures. Helpers: add fixtures, never remove one."""

from __future__ import annotations

import functools

import pytest

from ilcforce.config_load import load_config


@pytest.fixture(autouse=True)
def no_stop_signal_left():
    """Every test starts with no stop signal noted: a test that sends one in-process (a report or
    study stopped by SIGTERM) left it in stops.STOPS, and a CLI test after it (CliRunner calls
    the app, not the entry point that clears it) stopped at once with exit 143."""
    from ilcforce import stops

    stops.STOPS.clear()
    stops.ANNOUNCED.clear()
    yield


@pytest.fixture
def short_config():
    """A factory: the paper's setup on a short horizon (0.2 s = 2001 control samples), with overrides."""

    def make(path=None, **overrides):
        base = {"reference.duration": 0.2, "experiment.iterations": 3}
        base.update(overrides)
        return load_config(path, base)

    return make


def plant_experiment(model: str):
    """The experiment file that runs the paper's task on plant ``model`` (paper.toml first), or None.

    A plant model with no experiment file is run as the embedded paper setup with ``plant.model``
    set, so a newly registered robot is picked up by the tests that parametrize over the plants.
    """
    from pathlib import Path

    return _plant_experiments(Path.cwd()).get(model)


@functools.lru_cache(maxsize=None)
def _plant_experiments(cwd) -> dict:
    """Plant model -> the first experiment file (in :func:`plant_experiment`'s order) that runs it,
    read once per test process (and per working folder): the shipped experiment files do not change
    while the tests run, and reading them all (the spatial arm's files check their reference's
    reachability, about 0.1 s each) on every call of ``plant_config`` took about a minute of the
    suite."""
    from pathlib import Path

    # paper.toml first, then the hand-written experiments, the tuned ones (make tune's) last
    files = sorted(Path(cwd, "experiments").glob("*.toml"),
                   key=lambda p: (p.name != "paper.toml", p.stem.endswith("-tuned"), p.name))
    from ilcforce.study.spec import is_study_file

    found = {}
    for path in files:
        if is_study_file(path):  # a study file names an experiment; it is not one
            continue
        found.setdefault(load_config(path).plant.model, path.relative_to(cwd))
    return found


@pytest.fixture
def plant_config():
    """A factory: the paper's task on plant ``model`` (see :func:`plant_experiment`), with overrides."""

    def make(model: str, **overrides):
        path = plant_experiment(model)
        if path is None:
            overrides = {"plant.model": model, **overrides}
        return load_config(path, overrides)

    return make
