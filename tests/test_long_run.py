"""The long-run page (ilcforce.report.long_run) and the growth test's validation (report.growth_validation):
the truth of a run, the verdict on its first 20 and 40 iterations, and the confusion matrix, on constructed
runs whose answers are known. The page's numbers for the shipped studies come from `make long`."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd

from ilcforce import stability
from ilcforce.report import growth_validation, long_run


class _Study:
    """What ``read_study`` returns, as far as the page reads it: settings and per-setting metrics."""

    def __init__(self, frames: dict[str, pd.DataFrame], config: dict | None = None):
        config = config or {"plant": {"perturbation": {"from_iteration": 10}}}
        self._frames = list(frames.values())
        self.settings = pd.DataFrame({"setting": range(len(frames)), "label": list(frames),
                                      "config_json": [json.dumps(config)] * len(frames)})
        self.metrics = pd.concat(self._frames, ignore_index=True)
        self.description = "constructed"

    def setting_metrics(self, k: int) -> pd.DataFrame:
        return self._frames[k]


def _run(method: str, seed: int, n: int, hx, *, diverge_at: int | None = None, memory=None, noise=0.01):
    rng = np.random.default_rng(seed)
    rows = []
    for j in range(n):
        done = diverge_at is None or j < diverge_at
        row = {"seed": seed, "method": method, "iteration": j, "status": "complete" if done else "diverged",
               "diverged_time": np.nan if done else 0.5,
               "chattering_task_x_settled": hx(j) * np.exp(rng.normal(0, noise)) if done else np.nan,
               "chattering_task_y_settled": 0.03 * np.exp(rng.normal(0, noise)) if done else np.nan,
               "position_error_2norm": 1e-4 * np.exp(rng.normal(0, noise)) if done else np.nan,
               "force_error_2norm": 1.0 * np.exp(rng.normal(0, noise)) if done else np.nan}
        if memory is not None:
            row["memory_settled_v"] = memory(j) if done else np.nan
        rows.append(row)
        if not done:
            break
    return pd.DataFrame(rows)


def test_truth_and_verdicts_of_constructed_runs():
    runs = pd.concat([
        _run("grows", 0, 300, lambda j: 0.02 * 1.03 ** j),                     # unbounded, flagged at 20 and 40
        _run("flat", 0, 300, lambda j: 0.02),                                  # bounded, not flagged
        _run("late", 0, 300, lambda j: 0.02, diverge_at=250),                  # unbounded, not seen at 20 or 40
        _run("early", 0, 300, lambda j: 0.02, diverge_at=30),                  # flagged at 40 by its divergence
        _run("drift", 0, 300, lambda j: 0.02, memory=lambda j: 0.5 + 0.01 * j),  # memory x1.4: bounded truth
    ], ignore_index=True)
    cases = growth_validation.validation_cases({"constructed": _Study({"s": runs})}).set_index("method")
    assert cases.loc["grows", "truth"] == "unbounded" and cases.loc["grows", "verdict_20"] == stability.FLAGGED
    assert "reaches 10x in" in cases.loc["grows", "test_40"]
    assert cases.loc["flat", "truth"] == "bounded" and cases.loc["flat", "verdict_40"] == stability.NOT_FLAGGED
    assert cases.loc["late", "truth_reason"] == "diverged at j = 250"
    assert cases.loc["late", "verdict_40"] == stability.NOT_FLAGGED
    assert cases.loc["early", "test_40"] == "diverged at j = 30" and cases.loc["early", "verdict_20"] == stability.NOT_FLAGGED
    assert cases.loc["drift", "truth"] == "bounded"
    table = growth_validation.confusion(cases.reset_index(), 40)
    assert table.loc["unbounded", stability.FLAGGED] == 2 and table.loc["unbounded", stability.NOT_FLAGGED] == 1
    assert int(table.to_numpy().sum()) == 5
    text = growth_validation.confusion_text(cases.reset_index(), 40)
    assert text.startswith("1 of the 2 unbounded cases that had not diverged by j = 40 missed (late, constructed, seed 0: "
                           "diverged at j = 250)"), text


def test_a_capped_memory_is_not_judged():
    """alpha_hat growing towards its projection bound (C3-robust's alpha_max) is growth bounded by
    construction: shown, not flagged."""
    run = _run("c3-robust", 0, 40, lambda j: 0.02)
    run["memory_settled_alpha_hat"] = [0.005 + 1e-4 * j for j in range(40)]
    config = {"plant": {"perturbation": {"from_iteration": 10}}, "c3-robust": {"alpha_max": 0.03}}
    cases = growth_validation.validation_cases({"c": _Study({"s": run}, config)})
    assert cases.loc[0, "verdict_40"] == stability.NOT_FLAGGED
    unbounded = growth_validation.validation_cases({"c": _Study({"s": run}, {**config, "c3-robust": {}})})
    assert unbounded.loc[0, "verdict_40"] == stability.FLAGGED


def test_the_findings_cite_the_committed_summary_and_leave_make_longs_studies_out(tmp_path, monkeypatch):
    """The findings of make reproduce are the same with or without make long's studies in the results:
    those studies are left out, and the committed summary (date, commit, headline) is cited instead."""
    from ilcforce.report import readme, verdicts

    summary = {"provenance": "studies run on 2026-12-05 at commit abc", "headline": ["C3 diverges."]}
    monkeypatch.setattr(long_run, "committed_summary", lambda directory=None: summary)
    empty = dict(claims=pd.DataFrame(columns=verdicts.CLAIM_COLUMNS),
                 stability=pd.DataFrame(columns=verdicts.STABILITY_COLUMNS))
    long_study = {"description": "x", "settings": {}, "incomplete": "", "labelled": False}
    with_long = readme.findings_markdown({}, {"long-run-1000": long_study, "growth-validation": long_study}, **empty)
    assert with_long == readme.findings_markdown({}, {}, **empty)
    assert "`make long`, studies run on 2026-12-05 at commit abc): C3 diverges." in with_long
    assert long_run.is_long_study("growth-validation-serial2r") and not long_run.is_long_study("long-run-mc")
    # every study file of experiments/long/ is one of make long's, so the findings leave each out
    import tomllib
    from pathlib import Path

    for path in Path("experiments/long").glob("*.toml"):
        table = tomllib.loads(path.read_text(encoding="utf-8")).get("study")
        if table:
            assert long_run.is_long_study(table["name"]), path


def test_heldout_rates_count_misses_false_alarms_and_not_evaluable_with_wilson_intervals():
    """The out-of-sample page's rates: a miss is an unbounded case not flagged that had not diverged by the
    horizon; a false alarm a bounded case flagged; "not evaluable" is its own row over every case. Each rate
    carries its 95% Wilson interval (0 of 12 still allows up to 24%)."""
    rows = ([{"truth": "unbounded", "diverged_at": 5.0, "verdict_20": "flagged"}]  # diverged early: not counted
            + [{"truth": "unbounded", "diverged_at": float("nan"), "verdict_20": v}
               for v in ("flagged", "flagged", "not evaluable")]
            + [{"truth": "bounded", "diverged_at": float("nan"), "verdict_20": v}
               for v in ["not flagged"] * 10 + ["flagged", "not evaluable"]])
    table = growth_validation.rates(pd.DataFrame(rows), 20).set_index("what")
    assert (table.loc["misses", "count"], table.loc["misses", "of"]) == (1, 3)
    assert table.loc["  of which not evaluable", "count"] == 1
    assert (table.loc["false alarms", "count"], table.loc["false alarms", "of"]) == (1, 12)
    assert (table.loc["not evaluable", "count"], table.loc["not evaluable", "of"]) == (2, 16)
    low, high = table.loc["false alarms", ["rate_low", "rate_high"]]
    assert 0.01 < low < 1 / 12 < high < 0.36
    none = growth_validation.rates(pd.DataFrame(rows[4:]).assign(verdict_20="not flagged"), 20).set_index("what")
    assert none.loc["false alarms", "rate_low"] < 1e-12 and 0.2 < none.loc["false alarms", "rate_high"] < 0.3


def test_the_long_run_figure_says_what_its_marks_are(tmp_path, monkeypatch):
    """docs/long-run/long_run.png named the methods only: its crosses, bands and vertical lines were explained
    nowhere in the image. Its legends now name each, and the image is written."""
    from ilcforce.report import figure_files
    from ilcforce.report.figures import report_style

    runs = pd.concat([_run("c1", 0, 40, lambda j: 0.1), _run("c1", 1, 40, lambda j: 0.1),
                      _run("c2", 0, 40, lambda j: 0.02 * 1.05 ** j, diverge_at=30),
                      _run("c2", 1, 40, lambda j: 0.02 * 1.05 ** j, diverge_at=35)], ignore_index=True)
    study = _Study({"long": runs}, {"plant": {"perturbation": {"from_iteration": 10, "factor": 1.4}}})
    drawn = []
    save = figure_files.save_figure
    monkeypatch.setattr(figure_files, "save_figure", lambda fig, *a: drawn.append(fig) or save(fig, *a))
    with report_style():
        path = long_run.long_run_figure(study, tmp_path / "long_run.png")
    assert path.is_file() and path.stat().st_size > 0
    texts = [t.get_text() for legend in drawn[0].legends for t in legend.get_texts()]
    for said in (long_run.MEDIAN_TEXT, long_run.BAND_TEXT, long_run.CROSS_TEXT, long_run.PAPER_END_TEXT,
                 "dash-dotted: the plant's change, m3 x 1.4 from j = 10", "C1 (SMC)", "C2 (ILC)"):
        assert said in texts, (said, texts)
    # every mark the legend names is drawn: a cross where each diverged seed ended
    crosses = [line for ax in drawn[0].get_axes() for line in ax.get_lines() if line.get_marker() == "x"]
    assert {float(line.get_xdata()[0]) for line in crosses} == {29.0, 34.0}


def test_the_truth_at_1000_iterations_replaces_the_300_iteration_one_case_by_case():
    """A held-out case rerun to 1,000 iterations takes the rerun's truth (a slow divergence turns a bounded case
    unbounded, and its flag from a false alarm into a hit); an unbounded case not rerun keeps its truth; a
    bounded one not rerun has none; an unlabelled study's setting (its own name) is matched to the original's."""
    def case(study, setting, seed, truth, verdict, reason="r300", runs=300):
        return {"study": study, "setting": setting, "seed": seed, "method": "c2-robust", "truth": truth,
                "truth_reason": reason, "iterations_run": runs, "diverged_at": float("nan"),
                **{f"verdict_{h}": verdict for h in growth_validation.JUDGED_AT}}

    cases = pd.DataFrame([case("growth-heldout-robust", "Q 400", 560, "bounded", "flagged"),
                          case("growth-heldout-robust", "Q 400", 561, "bounded", "not flagged"),
                          case("growth-heldout-plain", "Ts", 560, "unbounded", "flagged"),
                          case("growth-heldout-plain", "Ts", 561, "bounded", "flagged"),
                          case("growth-heldout-serial2r", "growth-heldout-serial2r", 560, "bounded", "not flagged")])
    longer = pd.DataFrame([case("heldout-1000-robust", "Q 400", 560, "unbounded", "flagged", "diverged at j = 758", 759),
                           case("heldout-1000-robust", "Q 400", 561, "bounded", "not flagged", "r1000", 1000),
                           case("heldout-1000-serial2r", "heldout-1000-serial2r", 560, "unbounded", "flagged", "x12", 1000)])
    out = growth_validation.with_longer_truth(cases, longer)
    assert out["truth_1000"].tolist()[:3] == ["unbounded", "bounded", "unbounded"]
    assert out["truth_reason_1000"].iloc[0] == "diverged at j = 758"
    assert "not rerun" in out["truth_reason_1000"].iloc[2]
    assert pd.isna(out["truth_1000"].iloc[3])  # bounded at 300 and not rerun: no longer truth
    assert out["truth_1000"].iloc[4] == "unbounded" and out["iterations_run_1000"].iloc[4] == 1000
    # the serial2r rerun says "flagged" where the original said "not flagged": the verdicts do not agree there
    assert out["verdicts_agree"].tolist() == [True, True, True, True, False]
    judged = out[out["truth_1000"].notna()]
    at_1000 = growth_validation.rates(judged, 40, "truth_1000").set_index("what")
    at_300 = growth_validation.rates(judged, 40).set_index("what")
    assert at_300.loc["false alarms", "count"] == 1 and at_1000.loc["false alarms", "count"] == 0
    assert at_1000.loc["misses", "count"] == 1  # the serial2r case, unbounded at 1,000 and not flagged
