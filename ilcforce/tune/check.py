"""Tuning's stability constraint on one seed: a check run over ``check_iterations`` (at least three times
the scored horizon) is judged by the growth test of :mod:`ilcforce.stability`, the same test the report
applies, validated against long runs (docs/long-run/long-run.md).

A check run stops early (the iteration axis is where pruning saves time) when it diverges, or when the
growth test already flags it at one of :data:`PRUNE_AT` iterations: from 40 iterations on, the test's
false-alarm rate on bounded runs was 8% against 21% at 20, and a flag there says the run would not
survive the horizon anyway. The verdict of a run that goes the whole way is taken on all of it.
"""

from __future__ import annotations

import functools

#: Iteration counts at which a check run is judged before its end; a flag there stops it.
PRUNE_AT = (40, 50)


def _frame(rows: list[dict], method: str):
    import pandas as pd

    frame = pd.DataFrame(rows)
    frame["seed"], frame["method"] = 0, method
    return frame


def judge(rows: list[dict], method: str, perturbation_iteration: int, config: dict) -> tuple[str, str]:
    """(verdict, text) of the growth test on all of ``rows`` (one run's metrics rows, in order)."""
    from ilcforce.stability import verdict_of

    return verdict_of(_frame(rows, method), method, len(rows), perturbation_iteration, config)


def _stop(rows: list[dict], *, method: str, perturbation_iteration: int, config: dict, horizon: int) -> bool:
    from ilcforce.stability import FLAGGED

    if len(rows) not in PRUNE_AT or len(rows) >= horizon:
        return False
    return judge(rows, method, perturbation_iteration, config)[0] == FLAGGED


def stopper(method: str, perturbation_iteration: int, config: dict, horizon: int):
    """The ``stop`` a check cell passes to :func:`ilcforce.study.cell.run_cell` (picklable for Dask)."""
    return functools.partial(_stop, method=method, perturbation_iteration=perturbation_iteration, config=config,
                             horizon=horizon)
