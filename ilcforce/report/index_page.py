"""The report's index page: a table of every experiment's verdicts (its claims, unstable learning,
divergences, a lost task, warnings), a user's runs and variants apart, and the report's warnings."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import pandas as pd

from ilcforce.report import claims as claims_module
from ilcforce.report import table_write, tables


def index_text(
    results_dir: Path,
    verdicts: Mapping[str, pd.DataFrame],
    experiment_warnings: Mapping[str, list[str]],
    warnings: list[str],
) -> str:
    lines = ["# ilcforce reports", "",
             "One report per experiment: each runs C1 (sliding mode), C2 (traditional ILC) and C3 (the paper's "
             "ILC + sliding mode law) under the setting its description names, and judges the paper's five "
             "claims part by part.", "", f"Results read from `{results_dir}`.", ""]
    if not verdicts:
        lines += ["No experiment found (expected `<experiment>/<method>.h5` stores).", ""]
    else:
        def table(names, with_reason: bool) -> str:
            rows = []
            for name in names:
                claims = verdicts[name]
                row: dict[str, object] = {"experiment": f"[{name}]({name}/report.md)",
                                          "description": claims.attrs.get("description", "")}
                if with_reason:
                    row["why it is a variant"] = claims.attrs.get("variant", "")
                for claim in claims.itertuples(index=False):
                    row[f"claim {claim.claim}"] = claim.verdict
                flagged = claims.attrs.get("flags", {})
                row["unstable learning"] = ", ".join(flagged) if flagged else "none"
                # "unstable learning" is a growth test over the complete iterations after the perturbation,
                # so a method that diverged before them is not flagged by it: its divergence has its own
                # column, and "unstable learning: none" no longer reads as "all was well"
                diverged = claims.attrs.get("diverged", {})
                row["diverged"] = ", ".join(f"{m} (j = {j})" for m, j in diverged.items()) or "none"
                # completed every iteration but lost the task after the plant's change (tables.task_loss)
                row[tables.FAILS_THE_TASK] = ", ".join(claims.attrs.get("task_loss", {})) or "none"
                row["warnings"] = len(experiment_warnings.get(name, []))
                rows.append(row)
            return table_write.markdown_table(pd.DataFrame(rows))

        as_written = [name for name, claims in verdicts.items() if not claims.attrs.get("variant")]
        variants = [name for name in verdicts if name not in as_written]
        if as_written:
            lines += ["Verdicts on the paper's five claims, one experiment file each, run as written (see each "
                      "report for the numbers and rules):", "", table(as_written, False)]
        if variants:
            lines += ["## Your runs and variants", "",
                      "Runs that are not an experiment file as written: stored under another experiment's "
                      "folder, or run with `--set` or `--seed` overrides. "
                      "Their descriptions say what they changed; they are kept out of the findings "
                      "(`findings.md`, the README's copy).", "", table(variants, True)]
        for number, claim in enumerate(claims_module.CLAIMS, start=1):
            lines.append(f"{number}. {claim.statement}")
        lines.append("")
    lines += ["## Warnings", ""]
    lines += [f"* {w}" for w in warnings] or ["None."]
    lines.append("")
    return "\n".join(lines)

