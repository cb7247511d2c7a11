"""A tuned study's comparison at equal chattering: every method the tuning shipped, over the study's seeds
(none of them used by the tuning) and its whole horizon, its errors beside its settled chattering and the
tuning's cap, and the methods it withheld.

A study is *tuned* when its experiment is a file ``ilcforce tune`` wrote: its ``[tuning]`` table names the
cap (the cap's reference method's settled H per task axis on the tuning's held-out seeds) and the methods
withheld. Per method: the median over seeds [95% bootstrap interval] of the RMS errors averaged over the
last five iterations (the tuning's own error measure) and of the settled H at the last iteration, that H
over the cap, the seeds that diverged. Methods are compared at equal chattering: the ranking by error is
stated among the methods whose median settled H at the last iteration stays within the cap on every task axis,
and a method over it is named as such. The cap is also checked at every iteration, before and after the plant
changes (:func:`over_cap_iterations`): the median over seeds of each iteration's settled H against the cap, and
every method that exceeds it at some iteration is named with those iterations and how far. At the last
iteration a method is within the cap only when the 95% interval of its median H lies within it on every axis,
over it when that interval lies above the cap on some axis, and **uncertain** otherwise (an interval crosses
the cap): it is named as such and left out of the ranking.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pandas as pd

from ilcforce.records import TASK_DIMENSIONS, task_axes
from ilcforce.report.claim_ranges import FAIL, PASS, below, interval_outcomes
from ilcforce.stats import median_interval

#: The iterations at the end of a run whose RMS errors are averaged (the tuning's score_last).
LAST = 5
#: A method's place against the cap at the last iteration (module docstring).
WITHIN, OVER, UNCERTAIN = "within", "over", "uncertain"


def against_cap(values_by_axis, cap) -> str:
    """:data:`WITHIN` when the 95% interval of the median settled H lies within the cap on every axis,
    :data:`OVER` when it lies above it on some axis (or an axis has no finite value), else :data:`UNCERTAIN`.
    ``values_by_axis``: per task axis, the per-seed H; ``cap``: per axis, in the same order."""
    spans = []
    for values, limit in zip(values_by_axis, cap, strict=True):
        found = median_interval(values)
        spans.append(interval_outcomes(found.low, found.high, below(float(limit))) or frozenset({FAIL}))
    if any(s == {FAIL} for s in spans):
        return OVER
    return WITHIN if all(s == {PASS} for s in spans) else UNCERTAIN


def tuning_of(results) -> dict | None:
    """The ``[tuning]`` table of the study's (first) setting when its experiment is a tuned file with a cap."""
    config = json.loads(str(results.settings.iloc[0]["config_json"])) if len(results.settings) else {}
    tuning = config.get("tuning", {})
    return tuning if tuning.get("source") and len(tuning.get("cap", ())) in TASK_DIMENSIONS else None


def _interval(values) -> str:
    values = np.asarray(values, dtype=float)
    values = values[np.isfinite(values)]
    if not len(values):
        return "-"
    found = median_interval(values)
    return f"{found.estimate:.3g} [{found.low:.3g}, {found.high:.3g}]"


def _spans(iterations: list[int]) -> str:
    """[0, 1, 2, 5] -> "0-2, 5"."""
    spans: list[list[int]] = []
    for j in iterations:
        if spans and j == spans[-1][1] + 1:
            spans[-1][1] = j
        else:
            spans.append([j, j])
    return ", ".join(f"{a}-{b}" if b > a else f"{a}" for a, b in spans)


def over_cap_iterations(runs: pd.DataFrame, axes, cap) -> tuple[pd.Series, list[int]]:
    """One method's tidy metrics ``runs`` (every seed, every iteration) against the cap at every iteration:
    (per iteration, the median over seeds of settled H_a / cap_a, max over the axes; the iterations where
    that exceeds 1). A seed's iteration that did not complete has no H and is left out of that median."""
    done = runs[runs["status"] == "complete"]
    medians = done.groupby("iteration")[[f"chattering_task_{a}_settled" for a in axes]].median()
    relative = pd.concat([medians[f"chattering_task_{a}_settled"] / c for a, c in zip(axes, cap, strict=True)],
                         axis=1).max(axis=1)
    return relative, [int(j) for j in relative.index[relative > 1.0]]


def comparison(results) -> tuple[pd.DataFrame, str]:
    """(table, sentence) of the study's first setting at equal chattering; an empty table and "" when the
    study is not tuned."""
    from ilcforce.report.tables import ordered_methods
    from ilcforce.tune.heldout import NONE_UNDER_CAP

    tuning = tuning_of(results)
    if tuning is None:
        return pd.DataFrame(), ""
    cap = tuning["cap"]
    axes = task_axes(len(cap))  # the cap has one value per task axis
    metrics = results.setting_metrics(int(results.settings.iloc[0]["setting"]))
    last = int(metrics["iteration"].max())
    rows, within, over, unsure, ever = [], [], [], [], []
    for method in ordered_methods(metrics["method"].unique().tolist()):
        mine = metrics[metrics["method"] == method]
        by_iteration, exceeded = over_cap_iterations(mine, axes, cap)
        if exceeded:
            ever.append((method, _spans(exceeded), float(by_iteration.max()), int(by_iteration.idxmax())))
        per_seed = []
        for _seed, run in mine.groupby("seed"):
            run = run.sort_values("iteration")
            ok = bool((run["status"] == "complete").all()) and int(run["iteration"].max()) == last
            tail = run[run["iteration"] > last - LAST]
            end = run[run["iteration"] == last]
            per_seed.append({
                "diverged": not ok,
                "e_p": float(tail["position_error_rms"].mean()) if ok else math.nan,
                "e_f": float(tail["force_error_rms"].mean()) if ok else math.nan,
                **{f"h_{a}": float(end[f"chattering_task_{a}_settled"].iloc[0]) if ok else math.nan for a in axes}})
        seeds = pd.DataFrame(per_seed)
        relative = max(float(np.nanmedian(seeds[f"h_{a}"])) / c for a, c in zip(axes, cap, strict=True))
        place = against_cap([seeds[f"h_{a}"] for a in axes], cap)
        {WITHIN: within, OVER: over, UNCERTAIN: unsure}[place].append(
            (method, float(np.nanmedian(seeds["e_p"])), float(np.nanmedian(seeds["e_f"])), relative))
        rows.append({"method": method, f"e_P RMS, j = {last - LAST + 1}..{last}": _interval(seeds["e_p"]),
                     f"e_F RMS, j = {last - LAST + 1}..{last}": _interval(seeds["e_f"]),
                     **{f"H_{a} settled, j = {last}": _interval(seeds[f"h_{a}"]) for a in axes},
                     "H / cap (max over axes)": f"{relative:.2f}", "against the cap": place,
                     f"H / cap, most over j = 0..{last}": (f"{by_iteration.max():.2f} (j = {by_iteration.idxmax()})"
                                                          if len(by_iteration) else "-"),
                     "iterations over the cap": _spans(exceeded) or "none",
                     "diverged": f"{int(seeds['diverged'].sum())} of {len(seeds)}"})
    for method in tuning.get("withheld", ()):
        rows.append({"method": method, **{k: NONE_UNDER_CAP for k in rows[0] if k != "method"}} if rows else
                    {"method": method})
    table = pd.DataFrame(rows)
    cap_text = (f"{tuning.get('cap_reference', 'the reference')}'s settled H on the tuning's held-out seeds: "
                + ", ".join(f"H_{a} {c:.3g} N" for a, c in zip(axes, cap)))
    parts = [f"over {last + 1} iterations on {metrics['seed'].nunique()} seeds the tuning never used, "
             f"{len(within)} of {len(within) + len(over) + len(unsure)} shipped methods keep their median settled H "
             f"at j = {last} within the cap, its 95% interval clear of it ({cap_text})"]
    if within:
        by_p = sorted(within, key=lambda r: r[1])
        by_f = sorted(within, key=lambda r: r[2])
        parts.append("among them the smallest position error is " + ", then ".join(
            f"{m} ({p:.3g} m)" for m, p, _f, _r in by_p[:3]) + "; the smallest force error " + ", then ".join(
            f"{m} ({f:.3g} N)" for m, _p, f, _r in by_f[:3]))
    if over:
        parts.append("over the cap here: " + ", ".join(f"{m} ({r:.2f}x)" for m, _p, _f, r in over))
    if unsure:
        parts.append("uncertain against the cap (the interval of a median H crosses it), not ranked: "
                     + ", ".join(f"{m} ({r:.2f}x)" for m, _p, _f, r in unsure))
    parts.append(f"at every iteration j = 0..{last} (median settled H over seeds), "
                 + ("over the cap at some iteration: " + ", ".join(f"{m} (j = {j}; most {r:.2f}x, at j = {at})"
                                                                   for m, j, r, at in ever)
                    if ever else "no shipped method is over the cap"))
    if tuning.get("withheld"):
        parts.append(f"{NONE_UNDER_CAP}: {', '.join(tuning['withheld'])}")
    return table, "; ".join(parts) + "."
