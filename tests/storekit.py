"""Helpers shared by the tests: small records, a writer factory, forged files, record and store comparisons.

Arrays go through HDF5 as float64 without compression, so every comparison of stored data is
exact (``assert_array_equal``), not approximate.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from ilcforce import store
from ilcforce.records import LOG_SIGNALS, REFERENCE_SIGNALS, STATUS_COMPLETE, STATUS_DIVERGED, IterationRecord
from ilcforce.store import StoreWriter

N_LOG = 21  # log grid: 0.1 s over 2 s
N_CONTROL = 201  # control grid: 10 ms over 2 s
DURATION = 2.0
CONFIG = {"experiment": {"iterations": 3, "seed": 7}, "run": {"method": "c3"}, "plant": {"m3": 0.5, "scale": [1.0, 2.0]}}


def make_reference() -> dict[str, np.ndarray]:
    """Every REFERENCE_SIGNALS entry on the log grid, distinct values per signal."""
    time = np.linspace(0.0, DURATION, N_LOG)
    reference = {"time": time}
    for k, (name, (axes, _unit, _description)) in enumerate(REFERENCE_SIGNALS.items()):
        if axes is not None:
            reference[name] = np.column_stack([np.sin(time + k), np.cos(time * k)])
    return reference


def make_record(
    j: int,
    *,
    status: str = STATUS_COMPLETE,
    with_memory: bool = True,
) -> IterationRecord:
    """A record for iteration j: every LOG_SIGNALS entry, (N_LOG,) or (N_LOG, 2), distinct
    pseudo-random values; memory (N_CONTROL, 2) and (N_CONTROL,) when ``with_memory``."""
    rng = np.random.default_rng(1000 + j)
    time = np.linspace(0.0, DURATION, N_LOG)
    log = {
        name: time.copy() if axes is None else rng.standard_normal((N_LOG, len(axes)))
        for name, (axes, _unit, _description) in LOG_SIGNALS.items()
    }
    diverged_time = math.nan
    if status == STATUS_DIVERGED:
        diverged_time = 1.05
        for name in log:
            log[name][11:] = np.nan
    memory = {"theta_hat": rng.standard_normal((N_CONTROL, 2)), "alpha_hat": rng.standard_normal(N_CONTROL)} if with_memory else {}
    units = {"theta_hat": "kg m^2", "alpha_hat": "N"} if with_memory else {}
    return IterationRecord(
        iteration=j,
        status=status,
        diverged_time=diverged_time,
        diverged_reason="" if status == STATUS_COMPLETE else "|tau| above 1e3 N m",
        fallback_count=j,
        log=log,
        memory=memory,
        memory_units=units,
    )


def writer(path: Path, config: dict | None = None, **kwargs) -> StoreWriter:
    config = CONFIG if config is None else config
    arguments = dict(
        experiment="paper",
        method="c3",
        config_toml="[run]\nn_iterations = 3\n",
        config_json=json.dumps(config, sort_keys=True),
        seed=7,
        command="ilcforce simulate --config experiments/paper.toml --method c3",
        n_iterations=config["experiment"]["iterations"],
        reference=make_reference(),
    )
    arguments.update(kwargs)
    return StoreWriter(path, **arguments)


def write_run(path: Path, n: int, *, finish: str | None = STATUS_COMPLETE, **kwargs) -> list[IterationRecord]:
    """Write iterations 0..n-1, validating the file after every commit and at the end. A run
    finished "complete" asks for exactly its n iterations (a complete run holds all it asked for)."""
    if finish == STATUS_COMPLETE and "config" not in kwargs:
        kwargs["config"] = resumed_config(n)
    records = [make_record(j) for j in range(n)]
    with writer(path, **kwargs) as w:
        for record in records:
            w.append(record)
            store.validate(path)
        if finish is not None:
            w.finish(finish)
    store.validate(path)
    return records


def assert_one_line_naming(error: pytest.ExceptionInfo, path: Path) -> None:
    message = str(error.value)
    assert "\n" not in message and "\r" not in message, f"multi-line message: {message!r}"
    assert str(path) in message, f"message does not name {path}: {message!r}"


@pytest.fixture
def path(tmp_path: Path) -> Path:
    return tmp_path / "results" / "paper" / "c3.h5"



def resumed_config(n_iterations: int) -> dict:
    config = json.loads(json.dumps(CONFIG))
    config["experiment"]["iterations"] = n_iterations
    return config



def assert_same_records(a: list[IterationRecord], b: list[IterationRecord]) -> None:
    """Two runs' records are the same iterations with the same bits in every log and memory array."""
    assert len(a) == len(b) > 0
    for ra, rb in zip(a, b):
        assert (ra.iteration, ra.status, ra.fallback_count) == (rb.iteration, rb.status, rb.fallback_count)
        assert set(ra.log) == set(rb.log) and set(ra.memory) == set(rb.memory)
        for name in ra.log:
            np.testing.assert_array_equal(ra.log[name], rb.log[name], err_msg=f"iteration {ra.iteration} {name}")
        for name in ra.memory:
            np.testing.assert_array_equal(ra.memory[name], rb.memory[name], err_msg=f"iteration {ra.iteration} {name}")


def assert_same_datasets(a: Path, b: Path) -> None:
    """Two stores hold the same datasets with the same values (bits; NaN where NaN), attributes aside."""
    import h5py

    def datasets(path: Path) -> dict[str, np.ndarray]:
        found: dict[str, np.ndarray] = {}
        with h5py.File(path, "r") as handle:
            handle.visititems(lambda name, item: found.__setitem__(name, item[()])
                              if isinstance(item, h5py.Dataset) else None)
        return found

    da, db = datasets(a), datasets(b)
    assert sorted(da) == sorted(db)
    for name in da:
        np.testing.assert_array_equal(da[name], db[name], err_msg=name)


#: Root attributes that differ between any two writes (clock, checkout, version): left out of
#: :func:`store_structure`, with the root's seal over them.
VOLATILE_ROOT_ATTRS = ("created_utc", "updated_utc", "git_commit", "git_dirty", "ilcforce_version", "attrs_crc32",
                       "store_id")
#: Attributes whose values differ between any two stores (the store's random identity binds them,
#: ilcforce.store.binding): :func:`store_structure` keeps their names and types, not their values, and
#: those of the seal over them.
PER_STORE_ATTRS = ("binding_sha256",)


def store_structure(path: Path) -> dict:
    """Every object of a store: kind, type, shape, chunks, filters and attributes (type name and repr),
    as JSON-able data; the root's :data:`VOLATILE_ROOT_ATTRS` left out."""
    import h5py

    def describe(item) -> dict:
        out: dict = {"kind": "group" if isinstance(item, h5py.Group) else "dataset"}
        if isinstance(item, h5py.Dataset):
            out.update(dtype=str(item.dtype), shape=list(item.shape),
                       maxshape=[-1 if m is None else m for m in item.maxshape],
                       chunks=None if item.chunks is None else list(item.chunks), fletcher32=bool(item.fletcher32))
        attrs = {}
        per_store = any(name in PER_STORE_ATTRS for name in item.attrs)
        for name in sorted(item.attrs):
            if item.name == "/" and name in VOLATILE_ROOT_ATTRS:
                continue
            value = item.attrs[name]
            shown = ("<per store>" if name in PER_STORE_ATTRS or (per_store and name == "attrs_crc32") else
                     repr(value.tolist() if isinstance(value, np.ndarray) else value))
            attrs[name] = [type(value).__name__, shown]
        out["attrs"] = attrs
        return out

    with h5py.File(path, "r") as handle:
        found = {"/": describe(handle)}
        handle.visititems(lambda name, item: found.__setitem__(name, describe(item)))
    return found


def write_structure() -> None:
    """``python -c "import storekit; storekit.write_structure()" OUT.json``: the structure of a
    2-iteration :func:`write_run` store as the ilcforce on ``PYTHONPATH`` writes it
    (tests/test_store_dimension.py says when and how)."""
    import os
    import sys
    import tempfile

    import ilcforce

    print(f"ilcforce from {ilcforce.__file__}", file=sys.stderr)
    tree = os.environ.get("PYTHONPATH", "").split(os.pathsep)[0]
    if tree and not ilcforce.__file__.startswith(os.path.abspath(tree)):
        raise SystemExit(f"ilcforce was imported from {ilcforce.__file__}, not from {tree}")
    with tempfile.TemporaryDirectory() as folder:
        target = Path(folder) / "results" / "paper" / "c3.h5"
        write_run(target, 2)
        Path(sys.argv[1]).write_text(json.dumps(store_structure(target), indent=0, sort_keys=True) + "\n")
