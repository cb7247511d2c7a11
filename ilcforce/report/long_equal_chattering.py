"""NO-ILC against C3 and the robust variants over a long horizon, with the tuning's gains and chattering cap:
the page of ``experiments/long/long-equal-chattering*.toml`` (docs/long-run/equal-chattering-long.md).

The tuning (docs/tuning.md) ships each method's most accurate gains whose settled H at the last of 60 held-out
iterations is within the cap (C1's with the paper's gains): the methods are compared under the same chattering
ceiling. Whether what it chose holds on the horizon a user runs, the plant's change at j = 10 included, is read
here over the studies' 300 iterations on seeds that no tuning step used. Two studies feed the page: the tuned
five-bar file run for its shipped methods, and, for a method the tuning withheld (it found no stable gains
under the cap: plain C3), the same setup with the paper's gains, which is the only C3 there is to compare with.

Per method, over its seeds:

* **errors**: the position and force error 2-norms (Table 2's), each seed's mean over the last five iterations,
  median over the seeds that ran every iteration [95% bootstrap interval of that median];
* **settled H against the cap**: each seed's settled H at the last iteration over the cap, the largest over the
  task axes (1 is as much chattering as the cap allows), median [95% interval]; "against the cap" is
  :func:`ilcforce.report.equal_chattering.against_cap` (within only when the interval of the median H lies
  within the cap on every axis; uncertain when it crosses it);
* **divergence**: the seeds that did not complete every iteration, with the 95% Wilson interval of that rate,
  and the first iteration that did not complete (median over those seeds);
* **the plant's change**: the position error 2-norm at the change's first iteration p, and at p + 2, over its
  value at p - 1 (median over the seeds that ran to p + 2): how far the change throws the method back, and
  whether it has recovered two iterations later;
* **growth**: the learning-growth test's verdict on the seeds that ran every iteration
  (:func:`ilcforce.stability.verdict`, over its late window: after the plant's change).

A method is said to be more (or less) accurate than NO-ILC only where the two intervals of a median are
disjoint; overlapping intervals are "not separated".
"""

from __future__ import annotations

import argparse
import math
import posixpath
import sys
import tomllib
from pathlib import Path

import numpy as np
import pandas as pd

#: The tuned study (the tuned five-bar file's shipped methods) and the withheld methods' study (the paper's gains).
STUDY = "long-equal-chattering"
WITHHELD_STUDY = "long-equal-chattering-withheld"
#: The page and the table stem it writes.
PAGE = "equal-chattering-long.md"
TABLE = "equal_chattering_long"
#: The iterations at the end of a run whose error 2-norms are averaged.
LAST = 5
#: The iterations after the plant's change at which the position error is set against the one before it.
RECOVERY = 2
#: The method every other one is compared with.
SUBJECT = "no-ilc"
#: Where the seeds' values of two methods stand (disjoint 95% intervals of the medians, or not; or no value:
#: no seed of one of them ran every iteration).
LOWER, HIGHER, NOT_SEPARATED, NO_VALUE = "lower", "higher", "not separated", "-"


def is_study(name: str) -> bool:
    """A study this page reads (a ``make long`` study)."""
    return name in (STUDY, WITHHELD_STUDY)


def _interval_text(interval) -> str:
    from ilcforce.stats import format_interval

    return format_interval(interval)


def method_rows(results, cap, gains: str) -> list[dict]:
    """One row per method of one study (its first setting) against ``cap`` (settled H per task axis, N);
    ``gains`` says whose gains it ran. See the module doc for each column."""
    from ilcforce import stability
    from ilcforce.records import task_axes
    from ilcforce.report.equal_chattering import against_cap
    from ilcforce.report.growth_validation import setting_config, study_settings
    from ilcforce.report.tables import ordered_methods
    from ilcforce.stats import frequency_interval, median_interval

    k, _label, p = next(iter(study_settings(results)))
    config = setting_config(results, k)
    iterations = int(config.get("experiment", {}).get("iterations", 0))
    axes = task_axes(len(cap))
    metrics = results.setting_metrics(k)
    window = f"j = {iterations - LAST}..{iterations - 1}"
    rows = []
    for method in ordered_methods(metrics["method"].unique().tolist()):
        mine = metrics[metrics["method"] == method]
        e_p, e_f, ratio, by_axis, diverged, whole = [], [], [], {a: [] for a in axes}, [], []
        jump, after = [], []
        for seed, run in mine.groupby("seed", sort=True):
            run = run.sort_values("iteration")
            j = stability.diverged_at(run)
            complete = run[run["status"] == "complete"]
            e_at = complete.set_index("iteration")["position_error_2norm"]
            if {p - 1, p, p + RECOVERY} <= set(e_at.index):
                jump.append(float(e_at[p] / e_at[p - 1]))
                after.append(float(e_at[p + RECOVERY] / e_at[p - 1]))
            if math.isfinite(j) or len(complete) < iterations:
                diverged.append(j)
                continue
            whole.append(seed)
            tail = complete[complete["iteration"] >= iterations - LAST]
            e_p.append(float(tail["position_error_2norm"].mean()))
            e_f.append(float(tail["force_error_2norm"].mean()))
            end = complete[complete["iteration"] == iterations - 1].iloc[0]
            for a in axes:
                by_axis[a].append(float(end[f"chattering_task_{a}_settled"]))
            ratio.append(max(float(end[f"chattering_task_{a}_settled"]) / c for a, c in zip(axes, cap, strict=True)))
        seeds = mine["seed"].nunique()
        rate = frequency_interval(len(diverged), seeds)
        stopped = [j for j in diverged if math.isfinite(j)]
        growth = stability.learning_growth(mine[mine["seed"].isin(whole)], perturbation_iteration=p, config=config)
        rows.append({
            "method": method, "gains": gains, "seeds": seeds, f"ran all {iterations}": len(e_p),
            f"e_P 2-norm, {window} (m)": _interval_text(median_interval(e_p)),
            f"e_F 2-norm, {window} (N)": _interval_text(median_interval(e_f)),
            f"settled H / cap, j = {iterations - 1} (max over axes)": _interval_text(median_interval(ratio)),
            "against the cap": against_cap([by_axis[a] for a in axes], cap) if e_p else "-",
            "diverged": f"{len(diverged)} of {seeds}",
            "divergence rate [95% Wilson]": f"{rate.estimate:.2f} [{rate.low:.2f}, {rate.high:.2f}]",
            "diverged at j (median)": float(np.median(stopped)) if stopped else math.nan,
            "diverged at j (range)": f"{min(stopped):.0f}-{max(stopped):.0f}" if stopped else "-",
            f"e_P j = {p} / j = {p - 1} (median)": float(np.median(jump)) if jump else math.nan,
            f"e_P j = {p + RECOVERY} / j = {p - 1} (median)": float(np.median(after)) if after else math.nan,
            "growth test (seeds that ran all)": stability.verdict(growth, method) if whole else "-",
            "_e_p": median_interval(e_p), "_e_f": median_interval(e_f)})
    return rows


def _against(error: str) -> str:
    """The column saying where a method's ``error`` ("e_P", "e_F") stands against NO-ILC's."""
    return f"{error} against {SUBJECT}'s"


def compare(a, b) -> str:
    """Where median ``a`` stands against median ``b`` (two :class:`ilcforce.stats.Interval`): :data:`LOWER`
    or :data:`HIGHER` when their 95% intervals are disjoint, :data:`NOT_SEPARATED` otherwise, :data:`NO_VALUE`
    when either has none."""
    if a.n == 0 or b.n == 0:
        return NO_VALUE
    if a.high < b.low:
        return LOWER
    if a.low > b.high:
        return HIGHER
    return NOT_SEPARATED


def comparison_table(studies: dict[str, object]) -> pd.DataFrame:
    """Every method of the stored studies (``name -> read_study`` result), the tuned study first, against the
    tuned study's cap; columns of the module doc, and, per method, how its errors stand against NO-ILC's."""
    from ilcforce.report.equal_chattering import tuning_of

    tuned = studies.get(STUDY)
    tuning = tuning_of(tuned) if tuned is not None else None
    if tuning is None:
        return pd.DataFrame()
    cap = tuning["cap"]
    rows = method_rows(tuned, cap, f"tuned by {tuning.get('source', 'the tuning')}")
    if WITHHELD_STUDY in studies:
        rows += method_rows(studies[WITHHELD_STUDY], cap, "the paper's (the tuning withheld it)")
    subject = next((r for r in rows if r["method"] == SUBJECT), None)
    for row in rows:
        for key, name in (("_e_p", "e_P"), ("_e_f", "e_F")):
            row[_against(name)] = (NO_VALUE if subject is None or row is subject
                                   else compare(row[key], subject[key]))
    return pd.DataFrame(rows).drop(columns=["_e_p", "_e_f"])


def summary_lines(table: pd.DataFrame) -> list[str]:
    """The page's sentences, each read off a row of ``table``."""
    if table.empty:
        return []
    ran = next(c for c in table.columns if c.startswith("ran all "))
    ratio = next(c for c in table.columns if c.startswith("settled H / cap"))
    placed = [f"{r['method']} {r[ratio]}" for r in table.to_dict("records") if r[ran]]
    lines = [f"Settled H at the end over the cap, median [95% interval]: {', '.join(placed)}. All are compared "
             "under the same cap, not at the same H: an error told apart here may be bought with chattering "
             "(the tuning pages read every front at the same H: docs/tuning.md).", ""] if placed else []
    jump, after = (c for c in table.columns if c.startswith("e_P j = ") and c.endswith("(median)"))
    for row in table.to_dict("records"):
        text = (f"{row['method']}, gains {row['gains']}: diverged in {row['diverged']} seeds (rate "
                f"{row['divergence rate [95% Wilson]']})")
        if math.isfinite(row[jump]):
            text += (f"; the plant's change multiplies its e_P by {row[jump]:.2f} ({jump.split(' (')[0]}), and "
                     f"{after.split(' (')[0]} is {row[after]:.2f}")
        if row[ran]:
            text += f"; on the {row[ran]} that ran all, the growth test: {row['growth test (seeds that ran all)']}"
        if row[ran]:
            text += f"; settled H at the end {row['against the cap']} the cap"
        against_p, against_f = row[_against("e_P")], row[_against("e_F")]
        if row["method"] != SUBJECT and against_p != NO_VALUE:
            text += f"; against {SUBJECT}, its e_P is {against_p} and its e_F {against_f}"
        lines.append(f"- {text}.")
    return lines


def _experiment_file(results) -> str:
    """The experiment file a stored study ran, as a path from the repository's top when the study file sat in
    ``experiments/long/`` (its ``experiment`` is relative to the study file); the experiment's name otherwise."""
    try:
        experiment = str(tomllib.loads(results.study_toml)["study"]["experiment"])
    except (tomllib.TOMLDecodeError, KeyError, TypeError):
        return "EXPERIMENT"
    return experiment if Path(experiment).is_absolute() else posixpath.normpath(f"experiments/long/{experiment}")


def _read(results_dir: Path) -> dict[str, object]:
    from ilcforce.study import StudyStoreError, read_study

    found = {}
    for name in (STUDY, WITHHELD_STUDY):
        path = Path(results_dir) / "studies" / f"{name}.h5"
        if path.is_file():
            try:
                found[name] = read_study(path)
            except (StudyStoreError, OSError, KeyError, ValueError, TypeError):
                continue
    return found


def write_page(results_dir: Path, out_dir: Path) -> list[Path]:
    """Write the page and its table into ``out_dir`` from the studies under ``results_dir/studies``; nothing
    (an empty list) when the tuned study is absent or unreadable or its experiment is not a tuned file."""
    from ilcforce.plants import plant_title
    from ilcforce.records import task_axes
    from ilcforce.report import table_write, tables
    from ilcforce.report.growth_validation import setting_config
    from ilcforce.report.sections import perturbation_label
    from ilcforce.report.study import studies_provenance

    studies = _read(results_dir)
    table = comparison_table(studies)
    if table.empty:
        return []
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    written = table_write.write_table(table, out_dir, TABLE)
    tuned = studies[STUDY]
    config = setting_config(tuned, int(tuned.settings.iloc[0]["setting"]))
    tuning = config["tuning"]
    axes_text = ", ".join(f"H_{a} {c:.3g} N" for a, c in zip(task_axes(len(tuning["cap"])), tuning["cap"],
                                                               strict=True))
    seeds = sorted({int(s) for r in studies.values() for s in r.metrics["seed"].unique()})
    commands = " and ".join(f"`ilcforce study experiments/long/{name}.toml --workers 2 --results RESULTS`"
                            for name in studies)
    change = config.get("plant", {}).get("perturbation", {}).get("from_iteration", 10)
    iterations = int(config.get("experiment", {}).get("iterations", 0))
    lines = [
        f"# NO-ILC, C3 and the robust variants at equal chattering, over {iterations} iterations", "",
        "Generated by `python -m ilcforce.report.long_equal_chattering --results RESULTS --out docs/long-run` "
        f"(also by `make long`) from the studies run by {commands} ({studies_provenance(studies)}; seeds "
        f"{', '.join(map(str, seeds))}; the {plant_title(config['plant']['model'])}, the plant's change "
        f"{perturbation_label(config)} from "
        f"j = {change}).", "",
        __doc__.split("\n\n", 1)[1].strip().replace("``", "`").replace(
            ":func:`ilcforce.report.equal_chattering.against_cap`", "the tuned studies' rule").replace(
            ":func:`ilcforce.stability.verdict`", "the report's test").replace(
            ":class:`ilcforce.stats.Interval`", "interval"), "",
        f"The cap: {tuning.get('cap_reference', 'the reference')}'s settled H on the tuning's held-out seeds, "
        f"{axes_text} (the tuned file's `[tuning] cap`).", "",
        *[table_write.inert_markdown(f"{name}: {getattr(r, 'description', '')}.") for name, r in studies.items()],
        "", table_write.markdown_table(table), "", *summary_lines(table), "",
        "A cell's single run is " + " or ".join(
            f"`ilcforce simulate -c {_experiment_file(r)} -m METHOD -n {iterations} --seed SEED` (METHOD "
            f"{', '.join(tables.ordered_methods(r.metrics['method'].unique().tolist()))})" for r in studies.values())
        + "; the studies' cells are bit-identical to it (docs/studies.md).", ""]
    page = out_dir / PAGE
    page.write_text("\n".join(lines), encoding="utf-8")
    written.append(page)
    return written


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m ilcforce.report.long_equal_chattering",
                                     description=__doc__.split("\n")[0])
    parser.add_argument("--results", type=Path, default=Path("results"))
    parser.add_argument("--out", type=Path, default=Path("docs/long-run"))
    args = parser.parse_args(argv)
    written = write_page(args.results, args.out)
    if not written:
        print(f"error: no readable {STUDY} study of a tuned file in {args.results / 'studies'} (run make long)",
              file=sys.stderr)
        return 2
    print(f"wrote {written[-1]}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
