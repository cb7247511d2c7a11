"""What is at a store's path before a :class:`~ilcforce.store.write.StoreWriter` writes to it.

The checks the writer makes on entering, before its first commit: the directory exists and is
writable, an interrupted commit is undone and leftover copies are deleted, ``--overwrite``
replaces only an ilcforce store, ``--resume`` continues only the same run (same experiment,
method, seed, reference and, by the same-run check, configuration). Every refusal is a one-line
:class:`~ilcforce.store.safeio.StoreError` naming the file.
"""

from __future__ import annotations

import os
import stat
from pathlib import Path
from typing import Any

import numpy as np

from ilcforce.samerun import DifferentRun
from ilcforce.store import schema
from ilcforce.store.provenance import SameRunCheck
from ilcforce.store.read import open_store
from ilcforce.store.safeio import (StoreError, check_regular_file, dead_writers_copies, is_temporary_name,
                                   journal_path, not_a_run_store, os_reason, repair_interrupted_commit,
                                   superblock_version)


def make_parent(path: Path) -> None:
    """Create the store's directory; refuse one that is not a writable directory."""
    parent = path.parent
    try:
        parent.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise StoreError(f"{path}: cannot create directory {parent} ({os_reason(error)})") from None
    if not parent.is_dir():
        raise StoreError(f"{path}: {parent} is not a directory")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise StoreError(f"{path}: directory {parent} is not writable")


def clean_leftovers(path: Path) -> None:
    """Undo an interrupted commit; delete the copies a killed writer of this store left (the caller
    holds the lock): only ``.<name>.tmp-<pid>`` of a process that is gone (:func:`dead_writers_copies`),
    a name no store may have. Anything else stays, whatever its name: ``<name>.tmp`` may be a
    store of its own (an older ilcforce's temporary name, once deleted while its writer ran)."""
    if os.path.lexists(journal_path(path)) and os.path.lexists(path):
        repair_interrupted_commit(path)
    for stale in dead_writers_copies(path):
        try:
            os.unlink(stale)
        except OSError:
            pass


def check_replaceable(path: Path) -> None:
    """--overwrite replaces only an ilcforce store: refuse anything else at the path."""
    info = os.lstat(path)
    if stat.S_ISLNK(info.st_mode):
        raise StoreError(f"{path} is a symbolic link; --overwrite replaces only an ilcforce store file")
    if not stat.S_ISREG(info.st_mode):
        raise StoreError(f"{path} is not a regular file; --overwrite replaces only an ilcforce store")
    try:
        with open_store(path):
            pass
    except StoreError as error:
        raise StoreError(f"refusing to overwrite: {error}; --overwrite replaces only an ilcforce store") from None


def refuse_foreign_target(path: Path) -> None:
    """Refuse, before a lock file is made beside it, a target no option may write: a folder or other
    non-file, a study store (its journal is a folder), a file that is not HDF5 (--overwrite replaces
    only an ilcforce store). What needs the store opened is checked under the lock."""
    if is_temporary_name(path.name):
        raise StoreError(f"{path}: ilcforce names its temporary copies .<name>.tmp-<pid> and removes those "
                         "of dead processes; choose another name for a store")
    journal_folder = journal_path(path).is_dir()  # a study store's journal: cells not yet merged
    if not os.path.lexists(path):
        if journal_folder:
            raise StoreError(f"{path}: {journal_path(path)} is a study store's journal folder (it may hold cells "
                             "not yet merged) and the store beside it is missing; choose another --out")
        return
    if not os.path.exists(path):  # refused before a lock file is made beside it
        raise StoreError(f"{path} is a symbolic link to a missing file ({os.readlink(path)}); a store is written "
                         "to a regular file: remove the link or choose another --out")
    check_regular_file(path)  # a folder, a FIFO, an empty file: refused here, before anything opens it
    if journal_folder:
        raise StoreError(not_a_run_store(path))
    try:
        fd = os.open(path, os.O_RDONLY | os.O_CLOEXEC | os.O_NONBLOCK)
    except OSError:
        return  # no permission: the checks under the lock say why
    try:
        foreign = superblock_version(fd) is None
    finally:
        os.close(fd)
    if foreign:
        raise StoreError(f"{path}: exists and is not an ilcforce store (not an HDF5 file); neither --overwrite "
                         "nor --resume touches it: move it away or choose another --out")


def _iterations(n: int) -> str:
    return f"{n} iteration" + ("" if n == 1 else "s")


def existing_refusal(path: Path) -> str:
    """Why a plain run refuses the existing ``path``: what it holds and which option applies."""
    from ilcforce.store.access import iterations, read_provenance
    try:
        provenance = read_provenance(path)
        done = iterations(path)
    except StoreError as error:  # neither --overwrite nor --resume takes a store that cannot be read
        return f"{path} already exists and is not a usable store ({error}); move it away or choose another --out"
    return (f"{path} already exists (run_state {provenance['run_state']!r}, {_iterations(len(done))} stored); "
            "--overwrite replaces it or --resume continues it")


def check_resumable(path: Path, *, experiment: str, method: str, seed: int, same_run: SameRunCheck,
                    reference: dict[str, np.ndarray]) -> dict[str, Any]:
    """Validate the store at ``path`` and refuse to resume a different run; returns its provenance."""
    from ilcforce.store.access import read_provenance, read_reference, validate
    validate(path)
    provenance = read_provenance(path)
    for key, new in (("experiment", experiment), ("method", method), ("seed", seed)):
        if provenance[key] != new:
            raise StoreError(f"{path}: cannot resume: stored {key} is {provenance[key]!r}, this run has "
                             f"{new!r}; use --overwrite to start again")
    try:
        same_run(provenance)
    except (StoreError, DifferentRun) as error:
        raise StoreError(f"{path}: cannot resume: {error}; use --overwrite to start again") from None
    stored_dimension = int(provenance.get(schema.TASK_DIMENSION_ATTR, schema.DEFAULT_TASK_DIMENSION))
    dimension = int(np.shape(reference["force_desired"])[1])
    if stored_dimension != dimension:
        raise StoreError(f"{path}: cannot resume: the stored run has {stored_dimension} task axes, this run "
                         f"{dimension}; use --overwrite to start again")
    stored_reference = read_reference(path)
    for name, (axes, _unit, _description) in schema.reference_datasets(dimension).items():
        if name == "time":
            stored = stored_reference.index.to_numpy(dtype=np.float64)
        else:
            columns = [name] if axes is None else [f"{name}_{a}" for a in axes]
            stored = stored_reference[columns].to_numpy(dtype=np.float64)
        if stored.shape != reference[name].shape or not np.array_equal(stored, reference[name],
                                                                       equal_nan=True):
            raise StoreError(f"{path}: cannot resume: reference signal {name!r} differs from the stored "
                             "one; use --overwrite to start again")
    return provenance
