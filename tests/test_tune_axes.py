"""``ilcforce tune`` on a 3-axis task (experiments/arm3.toml: u, v in the wall's plane, n its normal): the
chattering objective over the task's axes, a gain range of the wrong width in one line, and a tiny real
tuning end to end through the CLI (tune, the tuned file, validate, the report's page), whose store then
refuses a record that mixes the planar task's keys with the plane's.

The planar task's stores keep their x, y keys (tests/test_tune*.py run them unchanged).
"""

from __future__ import annotations

import json
from pathlib import Path
import shutil
import tomllib

import pytest
from typer.testing import CliRunner

from ilcforce.cli.main import app
from ilcforce.tune import build_tuning
from ilcforce.tune.objectives import chattering_over, scored_means
from tunekit import EXPERIMENTS

#: A tiny tuning of the spatial arm: C1 (the cap's reference) and C2, 2 scoring seeds x 3 iterations, a check
#: of 6 on one seed, one held-out seed x 6 iterations, 2 trials each; C2 searches its in-plane u gain and
#: its normal n gain, v held at the experiment's 400.
ARM3 = f"""
[tune]
name = "arm3-tiny"
experiment = "{EXPERIMENTS / 'arm3.toml'}"
methods = ["c1", "c2"]
seeds = [0, 1]
iterations = 2
score_last = 2
check_seeds = [10]
check_iterations = 6
heldout_seeds = [90]
heldout_iterations = 6
sampler_seed = 0
[tune.budget]
base = 2
per_dimension = 0
extend = 1
[tune.cap]
reference = "c1"
[tune.set]
"reference.duration" = 0.2
[tune.gains.c1]
k = {{ low = 10.0, high = 1000.0, log = true }}
[tune.gains.c2]
k = [{{ low = 100.0, high = 1000.0, log = true }}, 400.0, {{ low = 1000.0, high = 20000.0, log = true }}]
"""


def test_the_chattering_objective_on_three_axes_is_the_worst_of_u_v_n():
    cap = (0.2, 0.1, 2.0)
    assert chattering_over((0.2, 0.1, 2.0), cap) == 0.0  # the cap's own chattering
    assert chattering_over((2.0, 0.1, 2.0), cap) == pytest.approx(1.0)  # u ten times its cap
    assert chattering_over((0.2, 1.0, 0.2), cap) == pytest.approx(1.0)  # v
    assert chattering_over((0.02, 0.01, 20.0), cap) == pytest.approx(1.0)  # n, though u and v are a tenth
    assert chattering_over((0.02, 0.01, 0.2), cap) == pytest.approx(-1.0)
    assert chattering_over((0.02, 0.05, 0.2), cap) == pytest.approx(-0.30103, abs=1e-5)  # v, the worst, at half
    with pytest.raises(ValueError, match="H has 3 axes and the cap 2"):
        chattering_over((0.2, 0.1, 2.0), cap[:2])


def test_a_three_axis_tuning_scores_h_per_axis_u_v_n():
    tuning = build_tuning(tomllib.loads(ARM3))
    assert tuning.axes == ("u", "v", "n")
    row = {"status": "complete", "position_error_rms": 1e-3, "force_error_rms": 0.1,
           "chattering_task_u_settled": 0.2, "chattering_task_v_settled": 0.3, "chattering_task_n_settled": 4.0}
    means = scored_means([dict(row, iteration=j) for j in range(2)], tuning)
    assert means == pytest.approx({"e_p": 1e-3, "e_f": 0.1, "h_u": 0.2, "h_v": 0.3, "h_n": 4.0})


def test_a_gain_range_of_the_planar_width_on_three_axes_is_one_line_exit_2(tmp_path):
    text = ARM3.replace(", 400.0, {{ low = 1000.0, high = 20000.0, log = true }}]".replace("{{", "{").replace("}}", "}"),
                        ", 400.0]")
    assert text != ARM3
    path = tmp_path / "bad.toml"
    path.write_text(text)
    result = CliRunner().invoke(app, ["tune", str(path), "--results", str(tmp_path / "r")])
    assert result.exit_code == 2, result.output
    assert result.stderr.strip() == (f"error: {path}: tune.gains.c2.k must list 3 entries (one per task axis u, v, n "
                                     "of arm3), got 2"), result.stderr
    assert result.stdout == "" and not (tmp_path / "r").exists()


def test_tiny_three_axis_tuning_end_to_end(tmp_path):
    """tune -> a tuned file with 3 entries per per-axis gain, a store validate accepts with u, v, n keys,
    the report's page naming H_u, H_v, H_n; a record mixing x, y keys into it is refused in one line."""
    from ilcforce.report.tuning import write_tuning_report
    from ilcforce.store import records

    path = tmp_path / "arm3-tune.toml"
    path.write_text(ARM3)
    result = CliRunner().invoke(app, ["tune", str(path), "--results", str(tmp_path / "r"), "--workers", "1"])
    assert result.exit_code == 0, result.output
    store = tmp_path / "r" / "tuning" / "arm3-tiny"
    shipped = [line for line in result.stdout.splitlines() if " ships trial " in line]
    assert len(shipped) == 2 and all(" H_u " in line and " H_v " in line and " H_n " in line and "H_x" not in line
                                     for line in shipped), result.stdout
    # the tuned file: the arm's experiment with 3 entries in every per-axis gain, the cap per axis
    document = tomllib.loads((store / "tuned.toml").read_text())
    assert document["surface"]["selection"] == [0.0, 0.0, 1.0]
    for method in ("c1", "c2"):
        vectors = {k: v for k, v in document[method].items() if isinstance(v, list)}
        assert "k" in vectors and all(len(v) == 3 for v in vectors.values()), (method, vectors)
    assert len(document["tuning"]["cap"]) == 3 and all(c > 0 for c in document["tuning"]["cap"])
    assert "H_u " in (store / "tuned.toml").read_text().split("\n[", 1)[0]
    # the store: per-axis keys of the plane, the cap one per axis
    trial = json.loads((store / "trials" / "c2-00001.json").read_text())
    assert len(trial["cap"]) == 3 and trial["params"] and len(trial["gains"]["c2.k"]) == 3
    assert {"chattering_task_u_settled", "chattering_task_v_settled", "chattering_task_n_settled"} <= set(trial["seeds"][0])
    assert {"h_u_last", "h_v_last", "h_n_last"} <= set(trial["checks"][0])
    assert not any(k.startswith(("h_x", "h_y", "chattering_task_x", "chattering_task_y"))
                   for e in trial["seeds"] + trial["checks"] for k in e)
    heldout = json.loads((store / "heldout" / "c1-00000.json").read_text())
    assert {"h_u", "h_v", "h_n"} <= set(heldout["seeds"][0]) and "h_x" not in heldout["seeds"][0]
    checked = CliRunner().invoke(app, ["validate", str(store)])
    assert checked.exit_code == 0 and "ok (tuning arm3-tiny" in checked.output, checked.output
    # the report's page: the objective, the cap and the tables along u, v, n
    files, lines = write_tuning_report(store, tmp_path / "out", ("png",))
    page = tmp_path / "out" / "arm3-tiny"
    text = (page / "index.md").read_text()
    assert "log10(max(H_u / cap_u, H_v / cap_v, H_n / cap_n))" in text and "H_x" not in text, text
    assert (page / "fronts.png").is_file() and (page / "convergence.png").is_file()
    assert (page / "tuning.csv").read_text().splitlines()[0].endswith("e_P,e_F,H_u,H_v,H_n")
    assert {"H_u settled", "H_v settled", "H_n settled"} <= set((page / "pareto.csv").read_text().splitlines()[0]
                                                               .split(","))
    assert lines and lines[0].startswith("- [tuning arm3-tiny]")

    # a check seed with the planar task's keys among the plane's: refused, one line, naming both
    def tampered(name, edit):
        copy = tmp_path / name
        shutil.copytree(store, copy)
        file = copy / "trials" / "c2-00001.json"
        record = json.loads(file.read_text())
        edit(record)
        file.write_text(json.dumps(records.seal({k: v for k, v in record.items() if k != "checksum"})))
        return CliRunner().invoke(app, ["validate", str(copy)])

    def planar(entry, form):  # u, v -> x, y and n dropped, in the key form ("h_{}_last", ...)
        for new, old in (("x", "u"), ("y", "v")):
            entry[form.format(new)] = entry.pop(form.format(old))
        del entry[form.format("n")]

    mixed = tampered("mixed", lambda r: planar(r["checks"][0], "h_{}_last"))
    assert mixed.exit_code == 2 and len(mixed.output.strip().splitlines()) == 1, mixed.output
    assert "check seed 10: its fields are of the task axes x, y, the record's others of u, v, n; a record is of " \
           "one task" in mixed.output, mixed.output

    # a whole record of the planar task's keys (its cap too) in the plane's search: refused by the search
    def all_planar(record):
        for entry in record["seeds"]:
            planar(entry, "chattering_task_{}_settled")
        planar(record["checks"][0], "h_{}_last")
        record["cap"] = record["cap"][:2]

    other = tampered("other", all_planar)
    assert other.exit_code == 2 and len(other.output.strip().splitlines()) == 1, other.output
    assert "are not of the task axes u, v, n of its experiment" in other.output, other.output


def test_a_tuned_file_written_elsewhere_names_its_model_file_relative_to_itself(tmp_path):
    """The spatial arm's model file is an absolute path in the configuration; written with -o, the tuned file names
    it relative to the file's own folder (an experiment file reads a relative path relative to itself), so the file
    loads from a clone anywhere, not only on the machine the tuning ran on."""
    from ilcforce.config_load import load_config

    path = tmp_path / "arm3-tune.toml"
    path.write_text(ARM3)
    out = tmp_path / "deeper" / "arm3-tiny-tuned.toml"
    result = CliRunner().invoke(app, ["tune", str(path), "--results", str(tmp_path / "r"), "--workers", "1",
                                      "-o", str(out)])
    assert result.exit_code == 0, result.output
    written = tomllib.loads(out.read_text())["plant"]["spatial_arm"]["path"]
    assert not Path(written).is_absolute() and written.endswith("models/arm3.xml"), written
    assert (out.parent / written).resolve() == (Path(__file__).parents[1] / "experiments/models/arm3.xml").resolve()
    assert load_config(out).plant.model == "spatial_arm"
