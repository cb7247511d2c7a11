"""A run store of a task of 3 axes (a spatial arm pressing on a plane) beside the 2-axis stores.

A 3-axis store holds its task-space and joint-space arrays (n_log, 3) with the axes ("u", "v", "n")
and ("1", "2", "3"), says so in its root attribute ``task_dimension`` and keeps the metrics columns
of :func:`ilcforce.metrics.metric_columns` (3). A 2-axis store has no such attribute and is, object
for object and attribute for attribute, the store the code wrote before n axes:
``tests/data/store_structure_2axis.json`` was written by that code (commit d5f0c0b) from the
storekit run below, and a fresh one must describe the same file. It was written again once, when
schema 2.2 bound every record to its store (ilcforce.store.binding): the only differences are
schema_version, the root's store_id and n_iterations_stored, and binding_sha256 on /reference and on
each iteration group (values per store, shown as such). To write it again (only when the 2-axis
layout changes on purpose, and said in that commit):

    mkdir /tmp/ref-tree && git archive <commit> ilcforce | tar -x -C /tmp/ref-tree
    (cd /tmp && PYTHONPATH=/tmp/ref-tree:$OLDPWD/tests $OLDPWD/.venv/bin/python -c \
        "import storekit; storekit.write_structure()" $OLDPWD/tests/data/store_structure_2axis.json)

(from outside the checkout, whose own ilcforce would win; ``storekit`` uses only names that code
had, and the script checks that ilcforce came from the tree.)

The records here are synthetic (random finite arrays of the right shapes): the store's job is to keep
bits, not physics.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import h5py
import numpy as np
import pytest

import ilcforce
from ilcforce import store
from ilcforce.metrics import METRIC_COLUMNS, iteration_metrics, metric_columns
from ilcforce.records import (LOG_SIGNALS, REFERENCE_SIGNALS, STATUS_COMPLETE, STATUS_DIVERGED, IterationRecord,
                              joint_axes, log_signals, reference_signals, task_axes)
from ilcforce.store import StoreError
from ilcforce.store.seal import seal_attrs
from storekit import (DURATION, N_CONTROL, N_LOG, assert_one_line_naming, make_record, path,  # noqa: F401
                      store_structure, write_run, writer)

STRUCTURE = Path(__file__).parent / "data" / "store_structure_2axis.json"


def reference_3() -> dict[str, np.ndarray]:
    """Every reference signal of a 3-axis task on the log grid, distinct values per signal."""
    time = np.linspace(0.0, DURATION, N_LOG)
    out = {"time": time}
    for k, (name, (axes, _unit, _description)) in enumerate(reference_signals(3).items()):
        if axes is not None:
            out[name] = np.column_stack([np.sin(time + k), np.cos(time * k), time * (k + 1)])
    return out


def record_3(j: int, status: str = STATUS_COMPLETE) -> IterationRecord:
    """Iteration j of a 3-axis task: every log signal (N_LOG,) or (N_LOG, 3), random finite values
    (NaN after 1.05 s when diverged, as the simulator leaves them); memory (N_CONTROL, 3) and (N_CONTROL,)."""
    rng = np.random.default_rng(3000 + j)
    time = np.linspace(0.0, DURATION, N_LOG)
    log = {name: time.copy() if axes is None else rng.standard_normal((N_LOG, 3))
           for name, (axes, _unit, _description) in log_signals(3).items()}
    if status == STATUS_DIVERGED:
        for name in log:
            log[name][11:] = np.nan
    return IterationRecord(iteration=j, status=status, diverged_time=1.05 if status == STATUS_DIVERGED else math.nan,
                           diverged_reason="" if status == STATUS_COMPLETE else "|tau| above 1e3 N m",
                           fallback_count=j, log=log,
                           memory={"theta_hat": rng.standard_normal((N_CONTROL, 3)),
                                   "alpha_hat": rng.standard_normal(N_CONTROL)},
                           memory_units={"theta_hat": "kg m^2", "alpha_hat": "N"},
                           memory_labels={"theta_hat": ("D11", "D22", "D33")})


def write_3(path: Path, statuses=(STATUS_COMPLETE, STATUS_COMPLETE, STATUS_DIVERGED)) -> list[IterationRecord]:
    records = [record_3(j, status) for j, status in enumerate(statuses)]
    config = {"experiment": {"iterations": len(records), "seed": 7}, "run": {"method": "c3"}}
    with writer(path, config=config, reference=reference_3(), control_time=np.linspace(0.0, DURATION, N_CONTROL)) as w:
        for record in records[:-1]:
            w.append(record)
        w.append(records[-1], finish=STATUS_DIVERGED if records[-1].diverged else STATUS_COMPLETE)
    return records


# -- records and metrics -------------------------------------------------------------------------------


def test_axes_and_tables_of_each_dimension():
    assert (task_axes(2), joint_axes(2)) == (("x", "y"), ("1", "2"))
    assert (task_axes(3), joint_axes(3)) == (("u", "v", "n"), ("1", "2", "3"))
    assert log_signals(2) == LOG_SIGNALS and reference_signals(2) == REFERENCE_SIGNALS  # the same tables, entry for entry
    assert metric_columns(2) == METRIC_COLUMNS and list(metric_columns(2)) == list(METRIC_COLUMNS)
    for n in (2, 3):
        for table in (log_signals(n), reference_signals(n)):
            assert list(table) == list(LOG_SIGNALS if table.keys() == LOG_SIGNALS.keys() else REFERENCE_SIGNALS)
            assert {axes for axes, _u, _d in table.values()} <= {None, task_axes(n), joint_axes(n)}
    h = [c for c in metric_columns(3) if c.startswith("chattering_")]
    assert h[:6] == ["chattering_task_u", "chattering_task_v", "chattering_task_n",
                     "chattering_joint_1", "chattering_joint_2", "chattering_joint_3"]
    assert len(h) == 18 and all(f"{c}_no_t0" in h and f"{c}_settled" in h for c in h[:6])
    assert metric_columns(3)["chattering_task_n"][0] == "N" and metric_columns(3)["chattering_joint_3"][0] == "N m"
    for bad in (1, 4, 2.0, True, "3"):
        with pytest.raises(ValueError, match="axes"):
            task_axes(bad)


def test_metrics_of_three_axes_by_hand():
    """A 5-sample record of 3 axes whose norms and H are worked out on paper."""
    time = np.linspace(0.0, 0.04, 5)  # dt = 10 ms; settled (t >= 20 ms): samples 2, 3, 4
    zero = np.zeros((5, 3))
    position_error = np.zeros((5, 3))
    position_error[:, 2] = [0.0, 1.0, 0.0, 2.0, 0.0]  # the normal axis only: sum of squares 5
    force_error = np.zeros((5, 3))
    force_error[1] = [3.0, 4.0, 0.0]  # |e_F| = 5 at one sample, in the plane
    task_delta = np.zeros((5, 3))
    task_delta[:, 1] = [4.0, 0.0, 2.0, 0.0, 2.0]  # v axis: mean 1.6
    joint_delta = np.zeros((5, 3))
    joint_delta[:, 2] = [0.0, 0.0, 1.0, 1.0, 1.0]
    log = {name: zero.copy() for name, (axes, _u, _d) in log_signals(3).items() if axes is not None}
    log.update(time=time, position_error=position_error, force_error=force_error, implicit_fallbacks=np.zeros(5),
               desired_task_input=task_delta, desired_torque=joint_delta)
    row = iteration_metrics(IterationRecord(0, STATUS_COMPLETE, math.nan, "", 0, log))
    assert list(row) == list(metric_columns(3))
    expected = {"position_error_2norm": math.sqrt(5), "position_error_l2": math.sqrt(0.01 * 5),
                "position_error_rms": 1.0, "position_error_max": 2.0,
                "force_error_2norm": 5.0, "force_error_l2": 0.5, "force_error_rms": math.sqrt(5), "force_error_max": 5.0,
                # v: values 4 0 2 0 2, mean 1.6, squares of deviations 5.76 2.56 0.16 2.56 0.16 = 11.2 -> var 2.24
                "chattering_task_v": math.sqrt(2.24), "chattering_task_v_no_t0": 1.0,  # 0 2 0 2
                "chattering_task_v_settled": math.sqrt(8 / 9),  # 2 0 2: mean 4/3, var (4/9 + 16/9 + 4/9) / 3
                "chattering_task_u": 0.0, "chattering_task_n": 0.0,
                "chattering_joint_3": math.sqrt(6 / 25), "chattering_joint_3_no_t0": math.sqrt(3 / 16),
                "chattering_joint_3_settled": 0.0, "chattering_joint_1": 0.0, "chattering_joint_2_settled": 0.0}
    for column, value in expected.items():
        assert math.isclose(row[column], value, rel_tol=1e-12, abs_tol=1e-15), (column, row[column], value)


def test_metrics_refuse_arrays_of_mixed_dimension():
    record = record_3(0)
    for name, width in (("torque", 2), ("position_error", 4)):
        log = dict(record.log, **{name: np.zeros((N_LOG, width))})
        with pytest.raises(ValueError, match=name):
            iteration_metrics(IterationRecord(0, STATUS_COMPLETE, math.nan, "", 0, log))


# -- the run store ---------------------------------------------------------------------------------------


def test_a_three_axis_store_reads_back_bit_for_bit(path: Path):
    records = write_3(path)
    assert store.validate(path) == []
    with h5py.File(path, "r") as handle:
        assert int(handle.attrs["task_dimension"]) == 3
        assert [str(a) for a in handle["reference/force_desired"].attrs["axes"]] == ["u", "v", "n"]
        log = handle["iterations/0000/log"]
        assert [str(a) for a in log["contact_force"].attrs["axes"]] == ["u", "v", "n"]
        assert [str(a) for a in log["torque"].attrs["axes"]] == ["1", "2", "3"]
        assert log["position"].shape == (N_LOG, 3)
        assert set(handle["metrics"]) == set(metric_columns(3))
        for record in records:  # the stored bytes themselves, NaN where NaN
            for name, values in record.log.items():
                np.testing.assert_array_equal(handle[f"iterations/{record.iteration:04d}/log/{name}"][()], values,
                                              err_msg=name)
    run = ilcforce.open(path)
    assert run.task_dimension == 3 and run.iterations == [0, 1, 2]
    for record in records:
        stored = run.iteration(record.iteration)
        assert (stored.status, stored.fallback_count) == (record.status, record.fallback_count)
        for name, values in record.log.items():
            if name == "time":  # a run object's time after a divergence is the log grid's (Run.iteration)
                values = np.where(np.isnan(values), np.linspace(0.0, DURATION, N_LOG), values)
            np.testing.assert_array_equal(stored.log[name], values, err_msg=name)
        for name, values in record.memory.items():
            np.testing.assert_array_equal(stored.memory[name], values, err_msg=name)
        frame = stored.to_pandas()
        assert "position_n" in frame and "torque_3" in frame and "position_x" not in frame
    reference = store.read_reference(path)
    for name, values in reference_3().items():
        if name != "time":
            np.testing.assert_array_equal(reference[[f"{name}_{a}" for a in "uvn"]].to_numpy(), values, err_msg=name)
    metrics = store.read_metrics(path)
    assert list(metrics.columns) == list(metric_columns(3))[1:]
    assert metrics.attrs["units"]["chattering_task_n"] == "N"
    for record in records:
        row = iteration_metrics(record)
        for column in list(metric_columns(3))[1:]:
            stored = metrics.at[record.iteration, column]
            same = stored == row[column] or (isinstance(row[column], float) and math.isnan(row[column])
                                             and math.isnan(stored))
            assert same, (record.iteration, column)
    assert metrics.loc[2, "chattering_task_u"] != metrics.loc[2, "chattering_task_u"]  # diverged: NaN


def test_a_stale_cache_of_a_three_axis_store_is_recomputed(path: Path):
    records = write_3(path, (STATUS_COMPLETE, STATUS_COMPLETE))
    with h5py.File(path, "a") as handle:
        del handle["metrics"]
    store.validate(path)
    metrics = store.read_metrics(path)
    assert metrics.loc[1, "chattering_joint_3_settled"] == iteration_metrics(records[1])["chattering_joint_3_settled"]


def test_a_three_axis_store_resumes_and_refuses_two_axes(path: Path):
    records = write_3(path, (STATUS_COMPLETE,))
    config = {"experiment": {"iterations": 2, "seed": 7}, "run": {"method": "c3"}}
    with writer(path, config=config, reference=reference_3(), resume=True,
                control_time=np.linspace(0.0, DURATION, N_CONTROL)) as w:
        assert w.last_complete_iteration == 0
        np.testing.assert_array_equal(w.resume_memory()["theta_hat"], records[0].memory["theta_hat"])
        w.append(record_3(1), finish=STATUS_COMPLETE)
    assert store.validate(path) == [] and store.iterations(path) == [0, 1]
    with pytest.raises(StoreError, match="3 task axes, this run 2") as error:
        with writer(path, config=config, resume=True):
            pass
    assert_one_line_naming(error, path)
    with writer(path.with_name("two.h5"), config=config, reference=reference_3()) as w:
        with pytest.raises(ValueError, match=r"has shape \(21, 2\), expected \(21, 3\)"):
            w.append(make_record(0))  # 2-axis logs into a 3-axis store


def test_a_two_axis_store_has_the_layout_it_had(path: Path):
    """Object for object and attribute for attribute (the clock's and the checkout's aside) the file
    the code before n axes wrote (module docstring), and no task_dimension attribute."""
    write_run(path, 2)
    found = store_structure(path)
    assert "task_dimension" not in found["/"]["attrs"]
    assert found == json.loads(STRUCTURE.read_text())


# -- damage: one line ----------------------------------------------------------------------------------------


def _set_dimension(path: Path, value) -> None:
    """Set (None: delete) the root attribute task_dimension and seal the root again, as a writer that
    knew the format would: the dimension check itself must catch it, not the seal."""
    with h5py.File(path, "a") as handle:
        if value is None:
            del handle.attrs["task_dimension"]
        else:
            handle.attrs["task_dimension"] = value
        seal_attrs(handle)


@pytest.mark.parametrize(("make", "value", "expected"), [
    ("2", 3, "task_dimension = 3 but /reference/force_desired has shape (21, 2)"),
    ("3", 2, "task_dimension = 2 but /reference/force_desired has shape (21, 3)"),
    ("3", None, "no root attribute task_dimension (2 axes) but /reference/force_desired has shape (21, 3)"),
    ("3", 4, "task_dimension is '4', expected 2 or 3"),
    ("2", "three", "task_dimension is 'three', expected 2 or 3"),
    ("3", 3.0, "task_dimension is '3.0', expected 2 or 3"),
], ids=["2-claims-3", "3-claims-2", "3-without", "4", "text", "float"])
def test_a_damaged_dimension_is_one_line(path: Path, make: str, value, expected: str):
    if make == "2":
        write_run(path, 2)
    else:
        write_3(path, (STATUS_COMPLETE, STATUS_COMPLETE))
    _set_dimension(path, value)
    for read in (store.validate, store.iterations, store.read_metrics, ilcforce.open):
        with pytest.raises(StoreError) as error:
            read(path)
        assert_one_line_naming(error, path)
        assert expected in str(error.value), str(error.value)


def test_a_dimension_changed_without_a_new_seal_is_damage(path: Path):
    write_3(path, (STATUS_COMPLETE,))
    with h5py.File(path, "a") as handle:
        handle.attrs["task_dimension"] = 2
    with pytest.raises(StoreError, match="do not match their checksum") as error:
        store.validate(path)
    assert_one_line_naming(error, path)


def test_a_log_of_another_width_is_one_line(path: Path):
    write_3(path, (STATUS_COMPLETE,))
    with h5py.File(path, "a") as handle:
        group = handle["iterations/0000/log"]
        attrs = dict(group["torque"].attrs)
        del group["torque"]
        group.create_dataset("torque", data=np.zeros((N_LOG, 2)))
        group["torque"].attrs.update(attrs)
    with pytest.raises(StoreError, match=r"has shape \(21, 2\), expected \(21, 3\)") as error:
        store.validate(path)
    assert_one_line_naming(error, path)


def test_validate_on_the_command_line(path: Path):
    from typer.testing import CliRunner

    from ilcforce.cli.main import app

    write_3(path)
    runner = CliRunner()
    result = runner.invoke(app, ["validate", str(path)])
    assert result.exit_code == 0, result.output
    _set_dimension(path, 2)
    result = runner.invoke(app, ["validate", str(path)])
    text = result.output.strip()
    assert result.exit_code == 2, text
    assert len(text.splitlines()) == 1 and "task_dimension" in text and "Traceback" not in text, text


# -- study stores ------------------------------------------------------------------------------------


def _cell_of(make):
    """A study cell function (runner.run_study's ``cell_function``) whose rows are the metrics and
    memory norms of ``make(j)``'s synthetic records, as run_cell makes them from simulated ones."""
    from ilcforce.metrics import memory_norms

    def cell(config, method, keep_store):
        records = [make(j) for j in range(config.experiment.iterations)]
        return {"rows": [{**iteration_metrics(r), **memory_norms(r.memory, settled_from_sample=2)} for r in records],
                "elapsed": 0.01, "worker": "test:0"}

    return cell


@pytest.fixture(scope="module")
def studies(tmp_path_factory) -> dict[int, Path]:
    """A study of each task dimension (seeds 0-1, methods c1 and c3, 3 iterations) from synthetic cells."""
    from ilcforce.study import run_study
    from test_study import small_study

    folder = tmp_path_factory.mktemp("studies")
    out = {}
    for name, make, n in (("arm3", record_3, 3), ("planar", make_record, 2)):
        summary = run_study(small_study(name=name), folder, workers=1, cell_function=_cell_of(make))
        assert summary.failed == () and summary.ran == summary.total == 4, summary.failed
        out[n] = summary.path
    return out


@pytest.mark.parametrize("n", [3, 2])
def test_a_study_of_three_axes_carries_its_columns(studies: dict[int, Path], n: int):
    """Rows of a 3-axis task go through the journal, the store and the tidy table with their own
    columns, in metric_columns(3)'s order; a 2-axis study's columns stay METRIC_COLUMNS."""
    from typer.testing import CliRunner

    from ilcforce.cli.main import app
    from ilcforce.study import tidy_metrics

    make = record_3 if n == 3 else make_record
    checked = CliRunner().invoke(app, ["validate", str(studies[n])])
    assert checked.exit_code == 0 and "refused" not in checked.output, checked.output
    frame = tidy_metrics(studies[n])
    metric = [c for c in frame.columns if c in metric_columns(2) or c in metric_columns(3)]
    assert metric == list(metric_columns(n))
    assert len(frame) == 2 * 2 * 3  # seeds x methods x iterations
    expected = iteration_metrics(make(1))
    row = frame[(frame["seed"] == 0) & (frame["method"] == "c3") & (frame["iteration"] == 1)].iloc[0]
    for column in metric[1:]:
        assert row[column] == expected[column] or column == "diverged_time" and math.isnan(row[column]), column
    units = frame.attrs["units"]
    assert all(units[c] == metric_columns(n)[c][0] for c in metric)


def test_the_generic_report_tables_read_three_axes(studies: dict[int, Path], tmp_path: Path):
    """The study's key numbers (per-method medians), its summary rows, the growth test's quantities and
    the method comparison of a run store name the 3-axis H columns where a 2-axis study has x and y."""
    from ilcforce import stability
    from ilcforce.report.comparison import MethodMetrics, comparison_rows
    from ilcforce.report.study import key_numbers
    from ilcforce.report.study_findings import setting_rows
    from ilcforce.study import tidy_metrics

    frames = {n: tidy_metrics(path) for n, path in studies.items()}
    for n, axes in ((3, "uvn"), (2, "xy")):
        quantities = list(key_numbers(frames[n], ["c1", "c3"], 3)["quantity"])
        for axis in axes:
            assert f"H {axis} at j = 2 (N)" in quantities and f"H {axis} settled at j = 2 (N)" in quantities, quantities
            # j = 2 is not the iteration claim 5 judges: the ratio is shown, on every axis
            assert f"H(C1) / H(C3) at j = 2, H on the whole grid (the paper's), {axis} (shown, not judged)" in quantities, \
                quantities
        assert not any(f"H {other} " in q for q in quantities for other in set("xyuvn") - set(axes)), quantities
        rows = setting_rows(frames[n], perturbation_iteration=2, iterations=3)[0]
        normal = axes[-1]
        assert {f"H_{a} (N) at j = 2" for a in axes} | {f"H_{normal} settled (N) at j = 2"} <= set(rows[0]), rows[0]
        judged = [c for c, j in stability.watched_columns(frames[n]) if j and c.startswith("chattering")]
        assert judged == [f"chattering_task_{a}_settled" for a in axes]
    run = tmp_path / "c3.h5"
    write_3(run)
    row = comparison_rows({"c3": MethodMetrics.from_rows(store.read_metrics_rows(run))})[0]
    assert row["iterations"] == 3 and row["diverged_iteration"] == 2 and row["fallback_total"] == 0 + 1 + 2


def test_a_journal_row_holds_the_columns_of_one_dimension():
    from ilcforce.metrics import columns_dimension
    from ilcforce.store.study_journal import RecordError, _check_rows

    good = [iteration_metrics(record_3(j)) for j in range(2)]
    _check_rows(good, "done", 3)  # accepted
    assert columns_dimension(good[0]) == 3 and columns_dimension(METRIC_COLUMNS) == 2
    for change, reason in ((lambda r: r.pop("chattering_task_n_settled"), "lacks ['chattering_task_n_settled']"),
                           (lambda r: r.update(chattering_task_x=0.1), "unknown columns ['chattering_task_x']")):
        rows = [dict(r) for r in good]
        for row in rows:
            change(row)
        with pytest.raises(RecordError, match=r"row 0 .*\(the metric columns of a task of 3 axes\)") as error:
            _check_rows(rows, "done", 3)
        assert reason in str(error.value)
