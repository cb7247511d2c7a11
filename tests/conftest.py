"""Shared fixtures. Helpers: add fixtures, never remove one."""

from __future__ import annotations

import pytest

from ilcforce.config import load_config


@pytest.fixture
def short_config():
    """A factory: the paper's setup on a short horizon (0.2 s = 2001 control samples), with overrides."""

    def make(path=None, **overrides):
        base = {"reference.duration": 0.2, "experiment.iterations": 3}
        base.update(overrides)
        return load_config(path, base)

    return make
