"""Studies: the study file, the driver in-process and on a LocalCluster, the study store, export.

Small on purpose: a 0.2 s horizon (2001 control samples), 3 iterations, 2 seeds.
"""

from __future__ import annotations

import json
import os

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from ilcforce import store
from ilcforce.cli.main import app
from ilcforce.experiment import run_method
from ilcforce.metrics import METRIC_COLUMNS
from ilcforce.study import (ExportError, StudyError, StudyStoreError, build_study, export, load_study, read_study,
                            run_study, tidy_metrics)
from ilcforce.study.spec import parse_seeds
from ilcforce.store.study import StudyStore, read_tables

SMALL = {"experiment.iterations": 3, "reference.duration": 0.2}


def small_study(name="tiny", seeds="0-1", methods=("c1", "c3"), sweep=None, **extra):
    table = {"name": name, "seeds": seeds, "methods": list(methods), "set": dict(SMALL), **extra}
    if sweep:
        table["sweep"] = sweep
    return build_study({"study": table})


def write_study_file(tmp_path, text: str):
    path = tmp_path / "study.toml"
    path.write_text(text, encoding="utf-8")
    return path


TINY_TOML = """
[study]
name = "tiny"
methods = ["c1", "c3"]
seeds = "0-1"
[study.set]
"experiment.iterations" = 3
"reference.duration" = 0.2
[study.sweep]
"c3.eta" = [5.0, 2.0]
"""


# ------------------------------------------------------------------------------------------------
# the study file


def test_seeds_forms():
    assert parse_seeds("0-3") == (0, 1, 2, 3)
    assert parse_seeds(" 7 - 7 ") == (7,)
    assert parse_seeds([5, 1, 3]) == (1, 3, 5)


def test_sweep_is_full_factorial_first_key_slowest():
    study = small_study(sweep={"c3.eta": [5.0, 2.0], "simulation.log_every": [10, 20]})
    assert [s.values for s in study.settings] == [
        (("c3.eta", 5.0), ("simulation.log_every", 10)), (("c3.eta", 5.0), ("simulation.log_every", 20)),
        (("c3.eta", 2.0), ("simulation.log_every", 10)), (("c3.eta", 2.0), ("simulation.log_every", 20))]
    assert study.settings[3].config.gains["c3"].eta == 2.0
    assert study.settings[3].config.simulation.log_every == 20
    assert len(study.cells()) == 4 * 2 * 2
    cell = study.cells()[-1]
    assert study.cell_config(cell).experiment.seed == cell.seed == 1


@pytest.mark.parametrize("table, message", [
    ({"sweep": {"simulation.sampel_time": [1e-4]}}, "did you mean 'sample_time'"),
    ({"sweep": {"simulaton.sample_time": [1e-4]}}, "did you mean 'simulation'"),
    ({"sweep": {"c3.eta": []}}, "empty list"),
    ({"sweep": {"c3.eta ": [1.0]}}, "unknown key 'c3.eta ' (did you mean 'eta'?)"),  # the space is shown
    ({"sweep": {"c3.eta": [5.0, 2.0, 5.0]}}, "lists a value twice"),
    ({"sweep": {"c3.eta": [5, 5.0]}}, "lists a value twice"),  # the same setting, as an int and a float
    ({"sweep": {"c3.k": [[1.0, 2.0], [1, 2]]}}, "lists a value twice"),
    ({"sweep": {"wall.stiffness": [int("1" * 400), 5]}}, "wall.stiffness"),  # no OverflowError on 400 digits
    ({"seeds": "5-2"}, "empty: 5 > 2"),
    ({"seeds": "-3-2"}, "range"),
    ({"seeds": [1, -2]}, ">= 0"),
    ({"sweep": {"c3.eta": [5.0, -1.0]}}, "setting 1 (c3.eta=-1.0)"),
    ({"name": "../escape"}, "escape the results folder"),
    ({"name": ".hidden"}, "escape the results folder"),
    ({"name": "my study"}, "not a plain file name (letters, digits, '.', '_', '-'; no '/' or leading '.'): it "
                           "names the study's store file"),
    ({"methods": ["c4"]}, "unknown method"),
    ({"set": {"experiment.seed": 3}}, "study.seeds"),
    ({"sweeps": {}}, "did you mean 'sweep'"),
])
def test_bad_study_names_the_key(table, message):
    base = {"name": "bad", "seeds": "0-1", "set": dict(SMALL)}
    base.update(table)
    with pytest.raises(StudyError) as info:
        build_study({"study": base})
    assert message in str(info.value)
    assert "\n" not in str(info.value)


def test_a_fault_of_the_experiment_file_is_named_as_the_file_s(tmp_path):
    """A fault of the study's experiment file itself is the file's, not the settings': it was
    reported as 'study.set: e.toml: unknown key simulation.seed'."""
    (tmp_path / "e.toml").write_text("[simulation]\nseed = 3\n", encoding="utf-8")
    path = write_study_file(tmp_path, '[study]\nname = "x"\nexperiment = "e.toml"\nseeds = "0-1"\n'
                                      '[study.set]\n"experiment.iterations" = 2\n')
    with pytest.raises(StudyError, match=r"study.experiment: .*e.toml: unknown key simulation.seed"):
        load_study(path)
    (tmp_path / "e.toml").write_text("[experiment]\niterations = 3\n", encoding="utf-8")
    path.write_text(path.read_text().replace('= 2', '= -2'), encoding="utf-8")
    with pytest.raises(StudyError, match=r"study.set: .*experiment.iterations"):
        load_study(path)


@pytest.mark.parametrize("text, message", [
    ('[study]\nname = "x"\nseeds = "0-1"\n[study.sweep]\n"c3.etaa" = [1.0]\n', "did you mean 'eta'"),
    ('[study]\nname = "x"\nseeds = "5-2"\n', "5 > 2"),
    ('[study]\nname = "a/b"\nseeds = "0-1"\n', "escape the results folder"),
    ('[study]\nname = "x"\nseeds = "0-1"\n[study.sweep]\n"c3.eta" = []\n', "empty list"),
    ('[study]\nname = "x"\nseeds = "0-1"\n[study.sweep]\n"simulation.sample_time" = [1e-4, "fast"]\n',
     "setting 1 (simulation.sample_time='fast')"),
    ("[study\n", "not valid TOML"),
])
def test_cli_bad_study_one_line_exit_2(tmp_path, text, message):
    path = write_study_file(tmp_path, text)
    result = CliRunner().invoke(app, ["study", str(path), "--results", str(tmp_path / "r"), "--workers", "1"])
    assert result.exit_code == 2, result.output
    assert message in result.output
    assert result.output.count("\n") == 1, result.output
    assert not (tmp_path / "r" / "studies").exists(), "nothing may be written for an invalid study"


@pytest.mark.parametrize("kind, message", [
    ("directory", "is a directory, not a TOML file"), ("fifo", "not a regular file"),
    ("loop", "symbolic link that leads nowhere"),
])
def test_cli_study_experiment_that_is_not_a_file_says_what_it_is(tmp_path, kind, message):
    """`experiment = "x.toml"` naming a directory, a FIFO or a symlink loop was "no experiment file"."""
    target = tmp_path / "x.toml"
    if kind == "directory":
        target.mkdir()
    elif kind == "fifo":
        os.mkfifo(target)
    else:
        os.symlink(target, target)
    path = write_study_file(tmp_path, '[study]\nname = "x"\nexperiment = "x.toml"\nseeds = "0-1"\n')
    result = CliRunner().invoke(app, ["study", str(path), "--results", str(tmp_path / "r"), "--workers", "1"])
    assert result.exit_code == 2, result.output
    assert f"study.experiment: experiment file {target}" in result.output and message in result.output, result.output
    assert result.output.count("\n") == 1, result.output


@pytest.mark.parametrize("kind, message", [
    ("missing", "does not exist"), ("directory", "is a directory, not a TOML file"), ("empty", "is empty"),
    ("fifo", "not a regular file"), ("latin-1", "cannot be read"),
])
def test_cli_study_file_that_cannot_be_read_is_one_line_exit_2(tmp_path, kind, message):
    """The file itself: the same checks and words as an experiment file (ilcforce.tomlfile); a FIFO
    is refused before it is opened (reading it would block)."""
    path = tmp_path / "study.toml"
    if kind == "directory":
        path.mkdir()
    elif kind == "empty":
        path.write_text(" \n")
    elif kind == "fifo":
        os.mkfifo(path)
    elif kind == "latin-1":
        path.write_bytes('[study]\nname = "caf\xe9"\n'.encode("latin-1"))
    result = CliRunner().invoke(app, ["study", str(path), "--results", str(tmp_path / "r"), "--workers", "1"])
    assert result.exit_code == 2, result.output
    assert f"study file {path}" in result.output and message in result.output, result.output
    assert result.output.count("\n") == 1, result.output


# ------------------------------------------------------------------------------------------------
# running, the store, bit identity


def test_in_process_study_matches_simulate_bit_for_bit(tmp_path):
    """Every cell's metrics equal those `ilcforce simulate` stores for the same (config, seed, method)."""
    study = small_study(sweep={"c3.eta": [5.0, 2.0]})
    summary = run_study(study, tmp_path, workers=1)
    assert (summary.total, summary.ran, summary.failed) == (8, 8, ())
    results = read_study(summary.path)
    for cell in (study.cells()[1], study.cells()[-1], study.cells()[-2]):
        config = study.cell_config(cell)
        path = tmp_path / "single" / f"{cell.key}.h5"
        run_method(config, cell.method, path)
        single = store.read_metrics(path).reset_index()
        rows = results.metrics
        rows = rows[(rows["c3.eta"] == dict(study.settings[cell.setting].values)["c3.eta"])
                    & (rows["seed"] == cell.seed) & (rows["method"] == cell.method)].reset_index(drop=True)
        for column in METRIC_COLUMNS:
            np.testing.assert_array_equal(rows[column].to_numpy(), single[column].to_numpy(),
                                          err_msg=f"{cell} {column}: a study cell must be bit-identical to simulate")


def test_tidy_frame_columns_and_memory_norms(tmp_path):
    study = small_study(sweep={"c3.eta": [5.0, 2.0]})
    run_study(study, tmp_path, workers=1)
    frame = tidy_metrics(tmp_path / "studies" / "tiny.h5")
    metric_columns = [c for c in METRIC_COLUMNS if c != "iteration"]
    assert list(frame.columns[:4]) == ["c3.eta", "seed", "method", "iteration"]
    assert list(frame.columns[4:4 + len(metric_columns)]) == metric_columns
    assert len(frame) == 2 * 2 * 2 * 3
    c3 = frame[frame["method"] == "c3"]
    c1 = frame[frame["method"] == "c1"]
    # C3 learns: its Theta_hat memory is nonzero and grows from iteration 0 on; C1 has no memory
    assert (c3["memory_norm_theta_hat"] > 0).all()
    assert c1["memory_norm_theta_hat"].isna().all()
    assert frame["seed"].dtype == np.int64 and frame["iteration"].dtype == np.int64
    # every column carries its unit and what it is, the swept key's included; the export writes them
    # beside the CSV, one row per CSV column in its order
    units = frame.attrs["units"]
    assert set(units) == set(frame.columns) == set(frame.attrs["descriptions"])
    assert (units["c3.eta"], units["seed"], units["method"], units["iteration"]) == ("N s/m", "1", "", "1")
    assert (units["position_error_l2"], units["memory_norm_alpha_hat"]) == ("m s^1/2", "N")
    out, _rows = export(tmp_path / "studies" / "tiny.h5", tmp_path / "tiny.csv")
    sidecar = pd.read_csv(tmp_path / "tiny.units.csv", keep_default_na=False)
    assert list(sidecar.columns) == ["column", "unit", "description"]
    assert sidecar["column"].tolist() == pd.read_csv(out).columns.tolist()
    assert dict(zip(sidecar["column"], sidecar["unit"])) == units
    (tmp_path / "again.units.csv").write_text("mine\n")
    with pytest.raises(ExportError, match=r"units file .*again\.units\.csv .* exists; pass --overwrite"):
        export(tmp_path / "studies" / "tiny.h5", tmp_path / "again.csv")
    assert not (tmp_path / "again.csv").exists() and (tmp_path / "again.units.csv").read_text() == "mine\n"


def test_memory_norm_is_rms_of_the_learned_memory(tmp_path):
    """memory_norm_* = sqrt(mean_k |m(t_k)|^2) of the memory the run store keeps for that iteration."""
    study = small_study(seeds=[3], methods=("c3",))
    run_study(study, tmp_path, workers=1, keep_stores=True)
    frame = read_study(tmp_path / "studies" / "tiny.h5").metrics
    kept = tmp_path / "studies" / "tiny" / "cells" / "setting0-seed3" / "c3.h5"
    for j in range(3):
        memory = store.read_memory(kept, j)
        for name, array in memory.items():
            expected = np.sqrt(np.mean(np.sum(np.square(array.reshape(len(array), -1)), axis=1)))
            assert frame.loc[j, f"memory_norm_{name}"] == pytest.approx(expected, rel=1e-12)
    # the kept run store holds the same metrics as the study
    np.testing.assert_array_equal(store.read_metrics(kept)["force_error_2norm"].to_numpy(),
                                  frame["force_error_2norm"].to_numpy())


def test_rerun_skips_finished_cells_and_extends_seeds(tmp_path):
    calls = []

    def counting(config, method, keep):
        from ilcforce.study.cell import run_cell

        calls.append((config.experiment.seed, method))
        return run_cell(config, method, keep)

    run_study(small_study(seeds="0-1"), tmp_path, workers=1, cell_function=counting)
    assert len(calls) == 4
    again = run_study(small_study(seeds="0-1"), tmp_path, workers=1, cell_function=counting)
    assert (again.skipped, again.ran, len(calls)) == (4, 0, 4)
    more = run_study(small_study(seeds="0-2"), tmp_path, workers=1, cell_function=counting)
    assert (more.skipped, more.ran) == (4, 2)
    assert calls[4:] == [(2, "c1"), (2, "c3")]


def test_changed_settings_are_refused_then_overwritten(tmp_path):
    run_study(small_study(), tmp_path, workers=1)
    changed = small_study(sweep={"c3.eta": [1.0]})
    with pytest.raises(StudyStoreError, match=r"different settings \(setting columns \[\] -> \['c3.eta'\]\)"):
        run_study(changed, tmp_path, workers=1)
    fixed = small_study(**{"set": {**SMALL, "c3.eta": 1.0}})
    # c3.eta reaches c3-leak and c3-robust too (a method family shares its keys): three keys differ, in order
    with pytest.raises(StudyStoreError, match=r"different settings \(setting 0: c3-leak.eta 5.0 -> 1.0 and 2 more"):
        run_study(fixed, tmp_path, workers=1)
    summary = run_study(changed, tmp_path, workers=1, overwrite=True)
    assert summary.ran == 4 and summary.skipped == 0


def test_resume_needs_a_store(tmp_path):
    with pytest.raises(StudyStoreError, match="no study store to resume"):
        run_study(small_study(), tmp_path, workers=1, resume=True)


def test_resume_and_overwrite_together_are_refused_and_keep_the_store(tmp_path):
    """--resume --overwrite asks for two opposite things: refused (as simulate does), nothing discarded."""
    run_study(small_study(), tmp_path, workers=1)
    stored = (tmp_path / "studies" / "tiny.h5").read_bytes()
    with pytest.raises(StudyStoreError, match="mutually exclusive"):
        run_study(small_study(), tmp_path, workers=1, resume=True, overwrite=True)
    assert (tmp_path / "studies" / "tiny.h5").read_bytes() == stored
    path = write_study_file(tmp_path, ONE_CELL_TOML)
    result = CliRunner().invoke(app, ["study", str(path), "--results", str(tmp_path), "--resume", "--overwrite"])
    assert result.exit_code == 2 and "mutually exclusive" in result.output, result.output
    assert len(result.output.strip().splitlines()) == 1, result.output


def test_foreign_file_is_never_replaced(tmp_path):
    target = tmp_path / "studies" / "tiny.h5"
    target.parent.mkdir()
    target.write_bytes(b"not a store")
    with pytest.raises(StudyStoreError, match="not an ilcforce study store"):
        run_study(small_study(), tmp_path, workers=1, overwrite=True)
    assert target.read_bytes() == b"not a store"


def test_failing_cell_is_retried_once_then_recorded(tmp_path):
    attempts = {}

    def flaky(config, method, keep):
        from ilcforce.study.cell import run_cell

        key = (config.experiment.seed, method)
        attempts[key] = attempts.get(key, 0) + 1
        if method == "c3" and config.experiment.seed == 1:
            raise RuntimeError("boom\nsecond line")
        if method == "c1" and config.experiment.seed == 0 and attempts[key] == 1:
            raise RuntimeError("transient")
        return run_cell(config, method, keep)

    summary = run_study(small_study(), tmp_path, workers=1, cell_function=flaky)
    assert attempts[(1, "c3")] == 2 and attempts[(0, "c1")] == 2
    assert [(c.seed, c.method) for c, _ in summary.failed] == [(1, "c3")]
    cells = read_study(summary.path).cells
    failed = cells[cells["state"] == "failed"]
    assert failed[["seed", "method", "attempts"]].values.tolist() == [[1, "c3", 2]]
    assert failed["message"].iloc[0] == "RuntimeError: boom second line"
    retried = cells[(cells["seed"] == 0) & (cells["method"] == "c1")]
    assert retried[["state", "attempts"]].values.tolist() == [["done", 2]]
    # a rerun retries only the failed cell
    again = run_study(small_study(), tmp_path, workers=1)
    assert (again.skipped, again.ran, again.failed) == (3, 1, ())


def test_committed_cells_survive_a_driver_that_never_consolidated(tmp_path):
    """A cell is durable once committed to the journal, before any consolidation of the HDF5 file."""
    from ilcforce.study.runner import _header

    study = small_study()
    path = tmp_path / "studies" / "tiny.h5"
    plan = {"seeds": [0, 1], "methods": ["c1", "c3"]}
    writer = StudyStore(path, header=_header(study), session={"id": "a", **plan}, consolidate_every=1e9)
    row = {**{c: 0.0 for c in METRIC_COLUMNS}, "iteration": 0, "status": "complete", "fallback_count": 0,
           "force_error_rms": 1.5}
    record = {"setting": 0, "seed": 1, "method": "c1", "state": "done", "attempts": 1, "message": "",
              "elapsed": 0.1, "worker": "w", "rows": [row]}
    writer.commit(record, now=1.0)
    writer.close()  # no consolidate(): as if the driver were killed here
    _header_read, metrics, cells = read_tables(path)
    assert metrics[["seed", "method", "iteration", "force_error_rms"]].values.tolist() == [[1, "c1", 0, 1.5]]
    reopened = StudyStore(path, header=_header(study), session={"id": "b", **plan})
    assert reopened.done == {(0, 1, "c1")}
    reopened.consolidate()
    reopened.close()
    assert not list((tmp_path / "studies" / "tiny.h5.journal").glob("*.json"))
    assert read_tables(path)[1]["force_error_rms"].tolist() == [1.5]


def test_second_driver_is_refused(tmp_path):
    from ilcforce.study.runner import _header

    study = small_study()
    first = StudyStore(tmp_path / "s.h5", header=_header(study), session={"id": "a"})
    try:
        with pytest.raises(StudyStoreError, match="another ilcforce study"):
            StudyStore(tmp_path / "s.h5", header=_header(study), session={"id": "b"})
    finally:
        first.close()


# ------------------------------------------------------------------------------------------------
# CLI and export


def test_cli_study_and_export_round_trip(tmp_path):
    path = write_study_file(tmp_path, TINY_TOML)
    results = tmp_path / "r"
    runner = CliRunner()
    first = runner.invoke(app, ["study", str(path), "--results", str(results), "--workers", "1", "--quiet"])
    assert first.exit_code == 0, first.output
    again = runner.invoke(app, ["study", str(path), "--results", str(results), "--workers", "2"])
    assert again.exit_code == 0, again.output
    assert "(8 already stored, 0 run, 0 failed)" in again.output and "(nothing to run)" in again.output
    assert "LocalCluster" not in again.output  # no cluster was started for it
    store_file = results / "studies" / "tiny.h5"
    out = tmp_path / "t.csv"
    exported = runner.invoke(app, ["export", str(store_file), "--out", str(out)])
    assert exported.exit_code == 0, exported.output
    frame = tidy_metrics(store_file)
    back = pd.read_csv(out)
    assert list(back.columns) == list(frame.columns)
    for column in frame.columns:
        if frame[column].dtype == object:
            assert back[column].astype(str).tolist() == frame[column].astype(str).tolist()
        else:  # floats are written with the shortest round-trip repr: bit for bit
            np.testing.assert_array_equal(back[column].to_numpy(), frame[column].to_numpy(), err_msg=column)
    refused = runner.invoke(app, ["export", str(store_file), "--out", str(out)])
    assert refused.exit_code == 2 and "--overwrite" in refused.output
    parquet = runner.invoke(app, ["export", str(store_file), "--out", str(tmp_path / "t.parquet")])
    assert parquet.exit_code == 2 and "pyarrow" in parquet.output


def test_export_of_a_run_store_is_the_one_seed_case(tmp_path, short_config):
    config = short_config(**{"experiment.seed": 4})
    run_method(config, "c2", tmp_path / "c2.h5")
    frame = tidy_metrics(tmp_path / "c2.h5")
    assert list(frame.columns[:3]) == ["seed", "method", "iteration"]
    assert set(frame["seed"]) == {4} and set(frame["method"]) == {"c2"}
    np.testing.assert_array_equal(frame["position_error_2norm"].to_numpy(),
                                  store.read_metrics(tmp_path / "c2.h5")["position_error_2norm"].to_numpy())
    out, rows = export(tmp_path / "c2.h5", tmp_path / "c2.csv")
    assert rows == 3 and out.is_file()


def test_validate_checks_study_stores_and_goes_on_after_a_bad_file(tmp_path):
    """`validate` on a study store said "cannot undo an unfinished commit" (it took the study's
    journal folder for a run store's journal) and stopped at the first bad file: now study stores are
    read whole, checksums included, and every file gets its line; exit 2 if any is bad."""
    import shutil

    import h5py

    path = write_study_file(tmp_path, TINY_TOML)
    run_study(load_study(path), tmp_path / "r", workers=1)
    good = tmp_path / "r" / "studies" / "tiny.h5"
    damaged = tmp_path / "damaged.h5"
    shutil.copy(good, damaged)
    with h5py.File(damaged, "r") as handle:  # a flipped byte inside a metric column's chunk
        offset = handle["metrics/position_error_2norm"].id.get_chunk_info(0).byte_offset + 8
    with damaged.open("r+b") as raw:
        raw.seek(offset)
        byte = raw.read(1)
        raw.seek(offset)
        raw.write(bytes([byte[0] ^ 0xFF]))
    result = CliRunner().invoke(app, ["validate", str(good), str(damaged), str(good)])
    assert result.exit_code == 2, result.output
    lines = result.output.splitlines()
    cells = len(load_study(path).cells())
    assert lines.count(f"{good}: ok (study tiny, {cells} cells: {cells} done, 0 failed)") == 2, result.output
    assert [line for line in lines if line.startswith("error:")] == [line for line in lines if str(damaged) in line]
    assert len(lines) == 3, result.output


@pytest.mark.parametrize("alias", ["same", "dotdot", "symlinked folder", "hard link"])
def test_export_overwrite_never_replaces_the_store_it_exports(tmp_path, short_config, alias):
    """A store named *.csv exported onto itself under --overwrite (any alias of its path) was
    replaced by its own table: the store must survive, byte for byte, and the refusal be one line."""
    run_method(short_config(), "c1", tmp_path / "c1.h5")
    source = tmp_path / "store.csv"
    os.replace(tmp_path / "c1.h5", source)
    before = source.read_bytes()
    (tmp_path / "d").mkdir()
    out = {"same": source, "dotdot": tmp_path / "d" / ".." / "store.csv"}.get(alias)
    if alias == "symlinked folder":
        os.symlink(tmp_path, tmp_path / "lnk")
        out = tmp_path / "lnk" / "store.csv"
    if alias == "hard link":
        out = tmp_path / "d" / "linked.csv"
        os.link(source, out)
    result = CliRunner().invoke(app, ["export", str(source), "--out", str(out), "--overwrite"])
    assert result.exit_code == 2, result.output
    assert "is the store being exported" in result.output and result.output.count("\n") == 1, result.output
    assert source.read_bytes() == before


def test_export_overwrite_never_replaces_another_store(tmp_path, short_config):
    run_method(short_config(), "c1", tmp_path / "c1.h5")
    run_method(short_config(), "c2", tmp_path / "c2.h5")
    other = tmp_path / "other.csv"
    os.replace(tmp_path / "c2.h5", other)
    before = other.read_bytes()
    result = CliRunner().invoke(app, ["export", str(tmp_path / "c1.h5"), "--out", str(other), "--overwrite"])
    assert result.exit_code == 2 and "is an HDF5 file (a store?)" in result.output, result.output
    assert other.read_bytes() == before
    table = tmp_path / "t.csv"  # a table it wrote is still replaced
    assert CliRunner().invoke(app, ["export", str(tmp_path / "c1.h5"), "--out", str(table)]).exit_code == 0
    again = CliRunner().invoke(app, ["export", str(tmp_path / "c1.h5"), "--out", str(table), "--overwrite"])
    assert again.exit_code == 0, again.output


@pytest.mark.parametrize("content", [b"", b"garbage", b"\x89HDF\r\n\x1a\n" + b"\0" * 64])
def test_export_of_a_foreign_file_is_one_line(tmp_path, content):
    bad = tmp_path / "bad.h5"
    bad.write_bytes(content)
    result = CliRunner().invoke(app, ["export", str(bad), "--out", str(tmp_path / "x.csv")])
    assert result.exit_code == 2, result.output
    assert result.output.count("\n") == 1 and "Traceback" not in result.output
    assert not (tmp_path / "x.csv").exists()


def test_study_store_records_provenance(tmp_path):
    path = write_study_file(tmp_path, TINY_TOML)
    run_study(load_study(path), tmp_path / "r", workers=1, command="ilcforce study x")
    results = read_study(tmp_path / "r" / "studies" / "tiny.h5")
    assert results.study_toml == TINY_TOML
    assert results.sweep_keys == ["c3.eta"]
    assert results.settings["c3.eta"].tolist() == [5.0, 2.0]
    config = json.loads(results.settings.loc[1, "config_json"])
    assert config["c3"]["eta"] == 2.0 and config["reference"]["duration"] == 0.2
    session = results.sessions[-1]
    assert session["command"] == "ilcforce study x" and session["scheduler"] == "in-process"
    assert {"ilcforce", "numpy", "numba", "h5py", "python"} <= set(session["versions"])


def test_shipped_study_files_load_and_are_named_after_their_file():
    """`make studies` finds study files by their [study] table and expects study.name == file stem."""
    from pathlib import Path

    from ilcforce.study.spec import is_study_file

    files = [p for p in sorted(Path("experiments").glob("*.toml")) if is_study_file(p)]
    assert Path("experiments/paper-mc.toml") in files
    for path in files:
        study = load_study(path)
        assert study.name == path.stem
    paper = load_study("experiments/paper-mc.toml")
    assert paper.seeds == tuple(range(100)) and paper.methods == ("c1", "c2", "c3")
    assert paper.settings[0].config.experiment.iterations == 20


@pytest.mark.slow
def test_paper_monte_carlo_100_seeds(tmp_path):
    """The shipped paper-mc study on the default LocalCluster: every cell done, and cells picked across
    the run bit-identical to `ilcforce simulate` of the same seed and method."""
    study = load_study("experiments/paper-mc.toml")
    summary = run_study(study, tmp_path)
    assert (summary.total, summary.ran, summary.failed) == (300, 300, ())
    frame = tidy_metrics(summary.path)
    assert len(frame) == frame.groupby(["seed", "method"]).ngroups * 20 or (frame["status"] == "diverged").any()
    for seed, method in ((0, "c1"), (57, "c3"), (99, "c2")):
        cell = next(c for c in study.cells() if (c.seed, c.method) == (seed, method))
        path = tmp_path / "single" / f"{seed}-{method}.h5"
        run_method(study.cell_config(cell), method, path)
        single = store.read_metrics(path).reset_index()
        rows = frame[(frame["seed"] == seed) & (frame["method"] == method)].reset_index(drop=True)
        for column in METRIC_COLUMNS:
            np.testing.assert_array_equal(rows[column].to_numpy(), single[column].to_numpy(),
                                          err_msg=f"seed {seed} {method} {column}")


ONE_CELL_TOML = TINY_TOML.replace('seeds = "0-1"', 'seeds = "0-0"').replace('"c3.eta" = [5.0, 2.0]', '"c3.eta" = [5.0]')


def _two_one_cell_studies(tmp_path):
    """Study files a/study.toml ("first") and b/study.toml ("second"), one seed, one setting each."""
    files = []
    for sub, name in (("a", "first"), ("b", "second")):
        (tmp_path / sub).mkdir()
        files.append(write_study_file(tmp_path / sub, ONE_CELL_TOML.replace('name = "tiny"', f'name = "{name}"')))
    return tuple(files)


@pytest.mark.parametrize("fault, message", [
    ("stale", "its study has different settings"),
    ("foreign", "is not an ilcforce study store"),
    ("directory", "is not a regular file"),
    ("resume without store", "no study store to resume"),
])
def test_several_study_files_refuse_a_later_store_before_any_cell_runs(tmp_path, fault, message):
    """`ilcforce study A.toml B.toml` when B's store cannot be used: refused in one line before A
    runs (found by an attack: A's cells ran and were stored first, then B was refused)."""
    a, b = _two_one_cell_studies(tmp_path)
    results = tmp_path / "r"
    studies = results / "studies"
    args = ["study", str(a), str(b), "--results", str(results), "--workers", "1", "--quiet"]
    if fault == "stale":  # B's store holds another study of the same name
        run_study(load_study(b), results, workers=1)
        b.write_text(b.read_text().replace('"c3.eta" = [5.0]', '"c3.eta" = [4.0]'))
    elif fault == "foreign":
        studies.mkdir(parents=True)
        (studies / "second.h5").write_bytes(b"not a store")
    elif fault == "directory":
        (studies / "second.h5").mkdir(parents=True)
    else:
        args.append("--resume")
        run_study(load_study(a), results, workers=1)
    before = sorted(p.name for p in studies.iterdir()) if studies.exists() else []
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 2, result.output
    assert message in result.output and len(result.output.strip().splitlines()) == 1, result.output
    after = sorted(p.name for p in studies.iterdir()) if studies.exists() else []
    assert after == before, "nothing may be created before every store is checked"


def test_several_study_files_run_in_one_command_on_one_cluster(tmp_path, monkeypatch):
    """`ilcforce study A.toml B.toml`: both stored, one after another, on one LocalCluster started once;
    two files naming the same study are refused before anything runs."""
    from ilcforce.study import dask_run

    starts = []
    real = dask_run.dask_client

    def counting(*args, **kwargs):
        starts.append(args)
        return real(*args, **kwargs)

    monkeypatch.setattr(dask_run, "dask_client", counting)
    a, b = _two_one_cell_studies(tmp_path)
    (tmp_path / "c").mkdir()
    results = tmp_path / "r"
    ran = CliRunner().invoke(app, ["study", str(a), str(b), "--results", str(results), "--workers", "2", "--quiet"])
    assert ran.exit_code == 0, ran.output
    assert len(starts) == 1
    for name in ("first", "second"):
        cells = read_study(results / "studies" / f"{name}.h5").cells
        assert len(cells) == 2 and (cells["state"] == "done").all()
    same = write_study_file(tmp_path / "c", ONE_CELL_TOML.replace('name = "tiny"', 'name = "first"'))
    refused = CliRunner().invoke(app, ["study", str(a), str(same), "--results", str(tmp_path / "r2"), "--workers", "1"])
    assert refused.exit_code == 2 and "same study 'first'" in refused.output
    assert len(refused.output.strip().splitlines()) == 1
    assert not (tmp_path / "r2" / "studies").exists()


@pytest.mark.parametrize("args", [[], ["--resume"], ["--overwrite"], ["python"]])
def test_a_study_store_given_as_a_run_store_is_named_and_untouched(tmp_path, args):
    """`simulate --out` (plain, --resume, --overwrite) or ilcforce.open on a study store: one line saying
    it is a study store, the study and its journal folder untouched (found by an attack: it read the
    study's journal folder as an interrupted run commit, 'cannot undo an unfinished commit (Is a directory)')."""
    import ilcforce

    run_study(small_study(seeds="0-0", methods=("c3",)), tmp_path, workers=1)
    path = tmp_path / "studies" / "tiny.h5"
    journal = tmp_path / "studies" / "tiny.h5.journal"
    before = path.read_bytes(), sorted(p.name for p in journal.iterdir())
    if args == ["python"]:
        with pytest.raises(store.StoreError, match="is a study store, not a run store") as info:
            ilcforce.open(path)
        assert "\n" not in str(info.value)
    else:
        result = CliRunner().invoke(app, ["simulate", "--method", "c3", "--iters", "1", "--out", str(path), *args])
        assert result.exit_code == 2, result.output
        assert "is a study store, not a run store" in result.output, result.output
        assert len(result.output.strip().splitlines()) == 1, result.output
    assert (path.read_bytes(), sorted(p.name for p in journal.iterdir())) == before
    alone = tmp_path / "copy" / "tiny.h5"  # the store copied without its journal folder: read by its schema
    alone.parent.mkdir()
    alone.write_bytes(path.read_bytes())
    with pytest.raises(store.StoreError, match="is a study store, not a run store"):
        ilcforce.open(alone)


def test_a_damaged_study_store_is_not_told_to_lose_its_journal(tmp_path):
    """A truncated study store whose journal folder holds cells not yet merged, read as a run store
    (`simulate --out`, ilcforce.open): the line says it is damaged and to keep the journal folder (it
    said 'move it away', which would lose the cells). Found by an attack."""
    import ilcforce

    run_study(small_study(seeds="0-0", methods=("c3",)), tmp_path, workers=1)
    path = tmp_path / "studies" / "tiny.h5"
    journal = tmp_path / "studies" / "tiny.h5.journal"
    (journal / "0-5-c3.json").write_text("{}", encoding="utf-8")  # a cell not yet merged
    os.truncate(path, 1000)
    with pytest.raises(store.StoreError) as info:
        ilcforce.open(path)
    message = str(info.value)
    assert "truncated" in message and "keep it" in message and "move it away" not in message, message
    result = CliRunner().invoke(app, ["simulate", "--method", "c3", "--iters", "1", "--out", str(path)])
    assert result.exit_code == 2 and "keep it" in result.output, result.output
    assert (journal / "0-5-c3.json").exists() and path.stat().st_size == 1000


def test_validate_names_what_the_study_journal_ignores(tmp_path):
    """A damaged record, a stray file and a folder in the journal: readers skip them (the cell runs
    again), and `validate` now says so instead of a plain 'ok' (found by an attack)."""
    run_study(small_study(seeds="0-0", methods=("c3",)), tmp_path, workers=1)
    path = tmp_path / "studies" / "tiny.h5"
    journal = tmp_path / "studies" / "tiny.h5.journal"
    result = CliRunner().invoke(app, ["validate", str(path)])
    assert result.exit_code == 0 and "ignored" not in result.output, result.output
    (journal / "sub").mkdir()
    result = CliRunner().invoke(app, ["validate", str(path)])
    assert result.exit_code == 0 and "1 journal entries ignored (sub: a folder)" in result.output, result.output
    assert "runs again" not in result.output, "no cell is lost to a folder"
    (journal / "0-9-c3.json").write_text('{"trunc', encoding="utf-8")
    (journal / "notes.txt").write_text("x", encoding="utf-8")
    result = CliRunner().invoke(app, ["validate", str(path)])
    assert result.exit_code == 0, result.output
    assert ("3 journal entries ignored (0-9-c3.json: refused (not JSON (Unterminated string starting at)), notes.txt: not a "
            ".json record, sub: a folder); a damaged record's cell runs again on the next study run"
            ) in result.output, result.output
    assert len(result.output.strip().splitlines()) == 1


def test_a_study_journal_without_its_store_is_not_written_beside(tmp_path):
    """Only `x.h5.journal/` left (the store moved or lost): `simulate --out x.h5` made a run store beside
    the study's unmerged cells, then failed at iteration 1 with 'cannot commit (File exists)'."""
    run_study(small_study(seeds="0-0", methods=("c3",)), tmp_path, workers=1)
    path = tmp_path / "studies" / "tiny.h5"
    (tmp_path / "studies" / "tiny.h5.journal" / "0-5-c3.json").write_text("{}", encoding="utf-8")
    path.unlink()
    before = sorted(p.name for p in path.parent.iterdir())
    result = CliRunner().invoke(app, ["simulate", "--method", "c3", "--iters", "2", "--out", str(path)])
    assert result.exit_code == 2 and "is a study store's journal folder" in result.output, result.output
    assert sorted(p.name for p in path.parent.iterdir()) == before


def test_fifos_where_files_belong_are_named_not_waited_on(tmp_path):
    """A FIFO as a store, as a study store, or inside a study's journal folder blocked validate,
    export, report and study for ever (each opened it for reading before looking at what it was;
    found by an attack on the CLI). Each is now named, or skipped, in bounded time."""
    import os
    import subprocess
    import sys

    study = load_study(write_study_file(tmp_path, TINY_TOML))
    run_study(study, tmp_path / "results", workers=1)
    os.mkfifo(tmp_path / "fifo.h5")
    journal = tmp_path / "results" / "studies" / "tiny.h5.journal"
    journal.mkdir(exist_ok=True)
    os.mkfifo(journal / "0-5-c1.json")
    os.mkfifo(tmp_path / "results" / "studies" / "piped.h5")

    def ilcforce(*args):
        return subprocess.run([sys.executable, "-m", "ilcforce", *args], capture_output=True, text=True,
                              timeout=120, cwd=tmp_path)

    fifo = ilcforce("validate", "fifo.h5")
    assert fifo.returncode == 2 and "not a regular file" in fifo.stderr and "Traceback" not in fifo.stderr, fifo
    checked = ilcforce("validate", "results/studies/tiny.h5")
    assert checked.returncode == 0 and "0-5-c1.json: not a regular file" in checked.stdout, checked
    assert ilcforce("export", "results/studies/tiny.h5", "--out", "cells.csv").returncode == 0
    report = ilcforce("report", "--results", "results", "--quiet")
    assert report.returncode == 0 and "piped.h5" in report.stderr, report


@pytest.mark.parametrize("workers", ["100000", str(4 * (__import__("os").cpu_count() or 1) + 1)])
def test_more_workers_than_the_machine_runs_usefully_is_one_line(tmp_path, workers):
    """--workers had no upper bound: 64 workers on 2 cores took 48 s for 2 cells, and 100000 printed
    nothing for minutes (found by an attack on the CLI)."""
    path = write_study_file(tmp_path, TINY_TOML)
    result = CliRunner().invoke(app, ["study", str(path), "--results", str(tmp_path / "r"), "--workers", workers])
    assert result.exit_code == 2, result.output
    assert "4 per core" in result.output and len(result.output.strip().splitlines()) == 1, result.output
    assert not (tmp_path / "r").exists()


def test_a_damaged_study_store_is_called_damaged_not_foreign(tmp_path):
    """Rerunning a study over its damaged store said the file "is not an ilcforce study store" (it
    is one, damaged; found by an attack on the CLI). The refusal now says what is wrong with it."""
    path = write_study_file(tmp_path, TINY_TOML)
    results = tmp_path / "r"
    assert CliRunner().invoke(app, ["study", str(path), "--results", str(results), "--workers", "1"]).exit_code == 0
    store_path = results / "studies" / "tiny.h5"
    data = bytearray(store_path.read_bytes())
    data[2000:6000] = bytes(b ^ 0xFF for b in data[2000:6000])
    store_path.write_bytes(bytes(data))
    result = CliRunner().invoke(app, ["study", str(path), "--results", str(results), "--workers", "1"])
    assert result.exit_code == 2, result.output
    assert "damaged" in result.output and "is not an ilcforce study store" not in result.output, result.output
    assert store_path.read_bytes() == bytes(data)
