"""Report sections shared by single-run and study reports: claims part by part, learning
stability, method labels that say when a law differs from the paper's, the experiment's own
description, and the findings section the README copies.

Pure text from DataFrames; never reads files.
"""

from __future__ import annotations

import json
import re
import math
from collections.abc import Mapping

import pandas as pd

from ilcforce.plants import changed_parameter
from ilcforce.report import claims as claims_module
from ilcforce import stability
from ilcforce.report.table_write import inert_markdown, markdown_table

#: Settings under which a method's law is not the paper's: (method, config section, key, paper value).
PAPER_LAW = (("c3", "c3", "psi_acceleration", "measured"), ("c3-leak", "c3-leak", "psi_acceleration", "measured"),
             ("c1", "wall", "force_sign", "applied"), ("c2", "wall", "force_sign", "applied"),
             ("c3", "wall", "force_sign", "applied"))


def config_of(provenance: Mapping[str, object]) -> dict:
    """The stored JSON configuration of a run (empty when absent or unreadable)."""
    try:
        loaded = json.loads(str(provenance.get("config_json", "")))
    except ValueError:
        return {}
    return loaded if isinstance(loaded, dict) else {}


def description(config: Mapping[str, object]) -> str:
    """The experiment's own one-line description from its configuration, as Markdown that embeds
    nothing (:func:`~ilcforce.report.table_write.inert_markdown`; "" when absent)."""
    experiment = config.get("experiment", {})
    return inert_markdown(str(experiment.get("description", ""))) if isinstance(experiment, dict) else ""


def perturbation_label(config: Mapping[str, object]) -> str:
    """The true plant's change as the configuration states it, e.g. ``"m3 x 1.4"`` (five-bar) or
    ``"m2 x 1.4"`` (serial 2R arm); the paper's ``"m3 x 1.4"`` when the configuration says nothing."""
    plant = config.get("plant", {}) if isinstance(config, Mapping) else {}
    change = plant.get("perturbation", {}) if isinstance(plant, Mapping) else {}
    factor = change.get("factor") if isinstance(change, Mapping) else None
    parameter = changed_parameter(config)  # the plant's own when the configuration names none
    factor = 1.4 if not isinstance(factor, (int, float)) or isinstance(factor, bool) else factor
    return f"{parameter} x {factor:g}"


def variant_reason(folder: str, provenance: Mapping[str, object]) -> str:
    """Why the run in results folder ``folder`` is a user's variant rather than an experiment file
    run as written ("" when it is one): stored under another experiment's name (``--out``
    elsewhere, or the folder ``--set`` gives a variant), or run with ``--set`` / ``--seed``."""
    import shlex

    name = str(provenance.get("experiment", folder))
    if name != folder:
        return f"stored in results/{folder}/ but run as experiment '{name}'"
    try:
        words = shlex.split(str(provenance.get("command", "")))
    except ValueError:
        words = str(provenance.get("command", "")).split()
    given = [f"{word} {words[k + 1]}" if "=" not in word and k + 1 < len(words) else word
             for k, word in enumerate(words) if word.split("=", 1)[0] in ("--set", "--seed")]
    return "run with " + " ".join(given) if given else ""


def law_differences(method: str, config: Mapping[str, object]) -> list[str]:
    """How ``method``'s law under ``config`` differs from the paper's, e.g. ["psi_acceleration = desired"]."""
    found = []
    for name, section, key, paper_value in PAPER_LAW:
        values = config.get(section, {})
        if name == method and isinstance(values, dict) and key in values and values[key] != paper_value:
            found.append(f"{section}.{key} = {values[key]!r}, not the paper's {paper_value!r}")
    return found


def method_label(method: str, config: Mapping[str, object], flags: Mapping[str, str] | None = None) -> str:
    """``c3`` -> ``c3 [law differs from the paper: ...] (unstable learning)`` as it applies."""
    text = method
    differences = law_differences(method, config)
    if differences:
        text += " [law differs from the paper: " + "; ".join(differences) + "]"
    if flags and method in flags:
        text += f" ({stability.UNSTABLE})"
    return text


def _interval(row) -> str:
    if not math.isfinite(row.median):
        return "–"
    if row.low == row.high == row.median:
        return f"{row.median:.3g}"
    return f"{row.median:.3g} [{row.low:.3g}, {row.high:.3g}]"


def _spread(row) -> str:
    low, high = getattr(row, "spread_low", math.nan), getattr(row, "spread_high", math.nan)
    if not (math.isfinite(low) and math.isfinite(high)) or low == high:
        return "–"
    return f"{low:.3g} to {high:.3g}"


def _margin(row) -> str:
    margin = getattr(row, "margin", math.nan)
    return f"{100 * margin:+.0f}%" if math.isfinite(margin) else "–"


def claims_markdown(parts: pd.DataFrame, flags: Mapping[str, str]) -> list[str]:
    """The claims section: one summary table, then each claim's parts with frequencies and intervals."""
    summary = claims_module.claim_summary(parts)
    n = int(parts["n_seeds"].iloc[0]) if len(parts) else 0
    deterministic = bool(len(parts) and "deterministic" in parts.columns and parts["deterministic"].iloc[0])
    if deterministic:
        lines = [f"Judged once: {claims_module.ONE_EVALUATION}.", ""]
    else:
        lines = [f"Judged over {n} seed{'s' if n != 1 else ''}. Each number is the median over seeds with the "
                 "95% percentile-bootstrap interval of the median (where the median lies; where a single seed "
                 "falls is the seeds' 5-95% column); each frequency counts the seeds where the part passes "
                 "(95% Wilson interval in brackets); the margin is the median's distance to the threshold (the nearer "
                 "edge of a range) as a fraction of it (>= 0 passes). With one seed there is no interval.", ""]
    lines.append(markdown_table(summary[["claim", "verdict", "frequency", "parts", "statement"]]))
    if flags:
        lines += ["Methods flagged for unstable learning (see Learning stability): "
                  + "; ".join(f"{m}: {text}" for m, text in flags.items()) + ".", ""]
    for claim in claims_module.CLAIMS:
        mine = parts[parts["claim"] == claim.number] if len(parts) else parts
        beside = claims_module.beside_text(mine)  # other readings' verdicts, where they differ (rule 6)
        lines += [f"### Claim {claim.number}: {claim.statement}", "",
                  f"Verdict: **{summary.loc[summary['claim'] == claim.number, 'verdict'].iloc[0]}**"
                  f"{f' ({beside})' if beside else ''}. "
                  f"Paper: {claim.paper} Parts: {claim.rule}", ""]
        rows = []
        for row in mine.itertuples(index=False):
            judged = row.role not in claims_module.NOT_JUDGED
            rows.append({
                "part": row.part_text, "role": row.role, "statistic": row.statistic,
                "passes when": getattr(row, "threshold", "") or "–",
                "median [95% CI of the median]": _interval(row), "seeds 5-95%": _spread(row),
                "margin": _margin(row), "over seeds": row.distribution,
                "passes": (f"{row.passed} of {row.evaluable} [{row.share_low:.2f}, {row.share_high:.2f}]"
                           if judged and row.evaluable else "–"),
                "verdict": row.part_verdict, "note": row.notes,
            })
        if rows:
            lines.append(markdown_table(pd.DataFrame(rows)))
    lines += ["### How the verdicts are reached", "", _RULE_TEXT, ""]
    return lines


_RULE_TEXT = (
    "A part passes or fails in each seed by its stated threshold (a part that needs a method which diverged "
    "within the iterations it reads fails; a baseline that diverged counts as an infinite norm); a part with "
    "a weaker reading (claim 2: C3 below C2, by less than the paper's margin) meets it or not. Over seeds a "
    "part holds when it passes in a strict majority of the seeds where it is evaluable, holds in part when "
    "it passes or meets its weaker reading in a strict majority, and fails otherwise; it is not evaluable "
    "without an evaluable seed or when the method it praises diverged in a majority of the seeds (the note "
    "names where). A claim is not evaluable when a central part is; otherwise it holds when every judged "
    "part holds, fails when no central part holds or holds in part, and holds in part otherwise. Each part's "
    "median comes with the 95% bootstrap interval of the median, the 5-95% spread of the seeds and its "
    "margin to the threshold (its distance to the nearest edge of the passing range as a fraction of that "
    "edge, >= 0 passing). A part whose interval of the median crosses its threshold (or its weaker reading's) "
    "is uncertain, between the verdicts a median in that interval would give; a claim with uncertain parts "
    "takes the verdict they give read either way, and is uncertain where the readings differ (so it holds only "
    "when every judged part holds with its interval clear, and fails only when every central part fails "
    "clear of its threshold). One seed's interval is its value: a single run is never uncertain. Shown parts (and cause "
    "parts, which name a modelling choice behind a verdict) are printed, never judged. The claim's frequency "
    "applies the same rule to each seed, and counts a seed where a praised method diverged as such, not as "
    "a failure; a deterministic setting (no noise source active) is one evaluation. Where the judged metric "
    "read without the first 20 ms (settled) would change a claim's verdict, that verdict is said beside it."
)


def stability_markdown(growth: pd.DataFrame, flags: Mapping[str, str]) -> list[str]:
    """The learning-stability section: the stated test, the rates, and the flags."""
    text = stability.__doc__.split("The test\n--------\n", 1)[-1].strip()
    lines = [re.sub(r":\w+:`([^`]+)`", r"`\1`", text).replace("``", "`"), ""]
    if growth.empty:
        return lines + [f"Not evaluable: {stability.NOT_FITTED.removeprefix('not evaluable (').rstrip(')')}.", ""]
    table = pd.DataFrame({
        "method": growth["method"], "quantity": [stability.short_name(q) for q in growth["quantity"]],
        "judged": ["yes" if j else "shown" for j in growth["judged"]],
        "window": growth["window"],
        "rate per iteration [95%]": [f"{r.rate:.4g} [{r.rate_low:.4g}, {r.rate_high:.4g}]"
                                     for r in growth.itertuples(index=False)],
        "10x in (iterations)": [f"{n:.0f}" if math.isfinite(n) else "-" for n in growth["iterations_to_10x"]],
        "value at the window's end": [f"{v:.3g}" for v in growth["value_end"]],
        "seeds growing": [f"{r.growing} of {r.fitted}" if r.judged else "-" for r in growth.itertuples(index=False)],
        "grows": ["yes" if g else ("saturating" if sat else "inconclusive" if i else "no") if j else "-"
                  for g, sat, i, j in zip(growth["grows"], growth["saturating"], growth["inconclusive"],
                                          growth["judged"], strict=True)],
    })
    lines.append(markdown_table(table))
    if flags:
        lines += [f"* **{m}**: {text}" for m, text in flags.items()]
    else:
        lines.append("* No method is flagged: nothing grows in a majority of seeds.")
    lines.append("")
    return lines
