"""The cheapest ways to write a run's numbers, for :mod:`benchmarks.floor` (not a store).

Each writes every record's log and memory arrays with nothing of the store around them (no
journal, no commit per iteration, no metrics, no provenance): today's layout, one dataset per
signal with its ``units`` attribute; one dataset per iteration and kind (stacked beforehand by
:func:`stack`, which is not timed); and the bare bytes.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

import h5py
import numpy as np


def _arrays(record) -> dict[str, np.ndarray]:
    return {**{f"log/{k}": v for k, v in record.log.items()}, **{f"memory/{k}": v for k, v in record.memory.items()}}


def write_per_signal(path: Path, records: Sequence) -> None:
    """Today's layout, as cheaply as h5py writes it: a dataset per signal, a ``units`` attribute each."""
    with h5py.File(path, "w", libver="latest") as f:
        for record in records:
            group = f.create_group(f"iterations/{record.iteration:04d}")
            for name, values in _arrays(record).items():
                group.create_dataset(name, data=values).attrs["units"] = "-"


def stack(records: Sequence) -> list[tuple[int, dict[str, np.ndarray]]]:
    """Each record's log signals as one (n, k) array and its memory as another (made before timing)."""
    out = []
    for record in records:
        parts = {"log": np.column_stack([v.reshape(len(v), -1) for v in record.log.values()])}
        if record.memory:
            parts["memory"] = np.column_stack([v.reshape(len(v), -1) for v in record.memory.values()])
        out.append((record.iteration, parts))
    return out


def write_one_per_iteration(path: Path, stacked: Sequence[tuple[int, dict[str, np.ndarray]]]) -> None:
    """The fewest datasets: one array per iteration and kind, one ``units`` attribute each."""
    with h5py.File(path, "w", libver="latest") as f:
        for iteration, parts in stacked:
            group = f.create_group(f"iterations/{iteration:04d}")
            for name, values in parts.items():
                group.create_dataset(name, data=values).attrs["units"] = "-"


def write_bare(path: Path, records: Sequence) -> None:
    """No format: every array's bytes, one ``os.write`` each."""
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
    try:
        for record in records:
            for values in _arrays(record).values():
                view = memoryview(np.ascontiguousarray(values)).cast("B")
                while view:
                    view = view[os.write(fd, view):]
    finally:
        os.close(fd)
