"""The store's format: round trip, self-description, schema, one-line errors on broken files, discovery."""

from __future__ import annotations

import json
import math
import re
from datetime import datetime
from pathlib import Path

import h5py  # the tests inspect and forge files directly; library code leaves h5py to the store
import numpy as np
import pytest

from ilcforce.store.seal import seal_attrs

from ilcforce import store
from ilcforce.metrics import METRIC_COLUMNS, iteration_metrics
from ilcforce.records import LOG_SIGNALS, REFERENCE_SIGNALS, STATUS_COMPLETE, STATUS_DIVERGED
from ilcforce.store import SCHEMA_NAME, SCHEMA_VERSION, StoreError, StoreExistsError, StoreLockedError
from storekit import CONFIG, N_LOG, assert_one_line_naming, make_record, make_reference, write_run, writer


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
    write_run(path, 3)
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
        assert handle["metrics/status"].dtype.kind == "S"  # fixed-length UTF-8: checksummed like the rest
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
    assert frame.shape == (N_LOG, len(expected_columns))
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
        handle.attrs["schema_version"] = "3.0"
    return "written by a newer ilcforce (schema 3.0); upgrade to read it"


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
        seal_attrs(handle["iterations/0000/memory/theta_hat"])  # as a writer that forgot the unit would
    return "no 'units' attribute"


def broken_metrics_lengths(path: Path) -> str:
    write_run(path, 2)
    with h5py.File(path, "a") as handle:
        handle["metrics/force_error_rms"].resize((1,))
    return "metrics columns have different lengths"


def _forged(name: str, n: int, where: str, key: str, value, message: str, reseal: bool = True):
    """A breaker that writes n iterations, then sets attribute ``key`` of ``where`` to ``value`` and
    (``reseal``) seals it again, as a writer with that bug would: only the consistency check can
    catch it; without ``reseal``, as damage after writing would."""
    def breaker(path: Path) -> str:
        write_run(path, n)
        with h5py.File(path, "a") as handle:
            handle[where].attrs[key] = value
            if reseal:
                seal_attrs(handle[where])
        return message
    breaker.__name__ = f"broken_{name}"
    return breaker


#: headers that disagree with the iterations
FORGED = [
    _forged("complete_but_short", 2, "/", "n_iterations_requested", 5,
            "run_state is 'complete' but it holds 2 of the 5 iterations requested"),
    _forged("diverged_without_divergence", 2, "/", "run_state", "diverged",
            "run_state is 'diverged' but no stored iteration diverged"),
    _forged("iteration_after_divergence", 2, "iterations/0000", "status", "diverged",
            "iteration 1 is stored after the diverged iteration 0"),
    _forged("config_json", 1, "/", "config_json", "[1, 2", "config_json is not a JSON object"),
    _forged("method_path", 1, "/", "method", "../../etc", "root attribute method '../../etc' is not a plain name"),
    _forged("method_unregistered", 1, "/", "method", "c9", "method 'c9' is not a registered method"),
    _forged("negative_requested", 1, "/", "n_iterations_requested", -3,
            "root attribute n_iterations_requested is -3, below 0"),
    _forged("negative_seed", 1, "/", "seed", -1, "root attribute seed is -1, below 0"),
    # changed after writing, seal untouched: config, units, Theta labels, metrics description
    _forged("config_changed", 1, "/", "config_json", '{"c3": {"eta": 4.0}}',
            "the root attributes (configuration, command, provenance) do not match their checksum", reseal=False),
    _forged("units_changed", 1, "iterations/0000/log/contact_force", "units", "mN",
            "the attributes of /iterations/0000/log/contact_force (units, labels, description or state) do not match",
            reseal=False),
    _forged("log_axes_changed", 1, "iterations/0000/log/contact_force", "axes", ["y", "x"],
            "the attributes of /iterations/0000/log/contact_force", reseal=False),
    _forged("status_changed", 1, "metrics", "description", "x", "the attributes of /metrics ", reseal=False),
    _forged("reference_description_changed", 1, "reference/time", "description", "t",
            "the attributes of /reference/time", reseal=False),
]


def broken_seal_removed(path: Path) -> str:
    write_run(path, 1)
    with h5py.File(path, "a") as handle:
        del handle["iterations/0000"].attrs["attrs_crc32"]
    return ("the attributes of /iterations/0000 (units, labels, description or state) do not match their checksum "
            "attrs_crc32 or have none")


BROKEN = [
    broken_missing, broken_empty, broken_truncated, broken_text, broken_foreign, broken_other_schema,
    broken_newer, broken_missing_attr, broken_missing_signal, broken_wrong_shape, broken_no_units,
    broken_metrics_lengths, broken_seal_removed, *FORGED,
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
        seal_attrs(handle)  # as a newer writer would
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
    store_package = Path(store.__file__).parent
    package = store_package.parent
    offenders = [
        str(p.relative_to(package))
        for p in package.rglob("*.py")
        if store_package not in p.parents
        and re.search(r"^\s*(import|from)\s+h5py\b", p.read_text(encoding="utf-8"), re.M)
    ]
    assert not offenders, f"h5py used outside ilcforce/store/: {offenders}"
