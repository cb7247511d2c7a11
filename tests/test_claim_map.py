"""The claim map (noise level x sample time), the shipped calibration study, and the findings summary
(the calibration's fit: tests/test_calibration.py)."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest

from ilcforce.report import calibration, claim_map, claims, readme, verdicts

from test_report import good_case, metrics_frame, sequence


def _rows(case: dict, name: str, setting: str, source: str = verdicts.STUDY, seeds: int = 1) -> pd.DataFrame:
    frames = [claims.tidy_from_methods(case, seed=seed) for seed in range(seeds)]
    parts = claims.judge_claims_over_seeds(pd.concat(frames, ignore_index=True))
    return verdicts.claim_rows(parts, source=source, name=name, setting=setting)


def _map_rows() -> tuple[pd.DataFrame, dict, dict]:
    """Four cells: the good case (every claim holds) at noise 0 and 0.1 ms, C3 30% below C2 in force
    elsewhere (claim 2 in part)."""
    weak_force = good_case(c3=metrics_frame(sequence(4, 5.5e-6), sequence(3, 0.07), (0.0359, 0.0205)))
    settings, frames = {}, []
    for scale in (0.0, 1.0):
        for sample_time in (1e-4, 2.5e-4):
            name = f"noise.scale = {scale:g}, simulation.sample_time = {sample_time:g}"
            settings[name] = (scale, sample_time)
            case = good_case() if (scale, sample_time) == (0.0, 1e-4) else weak_force
            frames.append(_rows(case, "claim-map", name))
    return pd.concat(frames, ignore_index=True), settings, dict.fromkeys(settings, 1)


def test_the_map_has_a_row_per_cell_and_claim_with_the_binding_part() -> None:
    rows = claim_map.claim_map(*_map_rows())
    assert list(rows.columns[:8]) == ["noise_scale", "sample_time", "claim", "verdict", "statistic", "statistic_low",
                                      "statistic_high", "seeds"]
    assert len(rows) == 4 * 5
    two = rows[rows["claim"] == 2].set_index(["noise_scale", "sample_time"])
    assert two.at[(0.0, 1e-4), "verdict"] == "holds"
    assert two.at[(1.0, 1e-4), "verdict"] == "in part"
    # the binding part is the force ratio 0.07 / 0.1, the one part that misses the threshold
    assert two.at[(1.0, 1e-4), "part"].startswith("force_")
    assert two.at[(1.0, 1e-4), "statistic"] == pytest.approx(0.7)
    assert two.at[(1.0, 1e-4), "margin"] < 0 <= two.at[(0.0, 1e-4), "margin"]
    said = claim_map.sentence(rows)
    assert "claim 2 holds in 1 of 4 cells (Ts = 0.1 ms: noise.scale 0)" in said
    assert "every claim holds together only at Ts = 0.1 ms: noise.scale 0" in said


def test_the_heat_maps_and_csv_are_written(tmp_path) -> None:
    rows = claim_map.claim_map(*_map_rows())
    written, lines = claim_map.write_claim_map(rows, tmp_path, {2: "After convergence ..."})
    names = sorted(p.name for p in written)
    assert names == ["claim_map.csv", *[f"fig_claim_map_{k}.png" for k in range(1, 6)]]
    assert all(p.stat().st_size > 5_000 for p in written if p.suffix == ".png")
    back = pd.read_csv(tmp_path / "claim_map.csv")
    assert len(back) == 20 and set(back["verdict"]) <= set(claims.VERDICTS)
    assert lines[2] == claim_map.sentence(rows)


def _findings() -> str:
    bad = good_case(c3=metrics_frame(sequence(4, 5.5e-6), sequence(3, 0.07), (0.0359, 0.0205)))
    claim_rows = pd.concat([_rows(good_case(), "paper-calibrated-mc", "-", seeds=20),
                            _rows(bad, "paper-mc", "-", seeds=20),
                            _rows(bad, "paper", "paper", source=verdicts.EXPERIMENT)], ignore_index=True)
    map_rows, settings, _seeds = _map_rows()
    sentence = claim_map.sentence(claim_map.claim_map(map_rows, settings, _seeds))
    entry = {"rows": [{"method": "c3", "divergence": "j = 115 (5 of 5 seeds)"},
                      {"method": "c2", "divergence": "stable through j = 149 (0 of 5)"}], "seeds": 5}
    studies = {"paper-mc": {"description": "paper", "settings": {"-": {"rows": [], "seeds": 20}}},
               "paper-calibrated-mc": {"description": "cal", "settings": {"-": {"rows": [], "seeds": 20}}},
               "claim-map": {"description": "map", "settings": {}, "claim_map_sentence": sentence,
                             "claim_map_seeds": 5},
               "long-run-mc": {"description": "long", "settings": {"-": entry}}}
    stability = pd.DataFrame(columns=verdicts.STABILITY_COLUMNS)
    return readme.findings_markdown({"paper": {"description": "seed 0", "diverged": {}, "iterations": 20}}, studies,
                                    claims=claim_rows, stability=stability)


def test_the_findings_lead_with_a_summary_of_at_most_12_kb() -> None:
    text = _findings()
    summary = text.split(readme.SUMMARY_END, 1)[0]
    assert readme.summary_size(text) <= readme.SUMMARY_LIMIT, readme.summary_size(text)
    assert summary.index("## Summary") < summary.index("**Claim 1.**") < summary.index("### Headline results")
    # per claim: the paper's numbers, ours at both setups with the bootstrap interval named, the verdict
    assert "Table 2 (at j̄): position 4.3e-6 / 7.6e-6 m = 0.566" in summary
    assert "95% bootstrap interval of the median" in summary and "seeds 5-95%" in summary
    two = summary.split("**Claim 2.**", 1)[1].split("**Claim 3.**", 1)[0]
    assert "Calibrated ([`paper-calibrated-mc`](studies/paper-calibrated-mc/findings.md), 20 seeds): **holds**" in two
    assert "Our noise ([`paper-mc`](studies/paper-mc/findings.md), 20 seeds): **in part**" in two
    assert "margin -14% of the threshold" in two, two
    # a part that does not hold says by how much: its number and threshold beside its verdict
    assert "not holding: C3 below C2 by the paper's margin before the perturbation, force: 0.7 (< 0.613: in part)" \
        in two, two
    # claim 5's judged number named as claims.csv names it
    five = summary.split("**Claim 5.**", 1)[1].split("###", 1)[0]
    assert "Judged on: H(C1) / H(C3) at j = 19, H on the whole grid (the paper's)." in five, five
    assert "The single run `paper` (seed 0 of our noise): in part" in two
    # the headline results: the claim map's sentence and the long runs' divergence
    assert "claim 2 holds in 1 of 4 cells" in summary and "c3: j = 115 (5 of 5 seeds)" in summary
    # the per-study tables are on the study pages: one line each here
    assert "| setting |" not in text


def test_the_summary_names_what_is_missing(monkeypatch) -> None:
    from ilcforce.report import long_run

    monkeypatch.setattr(long_run, "committed_summary", lambda directory=None: None)  # no make long page either
    text = readme.findings_markdown({}, {}, claims=pd.DataFrame(columns=verdicts.CLAIM_COLUMNS),
                                    stability=pd.DataFrame(columns=verdicts.STABILITY_COLUMNS))
    assert "Claim map: no claim-map study in these results." in text
    assert "Long runs: no long-run study in these results, and no `make long` summary." in text
    # a study not run is named, not linked: its page is not in the report (no dead link)
    assert "Calibrated (`paper-calibrated-mc`, not run): not run" in text
    assert "](studies/" not in text


def test_the_shipped_claim_map_and_calibration_studies() -> None:
    """The reproduce map (5 seeds a cell) and make claim-map's (20) sweep the same grid: noise.scale 0
    and log-spaced levels up to 1 (six or more), sample times 0.05, 0.1 and 0.25 ms; the calibration
    sweeps noise.scale alone; the shipped calibrated setup is the paper's with only noise.scale changed."""
    from ilcforce.config_load import load_config
    from ilcforce.study import load_study

    small, full = load_study("experiments/claim-map.toml"), load_study("experiments/full/claim-map-full.toml")
    assert full.name == "claim-map-full" and len(small.seeds) == 5 and len(full.seeds) == 20
    assert small.sweep == full.sweep and small.methods == full.methods == ("c1", "c2", "c3")
    scales = small.sweep["noise.scale"]
    assert scales[0] == 0 and scales[-1] == 1 and len(scales) >= 6
    steps = np.diff(np.log(scales[1:]))
    np.testing.assert_allclose(steps, steps[0], rtol=0.02, err_msg="log-spaced above 0")
    assert set(small.sweep["simulation.sample_time"]) >= {5e-5, 1e-4, 2.5e-4}
    assert claim_map.is_claim_map_study(type("R", (), {"sweep_keys": list(small.sweep), "labelled": False})())
    calib = load_study("experiments/calibration.toml")
    assert list(calib.sweep) == ["noise.scale"] and len(calib.seeds) >= 10
    shipped, paper_setup = load_config("experiments/paper-calibrated.toml"), load_config("experiments/paper.toml")
    assert 0 < shipped.noise.scale < 1
    import dataclasses
    assert dataclasses.replace(shipped.noise, scale=1.0) == paper_setup.noise
    assert shipped.gains == paper_setup.gains and shipped.simulation == paper_setup.simulation
