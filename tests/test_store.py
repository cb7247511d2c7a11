"""The HDF5 results store: round trip, self-description, refusal rules, resume, locking,
crash safety and one-line errors on broken files.

Arrays go through HDF5 as float64 without compression, so every comparison of stored data is
exact (``assert_array_equal``), not approximate.
"""

from __future__ import annotations

import json
import math
import re
import subprocess
import sys
from datetime import datetime
from pathlib import Path

import h5py  # the tests inspect and forge files directly; library code leaves h5py to the store
import numpy as np
import pytest

from ilcforce import store
from ilcforce.metrics import METRIC_COLUMNS, iteration_metrics
from ilcforce.records import LOG_SIGNALS, REFERENCE_SIGNALS, STATUS_COMPLETE, STATUS_DIVERGED, IterationRecord
from ilcforce.store import (
    SCHEMA_NAME,
    SCHEMA_VERSION,
    StoreError,
    StoreExistsError,
    StoreLockedError,
    StoreWriter,
)

N_LOG = 21  # log grid: 0.1 s over 2 s
N_CONTROL = 201  # control grid: 10 ms over 2 s
DURATION = 2.0
CONFIG = {"run": {"n_iterations": 3, "method": "c3"}, "plant": {"m3": 0.5, "scale": [1.0, 2.0]}, "seed": 7}


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
        n_iterations=config["run"]["n_iterations"],
        reference=make_reference(),
    )
    arguments.update(kwargs)
    return StoreWriter(path, **arguments)


def write_run(path: Path, n: int, *, finish: str | None = STATUS_COMPLETE, **kwargs) -> list[IterationRecord]:
    """Write iterations 0..n-1, validating the file after every commit and at the end."""
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


# -- round trip and self-description ---------------------------------------------------------


def test_round_trip_is_exact(path: Path):
    records = write_run(path, 3)
    assert store.iterations(path) == [0, 1, 2]
    for record in records:
        frame = store.read_iteration(path, record.iteration)
        np.testing.assert_array_equal(frame.index.to_numpy(), record.log["time"], err_msg="time index")
        for name, (axes, _unit, _description) in LOG_SIGNALS.items():
            if axes is None:
                if name != "time":
                    np.testing.assert_array_equal(frame[name].to_numpy(), record.log[name], err_msg=name)
                continue
            for column, axis in enumerate(axes):
                np.testing.assert_array_equal(
                    frame[f"{name}_{axis}"].to_numpy(), record.log[name][:, column], err_msg=f"{name}_{axis}"
                )
        memory = store.read_memory(path, record.iteration)
        assert set(memory) == set(record.memory)
        for name, values in record.memory.items():
            assert memory[name].dtype == np.float64
            np.testing.assert_array_equal(memory[name], values, err_msg=f"memory {name}")
        assert store.read_memory_units(path, record.iteration) == record.memory_units
        assert frame.attrs["status"] == STATUS_COMPLETE
        assert frame.attrs["fallback_count"] == record.iteration
        assert math.isnan(frame.attrs["diverged_time"])
        assert frame.attrs["diverged_reason"] == ""
    reference = store.read_reference(path)
    expected = make_reference()
    np.testing.assert_array_equal(reference.index.to_numpy(), expected["time"], err_msg="reference time")
    np.testing.assert_array_equal(
        reference[["position_desired_x", "position_desired_y"]].to_numpy(), expected["position_desired"],
        err_msg="position_desired",
    )
    metrics = store.read_metrics(path)
    for record in records:
        row = iteration_metrics(record)
        for column in list(METRIC_COLUMNS)[1:]:
            stored, computed = metrics.loc[record.iteration, column], row[column]
            if isinstance(computed, float) and math.isnan(computed):
                assert math.isnan(stored), column
            else:
                assert stored == computed, f"iteration {record.iteration} column {column}: {stored} != {computed}"


def test_provenance(path: Path):
    write_run(path, 2)
    provenance = store.read_provenance(path)
    assert list(provenance)[: len(store.ROOT_ATTRS)] == list(store.ROOT_ATTRS)
    assert provenance["schema"] == SCHEMA_NAME
    assert provenance["schema_version"] == SCHEMA_VERSION
    assert provenance["experiment"] == "paper" and provenance["method"] == "c3"
    assert provenance["seed"] == 7 and isinstance(provenance["seed"], int)
    assert provenance["n_iterations_requested"] == 3
    assert provenance["run_state"] == "complete"
    assert json.loads(provenance["config_json"]) == CONFIG
    assert provenance["config_toml"] == "[run]\nn_iterations = 3\n"
    assert provenance["command"].startswith("ilcforce simulate")
    assert isinstance(provenance["git_commit"], str)
    assert isinstance(provenance["ilcforce_version"], str) and provenance["ilcforce_version"]
    for stamp in ("created_utc", "updated_utc"):
        parsed = datetime.fromisoformat(provenance[stamp])
        assert parsed.utcoffset() is not None and parsed.utcoffset().total_seconds() == 0, stamp


def test_every_dataset_is_described(path: Path):
    write_run(path, 2)
    undescribed: list[str] = []
    without_axes: list[str] = []

    def visit(name: str, item) -> None:
        if isinstance(item, h5py.Dataset):
            if "units" not in item.attrs or "description" not in item.attrs:
                undescribed.append(name)
            signal = name.rsplit("/", 1)[-1]
            table = LOG_SIGNALS if "/log/" in name else REFERENCE_SIGNALS if name.startswith("reference/") else {}
            if signal in table and table[signal][0] is not None:
                if list(item.attrs.get("axes", [])) != list(table[signal][0]):
                    without_axes.append(name)

    with h5py.File(path, "r") as handle:
        handle.visititems(visit)
        assert handle["iterations/0001/log/position"].attrs["units"] == "m"
        assert handle["iterations/0001/memory/theta_hat"].attrs["units"] == "kg m^2"
        assert handle["metrics/status"].dtype.kind == "O"
        assert handle["metrics/position_error_2norm"].maxshape == (None,)
        assert handle["iterations/0001"].attrs["complete"]
    assert not undescribed, f"datasets without units/description: {undescribed}"
    assert not without_axes, f"datasets with wrong axes: {without_axes}"


def test_read_metrics_columns_and_units(path: Path):
    write_run(path, 3)
    metrics = store.read_metrics(path)
    assert metrics.index.name == "iteration"
    assert list(metrics.index) == [0, 1, 2]
    assert metrics.index.dtype == np.int64
    assert list(metrics.columns) == list(METRIC_COLUMNS)[1:]
    assert metrics.attrs["units"] == {name: unit for name, (unit, _d) in METRIC_COLUMNS.items() if name != "iteration"}
    assert list(metrics["status"]) == [STATUS_COMPLETE] * 3
    assert metrics["fallback_count"].dtype == np.int64


def test_read_iteration_columns_and_units(path: Path):
    write_run(path, 1)
    frame = store.read_iteration(path, 0)
    expected_columns = []
    for name, (axes, _unit, _description) in LOG_SIGNALS.items():
        if name != "time":
            expected_columns += [name] if axes is None else [f"{name}_{axis}" for axis in axes]
    assert list(frame.columns) == expected_columns
    assert frame.index.name == "time"
    assert frame.shape == (N_LOG, 32)
    assert {"position_x", "torque_1", "force_error_y", "joint_angle_2"} <= set(frame.columns)
    units = frame.attrs["units"]
    assert units["time"] == "s"
    assert units["position_x"] == "m" and units["torque_1"] == "N m" and units["contact_force_y"] == "N"
    assert set(units) == set(expected_columns) | {"time"}
    reference = store.read_reference(path)
    assert list(reference.columns) == [
        "position_desired_x", "position_desired_y", "velocity_desired_x", "velocity_desired_y",
        "acceleration_desired_x", "acceleration_desired_y", "force_desired_x", "force_desired_y",
    ]
    assert reference.attrs["units"]["acceleration_desired_y"] == "m/s^2"


def test_diverged_iteration_round_trip(path: Path):
    with writer(path) as w:
        w.append(make_record(0))
        w.append(make_record(1, status=STATUS_DIVERGED))
        assert w.stored_status() == STATUS_DIVERGED
        w.finish(STATUS_DIVERGED)
    store.validate(path)
    assert store.read_provenance(path)["run_state"] == "diverged"
    frame = store.read_iteration(path, 1)
    assert frame.attrs["status"] == STATUS_DIVERGED
    assert frame.attrs["diverged_time"] == 1.05
    assert frame.attrs["diverged_reason"] == "|tau| above 1e3 N m"
    # The log time is NaN after the divergence; the index falls back to the log grid.
    np.testing.assert_array_equal(frame.index.to_numpy(), make_reference()["time"], err_msg="index")
    assert np.isnan(frame["position_x"].to_numpy()[11:]).all()
    metrics = store.read_metrics(path)
    assert metrics.loc[1, "status"] == STATUS_DIVERGED
    assert math.isnan(metrics.loc[1, "position_error_2norm"])
    assert metrics.loc[1, "diverged_time"] == 1.05


def test_memoryless_controller(path: Path):
    with writer(path) as w:
        w.append(make_record(0, with_memory=False))
        assert w.resume_memory() == {}
        w.finish(STATUS_COMPLETE)
    assert store.read_memory(path, 0) == {}


def test_read_iteration_not_stored(path: Path):
    write_run(path, 2)
    with pytest.raises(StoreError, match="iteration 5 is not stored") as error:
        store.read_iteration(path, 5)
    assert_one_line_naming(error, path)
    with pytest.raises(StoreError, match="not stored"):
        store.read_memory(path, -1)


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
    with writer(path, overwrite=True) as w:
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
    with writer(path) as w:
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


def resumed_config(n_iterations: int) -> dict:
    config = json.loads(json.dumps(CONFIG))
    config["run"]["n_iterations"] = n_iterations
    return config


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
    with writer(path, resume=True) as w:
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
        (lambda c: c["plant"].__setitem__("scale", [1.0, 3.0]), "plant.scale[1]"),
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
    assert repr(key) in str(error.value), str(error.value)


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
    with writer(path) as w:
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
    stale = path.with_name(path.name + ".tmp-999999")
    stale.write_bytes(b"half a copy")
    stale_prev = path.with_name(path.name + ".tmp-999999.prev")
    stale_prev.write_bytes(b"")
    store.validate(path)
    assert store.iterations(path) == [0, 1]
    assert store.find_stores(path.parent.parent) == {"paper": {"c3": path}}
    with writer(path, config=resumed_config(3), resume=True) as w:
        assert not stale.exists() and not stale_prev.exists(), "the next writer removes stale copies"
        w.append(make_record(2))
    store.validate(path)


def test_kill_9_mid_run_leaves_valid_file(path: Path):
    # A real SIGKILL at an arbitrary moment of a run that commits as fast as it can.
    script = (
        "import sys\n"
        f"sys.path.insert(0, {str(Path(__file__).parent)!r})\n"
        "from pathlib import Path\n"
        "from test_store import make_record, writer\n"
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
        assert not list(path.parent.glob(path.name + ".tmp-*")), "leftover copies removed"
    assert store.read_provenance(path)["run_state"] == "partial"


def test_running_state_left_by_kill_becomes_partial_on_resume(path: Path):
    write_run(path, 2, finish=None)
    with h5py.File(path, "a") as handle:  # what a kill -9 after a commit leaves
        handle.attrs["run_state"] = "running"
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
            assert not list(path.parent.glob(path.name + ".tmp-*")), "writer should have fallen back"
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
        copies = list(path.parent.glob(path.name + ".tmp-*"))
        for copy in copies:  # the kept copy (if any) is a valid store with the same content
            store.validate(copy)
            assert store.iterations(copy) == [0, 1, 2]
            assert store.read_metrics(copy).equals(store.read_metrics(path))
        w.finish(STATUS_COMPLETE)
    assert not list(path.parent.glob(path.name + ".tmp-*"))


def test_without_hdf5_locking_every_commit_copies(path: Path, monkeypatch: pytest.MonkeyPatch):
    monkeypatch.setenv("HDF5_USE_FILE_LOCKING", "FALSE")
    records = write_run(path, 3)
    assert not list(path.parent.glob(path.name + ".tmp-*"))
    np.testing.assert_array_equal(store.read_memory(path, 2)["alpha_hat"], records[2].memory["alpha_hat"])


# -- broken files ----------------------------------------------------------------------------

READERS = {
    "validate": store.validate,
    "iterations": store.iterations,
    "read_provenance": store.read_provenance,
    "read_metrics": store.read_metrics,
    "read_reference": store.read_reference,
    "read_iteration": lambda p: store.read_iteration(p, 0),
    "read_memory": lambda p: store.read_memory(p, 0),
}


def broken_missing(path: Path) -> str:
    return "no such file"


def broken_empty(path: Path) -> str:
    path.write_bytes(b"")
    return "empty file"


def broken_truncated(path: Path) -> str:
    write_run(path, 3)
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    return "not a readable HDF5 file"


def broken_text(path: Path) -> str:
    path.write_text("hello\n" * 100)
    return "not a readable HDF5 file"


def broken_foreign(path: Path) -> str:
    with h5py.File(path, "w") as handle:
        handle.attrs["creator"] = "someone else"
        handle.create_dataset("data", data=np.arange(3))
    return "not an ilcforce store"


def broken_other_schema(path: Path) -> str:
    with h5py.File(path, "w") as handle:
        handle.attrs["schema"] = "other.format"
    return "not an ilcforce store"


def broken_newer(path: Path) -> str:
    write_run(path, 1)
    with h5py.File(path, "a") as handle:
        handle.attrs["schema_version"] = "2.0"
    return "written by a newer ilcforce (schema 2.0); upgrade to read it"


def broken_missing_attr(path: Path) -> str:
    write_run(path, 1)
    with h5py.File(path, "a") as handle:
        del handle.attrs["seed"]
    return "missing root attributes seed"


def broken_missing_signal(path: Path) -> str:
    write_run(path, 1)
    with h5py.File(path, "a") as handle:
        del handle["iterations/0000/log/force_error"]
    return "missing dataset /iterations/0000/log/force_error"


def broken_wrong_shape(path: Path) -> str:
    write_run(path, 1)
    with h5py.File(path, "a") as handle:
        del handle["iterations/0000/log/torque"]
        handle["iterations/0000/log/torque"] = np.zeros((N_LOG, 3))
        handle["iterations/0000/log/torque"].attrs["units"] = "N m"
    return "has shape (21, 3), expected (21, 2)"


def broken_no_units(path: Path) -> str:
    write_run(path, 1)
    with h5py.File(path, "a") as handle:
        del handle["iterations/0000/memory/theta_hat"].attrs["units"]
    return "no 'units' attribute"


def broken_metrics_lengths(path: Path) -> str:
    write_run(path, 2)
    with h5py.File(path, "a") as handle:
        handle["metrics/force_error_rms"].resize((1,))
    return "metrics columns have different lengths"


BROKEN = [
    broken_missing, broken_empty, broken_truncated, broken_text, broken_foreign, broken_other_schema,
    broken_newer, broken_missing_attr, broken_missing_signal, broken_wrong_shape, broken_no_units,
    broken_metrics_lengths,
]


@pytest.mark.parametrize("breaker", BROKEN, ids=[b.__name__.removeprefix("broken_") for b in BROKEN])
def test_broken_file_gives_one_line_store_error(path: Path, breaker):
    """validate() names every structural problem; readers never raise anything but a one-line StoreError.

    Readers check only what they read (a full check on every read would make each read cost
    O(file size) and a report over n iterations O(n^2)), so on a file broken elsewhere they may
    succeed; when they fail, it is with one line naming the file.
    """
    path.parent.mkdir(parents=True, exist_ok=True)
    expected = breaker(path)
    with pytest.raises(StoreError) as error:
        store.validate(path)
    assert_one_line_naming(error, path)
    assert expected in str(error.value), f"validate: {error.value}"
    for name, reader in READERS.items():  # every reader, on the same broken file
        try:
            reader(path)
        except StoreError as failure:
            assert "\n" not in str(failure) and str(path) in str(failure), f"{name}: {failure}"


def test_newer_minor_version_is_read(path: Path):
    write_run(path, 1)
    major = SCHEMA_VERSION.split(".")[0]
    with h5py.File(path, "a") as handle:
        handle.attrs["schema_version"] = f"{major}.99"
    store.validate(path)


def test_resume_of_broken_file_is_refused(path: Path):
    broken_truncated(path)
    with pytest.raises(StoreError, match="not a readable HDF5 file") as error:
        with writer(path, resume=True):
            pass
    assert_one_line_naming(error, path)


# -- discovery -------------------------------------------------------------------------------


def test_find_stores(tmp_path: Path):
    results = tmp_path / "results"
    for experiment, method in (("paper", "c1"), ("paper", "c3"), ("noise-free", "c2")):
        write_run(results / experiment / f"{method}.h5", 1)
    (results / "paper" / "c2.h5.tmp-123").write_bytes(b"junk")
    (results / "README.md").write_text("not a store")
    (results / "report").mkdir()
    found = store.find_stores(results)
    assert found == {
        "noise-free": {"c2": results / "noise-free" / "c2.h5"},
        "paper": {"c1": results / "paper" / "c1.h5", "c3": results / "paper" / "c3.h5"},
    }
    with pytest.raises(StoreError) as error:
        store.find_stores(tmp_path / "nowhere")
    assert str(tmp_path / "nowhere") in str(error.value)


def test_store_error_messages_are_single_line():
    assert str(StoreError("a\nb\n c")) == "a b c"
    assert issubclass(StoreLockedError, StoreError) and issubclass(StoreExistsError, StoreError)


def test_only_the_store_imports_h5py():
    package = Path(store.__file__).parent
    offenders = [
        str(p.relative_to(package))
        for p in package.rglob("*.py")
        if p.name != "store.py" and re.search(r"^\s*(import|from)\s+h5py\b", p.read_text(encoding="utf-8"), re.M)
    ]
    assert not offenders, f"h5py used outside ilcforce/store.py: {offenders}"
