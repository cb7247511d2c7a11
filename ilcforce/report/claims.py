"""The paper's five claims (docs/model.md#claims), judged part by part over seeds from OUR numbers.

Input is a tidy metrics frame for ONE setting (columns ``seed``, ``method``, ``iteration`` and the
metric columns of :data:`ilcforce.metrics.METRIC_COLUMNS`); a single run is the one-seed case,
so the single-run report and the studies share this code. The paper's figures are shown beside
ours; they never enter a verdict, except where a claim *is* a paper number (claim 5's magnitude) or
a threshold is derived from one (claim 3's "a few iterations": the paper's slowest j̄ plus one;
claim 2's ratio: the largest C3 / C2 Table 2's printed numbers allow). Claims 1, 2 and 4 are read
on 5-iteration converged windows and claim 5 on H over the whole grid (the paper's definition); the
reasons are stated with each claim's rule (:mod:`ilcforce.report.claim_parts`).
``tests/test_claims_paper.py`` feeds the paper's own Table 2 and Table 3 through these rules: every
claim holds.

How a verdict is reached (stated once, used for every claim)
-------------------------------------------------------------
1. Each claim is split into **parts**. A part is evaluated per seed: a number (its statistic)
   and pass / fail against a stated threshold, or "not evaluable" (missing data). A part with a
   weaker reading (claim 2: C3 below C2 at all, by less than the paper's margin) also says whether
   a failing value meets that. A part whose asserted method diverged within the iterations it
   reads fails in that seed; a baseline (a method claimed worse) that diverged counts as an
   infinite error norm from its divergence on.
2. Over seeds, a part **holds** when it passes in a strict majority of the seeds where it is
   evaluable; it holds **in part** when it does not, but passes or meets its weaker reading in a
   strict majority; it **fails** otherwise. It is **not evaluable** with no evaluable seed, or when
   the method it praises diverged in a strict majority of the seeds (the note names where; the
   comparison it asserts does not exist there). Its frequency ("12 of 20 seeds") carries a 95%
   Wilson interval; its statistic is the median over seeds with a 95% percentile-bootstrap
   interval **of the median** (:mod:`ilcforce.stats`), beside the 5-95% spread of the seeds
   themselves (where one seed would fall), and the median's **margin** to the threshold (its
   signed distance to the nearest edge of the passing range as a fraction of that edge, >= 0 on
   the passing side; for "within x1.1 of 1.67" the edges are 1.67 / 1.1 and 1.67 x 1.1).
   A part is **uncertain** when that interval of the median crosses a threshold: a median anywhere
   in it would give more than one of pass, in part (the weaker reading) and fail
   (:func:`ilcforce.report.claim_ranges.interval_outcomes`). It then lies *between* those verdicts
   (and the majority's, should the seeds with an infinite statistic, which the median leaves out,
   decide it). With one seed the interval is the value itself, so a single run or a deterministic
   setting is never uncertain; with 5 seeds the interval reaches about the lowest and the highest
   seed, so a part is uncertain unless every seed's value lies on one side.
3. Each part is **central** (what the claim is about), **secondary** (a qualifier) or **shown**
   (a number printed beside the claim, never judged). A claim is **not evaluable** when a central
   part is; otherwise it **holds** when every judged part holds, **fails** when no central part
   holds or holds in part, and holds **in part** otherwise (some of what it asserts holds: the
   parts say which). With uncertain parts: each is read as every verdict it lies between, and the
   claim's verdict is the one all these readings give; where they give different verdicts the
   claim is **uncertain**, between them. So a claim holds only when every judged part holds with
   its interval clear, and fails only when every central part fails with its interval clear of its
   threshold (and of its weaker reading's); a central part not evaluable makes the claim not
   evaluable whatever the others give.
4. The same rule applied to one seed's part results gives that seed's claim verdict; the claim's
   frequency ("holds in 3 of 20 seeds") counts them. A seed where a method the claim praises diverged
   is counted under no verdict word ("a praised method diverged in 1 of 20 seeds"): the comparison it
   asserts does not exist there, so a claim "not evaluable" for a divergence never reads "fails in 1
   of 1 seed" beside it. A part's own evaluation counts such seeds the same way.
5. A **deterministic** setting (no noise source active: every seed runs the same simulation) is
   one evaluation, judged on its first seed and said as such ("one evaluation, deterministic"),
   never "10 of 10 seeds".
6. Where the judged number has other readings (claim 5's H(C1) / H(C3):
   :data:`ilcforce.report.claim_parts.READINGS`), the same tests are applied to each: H settled (the
   first 20 ms left out, ilcforce.metrics.SETTLED_FROM), H with only the sample at t = 0 left out, and
   the whole-grid ratio read at j = p - 1 (before the plant changes) and at the last iteration C1 and
   C3 both completed (a run beyond j = 19). Each that would change the claim's verdict is stated
   beside it ("fails with the first 20 ms left out (settled, t >= 20 ms); holds read at j = 9, before
   the plant changes, instead of j = 19": the verdict rests on the start at t = 0, or on the iteration
   read); claims.csv's claim row carries it in ``note``. A reading no seed can give (a 20-iteration run
   has no later iteration) says nothing. They never decide the verdict.

Iterations are counted from 0; ``p`` (10 in the paper) is the perturbation iteration. The parts
themselves, with their thresholds, are in :mod:`ilcforce.report.claim_parts`.
"""

from __future__ import annotations

import dataclasses
import itertools
import math
from collections.abc import Mapping

import numpy as np
import pandas as pd

from ilcforce.plants import changed_parameter
from ilcforce.report import paper
from ilcforce.report.claim_parts import (CAUSE, CENTRAL, CLAIMS, PARTS, SECONDARY, parts_for,  # noqa: F401 (re-exported)
                                         READINGS, SHOWN, _Part, statement_at)
from ilcforce.report.claim_ranges import FAIL, PARTLY, PASS, interval_outcomes
from ilcforce.report.claim_seed import Seed, Stop
from ilcforce.report.seedframes import split_seeds
from ilcforce.stats import Interval, frequency_interval, median_interval

#: Roles printed beside a claim, never judged.
NOT_JUDGED = (SHOWN, CAUSE)

HOLDS = "holds"
IN_PART = "in part"
FAILS = "fails"
#: The interval of a median crosses a threshold (rule 2), or a claim's uncertain parts, read either way,
#: give different verdicts (rule 3).
UNCERTAIN = "uncertain"
NOT_EVALUABLE = "not evaluable"
VERDICTS = (HOLDS, IN_PART, FAILS, UNCERTAIN, NOT_EVALUABLE)
#: The verdict of each outcome of a value (:mod:`ilcforce.report.claim_ranges`).
OUTCOME_VERDICT = {PASS: HOLDS, PARTLY: IN_PART, FAIL: FAILS}
#: How a frequency counts a seed where a method the claim praises diverged: no verdict word (rule 4).
DIVERGED = "a praised method diverged"

# ---------------------------------------------------------------------------------------------
# Judging
# ---------------------------------------------------------------------------------------------


def _evaluate(part: _Part, seed: Seed) -> tuple[float, bool | None, str, bool]:
    """(statistic, passed, note, diverged) of one part in one seed."""
    try:
        value, passed = part.evaluate(seed)
        return float(value), passed, "", False
    except Stop as stop:
        return math.nan, stop.passed, stop.note, stop.diverged


def claim_verdict(part_verdicts: Mapping[str, str], roles: Mapping[str, str],
                  between: Mapping[str, frozenset[str]] | None = None) -> str:
    """The stated rule (module docstring, 3): a claim's verdict from its judged parts' verdicts.
    ``between``: part -> the verdicts an uncertain part lies between (all three without it)."""
    found = claim_verdicts_between(part_verdicts, roles, between)
    return next(iter(found)) if len(found) == 1 else UNCERTAIN


def claim_verdicts_between(part_verdicts: Mapping[str, str], roles: Mapping[str, str],
                           between: Mapping[str, frozenset[str]] | None = None) -> frozenset[str]:
    """Every verdict the claim takes when each uncertain judged part is read as each verdict it lies
    between (rule 3): one verdict, or the several an uncertain claim lies between."""
    unsure = [k for k, v in part_verdicts.items() if v == UNCERTAIN and roles[k] in (CENTRAL, SECONDARY)]
    if not unsure:
        return frozenset({_certain_claim_verdict(part_verdicts, roles)})
    options = [sorted((between or {}).get(k) or {HOLDS, IN_PART, FAILS}) for k in unsure]
    return frozenset(_certain_claim_verdict({**part_verdicts, **dict(zip(unsure, combo, strict=True))}, roles)
                     for combo in itertools.product(*options))


def _certain_claim_verdict(part_verdicts: Mapping[str, str], roles: Mapping[str, str]) -> str:
    central = [v for k, v in part_verdicts.items() if roles[k] == CENTRAL]
    judged = [v for k, v in part_verdicts.items() if roles[k] in (CENTRAL, SECONDARY)]
    if NOT_EVALUABLE in central or not central:
        return NOT_EVALUABLE
    if all(v == HOLDS for v in judged):
        return HOLDS
    if all(v == FAILS for v in central):
        return FAILS
    return IN_PART


def part_verdict(outcomes: list[str | None], diverged: int, spans: frozenset[str] = frozenset()) -> str:
    """The stated rule (module docstring, 2) over one part's per-seed outcomes: "pass", "partly"
    (fails the threshold, meets the weaker reading), "fail", None (not evaluable); ``diverged``: the
    seeds among the failures where the praised method diverged; ``spans``: the outcomes the median's
    95% interval spans (:func:`ilcforce.report.claim_ranges.interval_outcomes`): more than one is
    "uncertain"."""
    verdict = _majority_verdict(outcomes, diverged)
    return UNCERTAIN if verdict != NOT_EVALUABLE and len(spans) > 1 else verdict


def part_between(outcomes: list[str | None], diverged: int, spans: frozenset[str]) -> frozenset[str]:
    """The verdicts an uncertain part lies between: those of the outcomes its median's interval spans,
    and the majority's (rule 2). Empty for a part that is not uncertain."""
    if part_verdict(outcomes, diverged, spans) != UNCERTAIN:
        return frozenset()
    return frozenset({OUTCOME_VERDICT[o] for o in spans} | {_majority_verdict(outcomes, diverged)})


def between_text(verdicts) -> str:
    """"holds or fails", "holds, in part or fails": the verdicts an uncertain row lies between, in
    :data:`VERDICTS` order ("" without)."""
    words = [v for v in VERDICTS if v in set(verdicts)]
    return ", ".join(words[:-1]) + " or " + words[-1] if len(words) > 1 else "".join(words)


def judge_part(part: _Part, results: list[tuple[float, bool | None, str, bool]]
               ) -> tuple[str, frozenset[str], Interval]:
    """One judged part over seeds from its per-seed results (statistic, passed, note, diverged): its
    verdict (rule 2), the verdicts it lies between when uncertain, and the median with its 95% interval."""
    values = np.array([r[0] for r in results], dtype=float)
    outcomes = [_outcome(part, r[0], r[1]) for r in results]
    diverged = sum(1 for r in results if r[3])
    stat = median_interval(values)  # an infinite ratio (a diverged baseline) is dropped and counted in n
    spans = interval_outcomes(stat.low, stat.high, part.margin, part.partly) if part.margin is not None else frozenset()
    return part_verdict(outcomes, diverged, spans), part_between(outcomes, diverged, spans), stat


def _majority_verdict(outcomes: list[str | None], diverged: int) -> str:
    judged = [o for o in outcomes if o is not None]
    n = len(judged)
    if n == 0 or 2 * diverged > n:
        return NOT_EVALUABLE
    passed = judged.count("pass")
    if 2 * passed > n:
        return HOLDS
    return IN_PART if 2 * (passed + judged.count("partly")) > n else FAILS


def _outcome(part: _Part, value: float, passed: bool | None) -> str | None:
    if passed is None:
        return None
    if passed:
        return "pass"
    partly = part.partly is not None and math.isfinite(value) and part.partly.contains(value)
    return "partly" if partly else "fail"


def spread(values: np.ndarray, low: float = 5.0, high: float = 95.0) -> tuple[float, float]:
    """The 5-95% percentiles of the finite values over seeds (where one seed's value falls; NaN without any)."""
    finite = np.asarray(values, dtype=float)
    finite = finite[np.isfinite(finite)]
    if finite.size == 0:
        return math.nan, math.nan
    return float(np.percentile(finite, low)), float(np.percentile(finite, high))


def _distribution(values: np.ndarray) -> str:
    finite = values[np.isfinite(values)]
    if finite.size == 0 or not np.all(finite == np.round(finite)):
        return ""
    counts = pd.Series(finite.astype(int)).value_counts().sort_index()
    return ", ".join(f"{k}: {v}" for k, v in counts.items())


#: The frequency text of a deterministic setting (module docstring, rule 5).
ONE_EVALUATION = "one evaluation (deterministic: no noise source active, every seed is the same run)"


def is_deterministic(config: Mapping) -> bool:
    """Whether a resolved configuration (the TOML layout as a dict) draws nothing random: the
    disturbance and every sensor noise are 0, or noise.scale is (docs/model.md#noise: 0 turns a source off), so every
    seed gives the same run. A configuration without a ``noise`` table is the paper's: noisy."""
    noise = config.get("noise") if isinstance(config, Mapping) else None
    if not isinstance(noise, Mapping):
        return False
    if noise.get("scale", 1.0) == 0:  # one factor on every source (docs/model.md#noise)
        return True
    sources = ("disturbance_amplitude", "encoder", "joint_rate", "force_sensor")
    return all(isinstance(noise.get(k), (int, float)) and noise.get(k) == 0 for k in sources)


def first_seed_only(metrics: pd.DataFrame) -> pd.DataFrame:
    """The rows of the smallest seed (a deterministic setting's one evaluation)."""
    if metrics.empty or "seed" not in metrics.columns:
        return metrics
    return metrics[metrics["seed"] == metrics["seed"].min()].reset_index(drop=True)


def judge_claims_over_seeds(metrics: pd.DataFrame, *,
                            perturbation_iteration: int = paper.PERTURBATION_ITERATION,
                            deterministic: bool = False, config: Mapping | None = None) -> pd.DataFrame:
    """Every part of every claim, judged over the seeds of one setting.

    ``metrics``: tidy frame, columns ``seed``, ``method``, ``iteration`` + metric columns, one row
    per (seed, method, iteration); ONE setting (one seed for a single run).

    Returns one row per part: ``claim``, ``statement``, ``verdict`` (the claim's, by the stated
    rule), ``claim_frequency`` (e.g. "holds in 3 of 20 seeds"), ``part``, ``part_text``,
    ``role``, ``statistic`` (what the number is), ``median``, ``low``, ``high`` (median over seeds
    and its 95% bootstrap interval), ``distribution`` (counts per value for integer statistics),
    ``passed``, ``evaluable`` (seeds), ``share_low``, ``share_high`` (95% Wilson interval of the
    passing share), ``part_verdict`` ("-" for shown parts), ``notes`` (why a seed could not be
    judged, first reason), ``n_seeds``, ``threshold`` (the pass condition), ``deterministic``,
    ``partial`` (the weaker condition that makes a failing part "in part", "" without one),
    ``margin`` (the median's signed distance to the nearest edge of the passing range as a fraction of
    that edge, >= 0 passing; NaN for shown parts), ``diverged`` (the seeds where the method the part
    praises diverged), ``verdict_beside`` (the claim's verdict on each other reading of its judged number that
    would change it, rule 6, as the verdict line says it; "" when none would), ``verdict_between`` (an
    uncertain claim's verdicts, e.g. "holds or in part", rule 3; "" otherwise), ``between`` (the same for an
    uncertain part, rule 2), ``spread_low``, ``spread_high`` (5th and 95th percentile over seeds).
    :func:`claim_summary` reduces it to one row per claim. ``deterministic``: the setting draws
    nothing random (:func:`is_deterministic`); it is judged once, on its first seed (rule 5).
    ``config``: the setting's resolved configuration (TOML layout), read by the parts that name a
    modelling choice (role ``cause``); without it they are not evaluable.
    """
    if deterministic:
        metrics = first_seed_only(metrics)
    seeds = split_seeds(metrics)
    contexts = {seed: Seed(frames, perturbation_iteration, config) for seed, frames in seeds.items()}
    all_parts = parts_for(metrics.columns)  # claim 5 along the task's axes
    results = {part: [_evaluate(part, ctx) for ctx in contexts.values()] for part in all_parts}
    # the judged parts' same tests on the other readings of their number (rule 6): what the verdict would be
    readings = {(part, key): [_evaluate(dataclasses.replace(part, evaluate=test), ctx) for ctx in contexts.values()]
                for part in all_parts if part.role not in NOT_JUDGED for key, test in part.readings}
    roles = {part.key: part.role for part in all_parts}
    rows, claim_rows = [], {}
    parameter = changed_parameter(config or {})  # the plant's change, as claim 4 names it
    for claim in CLAIMS:
        mine = [part for part in all_parts if part.claim == claim.number]
        verdicts: dict[str, str] = {}
        between: dict[str, frozenset[str]] = {}
        for part in mine:
            values = np.array([r[0] for r in results[part]])
            passes = [r[1] for r in results[part]]
            diverged = sum(1 for r in results[part] if r[3])
            judged = [x for x in passes if x is not None]
            k, n = sum(bool(x) for x in judged), len(judged)
            share = frequency_interval(k, n)
            verdict, between[part.key], stat = judge_part(part, results[part])
            if part.role in NOT_JUDGED:
                verdict = "-"
            else:
                verdicts[part.key] = verdict
            low5, high95 = spread(values)
            margin = (float(part.margin(stat.estimate)) if part.margin is not None and math.isfinite(stat.estimate)
                      else math.nan)
            notes = sorted({r[2] for r in results[part] if r[2]})
            if diverged:
                first = next(r[2] for r in results[part] if r[3])
                notes = [f"{first} ({diverged} of {len(contexts)} seeds diverged)"] + [x for x in notes if x != first]
            rows.append({"claim": claim.number, "statement": statement_at(claim, perturbation_iteration, parameter),
                         "part": part.key,
                         "part_text": part.text, "role": part.role, "statistic": part.statistic,
                         "median": stat.estimate, "low": stat.low, "high": stat.high,
                         "distribution": _distribution(values), "passed": k if part.role not in NOT_JUDGED else pd.NA,
                         "evaluable": n if part.role not in NOT_JUDGED else int(np.isfinite(values).sum()),
                         "share_low": share.low, "share_high": share.high, "part_verdict": verdict,
                         "notes": notes[0] if notes else "", "n_seeds": len(contexts),
                         "threshold": part.threshold, "deterministic": bool(deterministic),
                         "partial": part.partial_text, "margin": margin, "diverged": diverged, "spread_low": low5,
                         "spread_high": high95, "between": between_text(between[part.key])})
        # the same rule per seed: how often the claim as a whole holds; a seed where a method the claim
        # praises diverged is counted as such, not as a verdict (rule 4)
        per_seed = {v: 0 for v in (*VERDICTS, DIVERGED)}
        for index in range(len(contexts)):
            seed_verdicts = {}
            for part in mine:
                if part.role in NOT_JUDGED:
                    continue
                value, passed = results[part][index][0], results[part][index][1]
                outcome = _outcome(part, value, passed)
                seed_verdicts[part.key] = {None: NOT_EVALUABLE, "pass": HOLDS, "partly": IN_PART}.get(outcome, FAILS)
            if any(results[part][index][3] for part in mine if part.role not in NOT_JUDGED):
                per_seed[DIVERGED] += 1
            else:
                per_seed[claim_verdict(seed_verdicts, roles)] += 1
        found = claim_verdicts_between(verdicts, roles, between)
        verdict = next(iter(found)) if len(found) == 1 else UNCERTAIN
        beside = _other_readings(mine, readings, verdicts, roles, verdict, contexts.values(), perturbation_iteration,
                                 between)
        claim_rows[claim.number] = (verdict, per_seed, beside, between_text(found) if len(found) > 1 else "")
    frame = pd.DataFrame(rows)
    if frame.empty:
        return frame
    frame.insert(2, "verdict", frame["claim"].map(lambda c: claim_rows[c][0]))
    frame.insert(3, "claim_frequency", frame["claim"].map(lambda c: _frequency_text(claim_rows[c][1], deterministic)))
    frame.insert(4, "claim_seeds_holding", frame["claim"].map(lambda c: int(claim_rows[c][1][HOLDS])))
    frame.insert(5, "verdict_beside", frame["claim"].map(lambda c: claim_rows[c][2]))
    frame.insert(6, "verdict_between", frame["claim"].map(lambda c: claim_rows[c][3]))
    return frame


def reading_text(key: str, perturbation_iteration: int, last: tuple[int, int] | None = None) -> str:
    """How a verdict line names another reading (rule 6; ``key`` of :data:`READINGS`): "with the first
    20 ms left out (settled, t >= 20 ms)", "read at j = 9, before the plant changes, instead of j = 19", ...
    ``last``: the smallest and largest last iteration C1 and C3 both completed over the seeds."""
    judged = paper.CHATTERING_ITERATION
    if key == "settled":
        return "with the first 20 ms left out (settled, t >= 20 ms)"
    if key == "no_t0":
        return "with only the sample at t = 0 left out (H without t = 0)"
    if key == "before":
        return f"read at j = {perturbation_iteration - 1}, before the plant changes, instead of j = {judged}"
    low, high = last if last is not None else (judged, judged)
    where = f"j = {low}" if low == high else f"j = {low}..{high} (per seed)"
    return f"read at {where}, the last iteration C1 and C3 both completed, instead of j = {judged}"


def _other_readings(mine, readings, verdicts: Mapping[str, str], roles: Mapping[str, str], verdict: str,
                    contexts, perturbation_iteration: int, between: Mapping[str, frozenset[str]]) -> str:
    """Rule 6: "<verdict> <reading>" for every other reading of the judged number that would change the
    claim's verdict, joined by "; " ("" when none would). A reading not evaluable in any part (no seed
    has it: a run of 20 iterations has no later one) says nothing."""
    said = []
    for key in READINGS:
        judged = {part.key: judge_part(part, readings[(part, key)]) for part in mine if (part, key) in readings}
        found = {k: v[0] for k, v in judged.items()}
        if not found or all(v == NOT_EVALUABLE for v in found.values()):
            continue
        otherwise = claim_verdict({**verdicts, **found}, roles, {**between, **{k: v[1] for k, v in judged.items()}})
        if otherwise == verdict:
            continue
        last = None
        if key == "last":
            ends = [_last_common(ctx) for ctx in contexts]
            ends = [j for j in ends if j > paper.CHATTERING_ITERATION]
            last = (min(ends), max(ends)) if ends else None
        said.append(f"{otherwise} {reading_text(key, perturbation_iteration, last)}")
    return "; ".join(said)


def _last_common(ctx: Seed) -> int:
    try:
        return ctx.last_common(("c1", "c3"))
    except Stop:
        return -1


def beside_text(mine: pd.DataFrame) -> str:
    """What a claim's verdict line says beside its verdict (rule 6), from one claim's rows of
    :func:`judge_claims_over_seeds`'s frame: "" when no other reading changes it."""
    if not len(mine) or "verdict_beside" not in mine:
        return ""
    return str(mine["verdict_beside"].iloc[0] or "")


def _frequency_text(per_seed: Mapping[str, int], deterministic: bool = False) -> str:
    if deterministic:
        return ONE_EVALUATION
    n = sum(per_seed.values())
    parts = ", ".join(f"{v} in {c}" for v, c in per_seed.items() if c)
    return f"{parts} of {n} seed{'s' if n != 1 else ''}"


def part_verdicts_text(mine: pd.DataFrame) -> str:
    """A claim's judged parts and their verdicts in one line, a part that does not hold with its number
    and threshold, so that "in part" never hides by how much a part fails: "C2 below C1, position:
    holds; C3 below C2 by the paper's margin ..., force: fails (1.88 against < 0.613); ..."."""
    judged = mine[~mine["role"].isin(NOT_JUDGED)] if len(mine) else mine
    return "; ".join(f"{r.part_text}: {r.part_verdict}" + _by_how_much(r) for r in judged.itertuples(index=False)) or "-"


def _by_how_much(row) -> str:
    """" (1.88 against < 0.613)" for a judged part that does not hold and has a number; "" otherwise."""
    if row.part_verdict == HOLDS or not math.isfinite(float(row.median)):
        return ""
    return f" ({float(row.median):.3g} against {row.threshold})"


def claim_summary(parts: pd.DataFrame) -> pd.DataFrame:
    """One row per claim: ``claim``, ``statement``, ``verdict``, ``frequency`` (with the verdicts other
    readings of the judged number would give where they differ, rule 6), ``parts`` (every
    judged part's verdict, so a claim that fails on one part of four says so), ``paper``, ``rule``."""
    rows = []
    for claim in CLAIMS:
        mine = parts[parts["claim"] == claim.number] if not parts.empty else parts
        verdict = str(mine["verdict"].iloc[0]) if len(mine) else NOT_EVALUABLE
        frequency = str(mine["claim_frequency"].iloc[0]) if len(mine) else "-"
        beside = beside_text(mine)
        frequency += f"; {beside}" if beside else ""  # rule 6: beside the verdict, never instead of it
        statement = str(mine["statement"].iloc[0]) if len(mine) else claim.statement
        rows.append({"claim": claim.number, "statement": statement, "verdict": verdict,
                     "frequency": frequency, "parts": part_verdicts_text(mine), "paper": claim.paper,
                     "rule": claim.rule})
    return pd.DataFrame(rows)


def tidy_from_methods(metrics_by_method: Mapping[str, pd.DataFrame], seed: int = 0) -> pd.DataFrame:
    """The tidy frame of one run (one seed) from per-method metrics frames indexed by iteration."""
    frames = []
    for method, frame in metrics_by_method.items():
        tidy = frame.reset_index().rename(columns={frame.index.name or "index": "iteration"})
        tidy.insert(0, "method", method)
        tidy.insert(0, "seed", seed)
        frames.append(tidy)
    if not frames:
        return pd.DataFrame(columns=["seed", "method", "iteration"])
    return pd.concat(frames, ignore_index=True)


def judge_claims(metrics_by_method: Mapping[str, pd.DataFrame], *,
                 perturbation_iteration: int = paper.PERTURBATION_ITERATION,
                 deterministic: bool = False, config: Mapping | None = None) -> pd.DataFrame:
    """A single run's claims: the one-seed case of :func:`judge_claims_over_seeds`, part by part."""
    return judge_claims_over_seeds(tidy_from_methods(metrics_by_method), perturbation_iteration=perturbation_iteration,
                                   deterministic=deterministic, config=config)
