"""The store's faults, each reproduced with real files and processes (hard links, symlinks,
a zeroed block, a file-size limit, flipped bits, forged types, symlinked lock files, FIFOs,
glob characters, HDF5 locking off). Each test failed on the store before the rebuild."""

from __future__ import annotations

import os
import resource
import subprocess
import sys
from pathlib import Path

import h5py  # the tests forge files directly; library code leaves h5py to the store
import numpy as np
import pytest

from ilcforce.store.seal import seal_attrs

from ilcforce import store
from ilcforce.store import StoreError
from storekit import assert_one_line_naming, make_record, resumed_config, write_run, writer

CLI = [sys.executable, "-m", "ilcforce"]
SHORT = ["--set", "reference.duration=0.2"]


@pytest.fixture
def path(tmp_path: Path) -> Path:
    return tmp_path / "results" / "paper" / "c3.h5"


def _cli(*args: str, timeout: float = 240, **kwargs) -> subprocess.CompletedProcess:
    return subprocess.run([*CLI, *args], capture_output=True, text=True, timeout=timeout, **kwargs)


def _one_line_exit_2(result: subprocess.CompletedProcess, *needles: str) -> None:
    assert result.returncode == 2, (result.returncode, result.stdout, result.stderr)
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and "Traceback" not in result.stderr, result.stderr
    for needle in needles:
        assert needle in lines[0], lines[0]


# -- fault 1: resume through a hard link or a symlink ------------------------------------------


def test_resume_through_hard_link_leaves_the_other_name_alone(path: Path):
    write_run(path, 2, finish=None)
    backup = path.with_name("backup.h5")
    os.link(path, backup)  # what `cp -al` makes
    before = backup.read_bytes()
    with writer(path, config=resumed_config(4), resume=True) as w:
        w.append(make_record(2))
        w.append(make_record(3))
        w.finish("complete")
    assert backup.read_bytes() == before, "the backup's data changed"
    assert store.iterations(backup) == [0, 1] and store.iterations(path) == [0, 1, 2, 3]
    assert os.stat(path).st_nlink == 1


def test_resume_through_symlink_leaves_the_target_alone(path: Path):
    target = path.with_name("target.h5")
    write_run(target, 2, finish=None)
    path.symlink_to(target.name)
    before = target.read_bytes()
    with writer(path, config=resumed_config(3), resume=True) as w:
        w.append(make_record(2))
        w.finish("complete")
    assert target.read_bytes() == before
    assert store.iterations(path) == [0, 1, 2]


# -- fault 2: a block of zeros hangs HDF5 ----------------------------------------------------------


def _zero_block(file: Path, offset: int) -> None:
    with open(file, "r+b") as handle:
        handle.seek(offset)
        handle.write(b"\0" * 4096)


def test_zeroed_block_ends_in_bounded_time(tmp_path: Path):
    results = tmp_path / "results"
    good = _cli("simulate", "-m", "c1", "-n", "2", "--results", str(results), *SHORT)
    assert good.returncode == 0, good.stderr
    stored = next(results.glob("*/c1.h5"))
    damaged = stored.with_name("c2.h5")
    damaged.write_bytes(stored.read_bytes())
    _zero_block(damaged, 4096)  # the root attributes' heap: HDF5 loops forever reading them
    # bounded: the probe's 10 s limit plus a cold start on a loaded machine
    _one_line_exit_2(_cli("validate", str(damaged), timeout=120), str(damaged))
    report = _cli("report", "--results", str(results), "--out", str(tmp_path / "rep"), timeout=240)
    assert report.returncode == 0, report.stderr
    assert "warning" in report.stderr and "c2.h5" in report.stderr and "Traceback" not in report.stderr
    _one_line_exit_2(_cli("simulate", "-m", "c3", "-n", "1", "--out", str(damaged), "--overwrite", *SHORT,
                          timeout=120), str(damaged))


# -- fault 3: a full disk / a file-size limit -----------------------------------------------------


def _limit_file_size(limit: int):
    def apply() -> None:
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))
    return apply


def test_file_size_limit_is_one_line_and_the_store_keeps_its_iterations(tmp_path: Path):
    out = tmp_path / "c3.h5"
    # an iteration of this short run is about 0.2 MB: the limit is hit after the first commits
    result = _cli("simulate", "-m", "c3", "-n", "8", "--out", str(out), *SHORT, preexec_fn=_limit_file_size(700_000))
    _one_line_exit_2(result, str(out))
    store.validate(out)
    done = store.iterations(out)
    assert 1 <= len(done) < 8 and done == list(range(len(done)))
    resumed = _cli("simulate", "-m", "c3", "-n", "8", "--out", str(out), "--resume", *SHORT)
    assert resumed.returncode == 0, resumed.stderr
    assert store.iterations(out) == list(range(8))


# -- fault 6: a flipped bit ------------------------------------------------------------------------


def _flip_bit_in(path: Path, dataset: str) -> None:
    with h5py.File(path, "r") as handle:
        offset = handle[dataset].id.get_offset()
    with open(path, "r+b") as raw:
        raw.seek(offset + 1001)
        byte = raw.read(1)
        raw.seek(offset + 1001)
        raw.write(bytes([byte[0] ^ 0x10]))


def test_flipped_bit_in_memory_fails_validate_and_resume(path: Path):
    write_run(path, 2, finish=None)
    _flip_bit_in(path, "iterations/0001/memory/theta_hat")
    with pytest.raises(StoreError, match="checksum") as error:
        store.validate(path)
    assert_one_line_naming(error, path)
    with pytest.raises(StoreError, match="checksum"):
        with writer(path, config=resumed_config(3), resume=True):
            pass


def test_flipped_bit_in_log_fails_the_reader(path: Path):
    write_run(path, 2)
    _flip_bit_in(path, "iterations/0000/log/position")
    with pytest.raises(StoreError, match="checksum"):
        store.read_iteration(path, 0)


# -- fault 7: wrong types and shapes ---------------------------------------------------------------


def _forge_iteration_attr(path: Path, name: str, value) -> None:
    with h5py.File(path, "a") as handle:
        handle["iterations/0001"].attrs[name] = value


def _forge_memory_shape(path: Path) -> None:
    with h5py.File(path, "a") as handle:
        group = handle["iterations/0001/memory"]
        del group["theta_hat"]
        group.create_dataset("theta_hat", data=np.zeros((5, 2)))
        group["theta_hat"].attrs["units"] = "kg"


FORGERIES = {
    "float iteration with inf": lambda p: _forge_iteration_attr(p, "iteration", np.inf),
    "string fallback_count": lambda p: _forge_iteration_attr(p, "fallback_count", "many"),
    "int status": lambda p: _forge_iteration_attr(p, "status", 3),
    "memory of the wrong shape": _forge_memory_shape,
}


@pytest.mark.parametrize("forge", FORGERIES.values(), ids=FORGERIES.keys())
def test_wrong_type_or_shape_is_one_line(path: Path, forge):
    write_run(path, 2, finish=None)
    forge(path)
    with pytest.raises(StoreError) as error:
        store.validate(path)
    assert_one_line_naming(error, path)
    with pytest.raises(StoreError):
        with writer(path, config=resumed_config(3), resume=True):
            pass


def test_int_status_column_in_metrics_is_not_trusted(path: Path):
    write_run(path, 2)
    with h5py.File(path, "a") as handle:
        del handle["metrics/status"]
        handle["metrics"].create_dataset("status", data=np.array([1, 2]))
        handle["metrics/status"].attrs["units"] = "-"
        seal_attrs(handle["metrics/status"])  # a cache column of the wrong kind, sealed by its writer
    store.validate(path)  # a stale cache is recomputed from the logs, never trusted
    assert list(store.read_metrics(path)["status"]) == ["complete", "complete"]


# -- fault 9: a lock file that is a symlink ----------------------------------------------------------


def test_symlinked_lock_file_is_refused_and_its_target_untouched(path: Path, tmp_path: Path):
    path.parent.mkdir(parents=True)
    victim = tmp_path / "victim.txt"
    victim.write_text("precious\n")
    path.with_name(path.name + ".lock").symlink_to(victim)
    with pytest.raises(StoreError, match="symbolic link") as error:
        with writer(path):
            pass
    assert_one_line_naming(error, path)
    assert victim.read_text() == "precious\n"


def test_existing_lock_file_is_never_truncated(path: Path):
    path.parent.mkdir(parents=True)
    lock = path.with_name(path.name + ".lock")
    lock.write_text("someone else's notes\n")
    write_run(path, 1)
    assert lock.read_text() == "someone else's notes\n"


# -- fault 10: --overwrite replaces only a store ------------------------------------------------------


def _fifo(p: Path) -> None:
    os.mkfifo(p)


THINGS = {"text file": lambda p: p.write_text("my notes\n"), "fifo": _fifo,
          "foreign HDF5": lambda p: h5py.File(p, "w").close()}


@pytest.mark.parametrize("make", THINGS.values(), ids=THINGS.keys())
def test_overwrite_refuses_what_is_not_a_store(path: Path, make):
    path.parent.mkdir(parents=True)
    make(path)
    kind = os.lstat(path).st_mode
    with pytest.raises(StoreError) as error:
        with writer(path, overwrite=True) as w:
            w.append(make_record(0))
    assert_one_line_naming(error, path)
    assert os.lstat(path).st_mode == kind


TARGETS = {**THINGS, "folder": lambda p: p.mkdir()}


@pytest.mark.parametrize("mode", [{}, {"overwrite": True}, {"resume": True}], ids=["plain", "overwrite", "resume"])
@pytest.mark.parametrize("kind", TARGETS)
def test_a_target_no_option_may_write_is_refused_without_a_hint_or_a_lock_file(path: Path, kind, mode):
    """Found by an attack: `simulate --out FOLDER` (or a text file) left FOLDER.lock behind and, plain,
    advised '--overwrite replaces it or --resume continues it', both of which are refused. A foreign
    HDF5 file is told apart only by opening it, under the lock (its lock file stays)."""
    path.parent.mkdir(parents=True)
    TARGETS[kind](path)
    with pytest.raises(StoreError) as error:
        with writer(path, **mode) as w:
            w.append(make_record(0))
    assert_one_line_naming(error, path)
    assert "--overwrite replaces it" not in str(error.value)
    if kind != "foreign HDF5":
        assert sorted(p.name for p in path.parent.iterdir()) == ["c3.h5"], "nothing made beside it"


def test_overwrite_replaces_a_store(path: Path):
    write_run(path, 2)
    with writer(path, overwrite=True) as w:
        w.append(make_record(0))
        w.finish("complete")
    assert store.iterations(path) == [0]


# -- fault 12: paths are never globbed ---------------------------------------------------------------


def test_a_store_named_like_a_glob_leaves_other_writers_alone(tmp_path: Path):
    folder = tmp_path / "results" / "paper"
    plain, globby = folder / "c1.h5", folder / "c[1].h5"
    with writer(plain) as first:
        first.append(make_record(0))
        leftover = plain.with_name(plain.name + ".tmp-12345")  # an old version's leftover copy of c1.h5
        leftover.write_bytes(b"not ours")
        with writer(globby) as second:  # its cleanup must not match c1.h5's files
            second.append(make_record(0))
            second.finish("complete")
        assert leftover.exists()
        first.append(make_record(1))
        first.finish("complete")
    assert store.iterations(plain) == [0, 1] and store.iterations(globby) == [0]


# -- fault 14: commits without HDF5 file locking ------------------------------------------------------


def test_commits_stay_in_place_without_hdf5_locking(path: Path, monkeypatch: pytest.MonkeyPatch):
    """With HDF5_USE_FILE_LOCKING=FALSE a commit must not copy the file: the store keeps its
    inode across commits (in place) and no second copy appears beside it."""
    monkeypatch.setenv("HDF5_USE_FILE_LOCKING", "FALSE")
    with writer(path, n_iterations=6) as w:
        w.append(make_record(0))
        inode = os.stat(path).st_ino
        for j in range(1, 6):
            w.append(make_record(j))
            assert os.stat(path).st_ino == inode, f"commit {j} replaced the file (a copy)"
            beside = sorted(p.name for p in path.parent.iterdir())
            assert beside == ["c3.h5", "c3.h5.lock"], beside
        w.finish("complete")
    store.validate(path)


# -- fault 7 in the report: one bad file never aborts it ------------------------------------------------


def test_report_skips_a_store_with_forged_types(tmp_path: Path):
    from typer.testing import CliRunner

    from ilcforce.cli.main import app
    from ilcforce.report.build import write_report

    results = tmp_path / "results"
    made = CliRunner().invoke(app, ["compare", "--methods", "c1,c2", "-n", "2", "--results", str(results), *SHORT])
    assert made.exit_code == 0, made.output
    folder = next(results.iterdir())
    with h5py.File(folder / "c2.h5", "a") as handle:  # a float iteration index with inf
        handle["iterations/0001"].attrs["iteration"] = np.inf
    summary = write_report(results, tmp_path / "report", formats=())
    assert summary.experiments == (folder.name,)
    assert any("c2.h5" in w for w in summary.warnings), summary.warnings


def test_a_store_marked_walked_skips_the_probe_until_it_changes(path: Path, monkeypatch):
    """compare's parent skips the forked walk of a store its worker has just written (the worker sends
    the file's key); any later change to the file is a new key and is walked again."""
    from ilcforce.store import filecheck, safeio

    write_run(path, 2)
    marks = path.parent / "walks.txt"  # the walk runs in a forked child: it leaves a mark in a file

    def walk(p, image=None, real=filecheck._walk):
        with open(marks, "a") as handle:
            handle.write("walk\n")
        real(p, image)

    def walks():
        return marks.read_text().split() if marks.exists() else []

    monkeypatch.setattr(filecheck, "_walk", walk)
    monkeypatch.setattr(filecheck, "_probed", set())
    safeio.mark_walked(safeio.file_key(path))
    store.read_metrics(path)
    assert walks() == []
    info = os.stat(path)
    os.utime(path, ns=(info.st_atime_ns, info.st_mtime_ns + 1_000_000))
    store.read_metrics(path)
    assert walks() == ["walk"]


# -- a second stop signal inside a commit (found by an attack on the CLI) ------------------------


@pytest.mark.parametrize("at_write", [1, 3, 10, 25])
@pytest.mark.parametrize("last", [False, True])
def test_a_stop_inside_a_commit_takes_effect_after_it(path: Path, monkeypatch, at_write: int, last: bool):
    """Two SIGINTs 10 ms apart: the second one's handler ran inside the stop commit, in HDF5's
    write-back of an object h5py was releasing; h5py swallowed the KeyboardInterrupt, the commit
    ended "normally" without the /metrics rows, and the store no longer validated (nor resumed).
    The handlers now call stops.interrupt(), which inside a commit raises only once it has
    ended. Here the handler's call is made from the at_write-th write of the store's file."""
    from ilcforce import stops
    from ilcforce.store import journal

    real_write = journal.JournaledFile.write
    calls = [0]

    def write(self, data):
        calls[0] += 1
        if calls[0] == at_write:
            stops.interrupt()  # what a second Ctrl-C's handler does, wherever it lands
        return real_write(self, data)

    with writer(path, config=resumed_config(3)) as w:
        w.append(make_record(0))
        w.append(make_record(1))
        monkeypatch.setattr(journal.JournaledFile, "write", write)
        with pytest.raises(KeyboardInterrupt):
            if last:
                w.append(make_record(2), finish="complete")
            else:
                w.append(make_record(2))
        monkeypatch.setattr(journal.JournaledFile, "write", real_write)
        assert calls[0] >= at_write, "the commit wrote less than expected: the test reached nothing"
    store.validate(path)  # raises on a damaged store
    assert store.iterations(path) == [0, 1, 2]  # the commit the signal landed in completed
    assert len(store.read_metrics_rows(path)) == 3
    assert store.read_provenance(path)["run_state"] == ("complete" if last else "partial")


def test_a_stop_outside_a_commit_raises_at_once():
    from ilcforce import stops

    with pytest.raises(KeyboardInterrupt):
        stops.interrupt()
    with stops.critical():  # a section that failed on its own: its error, not a stop, goes on
        pass


# -- a reader polling a live store does not hold up its writer -----------------------------------


def test_a_reader_holds_the_store_lock_only_while_it_copies_the_file(path: Path, monkeypatch):
    """A reader that held the shared lock for its whole read (ilcforce.open validates every byte)
    made the writer wait at every commit: a reader polling `ilcforce.open` slowed a 40-iteration
    writer from 1.4 s to 8.1 s, 8.4 s of it waiting for the lock (measured). The reader now copies
    the file under the lock and reads the copy: while it reads, the writer commits at once, and the
    reader sees the store as it was when it opened it."""
    import fcntl

    from ilcforce.store import read

    def locked_by_a_reader() -> bool:
        fd = os.open(path, os.O_RDONLY)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            return False
        except BlockingIOError:
            return True
        finally:
            os.close(fd)

    write_run(path, 2, finish=None)
    with read.open_store(path):  # no writer at work: read in place, lazily, under the lock
        assert locked_by_a_reader()
    with writer(path, config=resumed_config(3), resume=True) as w:
        with read.open_store(path) as (handle, _checked, _major):
            assert not locked_by_a_reader(), "the reader holds no lock while it reads its copy"
            w.append(make_record(2))
            w.finish("complete")
            assert sorted(handle["iterations"]) == ["0000", "0001"], "the reader's copy is the store it opened"
        monkeypatch.setattr(read, "SNAPSHOT_BYTES", 0)  # a store too large to copy is read under the lock
        with read.open_store(path):
            assert locked_by_a_reader()
    assert store.iterations(path) == [0, 1, 2]
