"""Verdicts as data: the rows of ``claims.csv`` and ``stability.csv``, and the findings text drawn from them.

Every sentence the findings generate about a claim or about learning stability is written from
these rows, so a reader who loads the CSVs with pandas filters the very verdicts the README states.

``claims.csv``: one row per claim (``part`` = "claim", ``role`` = "claim": the claim's verdict by the
stated rule, ``seeds_passed`` = the seeds where the whole claim holds) and one row per part (judged
or shown; its ``evaluation`` is the part's own, :func:`part_evaluation`). Every column: docs/tables.md. Columns: :data:`CLAIM_COLUMNS`. ``stability.csv``: one row per method and quantity
fitted by :func:`ilcforce.stability.learning_growth`. Columns: :data:`STABILITY_COLUMNS`.
"""

from __future__ import annotations

import math

import pandas as pd

from ilcforce.report import claims as claims_module
from ilcforce import stability

EXPERIMENT, STUDY = "experiment", "study"
CLAIM_ROW = "claim"
CLAIM_COLUMNS = ["source", "name", "setting", "claim", "part", "role", "verdict", "seeds_evaluated", "seeds_passed",
                 "statistic", "statistic_low", "statistic_high", "threshold", "evaluation", "part_text",
                 "statistic_name", "note", "margin", "spread_low", "spread_high", "partial", "between"]
STABILITY_COLUMNS = ["source", "name", "setting", "method", "quantity", "judged", "window", "rate_per_iteration",
                     "rate_low", "rate_high", "seeds_growing", "seeds_fitted", "value_end", "iterations_to_10x",
                     "saturating", "inconclusive", "flagged"]


def claim_rows(parts: pd.DataFrame, *, source: str, name: str, setting: str) -> pd.DataFrame:
    """The ``claims.csv`` rows of one setting from :func:`ilcforce.report.claims.judge_claims_over_seeds`'s frame."""
    rows = []
    if parts.empty:
        return pd.DataFrame(rows, columns=CLAIM_COLUMNS)
    for claim, mine in parts.groupby("claim", sort=True):
        first = mine.iloc[0]
        n = int(first["n_seeds"])
        evaluation = str(first["claim_frequency"])
        base = {"source": source, "name": name, "setting": setting, "claim": int(claim), "evaluation": evaluation}
        rows.append({**base, "part": CLAIM_ROW, "role": CLAIM_ROW, "verdict": str(first["verdict"]),
                     "seeds_evaluated": n, "seeds_passed": int(first["claim_seeds_holding"]),
                     "statistic": math.nan, "statistic_low": math.nan, "statistic_high": math.nan,
                     "threshold": "", "part_text": str(first["statement"]), "statistic_name": "",
                     "note": str(first.get("verdict_beside", "") or ""),
                     "margin": math.nan, "spread_low": math.nan, "spread_high": math.nan, "partial": "",
                     "between": str(first.get("verdict_between", "") or "")})
        for row in mine.itertuples(index=False):
            shown = row.role in claims_module.NOT_JUDGED
            rows.append({**base, "evaluation": part_evaluation(row), "part": row.part, "role": row.role,
                         "verdict": str(row.role) if shown else str(row.part_verdict),
                         "seeds_evaluated": int(row.evaluable),
                         "seeds_passed": pd.NA if shown else int(row.passed),
                         "statistic": float(row.median), "statistic_low": float(row.low),
                         "statistic_high": float(row.high), "threshold": str(row.threshold or ""),
                         "part_text": str(row.part_text), "statistic_name": str(row.statistic),
                         "note": str(row.notes or ""), "margin": float(row.margin),
                         "spread_low": float(row.spread_low), "spread_high": float(row.spread_high),
                         "partial": str(row.partial or ""), "between": str(getattr(row, "between", "") or "")})
    frame = pd.DataFrame(rows, columns=CLAIM_COLUMNS)
    frame["seeds_passed"] = frame["seeds_passed"].astype("Int64")
    return frame


def part_evaluation(row) -> str:
    """A part row's own evaluation (the claim row carries the claim's): how many seeds the part was
    judged on and what it gave in each, e.g. "holds in 7, fails in 3 of 10 seeds" (its verdict is
    the majority of the seeds judged); a shown part, how many seeds gave its number."""
    if bool(row.deterministic):
        return claims_module.ONE_EVALUATION
    total = int(row.n_seeds)
    seeds = f"{total} seed{'s' if total != 1 else ''}"
    if row.role in claims_module.NOT_JUDGED:
        return f"shown, not judged: a value in {int(row.evaluable)} of {seeds}"
    judged, passed = int(row.evaluable), int(row.passed)
    diverged = int(getattr(row, "diverged", 0) or 0)  # failures where the praised method diverged (rule 4)
    counts = [(claims_module.HOLDS, passed), (claims_module.FAILS, judged - passed - diverged),
              (claims_module.DIVERGED, diverged), (claims_module.NOT_EVALUABLE, total - judged)]
    return ", ".join(f"{word} in {n}" for word, n in counts if n) + f" of {seeds}"


def stability_rows(growth: pd.DataFrame, *, source: str, name: str, setting: str) -> pd.DataFrame:
    """The ``stability.csv`` rows of one setting from :func:`ilcforce.stability.learning_growth`'s frame."""
    rows = [{"source": source, "name": name, "setting": setting, "method": r.method, "quantity": r.quantity,
             "judged": bool(r.judged), "window": r.window, "rate_per_iteration": r.rate, "rate_low": r.rate_low,
             "rate_high": r.rate_high, "seeds_growing": int(r.growing), "seeds_fitted": int(r.fitted),
             "value_end": r.value_end, "iterations_to_10x": r.iterations_to_10x,
             "saturating": bool(r.saturating), "inconclusive": bool(r.inconclusive), "flagged": bool(r.grows)}
            for r in growth.itertuples(index=False)]
    return pd.DataFrame(rows, columns=STABILITY_COLUMNS)


# ---------------------------------------------------------------------------------------------
# The findings text, from the rows
# ---------------------------------------------------------------------------------------------


#: What the bracket after a median is, said once wherever medians are printed.
INTERVAL_NOTE = ("median over seeds [95% bootstrap interval of the median]; the spread of the seeds themselves "
                 "(5-95%), where a single run falls, is given as 'seeds 5-95%'")


def statistic_text(row) -> str:
    """"0.56 [0.5, 0.6]" (median and the 95% bootstrap interval of the median, :data:`INTERVAL_NOTE`),
    "0.56" with one value, "n/a" without."""
    value = row.statistic
    if value is None or not math.isfinite(float(value)):
        return "n/a"
    low, high = float(row.statistic_low), float(row.statistic_high)
    if not (math.isfinite(low) and math.isfinite(high)) or low == high:
        return f"{value:.3g}"
    return f"{value:.3g} [{low:.3g}, {high:.3g}]"


def _passes(row) -> str:
    if row.role in claims_module.NOT_JUDGED:
        return str(row.role)
    if int(row.seeds_evaluated) == 0 or row.verdict == claims_module.NOT_EVALUABLE:
        return f"{row.verdict}"  # never "not evaluable; passes in 0 of 1" (a praised method diverged there)
    return f"{row.verdict}; passes in {int(row.seeds_passed)} of {int(row.seeds_evaluated)}{margin_text(row)}"


def margin_text(row) -> str:
    """"; margin -13% of the threshold" from a row's ``margin`` (empty without one)."""
    margin = getattr(row, "margin", math.nan)
    try:
        margin = float(margin)
    except (TypeError, ValueError):
        return ""
    if not math.isfinite(margin):
        return ""
    return f"; margin {100 * margin:+.0f}% of the threshold"


def claim_lines(rows: pd.DataFrame) -> list[str]:
    """One bullet per claim: its verdict, how it was evaluated, and every judged part's statistic,
    threshold and verdict (so a claim that fails on one part of four says which)."""
    lines = []
    for claim, mine in rows.groupby("claim", sort=True):
        head = mine[mine["role"] == CLAIM_ROW].iloc[0]
        judged = mine[~mine["role"].isin([CLAIM_ROW, *claims_module.NOT_JUDGED])]
        detail = "; ".join(f"{r.part_text}: {statistic_text(r)} ({r.threshold} {_passes(r)})"
                           for r in judged.itertuples(index=False))
        how = "one evaluation" if head["evaluation"] == claims_module.ONE_EVALUATION else head["evaluation"]
        if str(head.get("between", "") or ""):  # rule 3: which verdicts an interval leaves open
            how = f"{head['between']}: an interval of a median crosses its threshold; {how}"
        beside = f"; {head['note']}" if str(head["note"] or "") else ""  # a verdict the settled metric changes
        lines.append(f"* Claim {int(claim)} **{head['verdict']}** ({how}{beside}). {detail}.")
    return lines


def cause_lines(rows: pd.DataFrame) -> list[str]:
    """Why C1 leads where claim 1 does not hold, from claim 1's ``cause`` rows: whether C1's nominal
    model is exact in the judged window, its fixed alpha against the disturbance bound, and the
    alpha_hat C3 learned. Empty when claim 1 holds or C1 leads nowhere."""
    one = rows[rows["claim"] == 1]
    central = one[one["role"] == "central"]
    if one.empty or central.empty or (central["verdict"] == "holds").all():
        return []
    leads = central[central["statistic"] >= 1.0]
    if leads.empty:
        return []
    cause = {r.part: r for r in one[one["role"] == claims_module.CAUSE].itertuples(index=False)}
    said = []
    model = cause.get("cause_c1_model")
    if model is not None and math.isfinite(float(model.statistic)):
        said.append("C1's nominal model is the true plant in the window judged (the plant changes only after it)"
                    if float(model.statistic) == 1.0 else
                    f"C1's nominal model is off by x{float(model.statistic):.3g} in the window judged")
    alpha = cause.get("cause_c1_alpha")
    if alpha is not None and math.isfinite(float(alpha.statistic)):
        said.append(f"its fixed switching gain alpha is {float(alpha.statistic):.3g}x the non-repetitive "
                    "disturbance's bound by the norm of eq. (2), so it rejects that disturbance in every iteration")
    elif alpha is not None and float(alpha.statistic) == math.inf:
        said.append("there is no disturbance for its alpha to reject")
    learned = cause.get("cause_c3_alpha_hat")
    if learned is not None and math.isfinite(float(learned.statistic)):
        said.append(f"C3's learned alpha_hat is {statistic_text(learned)} N (settled RMS), which the paper's proof "
                    "needs above that bound")
    names = ", ".join(str(r.part_text) for r in leads.itertuples(index=False))
    if not said:
        return []
    return [f"* Why claim 1 does not hold ({names}: C1 ahead): " + "; ".join(said) + "."]


def flag_lines(rows: pd.DataFrame) -> list[str]:
    """One bullet per flagged method, and one line when the test could not run (runs too short)."""
    if rows.empty:
        return [f"* Learning stability: {stability.NOT_FITTED}."]
    lines = []
    for method, mine in rows[rows["flagged"]].groupby("method", sort=False):
        mine = mine.sort_values("rate_per_iteration", ascending=False)
        parts = ", ".join(
            f"{stability.short_name(r.quantity)} grows x{r.rate_per_iteration:.3g} per iteration "
            f"[{r.rate_low:.3g}, {r.rate_high:.3g}] over {r.window}"
            + (f", 10x in {float(r.iterations_to_10x):.0f} iterations" if math.isfinite(float(r.iterations_to_10x))
               else "") + f" ({r.seeds_growing} of {r.seeds_fitted} seeds)" for r in mine.itertuples())
        lines.append(f"* Unstable learning, {method}: {parts}.")
    unsure = rows[rows["inconclusive"].astype(bool) & ~rows["flagged"].astype(bool)] if "inconclusive" in rows else rows[:0]
    for method, mine in unsure.groupby("method", sort=False):
        if method in set(rows.loc[rows["flagged"].astype(bool), "method"]):
            continue
        parts = ", ".join(f"{stability.short_name(r.quantity)} x{r.rate_per_iteration:.3g} "
                          f"[{r.rate_low:.3g}, {r.rate_high:.3g}]" for r in mine.itertuples())
        lines.append(f"* Learning stability of {method} not evaluable: too noisy to tell whether {parts} grows.")
    if not lines:
        lines.append("* Learning stability: nothing a method learns, and no settled output, grows over the "
                     "late iterations (" + ", ".join(sorted(set(rows["window"]))) + ").")
    return lines


def flagged_methods(rows: pd.DataFrame) -> list[str]:
    """The flagged methods of one setting's stability rows, in order of appearance."""
    return list(dict.fromkeys(rows.loc[rows["flagged"].astype(bool), "method"].astype(str))) if len(rows) else []


def claim_verdicts(rows: pd.DataFrame) -> dict[int, str]:
    """claim -> verdict of one setting's claim rows."""
    head = rows[rows["role"] == CLAIM_ROW]
    return {int(c): str(v) for c, v in zip(head["claim"], head["verdict"], strict=True)}


def read_back(path) -> pd.DataFrame:
    """A ``claims.csv`` or ``stability.csv`` as written (empty strings stay empty strings)."""
    frame = pd.read_csv(path, keep_default_na=False, na_values=[""])
    for column in ("threshold", "part_text", "note", "evaluation", "statistic_name", "window", "partial", "between"):
        if column in frame.columns:
            values = frame[column].astype(object)
            frame[column] = values.where(values.notna(), "").astype(str)
    for column in ("flagged", "judged"):
        if column in frame.columns:
            text = frame[column].astype(str).str.strip().str.lower()
            unknown = ~text.isin(["true", "false", "1", "0", "1.0", "0.0"])
            if unknown.any():
                raise ValueError(f"{path}: column {column} holds {frame.loc[unknown, column].iloc[0]!r}, not a truth value")
            frame[column] = text.isin(["true", "1", "1.0"])
    return frame


def bottom_line(rows: pd.DataFrame) -> str:
    """One plain sentence from the claim rows: how many of the paper's claims hold, hold in part,
    fail or cannot be judged (empty when there is no claim row), and, for a claim whose verdict another
    reading of its number would change (the claim row's ``note``, rule 6 of :mod:`ilcforce.report.claims`),
    what that reading gives: "claim 5 fails; in part with the first 20 ms left out (...)"."""
    head = rows[rows["role"] == CLAIM_ROW] if len(rows) else rows
    if not len(head):
        return ""
    words = {"holds": "hold", "in part": "hold in part", "fails": "fail", "uncertain": "are uncertain",
             "not evaluable": "cannot be judged"}
    said = []
    for verdict, word in words.items():
        claims = sorted(int(c) for c in head.loc[head["verdict"] == verdict, "claim"])
        if claims:
            said.append(f"{len(claims)} {word} ({', '.join(map(str, claims))})")
    line = f"Bottom line: of the paper's {len(head)} claims, " + ", ".join(said) + "."
    notes = head[head["note"].fillna("").astype(str) != ""] if "note" in head else head.iloc[0:0]
    for row in notes.itertuples(index=False):  # the verdict rests on how its number is read: said with it
        line += f" Claim {int(row.claim)} {row.verdict}; {row.note}."
    return line
