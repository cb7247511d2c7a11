"""Explicit settings lists in study files (``[[study.settings]]``): parsing, every
fault class, the tidy table, the store (resume, stale), export and the study report."""

from __future__ import annotations

import pandas as pd
import pytest
from typer.testing import CliRunner

from ilcforce.cli.main import app
from ilcforce.study import StudyError, StudyStoreError, build_study, export, read_study, run_study
from ilcforce.study.tidy import LABEL_COLUMN

from test_study import SMALL, write_study_file

LISTED = [
    {"label": "none", "noise.disturbance_amplitude": 0.0, "noise.encoder": 0.0},
    {"label": "encoder only", "noise.disturbance_amplitude": 0.0},
    {"label": "all"},
]


def listed_study(settings=None, name="listed", seeds="0-1", methods=("c1", "c3"), **extra):
    table = {"name": name, "seeds": seeds, "methods": list(methods), "set": dict(SMALL),
             "settings": LISTED if settings is None else settings, **extra}
    return build_study({"study": table})


TOML = """
[study]
name = "listed"
methods = ["c1", "c3"]
seeds = "0-1"
[study.set]
"experiment.iterations" = 2
"reference.duration" = 0.2
[[study.settings]]
label = "none"
"noise.disturbance_amplitude" = 0.0
"noise.encoder" = 0.0
[[study.settings]]
label = "encoder only"
"noise.disturbance_amplitude" = 0.0
[[study.settings]]
label = "all"
"""


# ------------------------------------------------------------------------------------------------
# the study file


def test_listed_settings_columns_are_the_union_with_the_experiment_values():
    study = listed_study()
    assert [s.label() for s in study.settings] == ["none", "encoder only", "all"]
    assert study.columns() == ["noise.disturbance_amplitude", "noise.encoder"]
    # a setting that leaves a key alone carries the experiment's (the paper's) value in its column
    assert [dict(s.values) for s in study.settings] == [
        {"noise.disturbance_amplitude": 0.0, "noise.encoder": 0.0},
        {"noise.disturbance_amplitude": 0.0, "noise.encoder": 1e-6},
        {"noise.disturbance_amplitude": 0.02, "noise.encoder": 1e-6}]
    assert study.settings[1].config.noise.encoder == 1e-6 and study.settings[1].config.noise.disturbance_amplitude == 0
    assert study.settings[2].config.experiment.iterations == SMALL["experiment.iterations"], "[study.set] applies"
    assert len(study.cells()) == 3 * 2 * 2
    assert study.definition()["labels"] == ["none", "encoder only", "all"]


def test_a_sweep_only_study_keeps_its_definition():
    """Adding settings lists must not make every existing sweep store stale."""
    study = build_study({"study": {"name": "s", "seeds": "0-1", "set": dict(SMALL), "sweep": {"c3.eta": [5.0, 2.0]}}})
    assert set(study.definition()) == {"name", "sweep_keys", "settings"}
    assert study.definition()["sweep_keys"] == ["c3.eta"]


def test_listed_settings_times_sweep_listed_slowest():
    study = listed_study(settings=LISTED[:2], sweep={"c3.eta": [5.0, 2.0]})
    assert [s.label() for s in study.settings] == ["none; c3.eta=5.0", "none; c3.eta=2.0",
                                                   "encoder only; c3.eta=5.0", "encoder only; c3.eta=2.0"]
    assert study.columns() == ["noise.disturbance_amplitude", "noise.encoder", "c3.eta"]
    assert study.settings[3].config.gains["c3"].eta == 2.0 and study.settings[3].config.noise.encoder == 1e-6


def test_an_unlabelled_setting_is_named_by_its_overrides():
    study = listed_study(settings=[{"noise.encoder": 0.0}, {}])
    assert [s.label() for s in study.settings] == ["noise.encoder=0.0", "base"]


@pytest.mark.parametrize("settings, extra, message", [
    ([], {}, "study.settings is an empty list"),
    ({"label": "x"}, {}, "must be a list of tables"),
    ([3], {}, "study.settings[0] must be a table"),
    ([{"label": "a", "noise.encodr": 0.0}], {}, "study.settings[0] ('a'): unknown key noise.encodr (did you mean 'encoder'?)"),
    ([{"nois.encoder": 0.0}], {}, "did you mean 'noise'"),
    ([{"label": "a"}, {"experiment.seed": 3}], {}, "study.settings[1]: experiment.seed is set by study.seeds"),
    ([{"label": "a"}, {"label": "a", "noise.encoder": 0.0}], {}, "label 'a' is already used by study.settings[0]"),
    ([{"label": "paper"}, {"label": "also paper", "noise.encoder": 1e-6}], {},
     "study.settings[1] ('also paper') resolves to the same configuration as study.settings[0] ('paper')"),
    ([{"label": 3}], {}, "study.settings[0].label must be a non-empty string"),
    ([{"label": " "}], {}, "study.settings[0].label must be a non-empty string"),
    ([{"noise": {"encoder": 0.0}}], {}, "write keys as quoted dotted names"),
    ([{"experiment.iterations": 4}], {}, "experiment.iterations is both in [study.set] and a listed setting"),
    ([{"c3.eta": 4.0}], {"sweep": {"c3.eta": [1.0, 2.0]}}, "c3.eta is both in [study.sweep] and a listed setting"),
    ([{"label": "ok"}, {"label": "bad", "c3.eta": -1.0}], {}, "study.settings[1] ('bad'): c3.eta must be"),
    ([{"label": "ok"}, {"label": "bad", "noise.encoder": "x"}], {"sweep": {"c3.eta": [1.0, 2.0]}},
     "study.settings[1] ('bad'): noise.encoder must be a number"),
    ([{"label": "a"}], {"sweep": {"c3.eta": [1.0, -2.0]}}, "study.settings[0] ('a') at c3.eta=-2.0: c3.eta must be"),
])
def test_bad_settings_list_names_the_entry(settings, extra, message):
    with pytest.raises(StudyError) as info:
        listed_study(settings=settings, **extra)
    assert message in str(info.value)
    assert "\n" not in str(info.value)


@pytest.mark.parametrize("text, message", [
    (TOML.replace('"noise.encoder" = 0.0', '"noise.encodr" = 0.0'), "did you mean 'encoder'"),
    (TOML.replace('label = "all"', 'label = "none"'), "label 'none' is already used"),
    (TOML + '"experiment.seed" = 4\n', "experiment.seed is set by study.seeds"),
    (TOML.replace('seeds = "0-1"\n', 'seeds = "0-1"\nsettings = []\n').split("[[study.settings]]")[0], "empty list"),
    (TOML.replace('label = "all"', 'label = "all"\n"noise.encoder" = 1e-6\n"noise.disturbance_amplitude" = 0.0'),
     "resolves to the same configuration as study.settings[1]"),
])
def test_cli_bad_settings_list_one_line_exit_2(tmp_path, text, message):
    path = write_study_file(tmp_path, text)
    result = CliRunner().invoke(app, ["study", str(path), "--results", str(tmp_path / "r"), "--workers", "1"])
    assert result.exit_code == 2, result.output
    assert message in result.output
    assert result.output.count("\n") == 1, result.output
    assert not (tmp_path / "r" / "studies").exists(), "nothing may be written for an invalid study"


# ------------------------------------------------------------------------------------------------
# running, the store, export, the report


@pytest.fixture(scope="module")
def ran(tmp_path_factory):
    root = tmp_path_factory.mktemp("listed")
    path = root / "listed.toml"
    path.write_text(TOML, encoding="utf-8")
    result = CliRunner().invoke(app, ["study", str(path), "--results", str(root), "--workers", "1", "--quiet"])
    assert result.exit_code == 0, result.output
    return root, path


def test_tidy_table_leads_with_label_and_every_key(ran):
    root, _path = ran
    results = read_study(root / "studies" / "listed.h5")
    assert results.labelled and results.sweep_keys == ["noise.disturbance_amplitude", "noise.encoder"]
    frame = results.metrics
    assert list(frame.columns[:6]) == [LABEL_COLUMN, "noise.disturbance_amplitude", "noise.encoder", "seed", "method",
                                       "iteration"]
    keys = frame.groupby(LABEL_COLUMN, sort=False)[["noise.disturbance_amplitude", "noise.encoder"]].first()
    assert keys.to_dict("index") == {"none": {"noise.disturbance_amplitude": 0.0, "noise.encoder": 0.0},
                                     "encoder only": {"noise.disturbance_amplitude": 0.0, "noise.encoder": 1e-6},
                                     "all": {"noise.disturbance_amplitude": 0.02, "noise.encoder": 1e-6}}
    assert len(frame) == 3 * 2 * 2 * 2 and frame.notna()[[LABEL_COLUMN, "noise.encoder"]].all().all()
    assert LABEL_COLUMN not in results.setting_metrics(1).columns
    assert set(results.cells[LABEL_COLUMN]) == {"none", "encoder only", "all"}
    # the sources differ between the settings: with no noise at all C1 sees no encoder noise
    none = results.setting_metrics(0)
    enc = results.setting_metrics(1)
    assert not none["position_error_2norm"].equals(enc["position_error_2norm"])


def test_export_round_trips_the_labels(ran, tmp_path):
    root, _path = ran
    out, rows = export(root / "studies" / "listed.h5", tmp_path / "listed.csv")
    back = pd.read_csv(out)
    assert rows == 24 and list(back.columns[:3]) == [LABEL_COLUMN, "noise.disturbance_amplitude", "noise.encoder"]
    assert list(dict.fromkeys(back[LABEL_COLUMN])) == ["none", "encoder only", "all"]


def test_rerun_skips_and_a_relabel_is_refused_then_replaced(ran, tmp_path):
    root, path = ran
    result = CliRunner().invoke(app, ["study", str(path), "--results", str(root), "--workers", "1", "--quiet",
                                      "--resume"])
    assert result.exit_code == 0, result.output
    relabelled = write_study_file(tmp_path, TOML.replace('label = "all"', 'label = "paper"'))
    with pytest.raises(StudyStoreError, match="different settings"):
        from ilcforce.study import load_study

        run_study(load_study(relabelled), root, workers=1)
    copy = tmp_path / "r"
    (copy / "studies").mkdir(parents=True)
    (copy / "studies" / "listed.h5").write_bytes((root / "studies" / "listed.h5").read_bytes())
    from ilcforce.study import load_study

    summary = run_study(load_study(relabelled), copy, workers=1, replace_stale=True)
    assert summary.ran == 12
    assert list(read_study(copy / "studies" / "listed.h5").settings["label"]) == ["none", "encoder only", "paper"]


def test_report_names_listed_settings(ran, tmp_path):
    from ilcforce.report.build import write_report

    root, _path = ran
    out = tmp_path / "report"
    write_report(root, out, formats=("png",), jobs=1)
    directory = out / "studies" / "listed"
    text = (directory / "report.md").read_text(encoding="utf-8")
    assert "listed by name (none; encoder only; all)" in text
    assert "## Setting 0: none" in text and "## Setting 2: all" in text
    assert "| setting | c1 | c3 |" in text and "| encoder only |" in text, "divergence rows are labelled"
    assert (directory / "sweep_key_numbers.png").stat().st_size > 10_000
    assert not (directory / "sweep_divergence_heatmap.png").exists(), "a list of settings is not a 2-D grid"
    page = (directory / "findings.md").read_text(encoding="utf-8")
    assert "## Setting: encoder only" in page
    # the per-setting tables are on the study's page; the findings link it
    assert "[`listed`](studies/listed/findings.md)" in (out / "findings.md").read_text(encoding="utf-8")
    assert "| encoder only | 2 |" in page
    assert "Error 2-norms and H_y (whole grid and settled, t >= 20 ms) at j = 1 per setting" in page, (
        "read at the last iteration of a 2-iteration study")
    assert "| none | 2 |" in page, "joint-rate and force-sensor noise still on: not deterministic, 2 seeds"
