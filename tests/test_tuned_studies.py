"""What a tuned experiment file's [tuning] table does downstream: a withheld method is refused by name and
left out of a study's default methods, every tuned table gives it a column saying so, and a tuned study's
comparison at equal chattering ranks only the methods within the cap."""

from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace

import pandas as pd
import pytest
from typer.testing import CliRunner

from ilcforce.cli.main import app
from ilcforce.report import equal_chattering
from ilcforce.report.study import key_numbers
from ilcforce.study.spec import StudyError, build_study
from ilcforce.tune.heldout import NONE_UNDER_CAP

EXPERIMENTS = Path(__file__).resolve().parent.parent / "experiments"


def tuned_file(tmp_path: Path, withheld=("c3",), cap=(0.1, 0.5)) -> Path:
    text = (EXPERIMENTS / "paper.toml").read_text()
    path = tmp_path / "mine-tuned.toml"
    path.write_text(text + f'\n[tuning]\nsource = "mine-tune"\nwithheld = {json.dumps(list(withheld))}\n'
                           f'cap_reference = "c1"\ncap = {json.dumps(list(cap))}\n')
    return path


def test_a_withheld_method_is_refused_by_every_command(tmp_path):
    path = tuned_file(tmp_path)
    result = CliRunner().invoke(app, ["simulate", "-c", str(path), "-m", "c3", "-n", "1", "--results",
                                      str(tmp_path / "r")])
    assert result.exit_code == 2
    lines = [line for line in result.output.splitlines() if line.strip()]
    assert len(lines) == 1 and "c3 has no gains in this tuned experiment" in lines[0] and "mine-tune" in lines[0]
    assert "Traceback" not in result.output
    assert not (tmp_path / "r").exists() or not any((tmp_path / "r").rglob("*.h5"))


def test_a_study_leaves_a_withheld_method_out_and_refuses_it_by_name(tmp_path):
    path = tuned_file(tmp_path)
    study = build_study({"study": {"name": "s", "experiment": str(path), "seeds": [1]}})
    assert "c3" not in study.methods and "c2" in study.methods
    with pytest.raises(StudyError, match="study.methods: c3 has no gains"):
        build_study({"study": {"name": "s", "experiment": str(path), "seeds": [1], "methods": ["c2", "c3"]}})


def test_a_bad_tuning_table_is_one_line(tmp_path):
    path = tuned_file(tmp_path, withheld=("c9",))
    result = CliRunner().invoke(app, ["simulate", "-c", str(path), "-m", "c2", "-n", "1", "--results",
                                      str(tmp_path / "r")])
    assert result.exit_code == 2 and "tuning.withheld: unknown method 'c9'" in result.output
    path = tuned_file(tmp_path, cap=(0.1, -1.0))
    result = CliRunner().invoke(app, ["simulate", "-c", str(path), "-m", "c2", "-n", "1", "--results",
                                      str(tmp_path / "r")])
    assert result.exit_code == 2 and "tuning.cap must hold positive numbers" in result.output


def _frame(runs: dict[str, tuple[float, float, float, float]], seeds=(100, 101, 102), iterations=60) -> pd.DataFrame:
    """A tidy metrics frame: per method constant e_P, e_F (RMS and 2-norm) and settled H_x, H_y."""
    rows = []
    for method, (e_p, e_f, h_x, h_y) in runs.items():
        for seed in seeds:
            for j in range(iterations):
                rows.append({"seed": seed, "method": method, "iteration": j, "status": "complete",
                             "position_error_rms": e_p, "force_error_rms": e_f, "position_error_2norm": e_p,
                             "force_error_2norm": e_f, "chattering_task_x": h_x, "chattering_task_y": h_y,
                             "chattering_task_x_settled": h_x, "chattering_task_y_settled": h_y})
    return pd.DataFrame(rows)


def test_key_numbers_give_a_withheld_method_a_column_that_says_so():
    frame = _frame({"c1": (1e-4, 0.1, 0.1, 0.5), "c2": (1e-5, 0.01, 0.05, 0.2)})
    table = key_numbers(frame, ["c1", "c2"], 60, withheld=("c3",))
    assert list(table.columns[:4]) == ["quantity", "c1", "c2", "c3"]
    assert (table["c3"] == NONE_UNDER_CAP).all()
    quantities = set(table["quantity"])
    assert "H x settled at j = 59 (N)" in quantities and "position 2-norm at j = 59 (m)" in quantities


def test_the_comparison_at_equal_chattering_ranks_only_methods_within_the_cap():
    frame = _frame({"c1": (1e-4, 0.1, 0.1, 0.5),          # at the cap: within
                    "c2-robust": (1e-5, 0.02, 0.05, 0.2),  # within, most accurate in position
                    "smc-bl": (1e-6, 0.001, 0.3, 0.5)})    # more accurate still, but 3x the cap on H_x
    config = {"tuning": {"source": "t", "withheld": ["c3"], "cap_reference": "c1", "cap": [0.1, 0.5]}}
    results = SimpleNamespace(settings=pd.DataFrame([{"setting": 0, "config_json": json.dumps(config)}]),
                              setting_metrics=lambda k: frame)
    table, sentence = equal_chattering.comparison(results)
    assert list(table["method"]) == ["c1", "smc-bl", "c2-robust", "c3"]
    assert table.set_index("method").loc["smc-bl", "H / cap (max over axes)"] == "3.00"
    assert (table.set_index("method").loc["c3"].drop("diverged") == NONE_UNDER_CAP).all()
    assert "2 of 3 shipped methods" in sentence
    assert "smallest position error is c2-robust (1e-05 m), then c1 (0.0001 m)" in sentence
    assert "over the cap here: smc-bl (3.00x)" in sentence and f"{NONE_UNDER_CAP}: c3" in sentence


def test_an_untuned_study_has_no_comparison_at_equal_chattering():
    results = SimpleNamespace(settings=pd.DataFrame([{"setting": 0, "config_json": json.dumps({"tuning": {}})}]),
                              setting_metrics=lambda k: _frame({"c1": (1, 1, 1, 1)}))
    table, sentence = equal_chattering.comparison(results)
    assert table.empty and sentence == ""


def test_a_three_axis_tuned_study_compares_at_equal_chattering_on_u_v_n():
    """A tuned file of a 3-axis task has a cap per axis u, v, n: the comparison reads H along each and a method
    over the cap on one axis alone (v) is over it."""
    frame = _frame({"c1": (1e-4, 0.1, 0.1, 0.5), "c2": (1e-5, 0.01, 0.05, 0.2)})
    frame = frame.rename(columns={"chattering_task_x_settled": "chattering_task_u_settled",
                                  "chattering_task_y_settled": "chattering_task_n_settled"})
    frame["chattering_task_v_settled"] = frame["method"].map({"c1": 0.2, "c2": 0.5})  # c2: 2.5x the cap on v
    config = {"tuning": {"source": "t", "withheld": [], "cap_reference": "c1", "cap": [0.1, 0.2, 0.5]}}
    results = SimpleNamespace(settings=pd.DataFrame([{"setting": 0, "config_json": json.dumps(config)}]),
                              setting_metrics=lambda k: frame)
    table, sentence = equal_chattering.comparison(results)
    assert [c for c in table.columns if c.startswith("H_")] == [f"H_{a} settled, j = 59" for a in "uvn"]
    assert table.set_index("method").loc["c2", "H / cap (max over axes)"] == "2.50"
    assert "H_u 0.1 N, H_v 0.2 N, H_n 0.5 N" in sentence and "over the cap here: c2 (2.50x)" in sentence


def test_the_cap_is_checked_at_every_iteration_and_a_method_over_it_before_the_plant_changes_is_named():
    """The cap is a settled H at the last iteration; a method under it there but over it at j = 0..9 (before
    the plant changes) is still ranked at j = 59, and the table and sentence name those iterations and the
    largest excess; the median over seeds decides (one seed over the cap alone is not the method over it)."""
    frame = _frame({"c1": (1e-4, 0.1, 0.1, 0.5), "smc-bl": (1e-5, 0.02, 0.05, 0.2)})
    early = (frame["method"] == "smc-bl") & (frame["iteration"] < 10)
    frame.loc[early, "chattering_task_y_settled"] = 1.0  # 2x the cap on H_y at j = 0..9, every seed
    frame.loc[early & (frame["iteration"] == 3), "chattering_task_y_settled"] = 1.5  # 3x at j = 3
    lone = (frame["method"] == "c1") & (frame["iteration"] == 20) & (frame["seed"] == 100)
    frame.loc[lone, "chattering_task_x_settled"] = 10.0  # one seed of three: the median stays at the cap
    config = {"tuning": {"source": "t", "withheld": [], "cap_reference": "c1", "cap": [0.1, 0.5]}}
    results = SimpleNamespace(settings=pd.DataFrame([{"setting": 0, "config_json": json.dumps(config)}]),
                              setting_metrics=lambda k: frame)
    table, sentence = equal_chattering.comparison(results)
    rows = table.set_index("method")
    assert rows.loc["smc-bl", "iterations over the cap"] == "0-9" and rows.loc["c1", "iterations over the cap"] == "none"
    assert rows.loc["smc-bl", "H / cap, most over j = 0..59"] == "3.00 (j = 3)"
    assert "2 of 2 shipped methods" in sentence, "the ranking at j = 59 is unchanged"
    assert "over the cap at some iteration: smc-bl (j = 0-9; most 3.00x, at j = 3)" in sentence


def test_iterations_over_the_cap_are_written_as_spans():
    assert equal_chattering._spans([0, 1, 2, 5, 7, 8]) == "0-2, 5, 7-8"
    assert equal_chattering._spans([]) == ""


def test_a_method_whose_interval_crosses_the_cap_is_uncertain_and_not_ranked():
    """c2's settled H_x over three seeds is 0.08, 0.10, 0.13 against a cap of 0.1: its median sits on the cap and
    the 95% interval of the median reaches both sides, so it is neither within nor over it."""
    frame = _frame({"c1": (1e-4, 0.1, 0.05, 0.2), "c2": (1e-6, 0.001, 0.1, 0.2)})
    by_seed = {100: 0.08, 101: 0.10, 102: 0.13}
    is_c2 = frame["method"] == "c2"
    frame.loc[is_c2, "chattering_task_x_settled"] = frame.loc[is_c2, "seed"].map(by_seed)
    config = {"tuning": {"source": "t", "withheld": [], "cap_reference": "c1", "cap": [0.1, 0.5]}}
    results = SimpleNamespace(settings=pd.DataFrame([{"setting": 0, "config_json": json.dumps(config)}]),
                              setting_metrics=lambda k: frame)
    table, sentence = equal_chattering.comparison(results)
    places = table.set_index("method")["against the cap"]
    assert places["c2"] == equal_chattering.UNCERTAIN and places["c1"] == equal_chattering.WITHIN
    assert "1 of 2 shipped methods" in sentence and "smallest position error is c1" in sentence
    assert "uncertain against the cap (the interval of a median H crosses it), not ranked: c2 (1.00x)" in sentence
    assert equal_chattering.against_cap([[0.2, 0.21, 0.22]], [0.1]) == equal_chattering.OVER
