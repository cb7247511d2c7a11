"""The store writer: refusal rules, resume, locking and crash safety."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import h5py  # the tests inspect and forge files directly; library code leaves h5py to the store
import numpy as np
import pytest

from ilcforce.store.seal import seal_attrs

from ilcforce import store
from ilcforce.records import STATUS_COMPLETE, IterationRecord
from ilcforce.store import StoreError, StoreExistsError, StoreLockedError
from storekit import (N_CONTROL, N_LOG, assert_one_line_naming, make_record, make_reference, resumed_config, write_run,
                      writer)


@pytest.fixture
def path(tmp_path: Path) -> Path:
    return tmp_path / "results" / "paper" / "c3.h5"


# -- writer rules ----------------------------------------------------------------------------


def test_creates_parent_and_unwritable_parent_is_one_line(tmp_path: Path):
    deep = tmp_path / "new" / "results" / "paper" / "c1.h5"
    write_run(deep, 1)
    assert deep.exists()
    blocker = tmp_path / "file"
    blocker.write_text("not a directory")
    bad = blocker / "paper" / "c1.h5"
    with pytest.raises(StoreError) as error:
        with writer(bad):
            pass
    assert_one_line_naming(error, bad)


def test_refuses_existing_without_overwrite(path: Path):
    write_run(path, 2, finish=None)
    before = path.read_bytes()
    with pytest.raises(StoreExistsError) as error:
        with writer(path):
            pass
    assert_one_line_naming(error, path)
    message = str(error.value)
    assert "--overwrite" in message and "--resume" in message and "partial" in message, message
    assert path.read_bytes() == before


def test_overwrite_replaces_at_first_commit(path: Path):
    write_run(path, 3)
    with writer(path, overwrite=True, config=resumed_config(1)) as w:
        assert w.last_complete_iteration == -1
        assert w.resume_memory() == {}
        assert store.iterations(path) == [0, 1, 2], "old file must stay until the first commit"
        w.append(make_record(0))
        assert store.iterations(path) == [0]
        w.finish(STATUS_COMPLETE)
    store.validate(path)
    assert len(store.read_metrics(path)) == 1


def test_overwrite_and_resume_are_exclusive(path: Path):
    with pytest.raises(StoreError, match="mutually exclusive") as error:
        writer(path, overwrite=True, resume=True)
    assert_one_line_naming(error, path)


def test_append_out_of_order_and_after_finish(path: Path):
    with writer(path, config=resumed_config(1)) as w:
        with pytest.raises(StoreError, match="next must be 0") as error:
            w.append(make_record(1))
        assert_one_line_naming(error, path)
        w.append(make_record(0))
        with pytest.raises(StoreError, match="next must be 1"):
            w.append(make_record(0))
        w.finish(STATUS_COMPLETE)
        with pytest.raises(StoreError, match="finished"):
            w.append(make_record(1))
        with pytest.raises(ValueError, match="status"):
            w.finish("done")
    store.validate(path)


def test_malformed_record_is_a_value_error(path: Path):
    record = make_record(0)
    del record.log["sliding_surface"]
    with writer(path) as w:
        with pytest.raises(ValueError, match="sliding_surface"):
            w.append(record)
        short = make_record(0)
        short.log["position"] = np.zeros((N_LOG - 1, 2))
        with pytest.raises(ValueError, match="position"):
            w.append(short)
        no_unit = IterationRecord(0, STATUS_COMPLETE, math.nan, "", 0, make_record(0).log, {"v": np.zeros(N_CONTROL)}, {})
        with pytest.raises(ValueError, match="'v'"):
            w.append(no_unit)
        assert w.last_complete_iteration == -1
    assert not path.exists(), "nothing was committed"


def test_writer_requires_context(path: Path):
    w = writer(path)
    with pytest.raises(RuntimeError, match="context manager"):
        w.append(make_record(0))


# -- resume ----------------------------------------------------------------------------------


def test_resume_continues_with_exact_memory(path: Path):
    records = write_run(path, 3, finish=None)
    assert store.read_provenance(path)["run_state"] == "partial"
    with writer(path, config=resumed_config(5), resume=True) as w:
        assert w.last_complete_iteration == 2
        assert w.stored_status() == STATUS_COMPLETE
        memory = w.resume_memory()
        assert set(memory) == set(records[2].memory)
        for name, values in records[2].memory.items():
            assert memory[name].dtype == np.float64
            np.testing.assert_array_equal(memory[name], values, err_msg=f"resumed memory {name}")
        with pytest.raises(StoreError, match="next must be 3"):
            w.append(make_record(4))
        w.append(make_record(3))
        w.append(make_record(4))
        w.finish(STATUS_COMPLETE)
    store.validate(path)
    assert store.iterations(path) == [0, 1, 2, 3, 4]
    provenance = store.read_provenance(path)
    assert provenance["n_iterations_requested"] == 5
    assert json.loads(provenance["config_json"]) == resumed_config(5)
    assert provenance["run_state"] == "complete"
    np.testing.assert_array_equal(
        store.read_memory(path, 1)["theta_hat"], records[1].memory["theta_hat"], err_msg="old iterations untouched"
    )


def test_resume_without_file_starts_fresh(path: Path):
    with writer(path, resume=True, config=resumed_config(1)) as w:
        assert w.last_complete_iteration == -1
        assert w.stored_status() is None
        assert w.resume_memory() == {}
        w.append(make_record(0))
        w.finish(STATUS_COMPLETE)
    store.validate(path)


def test_resume_of_untouched_run_keeps_its_state(path: Path):
    write_run(path, 2)
    with writer(path, resume=True) as w:
        assert w.last_complete_iteration == 1
    assert store.read_provenance(path)["run_state"] == "complete"


@pytest.mark.parametrize(
    ("change", "key"),
    [
        (lambda c: c["plant"].__setitem__("m3", 0.7), "plant.m3"),
        (lambda c: c["plant"].__setitem__("scale", [1.0, 3.0]), "plant.scale"),
        (lambda c: c.__setitem__("extra", 1), "extra"),
        (lambda c: c["run"].__setitem__("method", "c2"), "run.method"),
    ],
)
def test_resume_refuses_different_config(path: Path, change, key: str):
    write_run(path, 2, finish=None)
    config = resumed_config(4)
    change(config)
    with pytest.raises(StoreError, match="cannot resume") as error:
        with writer(path, config=config, resume=True):
            pass
    assert_one_line_naming(error, path)
    assert key in str(error.value), str(error.value)


@pytest.mark.parametrize(("argument", "value"), [("method", "c2"), ("experiment", "realistic"), ("seed", 8)])
def test_resume_refuses_other_run(path: Path, argument: str, value):
    write_run(path, 1, finish=None)
    with pytest.raises(StoreError, match=argument) as error:
        with writer(path, resume=True, **{argument: value}):
            pass
    assert_one_line_naming(error, path)


def test_resume_refuses_different_reference(path: Path):
    write_run(path, 1, finish=None)
    reference = make_reference()
    reference["force_desired"] = reference["force_desired"] + 1e-12
    with pytest.raises(StoreError, match="force_desired") as error:
        with writer(path, resume=True, reference=reference):
            pass
    assert_one_line_naming(error, path)


# -- locking ---------------------------------------------------------------------------------


def test_second_writer_in_same_process_is_refused(path: Path):
    with writer(path, config=resumed_config(2)) as w:
        w.append(make_record(0))
        with pytest.raises(StoreLockedError) as error:
            with writer(path, resume=True):
                pass
        assert_one_line_naming(error, path)
        assert "being written by another ilcforce process" in str(error.value)
        w.append(make_record(1))  # the refused writer did not disturb the first one
        w.finish(STATUS_COMPLETE)
    with writer(path, resume=True) as again:  # released on exit
        assert again.last_complete_iteration == 1


def test_writer_in_another_process_is_refused(path: Path):
    path.parent.mkdir(parents=True)
    lock = f"{path}.lock"
    holder = subprocess.Popen(
        [sys.executable, "-c",
         "import fcntl, os, sys\n"
         f"fd = os.open({lock!r}, os.O_RDWR | os.O_CREAT)\n"
         "fcntl.flock(fd, fcntl.LOCK_EX)\n"
         "print('locked', flush=True)\n"
         "sys.stdin.read()\n"],
        stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
    )
    try:
        assert holder.stdout.readline().strip() == "locked"
        with pytest.raises(StoreLockedError) as error:
            with writer(path):
                pass
        assert_one_line_naming(error, path)
    finally:
        holder.stdin.close()
        holder.wait(timeout=30)
        holder.stdout.close()
    write_run(path, 1)  # free again once the other process ended


# -- crash safety ----------------------------------------------------------------------------


@pytest.mark.parametrize("interrupt", [RuntimeError, KeyboardInterrupt])
def test_crash_leaves_partial_valid_file(path: Path, interrupt: type[BaseException]):
    with pytest.raises(interrupt):
        with writer(path) as w:
            w.append(make_record(0))
            w.append(make_record(1))
            raise interrupt("simulated crash")
    store.validate(path)
    assert store.iterations(path) == [0, 1]
    assert store.read_provenance(path)["run_state"] == "partial"
    assert sorted(p.name for p in path.parent.iterdir()) == ["c3.h5", "c3.h5.lock"], "no temporary left"


def test_killed_writer_leftovers_do_not_affect_readers(path: Path):
    write_run(path, 2, finish=None)
    stale = path.with_name(f".{path.name}.tmp-999999")  # a killed writer's copy (PID 999999 is gone)
    stale.write_bytes(b"half a copy")
    old_names = [path.with_name(path.name + ".tmp-999999"), path.with_name(path.name + ".tmp")]
    for old in old_names:  # an older version's temporary names: they may be stores of their own now
        old.write_bytes(b"someone's file")
    store.validate(path)
    assert store.iterations(path) == [0, 1]
    assert store.find_stores(path.parent.parent) == {"paper": {"c3": path}}
    with writer(path, config=resumed_config(3), resume=True) as w:
        assert not stale.exists(), "the next writer removes a dead writer's copy"
        assert all(old.read_bytes() == b"someone's file" for old in old_names), "and nothing by a name pattern"
        w.append(make_record(2))
    store.validate(path)


def test_kill_9_mid_run_leaves_valid_file(path: Path):
    # A real SIGKILL at an arbitrary moment of a run that commits as fast as it can.
    script = (
        "import sys\n"
        f"sys.path.insert(0, {str(Path(__file__).parent)!r})\n"
        "from pathlib import Path\n"
        "from storekit import make_record, writer\n"
        f"with writer(Path({str(path)!r}), n_iterations=1000) as w:\n"
        "    for j in range(1000):\n"
        "        w.append(make_record(j))\n"
        "        print(j, flush=True)\n"
    )
    child = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, text=True)
    try:
        for _ in range(4):
            assert child.stdout.readline(), "writer process ended early"
    finally:
        child.kill()
        child.wait(timeout=30)
        child.stdout.close()
    store.validate(path)
    done = store.iterations(path)
    assert len(done) >= 4 and done == list(range(len(done)))
    assert store.read_provenance(path)["run_state"] == "partial"  # no writer holds the lock any more: reported as partial
    with writer(path, n_iterations=1000, resume=True) as w:  # the lock died with the process
        assert w.last_complete_iteration == done[-1]
        assert not list(path.parent.glob(f".{path.name}.tmp-*")), "leftover copies removed"
    assert store.read_provenance(path)["run_state"] == "partial"


def test_running_state_left_by_kill_becomes_partial_on_resume(path: Path):
    write_run(path, 2, finish=None)
    with h5py.File(path, "a") as handle:  # what a kill -9 after a commit leaves
        handle.attrs["run_state"] = "running"
        seal_attrs(handle)  # the commit's seal covers its run_state
    with writer(path, resume=True):
        pass
    assert store.read_provenance(path)["run_state"] == "partial"


def test_incomplete_iteration_group_is_ignored(path: Path):
    write_run(path, 2)
    with h5py.File(path, "a") as handle:
        group = handle.create_group("iterations/0002")
        group.attrs["iteration"] = 2
        group.create_dataset("log/time", data=np.zeros(3))  # no units, wrong shape: still ignored
    store.validate(path)
    assert store.iterations(path) == [0, 1]
    assert list(store.read_metrics(path).index) == [0, 1]
    with pytest.raises(StoreError, match="not stored"):
        store.read_iteration(path, 2)
    with writer(path, config=resumed_config(3), resume=True) as w:
        assert w.last_complete_iteration == 1
        w.append(make_record(2))  # replaces the unfinished group
    store.validate(path)
    assert store.iterations(path) == [0, 1, 2]


def test_reader_holding_old_file_open_is_safe(path: Path):
    # A reader that opened the file before a commit keeps seeing the old content, and the
    # writer never modifies that file underneath it (it falls back to a fresh copy).
    records = [make_record(j) for j in range(4)]
    with writer(path) as w:
        w.append(records[0])
        w.append(records[1])
        with h5py.File(path, "r") as old:
            w.append(records[2])
            # The kept copy was the file the reader holds: the writer dropped it, did not touch it.
            assert not list(path.parent.glob(f".{path.name}.tmp-*")), "writer should have fallen back"
            assert sorted(old["iterations"]) == ["0000", "0001"]
            np.testing.assert_array_equal(old["iterations/0001/log/position"][()], records[1].log["position"])
        w.append(records[3])
        w.finish(STATUS_COMPLETE)
    store.validate(path)
    assert store.iterations(path) == [0, 1, 2, 3]
    for record in records:
        np.testing.assert_array_equal(
            store.read_memory(path, record.iteration)["theta_hat"], record.memory["theta_hat"],
            err_msg=f"iteration {record.iteration}",
        )
    assert len(store.read_metrics(path)) == 4


def test_commit_copy_kept_between_commits_matches_the_store(path: Path):
    with writer(path) as w:
        for j in range(3):
            w.append(make_record(j))
        copies = list(path.parent.glob(f".{path.name}.tmp-*"))
        for copy in copies:  # the kept copy (if any) is a valid store with the same content
            store.validate(copy)
            assert store.iterations(copy) == [0, 1, 2]
            assert store.read_metrics(copy).equals(store.read_metrics(path))
        w.finish(STATUS_COMPLETE)
    assert not list(path.parent.glob(f".{path.name}.tmp-*"))


def test_without_hdf5_locking_every_commit_copies(path: Path, monkeypatch: pytest.MonkeyPatch):
    monkeypatch.setenv("HDF5_USE_FILE_LOCKING", "FALSE")
    records = write_run(path, 3)
    assert not list(path.parent.glob(f".{path.name}.tmp-*"))
    np.testing.assert_array_equal(store.read_memory(path, 2)["alpha_hat"], records[2].memory["alpha_hat"])



def _crashed_commit(path: Path) -> bytes:
    """Leave ``path`` as a writer killed in mid-commit would: its first bytes overwritten, their old
    contents in the journal. Returns the file as it was before."""
    import os

    from ilcforce.store import journal

    before = path.read_bytes()
    fd = os.open(path, os.O_RDWR)
    try:
        jfd = journal.start(path.with_name(path.name + ".journal"), len(before), fd)
        half = journal.JournaledFile(fd, jfd, len(before))
        half.seek(0)
        half.write(b"\0" * 64)  # the superblock: the file is unreadable until the commit is undone
        os.close(jfd)
    finally:
        os.close(fd)
    return before


def test_an_interrupted_commit_is_undone_by_the_next_reader(path: Path):
    write_run(path, 2)
    before = _crashed_commit(path)
    assert path.read_bytes() != before
    store.validate(path)
    assert path.read_bytes() == before and not path.with_name(path.name + ".journal").exists()


def test_a_journal_left_beside_another_file_is_refused_not_applied(path: Path):
    """A journal was applied to whatever file had the store's name: a good store moved into place
    after a crash (a backup restored) was cut to the crashed store's old size, and a forged
    16-byte journal grew a store to 1 GB (found by an attack on the CLI). A journal now names its
    file (device and inode) and is refused, left as it is with the store untouched, otherwise."""
    import struct

    write_run(path, 2)
    _crashed_commit(path)
    other = path.with_name("other.h5")
    write_run(other, 3)
    good = other.read_bytes()
    other.replace(path)  # the backup moved into place; the crashed store's journal is still there
    jpath = path.with_name(path.name + ".journal")
    with pytest.raises(StoreError, match="journal of another file") as error:
        store.validate(path)
    assert_one_line_naming(error, path)
    assert path.read_bytes() == good and jpath.exists()
    jpath.write_bytes(b"ILCJRNL1" + struct.pack("<Q", 10**9))  # an old-format journal: no identity
    with pytest.raises(StoreError, match="does not fit this store"):
        store.validate(path)
    assert path.read_bytes() == good
    jpath.write_bytes(b"junk")  # not ours, and short: left alone, not taken for a torn header
    with pytest.raises(StoreError, match="not an ilcforce journal"):
        store.validate(path)
    assert jpath.read_bytes() == b"junk" and path.read_bytes() == good


def test_the_metrics_group_is_copied_from_the_one_built(tmp_path):
    """store/metrics_cache.create copies an in-memory /metrics group (H5Ocopy) instead of building
    24 datasets and 50 attributes in each store: the copy must be the built group, property for
    property, and take rows the same way."""
    import h5py

    from ilcforce.metrics import metric_columns
    from ilcforce.store import metrics_cache, schema

    with h5py.File(tmp_path / "copied.h5", "w", libver=schema.LIBVER) as copied, \
            h5py.File(tmp_path / "built.h5", "w", libver=schema.LIBVER) as built:
        metrics_cache.create(copied)
        metrics_cache._build(built)
        a, b = copied[schema.METRICS_GROUP], built[schema.METRICS_GROUP]
        assert dict(a.attrs) == dict(b.attrs) and sorted(a) == sorted(b) and len(a) == 24
        for name in b:
            x, y = a[name], b[name]
            assert (x.dtype, x.shape, x.maxshape, x.chunks, x.fletcher32, x.compression) == \
                   (y.dtype, y.shape, y.maxshape, y.chunks, y.fletcher32, y.compression), name
            assert dict(x.attrs) == dict(y.attrs), name
        row = {column: (0 if metrics_cache.column_kind(column) == "int" else "complete"
                        if metrics_cache.column_kind(column) == "str" else 0.5) for column in metric_columns(2)}
        for handle in (copied, built):
            metrics_cache.append_rows(handle, [dict(row, iteration=0), dict(row, iteration=1)])
            metrics_cache.append_rows(handle, [dict(row, iteration=1)])  # already held: skipped
        for name in b:
            assert a[name][()].tolist() == b[name][()].tolist() and len(a[name]) == 2, name
