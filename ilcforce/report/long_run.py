"""Long runs: what learning does past the paper's 20 iterations, and how well the growth test foretells it.

Three kinds of study feed this page (``make long``; their files are in ``experiments/long/``):

* **growth validation** (``growth-validation*``): runs of 300 iterations, each a *case* whose truth the
  whole run shows and whose first 20 and 40 iterations the growth test judges; the confusion matrix of
  the two (``ilcforce/report/growth_validation.py`` states the rules, and the page below).
* **cause** (``long-run-cause``): C2 and C3 with one candidate cause of the divergence changed at a time
  (each noise source alone, the sample time, the initial velocity, C3's regressor acceleration): when and
  where in the iteration each run diverged, and how its memory grew, at t = 0 and settled.
* **cause over seeds** (``long-run-cause-seeds``): the noise mechanisms alone and together on five held-out
  seeds, each mechanism's divergence iteration as a distribution and whether they interact
  (:mod:`ilcforce.report.cause_seeds`).
* **long run** (``long-run-1000``): every method over 1,000 iterations on held-out seeds: H and the error
  norms against the iteration (median and band over seeds), the divergence iterations, the growth rate
  over the late half, and the test's verdict at j = 20 and 40 beside what the 1,000 iterations show.
* **C3-robust taken apart** (``c3-robust-ablation``): its own page, ``c3-robust-ablation.md``
  (:mod:`ilcforce.report.c3_robust_ablation`), written beside this one and linked from it.
* **NO-ILC at equal chattering** (``long-equal-chattering*``): the tuned five-bar's NO-ILC, C2-robust and
  C3-robust, and C3 with the paper's gains, over 300 iterations: its own page, ``equal-chattering-long.md``
  (:mod:`ilcforce.report.long_equal_chattering`), linked from this one.

``python -m ilcforce.report.long_run --results results --out docs/long-run`` writes ``long-run.md``, the
CSV tables and the figures; ``ilcforce report`` writes the same into its output when the stores exist.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np
import pandas as pd

from ilcforce import stability
from ilcforce.stability import diverged_at
from ilcforce.report import (c3_robust_ablation, cause_seeds, growth_pages, growth_validation, long_equal_chattering,
                             table_write, tables)
from ilcforce.report.study import studies_provenance
from ilcforce.report.growth_validation import (
    JUDGED_AT, TRUTH_FROM, setting_config, study_settings, confusion, confusion_text, validation_cases,
)
from ilcforce.stats import growth_rate

#: Study names (prefixes) this page reads from results/studies/.
VALIDATION_PREFIX = "growth-validation"
LONG_RUN = "long-run-1000"
CAUSE = "long-run-cause"
#: The spatial arm's long run (experiments/long/arm3-long.toml): a study of make long, left out of the findings.
ARM3_LONG = "arm3-long"
#: The summary ``make long`` writes beside its page, read by the findings.
SUMMARY = "summary.json"
#: The iterations at which the long-run table reports settled H.
H_AT = (19, 99, 499, 999)


# ---------------------------------------------------------------------------------------------
# The long run
# ---------------------------------------------------------------------------------------------


def long_run_table(results) -> pd.DataFrame:
    """Per method over the long-run study: divergences, settled H at H_AT, the late growth, the test's verdicts."""
    metrics = results.metrics
    rows = []
    p = next(iter(study_settings(results)))[2]
    for method in tables.ordered_methods(metrics["method"].unique().tolist()):
        mine = metrics[metrics["method"] == method]
        per_seed = {int(s): f.sort_values("iteration") for s, f in mine.groupby("seed")}
        diverged = sorted(diverged_at(f) for f in per_seed.values() if math.isfinite(diverged_at(f)))
        n = len(per_seed)
        row = {"method": method, "seeds": n, "diverged": len(diverged),
               "diverged_at (median)": float(np.median(diverged)) if diverged else math.nan,
               "diverged_at (first)": diverged[0] if diverged else math.nan}
        for j in H_AT:
            for axis in ("x", "y"):
                values = [float(f.loc[f["iteration"] == j, f"chattering_task_{axis}_settled"].iloc[0])
                          for f in per_seed.values() if (f["iteration"] == j).any()
                          and (f.loc[f["iteration"] == j, "status"] == "complete").all()]
                row[f"H_{axis} settled j={j}"] = float(np.median(values)) if values else math.nan
        window = mine[(mine["iteration"] >= 15) & (mine["iteration"] <= 19)]
        row["e_P j=15..19"] = float(window["position_error_2norm"].median())
        row["e_F j=15..19"] = float(window["force_error_2norm"].median())
        growth = stability.learning_growth(mine, perturbation_iteration=p, config=setting_config(results, 0))
        judged = growth[growth["judged"] & growth["quantity"].str.startswith("chattering_task_")]
        fastest = judged.sort_values("rate", ascending=False).iloc[0] if len(judged) else None
        windows = sorted(set(fastest.window.split("; "))) if fastest is not None else []
        row["settled H growth (late half), % per iteration"] = (
            f"{100 * (fastest.rate - 1):+.3f} [{100 * (fastest.rate_low - 1):+.3f}, {100 * (fastest.rate_high - 1):+.3f}] "
            f"({stability.short_name(fastest.quantity)}, {windows[0] if len(windows) == 1 else 'each seed its own window'})"
            if fastest is not None else "-")
        row["late verdict"] = stability.verdict(growth, method)
        rows.append(row)
    return pd.DataFrame(rows)


def _band(ax, frame: pd.DataFrame, column: str, method: str) -> None:
    from ilcforce.report.figure_style import method_color, method_text

    # a diverged iteration's value is not data
    wide = frame[frame["status"] == "complete"].pivot_table(index="iteration", columns="seed", values=column)
    values = wide.to_numpy(dtype=float)
    alive = np.isfinite(values).sum(axis=1)
    keep = alive > 0
    with np.errstate(all="ignore"):
        median = np.nanmedian(values[keep], axis=1)
        low, high = np.nanpercentile(values[keep], 5, axis=1), np.nanpercentile(values[keep], 95, axis=1)
    j = wide.index.to_numpy()[keep]
    color = method_color(method)
    ax.fill_between(j, low, high, color=color, alpha=0.15, linewidth=0)
    ax.plot(j, median, color=color, lw=1.2, label=method_text(method))
    for seed in wide.columns:
        ended = frame[(frame["seed"] == seed) & (frame["status"] != "complete")]
        if len(ended):
            jj = int(ended["iteration"].min())
            before = wide.loc[:jj - 1, seed].dropna()
            if len(before):
                ax.plot([jj - 1], [before.iloc[-1]], marker="x", color=color, ms=5, mew=1.2, ls="none")


#: What the long-run figure draws besides the methods' colours, in its legend (and the page's caption).
MEDIAN_TEXT = "line: median over the seeds still running"
BAND_TEXT = "band: 5-95% of those seeds"
CROSS_TEXT = "x: a seed's last complete iteration before it diverged"
PAPER_END_TEXT = "dotted: j = 19, the paper's last iteration"


def _key_entries(ax, p: int, change: str) -> None:
    """Legend proxies (grey) for what the figure draws besides the methods' colours: the median line, the
    band, the cross at a divergence, the plant's change and the paper's last iteration."""
    ax.plot([], [], color="0.3", lw=1.2, label=MEDIAN_TEXT)
    ax.fill_between([], [], [], color="0.3", alpha=0.15, linewidth=0, label=BAND_TEXT)
    ax.plot([], [], marker="x", color="0.3", ms=5, mew=1.2, ls="none", label=CROSS_TEXT)
    ax.plot([], [], color="0.5", ls="-.", lw=0.8, label=f"dash-dotted: the plant's change, {change} from j = {p}")
    ax.plot([], [], color="0.7", ls=":", lw=0.8, label=PAPER_END_TEXT)


def long_run_figure(results, out: Path) -> Path:
    """Settled H (X, Y) and the error 2-norms against the iteration: median line, 5-95% band over seeds,
    a cross where a seed diverged (at its last complete iteration); the legend names the methods and
    says what each of those marks is (a colour per method; the marks in grey)."""
    from matplotlib.figure import Figure

    from ilcforce.report.figure_files import save_figure
    from ilcforce.report.sections import perturbation_label

    metrics = results.metrics
    methods = tables.ordered_methods(metrics["method"].unique().tolist())
    fig = Figure(figsize=(9.5, 6.5))  # under 2,000 px a side at the style's dpi (120)
    axes = fig.subplots(2, 2, sharex=True)
    panels = (("chattering_task_x_settled", "settled H_x (N)"), ("chattering_task_y_settled", "settled H_y (N)"),
              ("position_error_2norm", "|e_P| 2-norm (m)"), ("force_error_2norm", "|e_F| 2-norm (N)"))
    p = next(iter(study_settings(results)))[2]
    for ax, (column, title) in zip(axes.ravel(), panels, strict=True):
        for method in methods:
            _band(ax, metrics[metrics["method"] == method], column, method)
        ax.set_yscale("log")
        ax.set_ylabel(title)
        ax.axvline(p, color="0.5", ls="-.", lw=0.8)
        ax.axvline(19, color="0.7", ls=":", lw=0.8)
    for ax in axes[1]:
        ax.set_xlabel("iteration j")
    handles, labels = axes[0, 0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="outside upper center", ncol=min(len(labels), 5), frameon=False,
               title="colour: method", title_fontsize="small")
    marks = Figure().subplots()  # the marks' proxies, kept out of the panels
    _key_entries(marks, p, perturbation_label(setting_config(results, next(iter(study_settings(results)))[0])))
    fig.legend(*marks.get_legend_handles_labels(), loc="outside lower center", ncol=3, frameon=False,
               fontsize="small")
    return save_figure(fig, out.parent, out.stem, ("png",))[0]


def _memory_column(frame: pd.DataFrame, kind: str) -> str | None:
    """The first learned memory's ``memory_<kind>_<name>`` column (theta_hat for C3, v for C2)."""
    found = sorted(c for c in frame if c.startswith(f"memory_{kind}_") and frame[c].notna().any())
    return found[-1] if found else None


def cause_table(results) -> pd.DataFrame:
    """Per setting and method of the cause study: where the run diverged, and how its memory grew."""
    rows = []
    for k, label, _p in study_settings(results):
        metrics = results.setting_metrics(k)
        for method, frame in metrics.groupby("method", sort=False):
            frame = frame.sort_values("iteration")
            complete = frame[frame["status"] == "complete"]
            diverged = diverged_at(frame)
            settled, start = _memory_column(complete, "settled"), _memory_column(complete, "start")
            late = complete[complete["iteration"] >= TRUTH_FROM]
            rate = (growth_rate(late[settled], iterations=late["iteration"])
                    if settled is not None and len(late) >= 3 else None)
            first, last = (complete.iloc[0], complete.iloc[-1]) if len(complete) else (None, None)
            rows.append({
                "setting": label, "method": str(method),
                "diverged at j": int(diverged) if math.isfinite(diverged) else "-",
                "at t (s)": (f"{float(frame.loc[frame['iteration'] == diverged, 'diverged_time'].iloc[0]):.3g}"
                             if math.isfinite(diverged) else "-"),
                "settled memory growth from j = 20": (f"x{rate.estimate:.4g} [{rate.low:.4g}, {rate.high:.4g}]"
                                                      if rate is not None and math.isfinite(rate.estimate) else "-"),
                "t = 0 memory per iteration": (f"+{(float(last[start]) - float(first[start])) / max(1, int(last['iteration']) - int(first['iteration'])):.3g}"
                                               if start is not None and first is not None else "-"),
                "settled H_x last": float(last["chattering_task_x_settled"]) if last is not None else math.nan,
                "last complete j": int(last["iteration"]) if last is not None else -1})
    return pd.DataFrame(rows)


def cause_figure(results, out: Path) -> Path:
    """The settled memory and the memory at t = 0 against the iteration, per setting, for each method."""
    from matplotlib.figure import Figure

    from ilcforce.report.figure_files import save_figure

    methods = tables.ordered_methods(results.metrics["method"].unique().tolist())
    fig = Figure(figsize=(9.5, 3.5 * len(methods)))
    axes = fig.subplots(len(methods), 2, squeeze=False)
    styles = ["-", "--", ":", "-.", (0, (5, 1)), (0, (3, 1, 1, 1)), (0, (1, 2)), (0, (6, 2, 1, 2))]
    for k, label, _p in study_settings(results):
        metrics = results.setting_metrics(k)
        for row, method in enumerate(methods):
            mine = metrics[metrics["method"] == method]
            frame = mine[mine["status"] == "complete"].sort_values("iteration")
            diverged = math.isfinite(diverged_at(mine))
            for col, kind in enumerate(("settled", "start")):
                column = _memory_column(frame, kind)
                if column is None:
                    continue
                ax = axes[row, col]
                ax.plot(frame["iteration"], frame[column], ls=styles[k % len(styles)], color=f"C{k % 8}", lw=1.1,
                        label=label)
                if diverged and len(frame):  # the run's last complete iteration before it diverged
                    ax.plot(frame["iteration"].iloc[-1], frame[column].iloc[-1], marker="x", color=f"C{k % 8}",
                            ms=7, mew=1.5)
                ax.set_yscale("log" if kind == "settled" else "linear")  # the t = 0 drift is linear: shown so
                ax.set_title(f"{method}: {stability.short_name(column)}"
                             + (" (log scale)" if kind == "settled" else " (linear scale)"))
                ax.set_xlabel("iteration j")
    handles, labels = axes[0, 0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="outside lower center", ncol=4, frameon=False)
    return save_figure(fig, out.parent, out.stem, ("png",))[0]


def write_page(results_dir: Path, out_dir: Path) -> list[Path]:
    """Write ``long-run.md`` with its tables and figure into ``out_dir`` from the long-run and
    growth-validation studies under ``results_dir/studies``; nothing when none of them is stored."""
    from ilcforce.report.figures import report_style
    from ilcforce.study import StudyStoreError, read_study

    study_dir = Path(results_dir) / "studies"
    found: dict[str, object] = {}
    for path in sorted(study_dir.glob("*.h5")) if study_dir.is_dir() else []:
        if path.stem.startswith(VALIDATION_PREFIX) or path.stem in (LONG_RUN, CAUSE, cause_seeds.STUDY):
            try:
                found[path.stem] = read_study(path)
            except (StudyStoreError, OSError, KeyError, ValueError, TypeError):
                continue
    ablation = c3_robust_ablation.write_page(results_dir, out_dir)  # its own page, with or without the others
    compared = long_equal_chattering.write_page(results_dir, out_dir)  # the same
    if not found:
        return ablation + compared
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    written: list[Path] = [*ablation, *compared]
    provenance = studies_provenance(found)
    cases = pd.DataFrame()
    lines = ["# Long runs: does learning stay bounded, and does the growth test see it coming?", "",
             f"Generated by `make long` ({provenance}). "
             + __doc__.split("\n\n", 1)[1].split("``python -m")[0].strip().replace("``", "`"),
             ""]
    # the cause account over seeds is not a validation set: its noise-free setting is one run five times over
    cases = validation_cases({name: results for name, results in found.items() if name != cause_seeds.STUDY})
    if len(cases):
        written += table_write.write_table(cases, out_dir, "growth_validation")
        rules = growth_validation.__doc__.split("\n\n", 1)[1].split(" The page\n")[0].replace(
            ":mod:`ilcforce.stability`", "`ilcforce/stability.py`").replace("``", "`")
        lines += ["## The growth test against the truth", "", rules, "",
                  f"{len(cases)} cases ({', '.join(sorted(set(cases['study'])))}): "
                  f"{int((cases['truth'] == 'unbounded').sum())} unbounded, {int((cases['truth'] == 'bounded').sum())} "
                  "bounded.", ""]
        for horizon in JUDGED_AT:
            table = confusion(cases, horizon).reset_index()
            written += table_write.write_table(table, out_dir, f"confusion_{horizon}")
            lines += [f"### The test on the first {horizon} iterations", "", table_write.markdown_table(table), "",
                      confusion_text(cases, horizon) + ".", ""]
        lines += ["### If every memory's growth counts", "",
                  "The truth above counts settled quantities only. Counting growth of the learned memories too "
                  "(whole grid and t = 0 alone, more than 10x from j = 20 to the end), the test at "
                  + " and at ".join(f"j = {h}: {confusion_text(cases, h, 'truth_with_memories')}" for h in JUDGED_AT)
                  + ".", ""]
        lines += ["### Every case", "", table_write.markdown_table(cases[[
            "study", "setting", "seed", "method", "iterations_run", "truth", "truth_reason", "memory_growth",
            "test_20", "test_40"]]), ""]
    sections = (
        (LONG_RUN, long_run_table, long_run_figure, "long_run", "Every method over 1,000 iterations", "",
         "settled H and error norms against the iteration",
         "Colour: the method (upper legend). Line: median over the seeds still running; band: 5-95% of them; "
         "x: a seed's last complete iteration before it diverged; dash-dotted: the plant's change; dotted: j = 19, "
         "the paper's last iteration (the lower legend says the same)."),
        (CAUSE, cause_table, cause_figure, "cause", "Why the paper's laws diverge: one candidate cause at a time",
         " (the account: docs/model.md#long-run).", "memory growth per setting",
         "Left: the learned memory's norm over t >= 20 ms (log scale: geometric growth is a straight line); "
         "right: its norm at t = 0 alone (linear scale: the start drift is a straight line). x: the last complete "
         "iteration of a run that diverged. A setting that changes only C3's law (the desired acceleration in "
         "Psi) runs C2 as in the paper's setup: its line lies under that one."),
    )
    for name, make_table, make_figure, stem, title, after, alt, caption in sections:
        if name not in found:
            continue
        table = make_table(found[name])
        written += table_write.write_table(table, out_dir, stem)
        with report_style():
            figure = make_figure(found[name], out_dir / f"{stem}.png")
        written.append(figure)
        lines += [f"## {title}", "", table_write.inert_markdown(str(getattr(found[name], "description", ""))) + after, "",
                  table_write.markdown_table(table), "", f"![{alt}]({figure.name})", "", caption, ""]
    if cause_seeds.STUDY in found:
        seeds = cause_seeds.per_seed_table(found[cause_seeds.STUDY])
        summary_table = cause_seeds.summary_table(seeds)
        written += table_write.write_table(seeds, out_dir, "cause_seeds")
        written += table_write.write_table(summary_table, out_dir, "cause_seeds_summary")
        lines += ["## The cause account over seeds", "",
                  table_write.inert_markdown(str(getattr(found[cause_seeds.STUDY], "description", ""))) + ".", "",
                  "Each mechanism's divergence iteration over the seeds (median [min, max] over the seeds that "
                  "diverged; every seed's run in `cause_seeds.csv`):", "",
                  table_write.markdown_table(summary_table), "",
                  *[f"- {line}" for line in cause_seeds.account_lines(seeds)], ""]
    lines += ["## The growth test out of sample", "",
              "The cases above are in sample: the test's rules were changed on them. Its validation on cases drawn "
              "after its rules were frozen: [growth-heldout.md](growth-heldout.md) (seeds 560-562, on which its "
              "stated horizon was then chosen), [growth-fresh.md](growth-fresh.md) (seeds 600-602, drawn after "
              "the horizon was frozen too, on which a three-class truth was then chosen) and "
              "[growth-third.md](growth-third.md) (seeds 700-702, drawn after that truth was frozen, on which the "
              "test's midpoint reading was then chosen) and [growth-fourth.md](growth-fourth.md) (seeds 800-802, "
              "drawn after that).", ""]
    if ablation:
        lines += ["## C3-robust taken apart", "",
                  f"Each of C3-robust's four changes to C3 alone and left out: [{ablation[-1].name}]({ablation[-1].name}).",
                  ""]
    if compared:
        lines += ["## NO-ILC at equal chattering", "",
                  "The tuned NO-ILC against C3 and the robust variants over 300 iterations: "
                  f"[{compared[-1].name}]({compared[-1].name}).", ""]
    # the test out of sample: what the findings state
    outside = [line for line in (growth_pages.fresh_headline(results_dir),
                                 *(growth_pages.set_headline(results_dir, p) for p in growth_pages.THREE_CLASS_SETS))
               if line]
    summary = {"provenance": provenance, "headline": headline_lines(found, cases) + outside}
    (out_dir / SUMMARY).write_text(json.dumps(summary, indent=1) + "\n", encoding="utf-8")
    written.append(out_dir / SUMMARY)
    page = out_dir / "long-run.md"
    page.write_text("\n".join(lines), encoding="utf-8")
    written.append(page)
    return written


def headline_lines(found: dict[str, object], cases: pd.DataFrame) -> list[str]:
    """The findings' sentences on the long runs: who diverges over 1,000 iterations, and how the growth
    test did against the truth."""
    lines = []
    if LONG_RUN in found:
        table = long_run_table(found[LONG_RUN])
        records = table.to_dict("records")
        said = [f"{r['method']} diverges in {r['diverged']} of {r['seeds']} seeds (median j = "
                f"{r['diverged_at (median)']:.0f})" for r in records if r["diverged"]]
        bounded = [r["method"] for r in records if not r["diverged"]]
        lines.append("Over 1,000 iterations of the paper's setup on 10 held-out seeds: " + "; ".join(said)
                     + (f"; {', '.join(bounded)} run all 1,000 in every seed" if bounded else "") + ".")
    if len(cases):
        lengths = " or ".join(f"{n:,}" for n in sorted(set(cases["iterations_run"].clip(lower=300).map(
            lambda n: 300 if n <= 300 else 1000))))
        lines.append(f"The growth test on {len(cases)} runs of {lengths} iterations, applied to their first 40 "
                     f"iterations: {confusion_text(cases, 40, names=False)}; to their first 20: "
                     f"{confusion_text(cases, 20, names=False)} (docs/long-run/long-run.md names each case).")
    return lines


#: Where ``make long`` commits its pages (with their date and commit), for reports of results folders that
#: hold no long study (``make reproduce`` does not run them: its report holds the committed pages).
COMMITTED = Path(__file__).resolve().parents[2] / "docs" / "long-run"
#: The folder of a report that holds these pages (the findings link ``long-run/long-run.md`` from the
#: report's top, as docs/findings.md does from docs/).
REPORT_FOLDER = "long-run"


def report_pages(results_dir: Path, out_dir: Path) -> list[Path]:
    """The long runs' pages in a report (``out_dir`` is its :data:`REPORT_FOLDER`): written from the long
    studies under ``results_dir/studies`` where they are stored (:func:`write_page`,
    :func:`ilcforce.report.growth_pages.write_pages`), and the committed pages of ``make long`` (:data:`COMMITTED`) copied in
    for what they did not write; nothing where there are neither (an installed package has no docs)."""
    from ilcforce.report.figure_files import copy_committed

    written = write_page(results_dir, out_dir) + growth_pages.write_pages(results_dir, out_dir)
    return written + copy_committed(COMMITTED, out_dir, skip=frozenset(path.name for path in written))


def committed_summary(directory: Path | None = None) -> dict | None:
    """The summary ``make long`` committed (docs/long-run/summary.json), or None where there is none
    (an installed package without the repository's docs)."""
    directory = directory or COMMITTED
    try:
        return json.loads((directory / SUMMARY).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None


def is_long_study(name: str) -> bool:
    """A study of ``make long`` (summarised by its committed page, not by the findings of a report)."""
    return name.startswith((VALIDATION_PREFIX, growth_validation.HELDOUT_PREFIX, growth_validation.LONGER_PREFIX,
                            growth_validation.FRESH_PREFIX, growth_validation.THIRD_PREFIX,
                            growth_validation.FOURTH_PREFIX)) or name in (
        LONG_RUN, CAUSE, cause_seeds.STUDY, ARM3_LONG, c3_robust_ablation.STUDY, c3_robust_ablation.LEAK_CHECK
    ) or long_equal_chattering.is_study(name)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m ilcforce.report.long_run", description=__doc__.split("\n")[0])
    parser.add_argument("--results", type=Path, default=Path("results"))
    parser.add_argument("--out", type=Path, default=Path("docs/long-run"))
    args = parser.parse_args(argv)
    written = write_page(args.results, args.out) + growth_pages.write_pages(args.results, args.out)
    if not written:
        print(f"error: no long-run or growth-validation study in {args.results / 'studies'} (run make long)",
              file=sys.stderr)
        return 2
    print(f"wrote {written[-1]}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
