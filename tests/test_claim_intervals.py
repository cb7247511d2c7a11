"""A verdict near its threshold says so: a part whose median's 95% interval crosses its threshold is
"uncertain", and so is a claim whose uncertain parts, read either way, give different verdicts
(ilcforce/report/claims.py, rules 2 and 3). Synthetic seeds whose answer is known by construction."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest

from ilcforce.report import claim_map, claim_parts, claim_seed, claims, verdicts
from ilcforce.report.claim_ranges import FAIL, PARTLY, PASS, above, below, interval_outcomes, within
from ilcforce.report.seedframes import split_seeds

from test_report import good_case, metrics_frame, sequence

#: Claim 5's X magnitude passes from 1.67 / 1.1 = 1.518 to 1.67 x 1.1 = 1.837.
X_LOW_EDGE = 1.67 / 1.1


def _seeds(ratios_x: list[float], ratio_y: float = 0.05 / 0.0205) -> pd.DataFrame:
    """The good case (every claim holds) over one seed per ratio, C3's H on X set so that
    H(C1) / H(C3) on X is that seed's ratio (C1's H on X is 0.06 N), on Y ``ratio_y`` in every seed."""
    frames = []
    for seed, ratio in enumerate(ratios_x):
        case = good_case(c3=metrics_frame(sequence(4, 5.5e-6), sequence(3, 0.055), (0.06 / ratio, 0.05 / ratio_y)))
        frames.append(claims.tidy_from_methods(case, seed=seed))
    return pd.concat(frames, ignore_index=True)


def _claim5(ratios_x: list[float], **kwargs: float) -> pd.DataFrame:
    parts = claims.judge_claims_over_seeds(_seeds(ratios_x, **kwargs))
    return parts[parts["claim"] == 5].set_index("part")


def test_an_interval_that_straddles_the_threshold_is_uncertain() -> None:
    # 3 of 5 seeds inside the range, 2 below its edge 1.518: the majority holds, the median's interval does not
    mine = _claim5([1.45, 1.50, 1.53, 1.56, 1.60])
    row = mine.loc["magnitude_x"]
    assert row["low"] < X_LOW_EDGE < row["high"], row[["median", "low", "high"]].to_dict()
    assert row["part_verdict"] == claims.UNCERTAIN and row["between"] == "holds or fails"
    assert mine.loc["direction_x", "part_verdict"] == claims.HOLDS  # 1.45..1.60 all clear of 1
    # the central parts hold; the secondary one, read either way, makes the claim hold or hold in part
    assert row["verdict"] == claims.UNCERTAIN and row["verdict_between"] == "holds or in part"


@pytest.mark.parametrize(("ratios", "part", "claim"), [
    ([1.60, 1.62, 1.65, 1.67, 1.70], claims.HOLDS, claims.HOLDS),        # clear inside the range
    ([1.30, 1.35, 1.40, 1.42, 1.45], claims.FAILS, claims.IN_PART),      # clear below it; direction still holds
    ([1.90, 2.00, 2.10, 2.20, 2.30], claims.FAILS, claims.IN_PART),      # clear above it
])
def test_an_interval_clear_of_the_threshold_keeps_its_verdict(ratios: list[float], part: str, claim: str) -> None:
    mine = _claim5(ratios)
    assert mine.loc["magnitude_x", "part_verdict"] == part and mine.loc["magnitude_x", "between"] == ""
    assert mine.loc["magnitude_x", "verdict"] == claim and mine.loc["magnitude_x", "verdict_between"] == ""


def test_a_claim_fails_only_when_its_central_parts_fail_clear_of_their_thresholds() -> None:
    # C3 chatters more than C1 on Y in every seed; on X too, or in 2 of 5 seeds (the interval crosses 1)
    clear = _claim5([0.70, 0.75, 0.80, 0.85, 0.90], ratio_y=0.8)
    assert clear.loc["direction_x", "part_verdict"] == claims.FAILS and clear.loc["direction_x", "verdict"] == claims.FAILS
    unsure = _claim5([0.80, 0.90, 1.05, 1.10, 1.20], ratio_y=0.8)
    assert unsure.loc["direction_x", "part_verdict"] == claims.UNCERTAIN
    assert unsure.loc["direction_x", "verdict"] == claims.UNCERTAIN
    assert unsure.loc["direction_x", "verdict_between"] == "in part or fails"
    # with Y's direction holding, X's either way leaves the claim in part: settled, not uncertain
    assert _claim5([0.80, 0.90, 1.05, 1.10, 1.20]).loc["direction_x", "verdict"] == claims.IN_PART


def test_one_seed_and_a_deterministic_setting_are_never_uncertain() -> None:
    # one value's interval is the value itself: 1.50 fails the range, clear
    mine = _claim5([1.50])
    assert mine.loc["magnitude_x", "part_verdict"] == claims.FAILS
    parts = claims.judge_claims_over_seeds(_seeds([1.45, 1.50, 1.53, 1.56, 1.60]), deterministic=True)
    assert claims.UNCERTAIN not in set(parts["part_verdict"]) | set(parts["verdict"])


def test_the_combination_rule() -> None:
    roles = {"a": claims.CENTRAL, "b": claims.CENTRAL, "s": claims.SECONDARY}
    either = frozenset({claims.HOLDS, claims.FAILS})
    verdict = claims.claim_verdict
    assert verdict({"a": "uncertain", "b": "holds", "s": "holds"}, roles, {"a": either}) == claims.UNCERTAIN
    # a clear failure beside a clear hold is "in part" whatever the uncertain part gives
    assert verdict({"a": "holds", "b": "fails", "s": "uncertain"}, roles, {"s": either}) == claims.IN_PART
    assert verdict({"a": "fails", "b": "fails", "s": "uncertain"}, roles, {"s": either}) == claims.FAILS
    assert verdict({"a": "fails", "b": "uncertain", "s": "holds"}, roles, {"b": either}) == claims.UNCERTAIN
    assert claims.claim_verdicts_between({"a": "fails", "b": "uncertain", "s": "holds"}, roles,
                                         {"b": either}) == {claims.FAILS, claims.IN_PART}
    # a central part not evaluable decides whatever the uncertain ones give
    assert verdict({"a": "not evaluable", "b": "uncertain", "s": "holds"}, roles, {"b": either}) == claims.NOT_EVALUABLE
    # between unknown: an uncertain part may be any of the three
    assert verdict({"a": "holds", "b": "uncertain", "s": "holds"}, roles) == claims.UNCERTAIN


def test_interval_outcomes_read_the_edges_as_the_tests_do() -> None:
    assert interval_outcomes(0.5, 0.7, below(0.613, strict=True)) == {PASS, FAIL}
    assert interval_outcomes(0.5, 0.6, below(0.613, strict=True)) == {PASS}
    assert interval_outcomes(0.62, 0.9, below(0.613, strict=True)) == {FAIL}
    # j̄ is an integer and "<= 5" passes at 5: an interval [4, 5] is clear, [5, 6] is not
    assert interval_outcomes(4.0, 5.0, below(5)) == {PASS}
    assert interval_outcomes(5.0, 6.0, below(5)) == {PASS, FAIL}
    assert interval_outcomes(1.0, 1.0, above(1.0, strict=True)) == {FAIL}  # "> 1" fails at 1
    # an interval around the whole range fails at both ends and passes inside it
    assert interval_outcomes(1.0, 3.0, within(1.67, 1.1)) == {PASS, FAIL}
    # claim 2: below the paper's margin, below 1 (in part), or above
    partly = below(1.0, strict=True)
    assert interval_outcomes(0.7, 0.9, below(0.613, strict=True), partly) == {PARTLY}
    assert interval_outcomes(0.9, 1.1, below(0.613, strict=True), partly) == {PARTLY, FAIL}
    assert interval_outcomes(0.5, 1.1, below(0.613, strict=True), partly) == {PASS, PARTLY, FAIL}
    assert interval_outcomes(math.nan, math.nan, below(1.0)) == frozenset()


def test_every_judged_range_is_the_test_its_part_makes() -> None:
    """The range the interval is checked against passes exactly the values the part's own test passes,
    on seeds that put each part on both sides of its threshold."""
    rng = np.random.default_rng(7)
    frames = []
    for seed in range(40):
        scale = rng.uniform(0.5, 2.0, size=6)
        case = {
            "c1": metrics_frame([1e-3 * scale[0]] * 10 + [1e-3 * scale[0] * rng.uniform(1, 3)] * 10,
                                [10.0 * scale[1]] * 10 + [10.0 * scale[1] * rng.uniform(1, 3)] * 10,
                                (0.06, 0.05)),
            "c2": metrics_frame(sequence(int(rng.integers(1, 8)), 1e-5 * scale[2] * 50, jump=rng.uniform(1, 4),
                                         settle=rng.uniform(0.5, 2.5)),
                                sequence(int(rng.integers(1, 8)), 0.1 * scale[3] * 50, jump=rng.uniform(1, 4),
                                         settle=rng.uniform(0.5, 2.5)),
                                (0.05, 0.04)),
            "c3": metrics_frame(sequence(int(rng.integers(1, 8)), 5.5e-6 * scale[4] * 50, jump=rng.uniform(1, 4),
                                         settle=rng.uniform(0.5, 2.5)),
                                sequence(int(rng.integers(1, 8)), 0.055 * scale[5] * 50, jump=rng.uniform(1, 4),
                                         settle=rng.uniform(0.5, 2.5)),
                                (0.06 / rng.uniform(0.8, 2.2), 0.05 / rng.uniform(0.8, 3.0))),
        }
        frames.append(claims.tidy_from_methods(case, seed=seed))
    seeds = split_seeds(pd.concat(frames, ignore_index=True))
    contexts = [claim_seed.Seed(metrics, 10) for metrics in seeds.values()]
    judged = [p for p in claim_parts.PARTS if p.role not in claims.NOT_JUDGED]
    assert all(p.margin is not None for p in judged), "every judged part has a passing range"
    for part in judged:
        outcomes = set()
        for ctx in contexts:
            try:
                value, passed = part.evaluate(ctx)
            except claim_seed.Stop:
                continue
            if math.isfinite(value):
                assert part.margin.contains(value) == passed, (part.key, value, passed)
                outcomes.add(passed)
        assert outcomes == {True, False}, f"{part.key}: the seeds did not put it on both sides"


def test_the_claim_map_shows_and_names_an_uncertain_cell(tmp_path) -> None:
    settings, frames = {}, []
    for scale, ratios in ((0.1, [1.60, 1.62, 1.65, 1.67, 1.70]), (1.0, [1.45, 1.50, 1.53, 1.56, 1.60])):
        name = f"noise.scale = {scale:g}, simulation.sample_time = 0.0001"
        settings[name] = (scale, 1e-4)
        parts = claims.judge_claims_over_seeds(_seeds(ratios))
        frames.append(verdicts.claim_rows(parts, source=verdicts.STUDY, name="claim-map", setting=name))
    rows = claim_map.claim_map(pd.concat(frames, ignore_index=True), settings, dict.fromkeys(settings, 5))
    five = rows[rows["claim"] == 5].set_index("noise_scale")
    assert five.at[0.1, "verdict"] == claims.HOLDS and five.at[1.0, "verdict"] == claims.UNCERTAIN
    assert five.at[1.0, "between"] == "holds or in part" and five.at[1.0, "uncertain_parts"] == "magnitude_x"
    said = claim_map.sentence(rows)
    assert "claim 5 holds in 1 of 2 cells (Ts = 0.1 ms: noise.scale 0.1) and is uncertain in 1 " \
           "(Ts = 0.1 ms: noise.scale 1)" in said, said
    written, _lines = claim_map.write_claim_map(rows, tmp_path, {})
    back = pd.read_csv(tmp_path / "claim_map.csv", keep_default_na=False)
    assert set(back.loc[back["verdict"] == claims.UNCERTAIN, "between"]) == {"holds or in part"}
