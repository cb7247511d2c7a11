"""The study report: numbers over seeds with their intervals, claims as frequencies, figures, index."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from ilcforce.experiment import run_method
from ilcforce.report.build import write_report
from ilcforce.report.study import key_numbers, per_seed_numbers
from ilcforce.stats import format_interval, median_interval
from ilcforce.study import read_study, run_study

from test_study import SMALL, small_study


@pytest.fixture(scope="module")
def results(tmp_path_factory):
    """A results folder with a 1-D sweep study, a 2-D sweep study and one single run."""
    root = tmp_path_factory.mktemp("results")
    one = small_study(name="sweep1", seeds="0-2", methods=("c1", "c2", "c3"),
                      sweep={"c3.eta": [5.0, 2.0]})
    two = small_study(name="sweep2", seeds="0-1", methods=("c3",),
                      sweep={"c3.eta": [5.0, 2.0], "simulation.torque_bound": [1e3, 1.0]})
    run_study(one, root, workers=1)
    run_study(two, root, workers=1)
    from ilcforce.config_load import load_config

    run_method(load_config(None, {"reference.duration": 0.2, "experiment.iterations": 3}), "c1",
               root / "paper" / "c1.h5")
    out = root / "report"
    summary = write_report(root, out, formats=("png",), jobs=1)
    return root, out, summary


def test_key_numbers_are_medians_with_bootstrap_intervals(results):
    root, _out, _summary = results
    study = read_study(root / "studies" / "sweep1.h5")
    frame = study.setting_metrics(1)
    table = key_numbers(frame, ["c1", "c2", "c3"], 3).set_index("quantity")
    # recompute one number independently from the tidy frame
    c3 = frame[(frame["method"] == "c3") & (frame["iteration"] == 2)].sort_values("seed")
    expected = format_interval(median_interval(c3["force_error_2norm"].to_numpy()))
    assert table.loc["force 2-norm at j = 2 (N)", "c3"] == expected
    assert "[" in expected, "three distinct seeds give a proper interval"
    numbers = per_seed_numbers(frame, ["c1", "c2", "c3"], 3)
    h1 = frame[(frame["method"] == "c1") & (frame["iteration"] == 2)].sort_values("seed")["chattering_task_x"]
    h3 = c3["chattering_task_x"]
    np.testing.assert_allclose(numbers["H(C1) / H(C3) at j = 2, H on the whole grid (the paper's), x (shown, not judged)"]["ratio"], h1.to_numpy() / h3.to_numpy(),
                               rtol=0, atol=0, err_msg="ratios are taken seed by seed (common random numbers)")


def test_report_leads_with_studies_beside_single_runs(results):
    _root, out, summary = results
    assert set(summary.studies) == {"sweep1", "sweep2"} and "paper" in summary.experiments
    index = (out / "index.md").read_text(encoding="utf-8")
    assert index.index("## Studies") < index.index("[paper](paper/report.md)")
    assert "(studies/sweep1/report.md)" in index and "(studies/sweep2/report.md)" in index
    assert not any("studies" in w and "skipped" in w for w in summary.warnings), summary.warnings


def test_study_report_contents(results):
    _root, out, _summary = results
    text = (out / "studies" / "sweep1" / "report.md").read_text(encoding="utf-8")
    assert "percentile-bootstrap" in text and "## Setting 1: c3.eta=2.0" in text
    assert "### The paper's claims over seeds" in text and " of 3 seeds" in text
    for k in (0, 1):
        for stem in ("fig3_position_error_norm", "fig4_force_error_norm"):
            assert (out / "studies" / "sweep1" / f"{stem}_s{k}.png").stat().st_size > 0
    assert (out / "studies" / "sweep1" / "sweep_key_numbers.png").stat().st_size > 0
    # Figs. 5-7 over seeds, per setting, with the caption saying what is banded
    assert "### Figs. 5-7 over seeds" in text and "per-iteration metrics, not time signals" in text
    for k in (0, 1):
        for stem in ("fig5_tracking_error_seeds", "fig6_input_x_seeds", "fig7_input_y_seeds"):
            assert (out / "studies" / "sweep1" / f"{stem}_s{k}.png").stat().st_size > 10_000
            assert f"]({stem}_s{k}.png)" in text
    heat = out / "studies" / "sweep2" / "sweep_divergence_heatmap.png"
    assert heat.stat().st_size > 0
    text2 = (out / "studies" / "sweep2" / "report.md").read_text(encoding="utf-8")
    # a 1 N m torque bound stops C3 at once; the paper's 1e3 N m does not within 3 short iterations
    assert "stable through 2 (2 seeds)" in text2 and "j = 0 (2 of 2 seeds)" in text2


def test_a_damaged_study_store_is_a_warning_not_a_crash(tmp_path):
    (tmp_path / "studies").mkdir()
    (tmp_path / "studies" / "broken.h5").write_bytes(b"\x89HDF\r\n\x1a\n" + b"\0" * 100)
    summary = write_report(tmp_path, tmp_path / "report", formats=("png",))
    assert any("broken.h5" in w for w in summary.warnings)
    assert summary.studies == ()


def test_study_findings_and_boundary_figure(results):
    """The findings page of a study: per setting the first diverged iteration, the flags
    and the claims; for a one-key sweep, the stability-boundary figure; and the README section."""
    from ilcforce.report.study_findings import first_divergence

    _root, out, _summary = results
    page = (out / "studies" / "sweep1" / "findings.md").read_text(encoding="utf-8")
    assert "## Overview" in page and "c3.eta = 5" in page and "c3.eta = 2" in page
    from matplotlib.image import imread

    drawn = imread(out / "studies" / "sweep1" / "fig_stability_boundary.png")[..., :3]
    # data drawn, not only axes: two empty panels with their labels ink 1.7% of the pixels at the report's
    # dpi, this figure 3.2% (a byte count stood here before; it moved with the dpi, not with the content)
    assert (drawn < 0.9).any(axis=-1).mean() > 0.025, "the boundary figure shows no data"
    assert not (out / "studies" / "sweep2" / "fig_stability_boundary.png").exists(), "two keys: no 1-D figure"
    findings = (out / "findings.md").read_text(encoding="utf-8")
    # the findings link each study's page (its tables are there), after the summary, before the single runs
    link = "[`sweep1`](studies/sweep1/findings.md)"
    assert link in findings and findings.index(link) < findings.index("**`paper`**")
    assert findings.index("## Summary") < findings.index("## Per study") < findings.index(link)
    # the first diverged iteration is the first iteration with status "diverged", per seed and method
    import pandas as pd

    frame = pd.DataFrame({"seed": [0, 0, 0, 1, 1], "method": ["c3"] * 5, "iteration": [0, 1, 2, 0, 1],
                          "status": ["complete", "complete", "diverged", "complete", "complete"]})
    div = first_divergence(frame).set_index("seed")
    assert div.at[0, "diverged_at"] == 2 and np.isnan(div.at[1, "diverged_at"])
    assert list(div["iterations"]) == [3, 2]


@pytest.mark.slow  # among the slowest of the suite (8-28 s); `make test-slow` runs it
def test_report_on_two_processes_is_the_same_files_with_progress(results, tmp_path):
    """Experiments, study reports and findings pages run as pool tasks: the files are byte for byte
    those of the one-process report, and the workers' progress lines reach the caller."""
    root, out, _summary = results
    lines: list[str] = []
    summary = write_report(root, tmp_path / "par", formats=("png",), jobs=2, progress=lines.append)
    ours = sorted(p.relative_to(tmp_path / "par") for p in (tmp_path / "par").rglob("*") if p.is_file())
    theirs = sorted(p.relative_to(out) for p in out.rglob("*") if p.is_file())
    assert ours == theirs and len(ours) > 20
    for relative in ours:
        assert (tmp_path / "par" / relative).read_bytes() == (out / relative).read_bytes(), relative
    assert summary.studies == _summary.studies and summary.warnings == _summary.warnings
    assert "study sweep1: setting 2 of 2" in lines, "a worker's own progress line is shown"
    assert lines[0].startswith("1 experiment(s), 2 study report(s), 2 findings page(s) on 2 process(es)")
    assert sum(" done (" in line for line in lines) == 5 and lines[-1].endswith("(5 of 5)")


def test_report_command_shows_progress_and_quiet_silences_it(results, tmp_path, monkeypatch):
    """The command passes its progress printer to the report (one "report: ..." line each on
    stderr), and none with --quiet. The report itself is the real one, without figures (speed)."""
    from typer.testing import CliRunner

    import ilcforce.report.build as build
    from ilcforce.cli.main import app

    real = build.write_report
    monkeypatch.setattr(build, "write_report", lambda *a, **k: real(*a, **{**k, "formats": ()}))
    root, _out, _summary = results
    runner = CliRunner()
    loud = runner.invoke(app, ["report", "--results", str(root), "--out", str(tmp_path / "a"), "--jobs", "1"])
    quiet = runner.invoke(app, ["report", "--results", str(root), "--out", str(tmp_path / "b"), "--jobs", "1",
                                "--quiet"])
    assert loud.exit_code == 0 and quiet.exit_code == 0, (loud.output, quiet.output)
    assert "report: study sweep1: setting 1 of 2" in loud.stderr and "done (5 of 5)" in loud.stderr
    assert "report:" not in quiet.stderr and "written to" in quiet.stdout


def test_single_run_report_shows_the_bands_of_the_study_of_its_setup(results):
    """the paper run's Figs. 3-7 get the bands over seeds of the study that ran the
    same setup (here sweep1's setting 0: same config for C1, the seed apart), linked into its report."""
    _root, out, _summary = results
    text = (out / "paper" / "report.md").read_text(encoding="utf-8")
    for stem in ("fig3_position_error_norm", "fig5_tracking_error_seeds", "fig6_input_x_seeds", "fig7_input_y_seeds"):
        link = f"../studies/sweep1/{stem}_s0.png"
        assert f"]({link})" in text, stem
        assert (out / "paper" / link).resolve().stat().st_size > 10_000, "the link points at a drawn figure"
    assert "from study [`sweep1`](../studies/sweep1/report.md)" in text and "methods c1)" in text


def test_a_study_matches_only_the_same_setup():
    from ilcforce.config_load import load_config
    from ilcforce.report.study_match import _same

    base = load_config(None, {"experiment.iterations": 3}).to_dict()
    other_seed = load_config(None, {"experiment.iterations": 3, "experiment.seed": 7}).to_dict()
    c3_gain = load_config(None, {"experiment.iterations": 3, "c3.eta": 2.0}).to_dict()
    longer = load_config(None, {"experiment.iterations": 30}).to_dict()
    noise = load_config(None, {"experiment.iterations": 3, "noise.encoder": 0.0}).to_dict()
    assert _same(base, other_seed, "c3"), "the seed apart"
    assert _same(base, c3_gain, "c1") and not _same(base, c3_gain, "c3"), "only the method's own gains count"
    assert not _same(base, longer, "c1"), "a 3-iteration study does not stand for a 30-iteration run"
    assert not _same(base, noise, "c1")


def test_a_few_diverged_seeds_are_listed_not_given_an_interval():
    """Two diverged seeds out of 100 read "j = 14.5 [12, 17]": a median and a 95% interval that were
    only the middle and the range of two values. Up to four are listed; more get the interval."""
    import math

    from ilcforce.report.study_findings import _divergence_text

    def div(firsts, n):
        return pd.DataFrame({"seed": range(n), "method": "c3", "iterations": 20,
                             "diverged_at": list(firsts) + [math.nan] * (n - len(firsts))})

    assert _divergence_text(div([17, 12], 100)) == "j = 12, 17 (2 of 100 seeds)"
    assert _divergence_text(div([], 20)) == "stable through j = 19 (0 of 20)"
    many = _divergence_text(div([3, 4, 5, 6, 7, 8], 10))
    assert many.startswith("j = 5.5 [") and many.endswith("(6 of 10 seeds)")


def test_findings_judge_each_setting_with_its_own_perturbation_and_last_iteration(tmp_path):
    """A study of 4 iterations with the m3 change at j = 2 or 3: the findings page (and the README's
    section) judged it with the paper's p = 10 and read key numbers at j = 19 only, so claim 4 was
    'not evaluable' and every key number '-', while the study's own report judged it with p = 2."""
    from ilcforce.report import claims, verdicts
    from ilcforce.report.study_findings import study_markdown

    from ilcforce.study import build_study

    study = build_study({"study": {"name": "short", "seeds": "0-1", "methods": ["c1", "c2", "c3"],
                                   "set": {**SMALL, "experiment.iterations": 4},
                                   "sweep": {"plant.perturbation.from_iteration": [2, 3]}}})
    run_study(study, tmp_path, workers=1)
    results = read_study(tmp_path / "studies" / "short.h5")
    page, summary, claim_rows, _stability = study_markdown(results)
    for setting, p in ((0, 2), (1, 3)):
        frame = results.setting_metrics(setting)
        expected = claims.claim_summary(claims.judge_claims_over_seeds(frame, perturbation_iteration=p))
        name = f"plant.perturbation.from_iteration = {p}"
        entry = summary[name]
        judged = verdicts.claim_verdicts(claim_rows[claim_rows["setting"] == name])
        assert judged == dict(zip(expected["claim"], expected["verdict"])), (judged, p)
        # claim 4 is judged at the setting's own p: its rise at p is read (with p = 10 nothing could
        # be); reconvergence needs the window p+5..p+9, which 4 iterations do not reach
        mine = claim_rows[(claim_rows["setting"] == name) & (claim_rows["claim"] == 4)].set_index("part")
        assert mine.at["c2_strong_position", "seeds_evaluated"] == 2, "claim 4 is judged at the setting's own p"
        assert "needs iterations up to at least" in mine.at["c2_again_position", "note"]
        last = frame[(frame["method"] == "c3") & (frame["iteration"] == 3)]["force_error_2norm"]
        row = next(r for r in entry["rows"] if r["method"] == "c3")
        assert row["|e_F| 2-norm (N) at j = 3"] == format_interval(median_interval(last.to_numpy())) != "-"
        assert f"Judged here at this setting's change of the plant, j = {p}." in page, "claims 1 and 4 say where"
        said = expected.set_index("claim")["statement"]
        assert said[4].endswith(f"j = {p}.") and said[1].endswith(f"j = {p}.") and "Judged" not in said[5]
    paper_setup = claims.claim_summary(claims.judge_claims_over_seeds(frame, perturbation_iteration=10))
    assert not paper_setup["statement"].str.contains("Judged here").any(), "the paper's p: as stated"


def test_a_stopped_study_is_reported_as_incomplete_until_it_is_finished(tmp_path):
    """A study whose latest run was stopped says so, with the numbers, in its report, the index and
    the findings; the finished study does not. Only the latest plan's cells count: a rerun with other
    seeds that stops early is incomplete however many earlier cells are stored."""
    from ilcforce.report import verdicts
    from ilcforce.report.readme import findings_markdown
    from ilcforce.report.study import incomplete_text, write_study_report
    from ilcforce.report.study_findings import write_study_findings
    from ilcforce.study import load_study
    from ilcforce.study.cell import run_cell

    from test_study import TINY_TOML, write_study_file

    calls = []

    def stops_after(n):
        def cell(config, method, keep):
            if len(calls) == n:
                raise KeyboardInterrupt  # the user's Ctrl-C during cell n + 1
            calls.append(method)
            return run_cell(config, method, keep)
        return cell

    study = load_study(write_study_file(tmp_path, TINY_TOML))  # 2 settings x 2 seeds x 2 methods
    with pytest.raises(KeyboardInterrupt):
        run_study(study, tmp_path, workers=1, cell_function=stops_after(3))
    path = tmp_path / "studies" / "tiny.h5"
    expected = "Incomplete: 3 of the 8 planned cells are stored"
    assert expected in incomplete_text(read_study(path))
    report = write_study_report(path, tmp_path / "report")
    assert expected in (tmp_path / "report" / "tiny" / "report.md").read_text(encoding="utf-8")
    assert expected in "\n".join(report.index_lines)
    assert any("incomplete" in w for w in report.warnings)
    _written, name, found = write_study_findings(path, tmp_path / "findings")
    assert expected in (tmp_path / "findings" / "tiny" / "findings.md").read_text(encoding="utf-8")
    rows = {key: verdicts.read_back(tmp_path / "findings" / "tiny" / f"{key}.csv") for key in ("claims", "stability")}
    assert expected in findings_markdown({}, {name: found}, **rows)
    run_study(study, tmp_path, workers=1)  # the rerun finishes it
    assert incomplete_text(read_study(path)) == ""
    other = load_study(write_study_file(tmp_path, TINY_TOML.replace('seeds = "0-1"', 'seeds = "2-3"')))
    calls.clear()
    with pytest.raises(KeyboardInterrupt):
        run_study(other, tmp_path, workers=1, cell_function=stops_after(1))
    results = read_study(path)
    assert len(results.cells) == 9 and results.planned_cells == 8
    assert "Incomplete: 1 of the 8 planned cells are stored" in incomplete_text(results)
    assert 'seeds = "2-3"' in results.latest_study_toml and 'seeds = "0-1"' in results.study_toml


@pytest.mark.parametrize("stored_name", ["/abs/elsewhere", "../../../escaped", "a/b", ".."])
def test_a_stored_study_name_never_makes_a_path_outside_the_report(tmp_path, stored_name):
    """A study store whose name attribute was a path (edited or damaged) made the report write, and
    overwrite, files outside --out (found by an attack on the CLI). Readers now take such a store
    for the damaged file it is: validate refuses it, the report skips it with a warning."""
    import h5py

    from ilcforce.store.study_read import StudyStoreError, check_study_store
    from ilcforce.study import load_study

    from test_study import TINY_TOML, write_study_file

    run_study(load_study(write_study_file(tmp_path, TINY_TOML)), tmp_path / "results", workers=1)
    path = tmp_path / "results" / "studies" / "tiny.h5"
    target = (tmp_path / "results" / "report" / stored_name).resolve() if not stored_name.startswith("/") \
        else tmp_path / "abs" / "elsewhere"
    from ilcforce.store.seal import seal_attrs

    with h5py.File(path, "r+") as handle:
        handle.attrs["name"] = str(tmp_path / "abs" / "elsewhere") if stored_name.startswith("/") else stored_name
        seal_attrs(handle)  # as a writer would (unsealed, the checksum refuses it first)
    with pytest.raises(StudyStoreError, match="not a plain file name"):
        check_study_store(path)
    before = sorted(p for p in tmp_path.rglob("*") if "report" not in p.parts)
    summary = write_report(tmp_path / "results", tmp_path / "results" / "report", formats=("png",), jobs=1)
    assert summary.studies == () and any("tiny.h5" in w for w in summary.warnings)
    assert sorted(p for p in tmp_path.rglob("*") if "report" not in p.parts) == before
    assert not target.exists() or target == (tmp_path / "results").resolve()


def test_the_findings_agree_with_claims_csv_row_for_row(results):
    """Verdicts are data: every claim verdict, every judged part and every stability row the
    findings state is a row of the report's claims.csv / stability.csv (read here with plain pandas,
    not the report's reader), and every study writes the same rows beside its own report."""
    import re

    _root, out, _summary = results
    findings = (out / "findings.md").read_text(encoding="utf-8")
    rows = pd.read_csv(out / "claims.csv", keep_default_na=False, na_values=[""])
    assert set(rows["source"]) == {"study", "experiment"}
    heads = rows[rows["role"] == "claim"]
    # the single run: "Claim k **verdict**" once per claim, with its judged parts' verdicts in order
    paper = heads[heads["name"] == "paper"]
    section = findings.split("**`paper`**", 1)[1]
    stated = dict(re.findall(r"\* Claim (\d) \*\*([a-z ]+)\*\*", section))
    assert {int(k): v for k, v in stated.items()} == dict(zip(paper["claim"], paper["verdict"], strict=True))
    judged = rows[(rows["name"] == "paper") & rows["role"].isin(["central", "secondary"])]
    for row in judged.itertuples(index=False):
        assert f"{row.part_text}: " in section and f"{row.threshold} {row.verdict}" in section, row
    # the studies: each setting's line of the study page's overview carries that setting's claim
    # verdicts from the rows (the findings link the page)
    for name in ("sweep1", "sweep2"):
        mine = heads[heads["name"] == name]
        own = pd.read_csv(out / "studies" / name / "claims.csv", keep_default_na=False, na_values=[""])
        assert len(own) == len(rows[rows["name"] == name]), "the study's claims.csv holds the same rows"
        assert f"[`{name}`](studies/{name}/findings.md)" in findings
        page = (out / "studies" / name / "findings.md").read_text(encoding="utf-8")
        for setting, verdicts_of in mine.groupby("setting"):
            line = next(line for line in page.splitlines() if line.startswith(f"| {setting} |"))
            cells = [c.strip() for c in line.strip("|").split("|")]
            assert cells[2:2 + len(verdicts_of)] == list(verdicts_of.sort_values("claim")["verdict"]), (line, setting)
    stability = pd.read_csv(out / "stability.csv")
    assert list(stability.columns[:3]) == ["source", "name", "setting"]
    for row in stability[stability["flagged"]].itertuples(index=False):
        assert f"Unstable learning, {row.method}" in findings or row.source == "study", row


def test_report_on_a_sweep_whose_setting_diverges_in_every_cell(tmp_path):
    """A setting that diverges for every seed and method (a wall a million times stiffer): the
    report's divergence table took the count of diverged seeds for the setting's index and stopped
    with a KeyError and a 100-line traceback (found by an attack); it is now written, and says so."""
    from typer.testing import CliRunner

    from ilcforce.cli.main import app
    from ilcforce.study import run_study
    from ilcforce.study.spec import build_study

    study = build_study({"study": {"name": "stiff", "seeds": "0-1", "methods": ["c1", "c3"],
                                   "set": {"experiment.iterations": 2, "reference.duration": 0.2},
                                   "sweep": {"wall.stiffness": [1000.0, 1e9]}}})
    run_study(study, tmp_path / "results", workers=1)
    result = CliRunner().invoke(app, ["report", "--results", str(tmp_path / "results"), "--out",
                                      str(tmp_path / "out"), "--jobs", "1", "--quiet"])
    assert result.exit_code == 0, result.output
    text = "\n".join(p.read_text(encoding="utf-8") for p in (tmp_path / "out").rglob("*.md"))
    assert "j = 0 (2 of 2 seeds)" in text, text[:2000]


def test_the_number_tables_call_judged_is_the_one_claims_csv_judges(tmp_path):
    """Claim 5 was judged on H over the whole grid (claims.csv, docs/model.md) while the study tables
    labelled the settled ratio "(judged by claim 5)". Now each label a table tags "judged by claim k"
    names exactly the statistic claims.csv judges claim k's central parts on, and the settled ratio is
    "(shown, not judged)", in every report file that writes key numbers."""
    import re

    from ilcforce.report import claim_parts

    study = small_study(name="judged", seeds="0-1", methods=("c1", "c3"),
                        set={**SMALL, "experiment.iterations": 20})
    root = tmp_path / "results"
    run_study(study, root, workers=1)
    out = tmp_path / "report"
    write_report(root, out, formats=("png",), jobs=1)
    claims_csv = pd.read_csv(out / "claims.csv", keep_default_na=False)
    mine = claims_csv[(claims_csv["name"] == "judged") & (claims_csv["role"] == "central")]
    tables = sorted((out / "studies" / "judged").glob("key_numbers_s*.csv"))
    assert tables, "the study wrote its key numbers"
    tagged = []
    for table in tables:
        for label in pd.read_csv(table, keep_default_na=False)["quantity"]:
            found = re.fullmatch(r"(.*), (\w) \(judged by claim (\d)\)", label)
            if found:
                tagged.append(label)
                name, axis, claim = found.group(1), found.group(2), int(found.group(3))
                judged = mine[(mine["claim"] == claim) & mine["part"].str.endswith(f"_{axis}")]
                assert len(judged) and set(judged["statistic_name"]) == {name}, (label, judged)
            elif "judged" in label:
                assert label.endswith(claim_parts.SHOWN_TAG), label
    assert len(tagged) == 2 * len(tables), tagged  # x and y, at j = 19
    assert all("settled" not in label for label in tagged)
    text = (out / "studies" / "judged" / "report.md").read_text(encoding="utf-8")
    assert f"{claim_parts.h_ratio_name(19, '_settled')}, y {claim_parts.SHOWN_TAG}" in text
