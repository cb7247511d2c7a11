"""The noise level calibrated to Table 2 (docs/model.md#calibration).

The paper gives no noise levels. A study sweeping ``noise.scale`` alone (``experiments/calibration.toml``)
gives, per level and method, the converged error 2-norms: per seed the mean over the window claims 1
and 2 read before the plant changes (j = p-5..p-1, 5..9), then the median over seeds with its 95%
bootstrap interval of the median and the seeds' 5-95% spread. The calibrated level is the one at
which **C2's** converged norms best match Table 2's (C2: 7.6e-6 m, 0.096 N): the level minimising
the sum over position and force of log(ours / Table 2)^2, with our medians interpolated linearly in
log-log between the swept levels. Why C2 alone: Table 2 has no C1 numbers, and C3's are what claim 2
judges, so fitting them would fit the claim; C1's and C3's norms are drawn beside C2's and C3's
mismatch at the level found is reported, never fitted. The levels at which C2's position alone and
force alone match are reported too: when they differ, no one level reproduces both.

``python -m ilcforce.report.calibration STUDY.h5 [--write FILE.toml]`` prints the fit and, with
``--write``, writes the calibrated experiment file (``make calibrate``). The study report draws the
figure and writes ``calibration.csv`` (:func:`write_calibration`).
"""

from __future__ import annotations

import math
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
from matplotlib.figure import Figure

from ilcforce.report import figures, paper
from ilcforce.report.claim_parts import CONVERGED_WINDOW
from ilcforce.report.claims import spread
from ilcforce.report.seedframes import split_seeds
from ilcforce.stats import median_interval

#: The swept key a calibration study must have, alone.
KEY = "noise.scale"
QUANTITIES = (("position", "position_error_2norm", "m"), ("force", "force_error_2norm", "N"))
#: The method fitted (module docstring: why C2 alone).
FITTED = "c2"
#: Points of the fine log grid the interpolated mismatch is minimised on.
FINE_POINTS = 4001
#: The level found is written with this many significant figures (the swept levels are 1/4 decade apart).
DIGITS = 2


def is_calibration_study(results) -> bool:
    """A study sweeping noise.scale alone, over at least three positive levels."""
    if list(getattr(results, "sweep_keys", [])) != [KEY] or getattr(results, "labelled", False):
        return False
    values = [results.settings.loc[s, KEY] for s in results.settings.index]
    return sum(1 for v in values if isinstance(v, (int, float)) and v > 0) >= 3


def _window(p: int) -> tuple[int, int]:
    return max(1, p - CONVERGED_WINDOW), p - 1


def converged_norms(results, perturbation_iteration: int = paper.PERTURBATION_ITERATION) -> pd.DataFrame:
    """One row per (noise_scale, method, quantity): ``median``, ``low``, ``high`` (95% bootstrap
    interval of the median), ``spread_low``, ``spread_high`` (5-95% of the seeds), ``seeds`` (with a
    finite value), ``table2`` (the paper's value, NaN for C1). Per seed the value is the mean 2-norm
    over j = p-5..p-1; a seed whose run diverged there has none."""
    first, last = _window(perturbation_iteration)
    rows = []
    for setting in results.settings.index:
        scale = float(results.settings.loc[setting, KEY])
        frame = results.setting_metrics(int(setting))
        if frame.empty:
            continue
        by_seed = split_seeds(frame)
        methods = sorted({m for cells in by_seed.values() for m in cells})
        for method in methods:
            row = paper.table2_row(method)
            for quantity, column, _unit in QUANTITIES:
                values = []
                for cells in by_seed.values():
                    if method not in cells:
                        continue
                    found = [cells[method].value_at(column, j) for j in range(first, last + 1)]
                    values.append(float(np.mean(found)) if all(math.isfinite(v) for v in found) else math.nan)
                array = np.array(values, dtype=float)
                stat = median_interval(array)
                low5, high95 = spread(array)
                rows.append({"noise_scale": scale, "method": method, "quantity": quantity,
                             "median": stat.estimate, "low": stat.low, "high": stat.high,
                             "spread_low": low5, "spread_high": high95, "seeds": int(np.isfinite(array).sum()),
                             "table2": getattr(row, column) if row is not None else math.nan})
    return pd.DataFrame(rows)


@dataclass(frozen=True)
class Calibration:
    """The level found and what it matches.

    scale : the noise.scale minimising C2's log mismatch to Table 2 (DIGITS significant figures).
    position_only, force_only : the levels at which C2's position alone / force alone match best.
    ratios : (method, quantity) -> ours / Table 2 at ``scale`` (interpolated), for C2 and C3.
    span : (lowest, highest) swept positive level; a level found at an end is said to be so.
    """

    scale: float
    position_only: float
    force_only: float
    ratios: dict
    span: tuple[float, float]

    @property
    def at_edge(self) -> bool:
        return self.scale <= self.span[0] * 1.0001 or self.scale >= self.span[1] * 0.9999

    def text(self) -> str:
        """One paragraph stating the level found and how well it matches."""
        def r(method: str, quantity: str) -> str:
            value = self.ratios.get((method, quantity), math.nan)
            return f"{value:.2f}x" if math.isfinite(value) else "n/a"

        edge = " (at the end of the swept range: the best match may lie beyond it)" if self.at_edge else ""
        return (f"Calibrated noise.scale = {self.scale:g}{edge}: there C2's converged error norms are "
                f"{r('c2', 'position')} Table 2's in position and {r('c2', 'force')} in force (C3, not fitted: "
                f"{r('c3', 'position')}, {r('c3', 'force')}). C2's position alone matches best at "
                f"{self.position_only:.2g}, its force alone at {self.force_only:.2g}.")


def _interpolated(norms: pd.DataFrame, method: str, quantity: str, grid: np.ndarray) -> np.ndarray:
    mine = norms[(norms["method"] == method) & (norms["quantity"] == quantity) & (norms["noise_scale"] > 0)]
    mine = mine[np.isfinite(mine["median"]) & (mine["median"] > 0)].sort_values("noise_scale")
    if len(mine) < 2:
        return np.full(grid.shape, np.nan)
    return np.exp(np.interp(np.log(grid), np.log(mine["noise_scale"].to_numpy(float)),
                            np.log(mine["median"].to_numpy(float)), left=np.nan, right=np.nan))


def fit(norms: pd.DataFrame) -> Calibration | None:
    """The calibrated level from :func:`converged_norms`'s rows (module docstring); None without
    C2 norms at two positive levels."""
    positive = norms.loc[norms["noise_scale"] > 0, "noise_scale"]
    if positive.nunique() < 2:
        return None
    span = (float(positive.min()), float(positive.max()))
    grid = np.exp(np.linspace(math.log(span[0]), math.log(span[1]), FINE_POINTS))
    mismatch = {}
    for quantity, column, _unit in QUANTITIES:
        ours = _interpolated(norms, FITTED, quantity, grid)
        mismatch[quantity] = np.log(ours / getattr(paper.table2_row(FITTED), column)) ** 2
    total = mismatch["position"] + mismatch["force"]
    if not np.isfinite(total).any():
        return None

    def best(values: np.ndarray) -> float:
        return float(grid[int(np.nanargmin(values))])

    scale = float(f"{best(total):.{DIGITS}g}")
    ratios = {}
    for method in ("c2", "c3"):
        for quantity, column, _unit in QUANTITIES:
            value = _interpolated(norms, method, quantity, np.array([scale]))[0]
            ratios[(method, quantity)] = float(value / getattr(paper.table2_row(method), column))
    return Calibration(scale=scale, position_only=best(mismatch["position"]), force_only=best(mismatch["force"]),
                       ratios=ratios, span=span)


def figure(norms: pd.DataFrame, found: Calibration | None) -> Figure:
    """C1, C2 and C3's converged error norms against noise.scale (log-log; median with the 95%
    bootstrap interval of the median as a band), Table 2's C2 and C3 values as dashed lines in each
    method's colour, the calibrated level as a vertical line."""
    fig = Figure(figsize=(7.0, 6.4), layout="constrained")
    axes = fig.subplots(2, 1, sharex=True)
    for ax, (quantity, column, unit) in zip(axes, QUANTITIES, strict=True):
        mine = norms[(norms["quantity"] == quantity) & (norms["noise_scale"] > 0)]
        for method in sorted(mine["method"].unique()):
            line = mine[mine["method"] == method].sort_values("noise_scale")
            color = figures._color(method)
            ax.plot(line["noise_scale"], line["median"], marker="o", markersize=3, color=color,
                    label=figures.method_label(method))
            ax.fill_between(line["noise_scale"], line["low"], line["high"], color=color, alpha=0.2, linewidth=0)
            row = paper.table2_row(method)
            if row is not None:
                ax.axhline(getattr(row, column), color=color, linestyle="--", linewidth=1.0,
                           label=f"Table 2, {method.upper()}: {getattr(row, column):g} {unit}")
        if found is not None:
            ax.axvline(found.scale, color="0.3", linestyle=":", linewidth=1.2,
                       label=f"calibrated: {found.scale:g}" if quantity == "position" else None)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_ylabel(f"|e_{'P' if quantity == 'position' else 'F'}| 2-norm, mean j = 5..9 ({unit})")
        ax.legend(fontsize="x-small", ncol=2)
    axes[-1].set_xlabel("noise.scale (1: our noise levels, docs/model.md#noise)")
    axes[0].set_title("Converged error norms against the noise level (median over seeds, band: 95% "
                      "bootstrap interval of the median)", fontsize="small")
    return fig


#: The first line of every calibrated experiment file; --write replaces only a file that starts so.
HEADER = "# The paper's setup with the noise level calibrated to Table 2 (docs/model.md#calibration):"


def calibrated_toml(found: Calibration, source: str) -> str:
    """The experiment file of the calibrated setup: the paper's setup with noise.scale = the level found."""
    return (f"{HEADER}\n"
            f"# written by `make calibrate` (python -m ilcforce.report.calibration) from {source}.\n"
            f"# {found.text()}\n"
            "# Everything else is the paper's setup (experiments/paper.toml): only the noise level differs.\n"
            "[experiment]\n"
            'name = "paper-calibrated"\n'
            f'description = "The paper\'s setup with every noise source scaled by {found.scale:g}, the level at '
            'which C2\'s converged errors best match Table 2"\n\n'
            "[noise]\n"
            f"scale = {found.scale!r}\n")


def write_calibration(results, directory: Path, perturbation_iteration: int = paper.PERTURBATION_ITERATION
                      ) -> tuple[list[Path], list[str], Calibration | None]:
    """``calibration.csv`` and ``fig_calibration.png`` in ``directory``; the findings lines."""
    from ilcforce.report.figure_files import save_figure
    from ilcforce.report.table_write import write_csv

    norms = converged_norms(results, perturbation_iteration)
    found = fit(norms)
    written = [write_csv(norms, Path(directory) / "calibration.csv")]
    with figures.report_style():
        written += save_figure(figure(norms, found), Path(directory), "fig_calibration", ("png",))
    lines = ["## Calibration to Table 2", "",
             found.text() if found is not None else "No calibrated level: C2 has no converged norms at two levels.",
             "", "![calibration](fig_calibration.png)", ""]
    return written, lines, found


def main(argv: Sequence[str]) -> int:
    usage = "usage: python -m ilcforce.report.calibration STUDY.h5 [--write EXPERIMENT.toml]"
    args = list(argv)
    out = None
    if "--write" in args:
        at = args.index("--write")
        if at + 1 >= len(args):
            print(usage, file=sys.stderr)
            return 2
        out = Path(args[at + 1])
        del args[at:at + 2]
    if len(args) != 1:
        print(usage, file=sys.stderr)
        return 2
    from ilcforce.study import StudyStoreError, read_study

    path = Path(args[0])
    try:
        results = read_study(path)
    except (StudyStoreError, OSError, KeyError, ValueError) as exc:
        print(f"{path}: not a readable study store ({' '.join(str(exc).split())})", file=sys.stderr)
        return 2
    if not is_calibration_study(results):
        print(f"{path}: not a calibration study (it must sweep {KEY} alone over three or more levels > 0)",
              file=sys.stderr)
        return 2
    found = fit(converged_norms(results))
    if found is None:
        print(f"{path}: no calibrated level (C2 has no converged norms at two levels)", file=sys.stderr)
        return 1
    print(found.text())
    if out is not None:
        from ilcforce.report.figure_files import write_text_whole

        text = calibrated_toml(found, path.as_posix())
        if out.exists():
            try:
                old = out.read_text(encoding="utf-8")
            except (OSError, UnicodeDecodeError) as exc:
                print(f"{out}: cannot be read ({exc}); not overwritten", file=sys.stderr)
                return 2
            if not old.startswith(HEADER):
                print(f"{out}: not a calibrated experiment file written by this command; not overwritten",
                      file=sys.stderr)
                return 2
            if old == text:
                print(f"{out} unchanged")
                return 0
        write_text_whole(out, text)
        print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
