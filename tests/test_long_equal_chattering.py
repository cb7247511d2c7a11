"""NO-ILC at equal chattering over 300 iterations (experiments/long/long-equal-chattering*.toml,
ilcforce.report.long_equal_chattering): the shipped studies run the tuned five-bar's NO-ILC and robust variants
and the withheld C3 with its paper gains on seeds no other study uses, and the page's table reads a real study
store, made by the study engine from a stand-in cell whose answers are known. The page's numbers come from
`make long`."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from ilcforce import metrics
from ilcforce.report import long_equal_chattering as page
from ilcforce.stats import frequency_interval
from ilcforce.study import run_study
from ilcforce.study.spec import is_study_file, load_study

ROOT = Path(__file__).resolve().parents[1]
TUNED_STUDY = ROOT / "experiments" / "long" / "long-equal-chattering.toml"
WITHHELD_STUDY = ROOT / "experiments" / "long" / "long-equal-chattering-withheld.toml"
ITERATIONS = 30


def test_the_shipped_studies_run_the_tuned_no_ilc_beside_the_robust_variants_and_the_withheld_c3():
    tuned, withheld = load_study(TUNED_STUDY), load_study(WITHHELD_STUDY)
    assert (tuned.name, withheld.name) == (page.STUDY, page.WITHHELD_STUDY)
    config = tuned.settings[0].config
    assert config.tuning.source == "fivebar-tune" and len(config.tuning.cap) == 2, "the tuned five-bar file"
    assert set(tuned.methods) == {"no-ilc", "c2-robust", "c3-robust"}
    assert not set(tuned.methods) & set(config.tuning.withheld), "every tuned method ships gains"
    assert set(withheld.methods) == {"c3"} <= set(config.tuning.withheld), "plain C3 is the tuning's withheld"
    other = withheld.settings[0].config
    assert other.gains["c3"] == config.gains["c3"], "the withheld C3 runs the gains the tuned file kept (the paper's)"
    assert tuned.seeds == withheld.seeds and len(tuned.seeds) >= 5
    assert config.experiment.iterations == other.experiment.iterations >= 300
    assert config.plant.perturbation == other.plant.perturbation and config.plant.perturbation.from_iteration == 10


def test_their_seeds_are_held_out_from_every_other_study_and_they_are_long_studies():
    from ilcforce.report import long_run

    ours = set(load_study(TUNED_STUDY).seeds)
    for path in sorted((ROOT / "experiments").rglob("*.toml")):
        if path in (TUNED_STUDY, WITHHELD_STUDY) or not is_study_file(path):
            continue
        assert not ours & set(load_study(path).seeds), path
    assert ours.isdisjoint(range(0, 3)) and ours.isdisjoint(range(10, 12)) and ours.isdisjoint(range(90, 93)), \
        "nor a tuning's scoring, check or held-out seed"
    assert long_run.is_long_study(page.STUDY) and long_run.is_long_study(page.WITHHELD_STUDY)
    assert not long_run.is_long_study("tuned-mc")


def _stand_in(config, method, keep_store=None, stop=None):
    """Known rows: NO-ILC e_P 1 mm (+1% per seed), C2-robust 100x smaller; e_F 0.1 N for all; settled H
    0.5x the cap (NO-ILC) or 2x (C2-robust); C3 diverges at j = 7 on seeds 0-2 and runs like NO-ILC on 3-4.
    The plant's change (j = 10) multiplies e_P by 4, the next iteration by 2, then it is back."""
    cap = config.tuning.cap or (0.1, 0.5)
    seed = config.experiment.seed
    e_p = (1e-5 if method == "c2-robust" else 1e-3) * (1 + 0.01 * seed)
    share = 2.0 if method == "c2-robust" else 0.5
    stop_at = 7 if method == "c3" and seed <= 2 else None
    rows = []
    for j in range(config.experiment.iterations):
        done = stop_at is None or j < stop_at
        row = {c: (0 if metrics.column_kind(c) == "int" else 0.01) for c in metrics.metric_columns(2)}
        row.update({"iteration": j, "status": "complete" if done else "diverged",
                    "diverged_time": math.nan if done else 0.5,
                    "position_error_2norm": e_p * {10: 4.0, 11: 2.0}.get(j, 1.0) if done else math.nan,
                    "force_error_2norm": 0.1 if done else math.nan,
                    "chattering_task_x_settled": share * cap[0] if done else math.nan,
                    "chattering_task_y_settled": share * cap[1] if done else math.nan})
        rows.append(row)
        if not done:
            break
    return {"rows": rows, "elapsed": 0.0, "worker": "test"}


@pytest.fixture(scope="module")
def stored(tmp_path_factory):
    """A results folder holding both studies, small (5 seeds x 30 iterations), made by the study engine."""
    results, files = tmp_path_factory.mktemp("results"), tmp_path_factory.mktemp("files")
    for name, experiment, methods in ((page.STUDY, "fivebar-tuned.toml", '["no-ilc", "c2-robust"]'),
                                      (page.WITHHELD_STUDY, "paper.toml", '["c3"]')):
        study_file = files / f"{name}.toml"
        study_file.write_text("\n".join([
            "[study]", f'name = "{name}"', f'description = "constructed {name}"',
            f'experiment = "{ROOT / "experiments" / experiment}"', f"methods = {methods}", 'seeds = "0-4"',
            "[study.set]", f'"experiment.iterations" = {ITERATIONS}', ""]), encoding="utf-8")
        run_study(load_study(study_file), results, workers=1, cell_function=_stand_in)
    return results


def test_the_table_of_a_stored_study_with_known_answers(stored):
    from ilcforce.study import read_study

    studies = {name: read_study(stored / "studies" / f"{name}.h5") for name in (page.STUDY, page.WITHHELD_STUDY)}
    table = page.comparison_table(studies).set_index("method")
    assert list(table.index) == ["c2-robust", "no-ilc", "c3"], "tuned study first, in registry order"
    window = f"j = {ITERATIONS - page.LAST}..{ITERATIONS - 1}"
    no_ilc, c2, c3 = table.loc["no-ilc"], table.loc["c2-robust"], table.loc["c3"]
    assert no_ilc[f"ran all {ITERATIONS}"] == 5 and c3[f"ran all {ITERATIONS}"] == 2
    assert no_ilc[f"e_P 2-norm, {window} (m)"].startswith("0.00102 [")  # median of 1.00..1.04 mm
    assert c3[f"e_P 2-norm, {window} (m)"] == "0.00104 [0.00103, 0.00104]"  # seeds 3 and 4 only: 1.03, 1.04 mm
    assert no_ilc[f"e_F 2-norm, {window} (N)"] == "0.1"  # every seed the same: the interval collapses
    assert no_ilc[f"settled H / cap, j = {ITERATIONS - 1} (max over axes)"] == "0.5"
    assert (no_ilc["against the cap"], c2["against the cap"]) == ("within", "over")
    assert no_ilc["diverged"] == "0 of 5" and no_ilc["divergence rate [95% Wilson]"] == "0.00 [0.00, 0.43]"
    wilson = frequency_interval(3, 5)
    assert c3["diverged"] == "3 of 5" and c3["diverged at j (median)"] == 7
    assert c3["divergence rate [95% Wilson]"] == f"0.60 [{wilson.low:.2f}, {wilson.high:.2f}]"
    assert (c2["e_P against no-ilc's"], c2["e_F against no-ilc's"]) == (page.LOWER, page.NOT_SEPARATED)
    assert c3["e_P against no-ilc's"] == page.NOT_SEPARATED and no_ilc["e_P against no-ilc's"] == page.NO_VALUE
    assert c3["diverged at j (range)"] == "7-7" and no_ilc["diverged at j (range)"] == "-"
    assert no_ilc["e_P j = 10 / j = 9 (median)"] == 4.0 and no_ilc["e_P j = 12 / j = 9 (median)"] == 1.0
    assert c3["e_P j = 10 / j = 9 (median)"] == 4.0, "the seeds that diverged before the change are left out"
    assert set(table["gains"]) == {"tuned by fivebar-tune", "the paper's (the tuning withheld it)"}


def test_the_page_is_written_beside_the_long_run_pages(stored, tmp_path):
    from ilcforce.report import long_run

    out = tmp_path / "out"
    written = long_run.write_page(stored, out)  # make long's writer: no long-run store here, this page alone
    assert sorted(p.name for p in written) == sorted([page.PAGE, f"{page.TABLE}.csv", f"{page.TABLE}.md"])
    text = (out / page.PAGE).read_text(encoding="utf-8")
    assert "ilcforce study experiments/long/long-equal-chattering.toml" in text
    assert "ilcforce study experiments/long/long-equal-chattering-withheld.toml" in text
    assert "m3 x 1.4 from j = 10" in text and "seeds 0, 1, 2, 3, 4" in text
    assert "- c3, gains the paper's (the tuning withheld it): diverged in 3 of 5 seeds" in text
    assert "the plant's change multiplies its e_P by 4.00 (e_P j = 10 / j = 9), and e_P j = 12 / j = 9 is 1.00" in text
    assert "on the 2 that ran all, the growth test: no growth" in text  # constant rows: nothing grows
    assert "against no-ilc, its e_P is lower and its e_F not separated" in text
    assert "Settled H at the end over the cap, median [95% interval]: c2-robust 2, no-ilc 0.5, c3 0.512." in text
    assert f"`ilcforce simulate -c {ROOT / 'experiments' / 'paper.toml'} -m METHOD -n {ITERATIONS} --seed SEED` " \
           "(METHOD c3)" in text, "each study's single run, from the experiment its study file names"
    assert ":func:" not in text and "``" not in text


def test_no_tuned_study_no_page(tmp_path):
    """Without the tuned study there is no cap to compare at: nothing written, exit 2 with one line."""
    out = tmp_path / "out"
    assert page.write_page(tmp_path / "results", out) == [] and not out.exists()
    assert page.main(["--results", str(tmp_path / "results"), "--out", str(out)]) == 2


@pytest.mark.parametrize(("a", "b", "expected"), [((1.0, 0.9, 1.1), (2.0, 1.5, 2.5), page.LOWER),
                                                  ((2.0, 1.5, 2.5), (1.0, 0.9, 1.1), page.HIGHER),
                                                  ((1.0, 0.9, 1.6), (2.0, 1.5, 2.5), page.NOT_SEPARATED)])
def test_two_medians_are_ordered_only_when_their_intervals_are_disjoint(a, b, expected):
    from ilcforce.stats import Interval

    assert page.compare(Interval(*a, 5), Interval(*b, 5)) == expected
    assert page.compare(Interval(math.nan, math.nan, math.nan, 0), Interval(*b, 5)) == page.NO_VALUE
