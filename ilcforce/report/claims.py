"""The paper's five claims (SPEC section 7), each judged from OUR measured numbers by a stated rule.

A verdict is one of ``"holds"``, ``"in part"``, ``"fails"`` or ``"not evaluable"``. The paper's
figures are shown beside ours for the reader; they never enter a verdict.

Rules common to every claim
---------------------------
* A method whose good behaviour the claim asserts diverged at or before the last iteration the
  claim reads -> ``"fails"``, naming the divergence (iteration and time). This is checked first:
  a divergence settles the claim even if another method has no results.
* A method the claim needs has no results -> ``"not evaluable"`` (naming the method).
* A *baseline* (a method the claim says is worse) that diverged inside the window counts as
  having an infinite error norm there: it lost tracking, so it compares as worse. This is said
  in the "ours" column.
* An iteration the rule reads that is missing (a partial run) -> ``"not evaluable"``.

Iterations are counted from 0; the perturbation iteration ``p`` (10 in the paper) is read from
the experiment's config by the caller.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
import pandas as pd

from ilcforce.report import paper
from ilcforce.report.tables import chattering_iteration, complete_iterations, divergence, jbar, value_at

HOLDS = "holds"
IN_PART = "in part"
FAILS = "fails"
NOT_EVALUABLE = "not evaluable"
VERDICTS = (HOLDS, IN_PART, FAILS, NOT_EVALUABLE)

#: Claim 2: C3's converged norm must be below this fraction of C2's ("more than 40% below").
REDUCTION_RATIO = 1.0 - paper.ERROR_REDUCTION_C3_VS_C2
#: Claim 3: |our j̄ - paper's j̄| allowed, in iterations.
JBAR_TOLERANCE = 1
#: Claim 4: a norm "rises strongly" at the perturbation if norm(p) / norm(p - 1) >= this.
STRONG_RISE = 2.0
#: Claim 4: a learning method "converges again" if norm(19) <= this x norm(p - 1).
RECONVERGED = 1.5
#: Claim 2: window of iterations averaged as "after convergence" (the j̄ median window).
CONVERGED_WINDOW = (5, 9)

METRICS = (("position", "position_error_2norm", "m"), ("force", "force_error_2norm", "N"))


@dataclass(frozen=True)
class Claim:
    """One of the paper's claims: its statement, the paper's figure, and our verdict rule."""

    number: int
    statement: str
    paper: str
    rule: str


CLAIMS: tuple[Claim, ...] = (
    Claim(
        1,
        "Before j = 10, C2 and C3 track better than C1 (position and force).",
        "Figs. 3, 4 (no numbers): 'C2 and C3 achieve better tracking performance than C1'.",
        "Mean error 2-norm over j = 1..p-1 of C2 and of C3 below C1's, for position and for force "
        "(4 comparisons): all -> holds; some -> in part; none -> fails.",
    ),
    Claim(
        2,
        "After convergence, C3's error 2-norm is more than 40% below C2's.",
        "Table 2: position 4.3e-6 / 7.6e-6 m = 0.566 (-43.4%); force 0.058 / 0.096 N = 0.604 (-39.6%).",
        "Ratio C3 / C2 of the mean error 2-norm over j = 5..9 below 0.6, for position and for force: "
        "both -> holds; one -> in part; none -> fails. The ratio at each method's j̄ is shown too.",
    ),
    Claim(
        3,
        "Convergence iterations: C2 j̄ = 3 (position), 2 (force); C3 j̄ = 4, 3.",
        "Table 2: C2 j̄ = 3, 2; C3 j̄ = 4, 3.",
        "Our j̄ (first j <= 9 within 1.5x the median of j = 5..9) within +-1 iteration of the paper's, "
        "for the 4 values: all -> holds; at least 2 -> in part; fewer -> fails.",
    ),
    Claim(
        4,
        "The m3 change at j = 10 degrades C2 and C3 strongly and C1 slightly; C2 and C3 converge again.",
        "Figs. 3, 4 (no numbers): C2, C3 'significantly deteriorated', C1 'slightly worse', "
        "C2, C3 'convergent again'.",
        "10 parts, position and force each: norm(p) / norm(p-1) >= 2 for C2 and C3 (4); < 2 for C1 (2); "
        "norm(19) <= 1.5 x norm(p-1) for C2 and C3 (4), with 19 replaced by the last iteration run if "
        "fewer: all -> holds; some -> in part; none -> fails.",
    ),
    Claim(
        5,
        "Chattering at j = 20: H(C1) / H(C3) = 1.67 (X) and 2.44 (Y).",
        "Table 3: C1 0.06, 0.0534 N; C3 0.0359, 0.0219 N; ratios 1.67 (X), 2.44 (Y).",
        "Ratio H(C1) / H(C3) in task space at the 20th iteration (j = 19, or the last complete one "
        "of both) above 1 on X and on Y: both -> holds; one -> in part; none -> fails.",
    ),
)


@dataclass(frozen=True)
class Judgement:
    """What a claim's rule found: our numbers in words, and the verdict."""

    ours: str
    verdict: str


class _Stop(Exception):
    """Raised inside a rule to end it early with a verdict (missing data, divergence)."""

    def __init__(self, verdict: str, ours: str) -> None:
        super().__init__(ours)
        self.judgement = Judgement(ours, verdict)


def _count_verdict(passed: Sequence[bool]) -> str:
    if passed and all(passed):
        return HOLDS
    if any(passed):
        return IN_PART
    return FAILS


def _ratio(numerator: float, denominator: float) -> float:
    """numerator / denominator for norms >= 0: x / 0 is inf (0 / 0 is NaN), x / inf is 0."""
    numerator, denominator = float(numerator), float(denominator)
    if denominator == 0.0:
        return math.nan if numerator == 0.0 else math.inf
    return numerator / denominator


def _fmt(value: float) -> str:
    if math.isinf(value):
        return "inf"
    if math.isnan(value):
        return "n/a"
    return f"{value:.3g}"


class _Context:
    """The metrics frames plus the checks every rule starts with."""

    def __init__(self, metrics_by_method: Mapping[str, pd.DataFrame], perturbation_iteration: int) -> None:
        self.metrics = metrics_by_method
        self.p = int(perturbation_iteration)
        self.notes: list[str] = []

    def require(self, *methods: str) -> None:
        missing = [m for m in methods if m not in self.metrics]
        if missing:
            raise _Stop(NOT_EVALUABLE, "no results for " + ", ".join(missing))

    def diverged_by(self, method: str, last: int) -> tuple[int, float] | None:
        found = divergence(self.metrics[method])
        if found is not None and found[0] <= last:
            return found
        return None

    def asserted(self, methods: Sequence[str], last: int) -> None:
        """A method the claim praises diverged at or before ``last`` -> the claim fails."""
        failures = []
        for method in methods:
            if method not in self.metrics:
                continue  # missing: require() reports it
            found = self.diverged_by(method, last)
            if found is not None:
                failures.append(f"{method} diverged at iteration {found[0]}, t = {found[1]:.4g} s")
        if failures:
            raise _Stop(FAILS, "; ".join(failures))

    def norms(self, method: str, column: str, iterations: Sequence[int]) -> np.ndarray:
        """Norms at ``iterations``; inf from a divergence on (baselines); missing -> not evaluable."""
        found = divergence(self.metrics[method])
        values = []
        for j in iterations:
            if found is not None and j >= found[0]:
                values.append(math.inf)
                continue
            value = value_at(self.metrics[method], column, j)
            if not math.isfinite(value):
                raise _Stop(NOT_EVALUABLE, f"{method} has no complete iteration {j} ({column})")
            values.append(value)
        if found is not None and found[0] <= max(iterations):
            note = f"{method} diverged at iteration {found[0]} (counted as an infinite norm)"
            if note not in self.notes:
                self.notes.append(note)
        return np.asarray(values, dtype=float)

    def mean_norm(self, method: str, column: str, first: int, last: int) -> float:
        return float(np.mean(self.norms(method, column, range(first, last + 1))))

    def finish(self, ours: str, verdict: str) -> Judgement:
        if self.notes:
            ours = ours + " (" + "; ".join(self.notes) + ")"
        return Judgement(ours, verdict)


def _claim1(ctx: _Context) -> Judgement:
    last = ctx.p - 1
    if last < 1:
        raise _Stop(NOT_EVALUABLE, f"perturbation at iteration {ctx.p} leaves no iteration 1..p-1")
    ctx.asserted(("c2", "c3"), last)
    ctx.require("c1", "c2", "c3")
    passed, parts = [], []
    for quantity, column, unit in METRICS:
        means = {m: ctx.mean_norm(m, column, 1, last) for m in ("c1", "c2", "c3")}
        passed += [means["c2"] < means["c1"], means["c3"] < means["c1"]]
        parts.append(
            f"{quantity}: C1 {_fmt(means['c1'])}, C2 {_fmt(means['c2'])}, C3 {_fmt(means['c3'])} {unit}"
        )
    return ctx.finish(f"mean 2-norm over j = 1..{last}: " + "; ".join(parts), _count_verdict(passed))


def _claim2(ctx: _Context) -> Judgement:
    first, last = CONVERGED_WINDOW
    ctx.asserted(("c3",), last)
    ctx.require("c2", "c3")
    passed, parts = [], []
    for quantity, column, _unit in METRICS:
        c3 = ctx.mean_norm("c3", column, first, last)
        c2 = ctx.mean_norm("c2", column, first, last)
        ratio = _ratio(c3, c2)
        passed.append(bool(ratio < REDUCTION_RATIO))
        text = f"{quantity} C3/C2 = {_fmt(ratio)}"
        if math.isfinite(ratio):
            text += f" ({(ratio - 1) * 100:+.1f}%)"
        j2, j3 = jbar(ctx.metrics["c2"], column), jbar(ctx.metrics["c3"], column)
        if j2 is not None and j3 is not None:
            at_jbar = _ratio(value_at(ctx.metrics["c3"], column, j3), value_at(ctx.metrics["c2"], column, j2))
            text += f", at j̄: {_fmt(at_jbar)}"
        parts.append(text)
    return ctx.finish(f"mean 2-norm over j = {first}..{last}: " + "; ".join(parts), _count_verdict(passed))


def _claim3(ctx: _Context) -> Judgement:
    ctx.asserted(("c2", "c3"), CONVERGED_WINDOW[1])
    ctx.require("c2", "c3")
    passed, parts = [], []
    for method in ("c2", "c3"):
        published = paper.table2_row(method)
        assert published is not None  # the paper's Table 2 has C2 and C3
        for quantity, column, _unit in METRICS:
            ours = jbar(ctx.metrics[method], column)
            if ours is None:
                raise _Stop(NOT_EVALUABLE, f"{method}: j̄ ({quantity}) needs complete iterations 0..9")
            theirs = getattr(published, f"jbar_{quantity}")
            passed.append(abs(ours - theirs) <= JBAR_TOLERANCE)
            parts.append(f"{method.upper()} {quantity} {ours} (paper {theirs})")
    verdict = HOLDS if all(passed) else IN_PART if sum(passed) >= 2 else FAILS
    return ctx.finish("j̄: " + ", ".join(parts), verdict)


def _claim4(ctx: _Context) -> Judgement:
    before, after = ctx.p - 1, ctx.p
    if before < 0:
        raise _Stop(NOT_EVALUABLE, f"perturbation at iteration {ctx.p} has no iteration before it")
    ctx.asserted(("c1", "c2", "c3"), paper.CHATTERING_ITERATION)
    ctx.require("c1", "c2", "c3")
    # The last iteration read: 19, or the last one all three methods completed if fewer were run.
    ends = [max(complete_iterations(ctx.metrics[m]), default=-1) for m in ("c1", "c2", "c3")]
    end = min(paper.CHATTERING_ITERATION, *ends)
    if end <= after:
        raise _Stop(NOT_EVALUABLE, f"needs iterations up to at least {after + 1}; the runs stop at {end}")
    passed, parts = [], []
    for quantity, column, _unit in METRICS:
        rises, again = [], []
        for method in ("c1", "c2", "c3"):
            norm_before, norm_after, norm_end = ctx.norms(method, column, (before, after, end))
            rise = _ratio(norm_after, norm_before)
            rises.append(f"{method.upper()} x{_fmt(rise)}")
            if method == "c1":
                passed.append(bool(rise < STRONG_RISE))
            else:
                passed.append(bool(rise >= STRONG_RISE))
                passed.append(bool(norm_end <= RECONVERGED * norm_before))
                again.append(f"{method.upper()} {_fmt(_ratio(norm_end, norm_before))}")
        parts.append(
            f"{quantity}: rise j = {before} -> {after}: {', '.join(rises)}; "
            f"norm(j = {end}) / norm(j = {before}): {', '.join(again)}"
        )
    return ctx.finish("; ".join(parts) + f" ({sum(passed)} of {len(passed)} parts)", _count_verdict(passed))


def _claim5(ctx: _Context) -> Judgement:
    target = paper.CHATTERING_ITERATION
    ctx.asserted(("c3",), target)
    ctx.require("c1", "c3")
    c1_diverged = ctx.diverged_by("c1", target)
    if c1_diverged is not None:
        j, t = c1_diverged
        raise _Stop(NOT_EVALUABLE, f"c1 diverged at iteration {j}, t = {t:.4g} s: no H at j = {target}")
    found = [chattering_iteration(ctx.metrics[m], target) for m in ("c1", "c3")]
    if any(j is None for j in found):
        raise _Stop(NOT_EVALUABLE, "no complete iteration to read H from")
    j = min(int(x) for x in found if x is not None)
    passed, parts = [], []
    for axis, published in (("x", paper.CHATTERING_RATIO_X), ("y", paper.CHATTERING_RATIO_Y)):
        column = f"chattering_task_{axis}"
        h1 = value_at(ctx.metrics["c1"], column, j)
        h3 = value_at(ctx.metrics["c3"], column, j)
        if not (math.isfinite(h1) and math.isfinite(h3)):
            raise _Stop(NOT_EVALUABLE, f"H ({axis.upper()}) not available at j = {j}")
        ratio = _ratio(h1, h3)
        passed.append(bool(ratio > 1.0))
        parts.append(f"{axis.upper()} {_fmt(ratio)} (paper {published}; H: C1 {_fmt(h1)}, C3 {_fmt(h3)} N)")
    where = f"j = {j}" + ("" if j == target else f" (last complete; j = {target} not run)")
    return ctx.finish(f"H(C1)/H(C3) at {where}: " + "; ".join(parts), _count_verdict(passed))


_RULES = {1: _claim1, 2: _claim2, 3: _claim3, 4: _claim4, 5: _claim5}


def judge_claim(
    number: int,
    metrics_by_method: Mapping[str, pd.DataFrame],
    *,
    perturbation_iteration: int = paper.PERTURBATION_ITERATION,
) -> Judgement:
    """Judge claim ``number`` (1..5) from the per-method metrics frames."""
    ctx = _Context(metrics_by_method, perturbation_iteration)
    try:
        return _RULES[number](ctx)
    except _Stop as stop:
        return stop.judgement


def judge_claims(
    metrics_by_method: Mapping[str, pd.DataFrame],
    *,
    perturbation_iteration: int = paper.PERTURBATION_ITERATION,
) -> pd.DataFrame:
    """All five claims judged: one row each.

    Columns: ``claim`` (1..5), ``statement``, ``paper`` (the paper's figure), ``ours`` (our
    numbers), ``verdict`` (one of :data:`VERDICTS`), ``rule`` (how the verdict was reached).
    """
    rows = []
    for claim in CLAIMS:
        judgement = judge_claim(claim.number, metrics_by_method, perturbation_iteration=perturbation_iteration)
        rows.append(
            {
                "claim": claim.number,
                "statement": claim.statement,
                "paper": claim.paper,
                "ours": judgement.ours,
                "verdict": judgement.verdict,
                "rule": claim.rule,
            }
        )
    return pd.DataFrame(rows, columns=["claim", "statement", "paper", "ours", "verdict", "rule"])


def judge_claims_over_seeds(
    metrics: pd.DataFrame,
    *,
    perturbation_iteration: int = paper.PERTURBATION_ITERATION,
) -> pd.DataFrame:
    """Each claim judged per seed, then summarised as verdict frequencies over seeds.

    ``metrics`` is a tidy frame for ONE setting: columns ``seed``, ``method``, ``iteration`` and
    the metric columns (:data:`ilcforce.metrics.METRIC_COLUMNS`), one row per (seed, method,
    iteration). A single run is the one-seed case.

    Returns one row per claim with ``claim``, ``statement``, ``n_seeds``, one count column per
    verdict (``holds``, ``in part``, ``fails``, ``not evaluable``), ``verdict`` (the most frequent
    one; ties go to the weaker verdict) and ``frequency`` ("holds in 97 of 100 seeds").
    """
    from ilcforce.stats import frequency_interval, format_interval

    counts = {claim.number: dict.fromkeys(VERDICTS, 0) for claim in CLAIMS}
    seeds = sorted(metrics["seed"].unique())
    for seed in seeds:
        per_seed = metrics[metrics["seed"] == seed]
        by_method = {m: frame.drop(columns=["seed", "method"]).set_index("iteration").sort_index()
                     for m, frame in per_seed.groupby("method")}
        for claim in CLAIMS:
            verdict = judge_claim(claim.number, by_method, perturbation_iteration=perturbation_iteration).verdict
            counts[claim.number][verdict] += 1
    weakest_first = (NOT_EVALUABLE, FAILS, IN_PART, HOLDS)
    rows = []
    for claim in CLAIMS:
        c = counts[claim.number]
        top = max(weakest_first, key=lambda v: c[v])  # max keeps the first (weakest) of a tie
        share = frequency_interval(c[top], len(seeds)) if seeds else None
        rows.append({"claim": claim.number, "statement": claim.statement, "n_seeds": len(seeds), **c,
                     "verdict": top,
                     "frequency": (f"{top} in {c[top]} of {len(seeds)} seeds "
                                   f"(95% Wilson interval of the share {format_interval(share)})"
                                   if seeds else "-")})
    return pd.DataFrame(rows)
