"""The claim map: every claim's verdict over noise level x sample time (experiments/claim-map.toml).

A study sweeping ``noise.scale`` and ``simulation.sample_time`` (both, nothing else) is judged
setting by setting with the same rules as every report (:mod:`ilcforce.report.claims`); this module
lays the verdicts out as a map. Per (noise_scale, sample_time, claim): the claim's verdict and its
**binding** part: the judged part (central or secondary) with the smallest margin to its threshold
(the one nearest to failing, or failing worst), whose median over seeds and 95% bootstrap interval
of the median are the cell's statistic. A cell is **uncertain** where an interval of a median crosses
its threshold so that the claim's verdict is not settled (the rule: :mod:`ilcforce.report.claims`,
rules 2 and 3); its binding part is then the one of its uncertain parts with the smallest margin,
``between`` names the verdicts it lies between and ``uncertain_parts`` the parts whose interval crosses. ``claim_map.csv`` holds the rows; one heat map per claim colours each cell by verdict
and writes the statistic in.
"""

from __future__ import annotations

import math
import textwrap
from collections.abc import Mapping
from pathlib import Path

import numpy as np
import pandas as pd
from matplotlib.colors import ListedColormap
from matplotlib.figure import Figure

from ilcforce.report import figures
from ilcforce.report.claims import FAILS, HOLDS, IN_PART, NOT_EVALUABLE, UNCERTAIN, VERDICTS

KEYS = ("noise.scale", "simulation.sample_time")
COLUMNS = ["noise_scale", "sample_time", "claim", "verdict", "statistic", "statistic_low", "statistic_high",
           "seeds", "part", "margin", "between", "uncertain_parts"]
#: Cell colours by verdict (colour-blind safe: blue, yellow, vermillion, reddish purple, grey).
COLORS = {HOLDS: "#56B4E9", IN_PART: "#F0E442", FAILS: "#D55E00", UNCERTAIN: "#CC79A7", NOT_EVALUABLE: "#BBBBBB"}


def is_claim_map_study(results) -> bool:
    """A study sweeping exactly noise.scale and simulation.sample_time (a full grid)."""
    return sorted(getattr(results, "sweep_keys", [])) == sorted(KEYS) and not getattr(results, "labelled", False)


def claim_map(claim_rows: pd.DataFrame, settings: Mapping[str, tuple[float, float]],
              seeds: Mapping[str, int]) -> pd.DataFrame:
    """The map's rows (:data:`COLUMNS`) from a study's ``claims.csv`` rows
    (:func:`ilcforce.report.verdicts.claim_rows`). ``settings``: setting name -> (noise_scale,
    sample_time); ``seeds``: setting name -> seeds judged (1 for a deterministic setting)."""
    rows = []
    for name, (scale, sample_time) in settings.items():
        mine = claim_rows[claim_rows["setting"] == name]
        for claim, parts in mine.groupby("claim", sort=True):
            head = parts[parts["role"] == "claim"]
            verdict = str(head["verdict"].iloc[0]) if len(head) else NOT_EVALUABLE
            central = parts[parts["role"].isin(["central", "secondary"]) & np.isfinite(parts["margin"].astype(float))]
            if verdict == UNCERTAIN and (central["verdict"] == UNCERTAIN).any():  # the part that leaves it open
                central = central[central["verdict"] == UNCERTAIN]
            binding = central.loc[central["margin"].astype(float).idxmin()] if len(central) else None
            judged = parts[parts["role"].isin(["central", "secondary"])]
            unsure = judged.loc[judged["verdict"] == UNCERTAIN, "part"].astype(str)
            rows.append({"noise_scale": float(scale), "sample_time": float(sample_time), "claim": int(claim),
                         "verdict": verdict,
                         "statistic": float(binding["statistic"]) if binding is not None else math.nan,
                         "statistic_low": float(binding["statistic_low"]) if binding is not None else math.nan,
                         "statistic_high": float(binding["statistic_high"]) if binding is not None else math.nan,
                         "seeds": int(seeds.get(name, 0)),
                         "part": str(binding["part"]) if binding is not None else "",
                         "margin": float(binding["margin"]) if binding is not None else math.nan,
                         "between": str(head["between"].iloc[0] or "") if len(head) and "between" in head else "",
                         "uncertain_parts": ";".join(unsure)})
    frame = pd.DataFrame(rows, columns=COLUMNS)
    return frame.sort_values(["claim", "sample_time", "noise_scale"], ignore_index=True)


def _scale_text(value: float) -> str:
    return f"{value:.3g}"


def heat_map(rows: pd.DataFrame, claim: int, statement: str = "") -> Figure:
    """One claim's map: sample time across (ms), noise scale up, each cell coloured by verdict with the
    binding part's median written in (and the part's name below it; an uncertain cell's "?" after it)."""
    mine = rows[rows["claim"] == claim]
    scales = sorted(mine["noise_scale"].unique())
    times = sorted(mine["sample_time"].unique())
    codes = np.full((len(scales), len(times)), VERDICTS.index(NOT_EVALUABLE), dtype=float)
    fig = Figure(figsize=(1.5 * len(times) + 2.6, 0.5 * len(scales) + 1.8), layout="constrained")
    ax = fig.subplots()
    ax.grid(False)
    for row in mine.itertuples(index=False):
        i, k = scales.index(row.noise_scale), times.index(row.sample_time)
        codes[i, k] = VERDICTS.index(row.verdict) if row.verdict in VERDICTS else VERDICTS.index(NOT_EVALUABLE)
        value = "-" if not math.isfinite(row.statistic) else f"{row.statistic:.3g}"
        mark = " ?" if row.verdict == UNCERTAIN else ""
        ax.text(k, i, f"{value}{mark}\n{row.part}", ha="center", va="center", fontsize=6.5, color="black")
    ax.imshow(codes, cmap=ListedColormap([COLORS[v] for v in VERDICTS]), vmin=-0.5, vmax=len(VERDICTS) - 0.5,
              origin="lower", aspect="auto")
    ax.set_xticks(range(len(times)), [f"{t * 1e3:g}" for t in times])
    ax.set_yticks(range(len(scales)), [_scale_text(s) for s in scales])
    ax.set_xlabel("sample time Ts (ms)")
    ax.set_ylabel("noise.scale (1: our noise levels)")
    for verdict in VERDICTS:
        ax.plot([], [], marker="s", linestyle="none", markersize=8, color=COLORS[verdict], label=verdict)
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize="x-small", title="verdict",
              title_fontsize="x-small")
    title = f"Claim {claim}" + (f": {statement}" if statement else "")
    ax.set_title("\n".join(textwrap.wrap(title, 60)), fontsize="small")
    return fig


def _cells_text(cells: pd.DataFrame) -> str:
    by_time = []
    for sample_time, mine in cells.groupby("sample_time", sort=True):
        scales = ", ".join(_scale_text(s) for s in sorted(mine["noise_scale"]))
        by_time.append(f"Ts = {sample_time * 1e3:g} ms: noise.scale {scales}")
    return "; ".join(by_time)


def sentence(rows: pd.DataFrame) -> str:
    """Where each claim holds and where it is uncertain, whether any cell has every claim holding, and,
    when cells are uncertain, that their seeds are too few to settle them, in plain words."""
    if rows.empty:
        return "The claim map has no judged cell."
    n = int(rows.groupby(["noise_scale", "sample_time"]).ngroups)
    said = []
    for claim, mine in rows.groupby("claim", sort=True):
        holding = mine[mine["verdict"] == HOLDS]
        unsure = mine[mine["verdict"] == UNCERTAIN]
        said.append(f"claim {claim} holds in {len(holding)} of {n} cells"
                    + (f" ({_cells_text(holding)})" if 0 < len(holding) < n else "")
                    + (f" and is uncertain in {len(unsure)} ({_cells_text(unsure)})" if len(unsure) else ""))
    claims = rows["claim"].nunique()
    together = rows[rows["verdict"] == HOLDS].groupby(["noise_scale", "sample_time"]).filter(
        lambda g: len(g) == claims)
    if together.empty:
        every = "no cell has every claim holding"
    else:
        every = f"every claim holds together only at {_cells_text(together.drop_duplicates(['noise_scale', 'sample_time']))}"
    unsure = rows[rows["verdict"] == UNCERTAIN]
    if len(unsure):
        seeds = sorted({int(s) for s in unsure["seeds"]})
        few = f"{seeds[0]}" if len(seeds) == 1 else f"{seeds[0]} to {seeds[-1]}"
        every += (f"; {len(unsure)} of {len(rows)} claim cells are uncertain (the 95% interval of a median crosses "
                  f"its threshold): {few} seeds a cell are too few to settle them")
    return "Over the claim map, " + "; ".join(said) + f"; {every}."


def write_claim_map(rows: pd.DataFrame, directory: Path, statements: Mapping[int, str]) -> tuple[list[Path], list[str]]:
    """``claim_map.csv`` and ``fig_claim_map_<k>.png`` per claim in ``directory``; the findings lines."""
    from ilcforce.report.figure_files import save_figure
    from ilcforce.report.table_write import write_csv

    written = [write_csv(rows, Path(directory) / "claim_map.csv")]
    lines = ["## Claim map", "", sentence(rows), "",
             "Each cell: the claim's verdict over the seeds of that setting (colour) and the median of its binding "
             "part (the judged part nearest to failing, or failing worst; its name below the number); `claim_map.csv` has the 95% "
             "bootstrap interval of each median. A noise.scale of 0 is deterministic: one evaluation.", ""]
    with figures.report_style():
        for claim in sorted(rows["claim"].unique()):
            [path] = save_figure(heat_map(rows, int(claim), statements.get(int(claim), "")), Path(directory),
                                 f"fig_claim_map_{int(claim)}", ("png",))
            written.append(path)
            lines += [f"![claim {int(claim)}]({path.name})", ""]
    return written, lines
