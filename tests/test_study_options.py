"""A study from the command line (``ilcforce study -m c3 --sweep c3.eta=1,2,5 --seeds 0-19``,
ilcforce.study.options): the same store as the study file it stands for, that file saved beside the
store, named by its content; bad options one line, exit 2, nothing written."""

from __future__ import annotations

import tomllib
from pathlib import Path

import pandas as pd
import pytest
from typer.testing import CliRunner

from ilcforce.cli.main import app
from ilcforce.study import read_study
from ilcforce.study.options import parse_sweep, study_content, study_name, study_text

#: a short horizon, few iterations: cells of a fraction of a second (the numbers are not the point)
SHORT = ["--set", "reference.duration=0.1", "--set", "experiment.iterations=2"]


def _study(args: list[str], results) -> object:
    return CliRunner().invoke(app, ["study", *args, "--results", str(results), "--workers", "1", "--quiet"])


def test_a_sweep_on_the_command_line_stores_what_its_study_file_stores(tmp_path):
    results = tmp_path / "results"
    ran = _study(["-m", "c1,c3", "--sweep", "c3.eta=1,2.5", "--sweep", "simulation.sample_time=1e-4,2e-4",
                  "--seeds", "0-1", *SHORT], results)
    assert ran.exit_code == 0, ran.output
    saved = sorted((results / "studies").glob("*.toml"))
    assert len(saved) == 1, saved
    name = saved[0].stem
    assert name.startswith("sweep-c3.eta-simulation.sample_time-"), name
    assert (results / "studies" / f"{name}.h5").is_file()
    data = tomllib.loads(saved[0].read_text())["study"]
    assert data["name"] == name and data["methods"] == ["c1", "c3"] and data["seeds"] == "0-1"
    assert data["sweep"] == {"c3.eta": [1, 2.5], "simulation.sample_time": [1e-4, 2e-4]}
    assert data["set"] == {"reference.duration": 0.1, "experiment.iterations": 2}

    # the same study written by hand, under another name
    by_hand = tmp_path / "by-hand.toml"
    by_hand.write_text("""
[study]
name = "by-hand"
methods = ["c1", "c3"]
seeds = "0-1"
[study.set]
"reference.duration" = 0.1
"experiment.iterations" = 2
[study.sweep]
"c3.eta" = [1, 2.5]
"simulation.sample_time" = [1e-4, 2e-4]
""")
    ran = _study([str(by_hand)], results)
    assert ran.exit_code == 0, ran.output
    inline, written = read_study(results / "studies" / f"{name}.h5"), read_study(results / "studies" / "by-hand.h5")
    assert inline.sweep_keys == written.sweep_keys == ["c3.eta", "simulation.sample_time"]
    pd.testing.assert_frame_equal(inline.settings, written.settings)  # every setting's whole configuration
    assert len(inline.metrics) == 2 * 2 * 2 * 2 * 2  # settings x seeds x methods x iterations
    pd.testing.assert_frame_equal(inline.metrics, written.metrics)
    assert inline.study_toml == saved[0].read_text(), "the store keeps the file saved beside it"

    # the same command again: the same name, nothing to run, the file as it was
    before = saved[0].stat().st_mtime_ns
    again = _study(["-m", "c1,c3", "--sweep", "c3.eta=1,2.5", "--sweep", "simulation.sample_time=1e-4,2e-4",
                    "--seeds", "0,1", *SHORT], results)
    assert again.exit_code == 0, again.output
    assert sorted((results / "studies").glob("*.toml")) == saved and saved[0].stat().st_mtime_ns == before
    # and the saved file runs it again as a study file
    rerun = CliRunner().invoke(app, ["study", str(saved[0]), "--results", str(results), "--workers", "1"])
    assert rerun.exit_code == 0 and "(16 already stored, 0 run, 0 failed)" in rerun.output, rerun.output


def test_the_name_comes_from_the_content_alone():
    def name(**changes):
        options = {"methods": ["c3"], "seeds": "0-19", "sweeps": ["c3.eta=1,2,5"], "sets": [], "experiment": None}
        options.update(changes)
        return study_name(study_content(**options))

    assert name() == name(seeds="0,1,2,3,4,5,6,7,8,9,10,11,12,13,14,15,16,17,18,19") == name(seeds=" 0 - 19 ")
    assert len({name(), name(sweeps=["c3.eta=1,2,6"]), name(seeds="0-18"), name(methods=["c1"]),
                name(sets=["noise.scale=0.5"]), name(methods=None)}) == 6
    assert name(sweeps=[]).startswith("seeds-")
    content = study_content(methods=None, seeds="3,1", sweeps=["c3.k=[1, 2],[3, 4]", "c3.psi_acceleration=desired,measured"],
                            sets=[], experiment=None)
    read = tomllib.loads(study_text("x", content))["study"]
    assert read["seeds"] == [1, 3] and "methods" not in read
    assert read["sweep"] == {"c3.k": [[1, 2], [3, 4]], "c3.psi_acceleration": ["desired", "measured"]}
    assert parse_sweep("c3.eta = 1, 2.5 ,5") == ("c3.eta", [1, 2.5, 5])
    shipped = study_content(methods=None, seeds="0", sweeps=[], sets=[], experiment=Path("serial2r"))["experiment"]
    assert Path(shipped).is_absolute() and Path(shipped).name == "serial2r.toml", "a shipped experiment by its name"


@pytest.mark.parametrize(("args", "message"), [
    (["--sweep", "c3.eta", "--seeds", "0-1"], "--sweep expects KEY=V1,V2,... (e.g. c3.eta=1,2,5), got 'c3.eta'"),
    (["--sweep", "c3.eta=1,,2", "--seeds", "0-1"], "--sweep c3.eta: an empty value"),
    (["--sweep", "c3.eta=1,2", "--sweep", "c3.eta=3", "--seeds", "0-1"], "--sweep c3.eta is given twice"),
    (["--sweep", "c3.eta=1,2"], "--seeds is missing (e.g. --seeds 0-19)"),
    (["--sweep", "c3.eta=1,2", "--seeds", "a-b"], "--seeds must be a range a-b or a comma-separated list"),
    (["--sweep", "c3.eta=1,1.0", "--seeds", "0"], "lists a value twice"),
    (["--sweep", "c3.eta=1,2", "--seeds", "0", "--set", "experiment.seed=3"], "--set experiment.seed: a study's seeds "
                                                                              "are --seeds"),
    (["--sweep", "experiment.seed=1,2", "--seeds", "0"], "--sweep experiment.seed: a study's seeds are --seeds"),
    (["--sweep", "c3.nothing=1,2", "--seeds", "0"], "c3.nothing"),
    (["--sweep", "c3.eta=1,2", "--seeds", "0", "-m", "c9"], "unknown method 'c9'"),
    (["--sweep", "c3.eta=1,2", "--seeds", "0", "-c", "nowhere.toml"], "--config: no experiment file nowhere.toml"),
    (["paper-mc", "--sweep", "c3.eta=1,2"], "give study files or --sweep, not both"),
    ([], "give a study file, or a study by its options"),
])
def test_bad_options_are_one_line_and_write_nothing(tmp_path, args, message):
    done = _study(args, tmp_path / "results")
    assert done.exit_code == 2, done.output
    lines = done.output.strip().splitlines()
    assert len(lines) == 1 and message in lines[0], done.output
    assert not (tmp_path / "results").exists()


def test_another_file_under_the_name_is_never_replaced(tmp_path):
    results = tmp_path / "results"
    content = study_content(methods=["c3"], seeds="0", sweeps=["c3.eta=1,2"], sets=[], experiment=None)
    taken = results / "studies" / f"{study_name(content)}.toml"
    taken.parent.mkdir(parents=True)
    taken.write_text("# mine\n")
    done = _study(["-m", "c3", "--sweep", "c3.eta=1,2", "--seeds", "0"], results)
    assert done.exit_code == 2 and "exists with other content" in done.output, done.output
    assert taken.read_text() == "# mine\n" and sorted(p.name for p in taken.parent.iterdir()) == [taken.name]
