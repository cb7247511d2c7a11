"""The cause account over seeds: each noise mechanism's divergence iteration as a distribution.

The ``long-run-cause`` study changes one candidate cause at a time on one seed. The
``long-run-cause-seeds`` study (``experiments/long/long-run-cause-seeds.toml``) runs C2 and C3 on five
held-out seeds with no noise, each noise source alone, both (the paper's setup) and both at a tenth, over
300 iterations. This module makes its tables (per seed, and per setting and method over the seeds) and
the sentences of the account that the tables decide: whether the two mechanisms interact (the paper's
setup diverging before either mechanism alone on the same seed) and how much a tenth of the noise delays
the divergence. A run that did not diverge is *censored*: it counts as "ran every iteration", never as a
divergence at the last one, and a difference involving it is a lower bound (">=").
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd

from ilcforce.report.growth_validation import TRUTH_FROM, study_settings
from ilcforce.stability import diverged_at
from ilcforce.stats import growth_rate

#: The study this module reads.
STUDY = "long-run-cause-seeds"
#: The settings the sentences compare, by label (the study file's).
NO_NOISE, DISTURBANCE, SENSORS, BOTH, TENTH = (
    "no noise", "disturbance only", "sensor noise only", "both (paper setup)", "both at a tenth (noise.scale 0.1)")


def _memory_column(frame: pd.DataFrame, kind: str) -> str | None:
    """The learned memory's ``memory_<kind>_<name>`` column (theta_hat for C3, v for C2)."""
    found = sorted(c for c in frame if c.startswith(f"memory_{kind}_") and frame[c].notna().any()
                   and not c.endswith("alpha_hat"))
    return found[-1] if found else None


def per_seed_table(results) -> pd.DataFrame:
    """One row per setting, method and seed: where the run diverged (iteration and time into it; NaN when
    it ran every iteration), its settled memory's growth per iteration from j = 20, and its memory's
    drift at t = 0 per iteration."""
    rows = []
    for k, label, _p in study_settings(results):
        metrics = results.setting_metrics(k)
        for (method, seed), frame in metrics.groupby(["method", "seed"], sort=False):
            frame = frame.sort_values("iteration")
            complete = frame[frame["status"] == "complete"]
            diverged = diverged_at(frame)
            settled, start = _memory_column(complete, "settled"), _memory_column(complete, "start")
            late = complete[complete["iteration"] >= TRUTH_FROM]
            rate = (growth_rate(late[settled], iterations=late["iteration"]).estimate
                    if settled is not None and len(late) >= 3 else math.nan)
            drift = math.nan
            if start is not None and len(complete) >= 2:
                first, last = complete.iloc[0], complete.iloc[-1]
                drift = (float(last[start]) - float(first[start])) / (int(last["iteration"]) - int(first["iteration"]))
            at_t = (float(frame.loc[frame["iteration"] == diverged, "diverged_time"].iloc[0])
                    if math.isfinite(diverged) else math.nan)
            rows.append({"setting": label, "method": str(method), "seed": int(seed), "diverged_at": diverged,
                         "diverged_time_s": at_t, "iterations_run": int(frame["iteration"].max()) + 1,
                         "settled_growth_per_iteration": rate, "start_drift_per_iteration": drift})
    return pd.DataFrame(rows)


def _range(values, fmt: str) -> str:
    """'median [min, max]' of the finite values, '-' when there are none."""
    values = np.asarray([v for v in values if math.isfinite(v)], dtype=float)
    if not len(values):
        return "-"
    return f"{np.median(values):{fmt}} [{values.min():{fmt}}, {values.max():{fmt}}]"


def summary_table(seeds: pd.DataFrame) -> pd.DataFrame:
    """Per setting and method over the seeds: how many diverged within the run, the divergence iteration
    and time (median [min, max] over the seeds that diverged), the settled growth and the t = 0 drift
    (median [min, max] over every seed)."""
    rows = []
    for (label, method), group in seeds.groupby(["setting", "method"], sort=False):
        diverged = group["diverged_at"].notna()
        rows.append({
            "setting": label, "method": method,
            "diverged": f"{int(diverged.sum())} of {len(group)}",
            "diverged at j": _range(group.loc[diverged, "diverged_at"], ".0f"),
            "at t (s)": _range(group.loc[diverged, "diverged_time_s"], ".3g"),
            "settled memory growth per iteration": _range(group["settled_growth_per_iteration"], ".4f"),
            "t = 0 memory per iteration": _range(group["start_drift_per_iteration"], ".3g"),
            "iterations run": _range(group["iterations_run"], ".0f")})
    return pd.DataFrame(rows)


def _end(row) -> float:
    """The run's divergence iteration, +inf when it ran every iteration (censored)."""
    return float(row["diverged_at"]) if math.isfinite(row["diverged_at"]) else math.inf


def account_lines(seeds: pd.DataFrame) -> list[str]:
    """The account's sentences the per-seed table decides, one per method and question."""
    lines = []
    run = int(seeds["iterations_run"].max()) if len(seeds) else 0  # the study's length (a run that never diverged)
    for method, mine in seeds.groupby("method", sort=False):
        by = {label: frame.set_index("seed") for label, frame in mine.groupby("setting", sort=False)}
        if not all(label in by for label in (NO_NOISE, DISTURBANCE, SENSORS, BOTH)):
            continue
        common = sorted(set.intersection(*(set(by[label].index) for label in (NO_NOISE, DISTURBANCE, SENSORS, BOTH))))
        earlier = [s for s in common
                   if _end(by[BOTH].loc[s]) < min(_end(by[label].loc[s]) for label in (NO_NOISE, DISTURBANCE, SENSORS))]
        alone = {label: sum(math.isfinite(_end(by[label].loc[s])) for s in common)
                 for label in (NO_NOISE, DISTURBANCE, SENSORS, BOTH)}
        lines.append(
            f"{method.upper()}: within {run} iterations it diverged on {alone[NO_NOISE]} of {len(common)} seeds with no "
            f"noise, {alone[DISTURBANCE]} with the disturbance alone, {alone[SENSORS]} with the sensor noise alone and "
            f"{alone[BOTH]} with both; both together diverged before every mechanism alone on "
            f"{len(earlier)} of {len(common)} seeds"
            + (" (the mechanisms interact: together they end the run sooner than either does)." if earlier else "."))
        if TENTH in by:
            shared = [s for s in common if s in by[TENTH].index]
            delays = []
            for s in shared:
                full, tenth = _end(by[BOTH].loc[s]), _end(by[TENTH].loc[s])
                if math.isfinite(full):
                    delays.append((tenth - full) if math.isfinite(tenth) else math.inf)
            if delays:
                bounded = [d for d in delays if math.isfinite(d)]
                censored = len(delays) - len(bounded)
                text = (f"a tenth of the noise delayed the divergence by {_range(bounded, '.0f')} iterations "
                        f"(median [min, max] over the {len(bounded)} seeds on which both runs diverged)" if bounded
                        else "a tenth of the noise kept every run that diverged at full noise from diverging")
                if bounded and censored:
                    text += f"; on {censored} more the run at a tenth did not diverge within {run} iterations"
                lines.append(f"{method.upper()}: {text}.")
            rates = {label: by[label]["settled_growth_per_iteration"] for label in (BOTH, TENTH)}
            finite = {label: [v for v in rates[label] if math.isfinite(v)] for label in rates}
            if all(finite.values()):
                overlap = (max(min(finite[BOTH]), min(finite[TENTH])) <= min(max(finite[BOTH]), max(finite[TENTH])))
                lines.append(
                    f"{method.upper()}: the settled memory's norm grows x{_range(finite[BOTH], '.4f')} per iteration "
                    f"from j = {TRUTH_FROM} at full noise and x{_range(finite[TENTH], '.4f')} at a tenth (median "
                    "[min, max] over seeds; the norm mixes every frequency band, the lifted check's page gives the "
                    "growth per band)"
                    + ("; the ranges overlap." if overlap else "; the ranges do not overlap."))
    return lines
