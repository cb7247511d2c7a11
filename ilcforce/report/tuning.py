"""The page of a tuning (``ilcforce tune``): every search's convergence, every method's front re-evaluated on
held-out seeds (``pareto.csv`` and one figure of every front against the chattering cap), and what each
method ships.

Figures draw on the Axes they are given and return the artists, as every report figure does; their inputs
are :func:`trials_frame` (one row per trial) and :func:`pareto_frame` (one row per held-out point).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pandas as pd
from matplotlib.axes import Axes

from ilcforce.controllers import REGISTRY
from ilcforce.report.table_write import inert_markdown

#: Where ``make tune`` commits each tuning's page (with its date and commit), for reports of results folders
#: that hold no tuning store (``make reproduce`` does not tune: it reports the committed page).
COMMITTED = Path(__file__).resolve().parent.parent.parent / "docs" / "tuning"


def _dimension(gains: list[dict]) -> int:
    return sum(isinstance(e, dict) for g in gains for e in g["elements"])


def searches(definition: dict, trials: dict[str, dict[int, dict]]) -> dict[str, dict]:
    """Per method, how far its search went (:func:`ilcforce.tune.search.extent`) from the stored trials."""
    from ilcforce.tune.search import extent

    budget = definition["budget"]
    out = {}
    for method in definition["methods"]:
        first = budget["base"] + budget["per_dimension"] * _dimension(definition["gains"][method])
        out[method] = extent(trials.get(method, {}), first, budget["extend"] * first, budget["stop_gain"])
    return out


def trials_frame(trials: dict[str, dict[int, dict]]) -> pd.DataFrame:
    """One row per (method, trial) in trial order: method, trial, state, error, chattering (NaN when
    failed), feasible, hypervolume (of the method's feasible front up to and including this trial),
    message, elapsed (s), then one column per gain (dotted key; a vector gain holds a list)."""
    from ilcforce.tune.front import hypervolume
    from ilcforce.tune.search import point
    from ilcforce.tune.objectives import HV_REFERENCE

    rows = []
    for method, stored in trials.items():
        seen = []
        for number in sorted(stored):
            record = stored[number]
            if (p := point(record)) is not None:
                seen.append(p)
            complete = record["state"] == "complete"
            rows.append({"method": method, "trial": number, "state": record["state"],
                         "error": record["value"] if complete else math.nan,
                         "chattering": record["chattering"] if complete else math.nan,
                         "feasible": bool(record["feasible"]), "hypervolume": hypervolume(seen, HV_REFERENCE),
                         "message": record["message"], "elapsed": record["elapsed"], **record["gains"]})
    return pd.DataFrame(rows, columns=None if rows else ["method", "trial", "state", "error", "chattering",
                                                          "feasible", "hypervolume", "message", "elapsed"])


def pareto_frame(definition: dict, trials: dict, heldout: dict, chosen: dict, cap) -> pd.DataFrame:
    """``pareto.csv``: one row per point re-evaluated on the held-out seeds: method, trial, every gain, the
    held-out medians e_P, e_F (RMS, last score_last iterations), the settled H at the last iteration per
    task axis (H_x, H_y; or H_u, H_v, H_n), relative chattering max over the axes of H_a / cap_a, feasible
    (in the search), front (on the search's front; trial 0 is evaluated either way), stable (no held-out
    seed diverged or was flagged), diverged iteration (first over seeds), flagged seeds, under cap, shipped."""
    from types import SimpleNamespace

    from ilcforce.tune.heldout import summary
    from ilcforce.tune.spec import definition_axes

    tuning = SimpleNamespace(objective=definition["objective"])
    axes = definition_axes(definition)
    rows = []
    for (method, number), record in sorted(heldout.items(), key=lambda kv: (definition["methods"].index(kv[0][0]),
                                                                             kv[0][1])):
        s = summary(tuning, record)
        trial = trials[method][number]
        relative = (max(s[f"h_{a}"] / c for a, c in zip(axes, cap, strict=True))
                    if cap and s[f"h_{axes[0]}"] is not None else math.nan)
        shipped = chosen.get(method) is not None and chosen[method]["trial"] == number
        rows.append({"method": method, "trial": number, **{k: _plain(v) for k, v in trial["gains"].items()},
                     "e_P": s["e_p"], "e_F": s["e_f"], **{f"H_{a} settled": s[f"h_{a}"] for a in axes},
                     "chattering / cap": relative, "error objective": s["error"],
                     "feasible": bool(trial["feasible"]), "stable": s["stable"],
                     "diverged iteration": s["diverged"] if s["diverged"] is not None else math.nan,
                     "flagged seeds": s["flagged"], "under cap": bool(relative <= 1.0) if relative == relative else False,
                     "shipped": shipped})
    frame = pd.DataFrame(rows)
    frame.attrs["units"] = {"e_P": "m", "e_F": "N", **{f"H_{a} settled": "N" for a in axes}}
    return frame


def _plain(value):
    return json.dumps(value) if isinstance(value, list) else value


def _style(method: str) -> tuple[str | None, str]:
    spec = REGISTRY.get(method)
    return (spec.color, spec.label) if spec is not None else (None, method)


def plot_convergence(ax: Axes, frame: pd.DataFrame, method: str, state: dict) -> list:
    """The hypervolume of the method's feasible front against the trial number (a step line), its first
    budget (a dotted line) and where the search stopped (a ring: converged; a cross: not)."""
    rows = frame[frame["method"] == method].sort_values("trial")
    color, label = _style(method)
    artists = [ax.step(rows["trial"], rows["hypervolume"], where="post", color=color, label=label)[0]]
    artists.append(ax.axvline(state["first"] - 1, color=color, ls=":", lw=0.8))
    if len(rows):
        end = rows.iloc[-1]
        artists.append(ax.plot(end["trial"], end["hypervolume"], "o" if state["converged"] else "x", ms=7,
                               mfc="none", color=color)[0])
    return artists


def convergence_figure(frame: pd.DataFrame, states: dict[str, dict]):
    """One panel per method (:func:`plot_convergence`), three to a row, each with its own y scale."""
    from matplotlib.figure import Figure

    from ilcforce.tune.search import outcome

    methods = [m for m in states if (frame["method"] == m).any()]
    columns = min(3, max(1, len(methods)))
    rows = -(-len(methods) // columns)
    fig = Figure(figsize=(3.6 * columns, 2.2 * rows + 0.5), layout="constrained")
    axes = fig.subplots(rows, columns, squeeze=False).ravel()
    for ax, method in zip(axes, methods):
        plot_convergence(ax, frame, method, states[method])
        s = states[method]
        ax.set_title(f"{_style(method)[1]}: {s['trials']} trials, {outcome(s)}", fontsize="small")
        ax.set_xlabel("trial", fontsize="small")
        ax.set_ylabel("hypervolume", fontsize="small")
    for ax in axes[len(methods):]:
        ax.set_visible(False)
    fig.suptitle("Each search's feasible front: its hypervolume against the trial (dotted: the first budget; "
                 "ring: stopped converged, cross: not)", fontsize="small")
    return fig


def plot_front(ax: Axes, pareto: pd.DataFrame, method: str) -> list:
    """One method's held-out points: error objective against chattering relative to the cap (log x). Every
    stable point is a dot; the line joins those no other stable point beats on both (the front as the
    held-out seeds see it); unstable points are crosses at the foot; the shipped one is ringed."""
    from ilcforce.tune.front import pareto_indices

    rows = pareto[pareto["method"] == method]
    color, label = _style(method)
    stable = rows[rows["stable"] & rows["error objective"].notna()]
    points = list(zip(stable["chattering / cap"], stable["error objective"]))
    front = stable.iloc[pareto_indices([(c, e) for c, e in points])] if len(stable) else stable
    artists = [ax.plot(front["chattering / cap"], front["error objective"], "-", lw=1.2, color=color, label=label)[0],
               ax.plot(stable["chattering / cap"], stable["error objective"], "o", ms=3.5, color=color)[0]]
    unstable = rows[~rows["stable"] & rows["chattering / cap"].notna()]
    if len(unstable):
        artists.append(ax.plot(unstable["chattering / cap"], np.zeros(len(unstable)) + 0.02, "x", color=color,
                               transform=ax.get_xaxis_transform(), clip_on=False)[0])
    shipped = rows[rows["shipped"]]
    if len(shipped):
        artists.append(ax.plot(shipped["chattering / cap"], shipped["error objective"], "o", ms=10, mfc="none",
                               mew=1.5, color=color)[0])
    return artists


def fronts_figure(pareto: pd.DataFrame, methods: list[str], title: str):
    """Every method's held-out front on one axes (:func:`plot_front`) with the cap as a vertical line."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(8.5, 5.2), layout="constrained")
    ax = fig.subplots()
    for method in methods:
        plot_front(ax, pareto, method)
    ax.axvline(1.0, color="0.3", ls="--", lw=1, label="the cap (C1's chattering)")
    ax.set_xscale("log")
    ax.set_xlabel("settled chattering at the last held-out iteration / cap (max over the task axes)")
    ax.set_ylabel("error objective: log10(e_P / 1 mm) + log10(e_F / 1 N)")
    ax.set_title(title, fontsize="medium")
    from matplotlib.ticker import FuncFormatter

    def some(x, _pos):  # 0.2, 0.5, 2, 5 ... between the decades: every minor label crowded a wide axis
        return f"{x:g}" if x > 0 and round(x / 10 ** math.floor(math.log10(x))) in (2, 5) else ""

    ax.xaxis.set_major_formatter(FuncFormatter(lambda x, _pos: f"{x:g}"))
    ax.xaxis.set_minor_formatter(FuncFormatter(some))
    ax.tick_params(axis="x", which="minor", labelsize="x-small")
    ax.legend(fontsize="small", ncol=2, loc="best")
    return fig


def outcome_table(definition: dict, states: dict, chosen: dict, trials: dict) -> pd.DataFrame:
    """Per method: its search (trials, first budget, most, converged, last-quarter gain, feasible trials,
    front) and what it ships (trial, held-out medians: e_P, e_F, H per task axis), or the words of
    :data:`NONE_UNDER_CAP`."""
    from ilcforce.tune.heldout import NONE_UNDER_CAP
    from ilcforce.tune.search import outcome
    from ilcforce.tune.spec import definition_axes

    axes = definition_axes(definition)
    rows = []
    for method in definition["methods"]:
        s, point = states[method], chosen.get(method)
        stored = trials.get(method, {})
        rows.append({"method": method, "trials": s["trials"], "first budget": s["first"], "at most": s["most"],
                     "converged": {"converged": "yes", "NOT converged": "NO"}.get(outcome(s), outcome(s)),
                     "front gain, last quarter": f"{s['gain']:.1%}" if math.isfinite(s["gain"]) else "-",
                     "feasible": sum(r["feasible"] for r in stored.values()), "front": s["front"],
                     "shipped": f"trial {point['trial']}" if point else NONE_UNDER_CAP,
                     "e_P": point["e_p"] if point else math.nan, "e_F": point["e_f"] if point else math.nan,
                     **{f"H_{a}": point[f"h_{a}"] if point else math.nan for a in axes}})
    frame = pd.DataFrame(rows)
    frame.attrs["units"] = {"e_P": "m", "e_F": "N", **{f"H_{a}": "N" for a in axes}}
    return frame


def write_tuning_report(path, out_dir, formats: tuple[str, ...]) -> tuple[list, list[str]]:
    """``<out_dir>/<name>/index.md`` with ``tuning.csv`` (per method), ``pareto.csv`` (per held-out point),
    ``fronts.<fmt>`` and ``convergence.<fmt>`` for the tuning store ``path``. Returns (files, index lines).
    Raises TuningStoreError for a store that is not valid."""
    from types import SimpleNamespace

    from ilcforce.report.figure_files import save_figure, write_text_whole
    from ilcforce.report.table_write import markdown_table, write_table
    from ilcforce.store.tuning import read_header, read_heldout
    from ilcforce.tune.heldout import choose
    from ilcforce.tune.objectives import chattering_formula, per_axis_text
    from ilcforce.tune.runner import read_trials, stored_check, validate_tuning
    from ilcforce.tune.spec import definition_axes

    path, out_dir = Path(path), Path(out_dir)
    validate_tuning(path)
    header = read_header(path)
    definition = json.loads(header["definition_json"])
    trials = read_trials(path)
    heldout = read_heldout(path, stored_check(path))
    cap_spec = definition["cap"]
    axes = definition_axes(definition)
    view = SimpleNamespace(methods=definition["methods"], cap_reference=cap_spec["reference"],
                           cap_factor=cap_spec["factor"], objective=definition["objective"])
    chosen, cap = choose(view, SimpleNamespace(heldout=heldout))
    states = searches(definition, trials)
    name = header["name"]
    target = out_dir / path.name  # a renamed copy of a store is its own page, not the original's
    target.mkdir(parents=True, exist_ok=True)
    files: list[Path] = []
    frame = trials_frame(trials)
    pareto = pareto_frame(definition, trials, heldout, chosen, cap)
    outcome = outcome_table(definition, states, chosen, trials)
    files += write_table(outcome, target, "tuning")
    if len(pareto):
        files += write_table(pareto, target, "pareto")
    if formats and len(frame):
        files += save_figure(convergence_figure(frame, states), target, "convergence", formats)
    if formats and len(pareto):
        files += save_figure(fronts_figure(pareto, definition["methods"], f"{name}: every method's front on "
                                           f"{len(definition['heldout_seeds'])} held-out seeds x "
                                           f"{definition['heldout_iterations']} iterations"), target, "fronts", formats)
    b = definition["budget"]
    checks = [c for stored in trials.values() for r in stored.values() for c in r["checks"]]
    ran, planned = sum(c["iterations_run"] for c in checks), sum(c["planned"] for c in checks)
    pruning = (f" Check runs ran {ran:,} of {planned:,} iterations: pruning (a divergence, or a flag at 40 or 50 "
               f"iterations) saved {1 - ran / planned:.0%} of them." if planned else "")
    shipped = [m for m in definition["methods"] if chosen.get(m)]
    withheld = [m for m in definition["methods"] if not chosen.get(m)]
    text = [f"# Tuning {name}" + (f" (the store {path.name})" if path.name != name else ""), "",
            *([inert_markdown(str(header["description"])), ""] if header.get("description") else []),
            f"Each method's gains searched for two objectives on seeds {_seeds(definition['seeds'])} x "
            f"{definition['iterations']} iterations (the last {definition['score_last']} scored): the error "
            f"log10(e_P / 1 mm) + log10(e_F / 1 N) and the chattering log10({chattering_formula(axes)}) of the "
            f"settled H, relative to {cap_spec['reference']} with the experiment's gains. A trial is feasible only "
            f"when check seeds {_seeds(definition['check_seeds'])} run {definition['check_iterations']} iterations "
            "without divergence and the growth test flags neither (a check run flagged at 40 or 50 iterations "
            f"stops there). Budget: {b['base']} + {b['per_dimension']} x (searched parameters) trials, then one at a "
            f"time until the feasible front's hypervolume grew less than {b['stop_gain']:.0%} over the last quarter "
            f"of the trials, at most {b['extend']}x the first budget. Each front (at most 6 points, its ends "
            f"always) and trial 0 are then re-run on held-out seeds {_seeds(definition['heldout_seeds'])} x "
            f"{definition['heldout_iterations']} iterations; the shipped point is the stable one with the lowest "
            "error whose settled H at the last iteration is within the cap"
            + (f" ({per_axis_text(axes, cap)}: {cap_spec['factor']:g} x {cap_spec['reference']}'s "
               "held-out median)." if cap else "."), "",
            f"{sum(s['trials'] for s in states.values())} trials in all.{pruning}", "",
            f"Shipped: {', '.join(shipped) or 'none'}." + (f" No stable gains under the cap: {', '.join(withheld)}."
                                                          if withheld else ""), "",
            markdown_table(outcome), ""]
    if formats and len(pareto):
        text += [f"![every method's held-out front](fronts.{formats[0]})", "",
                 "A dot is a point re-evaluated on the held-out seeds (median over them): its error objective "
                 "against its chattering relative to the cap; right of the dashed line is over the cap. The line "
                 "joins each method's points that no other of its stable points beats on both (its front as the "
                 "held-out seeds see it). A ring marks the point shipped; crosses at the foot are points that "
                 "diverged or were flagged by the growth test on a held-out seed. Every point is listed in "
                 "[pareto.csv](pareto.csv).", ""]
    if formats and len(frame):
        text += [f"![each search's convergence](convergence.{formats[0]})", "",
                 "Each search's feasible front, as the hypervolume it dominates (up to the reference point: error "
                 "1.0, chattering 10x the cap), against the trial: a search stopped when the last quarter of its "
                 "trials added less than the stated share.", ""]
    if len(pareto) and cap:
        from ilcforce.plants import DEFAULT_MODEL
        from ilcforce.report.tuning_levels import caps, write_levels

        model = json.loads(definition["experiment"]).get("plant", {}).get("model", DEFAULT_MODEL)
        level_files, level_lines = write_levels(target, pareto, definition["methods"], axes,
                                                caps(model, axes, cap, cap_spec["reference"]))
        files += level_files
        text += level_lines
    files.append(write_text_whole(target / "index.md", "\n".join(text)))
    line = f"- [tuning {path.name}](tuning/{path.name}/index.md): " + ", ".join(
        f"{m} {'ships trial ' + str(chosen[m]['trial']) if chosen.get(m) else 'none under the cap'}"
        for m in definition["methods"])
    return files, [line]


def _seeds(seeds: list[int]) -> str:
    return f"{seeds[0]}-{seeds[-1]}" if seeds == list(range(seeds[0], seeds[-1] + 1)) and len(seeds) > 1 else \
        ", ".join(map(str, seeds))


def committed_pages(out_dir: Path, written: list, sources: set[str]) -> list[str]:
    """The pages ``make tune`` committed under docs/tuning/ for the tunings named in ``sources`` (those
    whose tuned experiment a reported study ran), copied into the report: ``make reproduce`` does not tune,
    and its tuned studies' gains come from these tunings. Index lines; nothing when there are none."""
    from ilcforce.report.figure_files import copy_committed

    lines = []
    for page in sorted(COMMITTED.glob("*/index.md")) if COMMITTED.is_dir() else []:
        if page.parent.name not in sources:
            continue
        written += copy_committed(page.parent, out_dir / "tuning" / page.parent.name)
        title = page.read_text(encoding="utf-8").split("\n", 1)[0].removeprefix("# ")
        lines.append(f"- [{title}](tuning/{page.parent.name}/index.md) (committed by `make tune`)")
    return lines


def tuning_pages(results_dir: Path, out_dir: Path, formats: tuple[str, ...], written: list,
                 warnings: list, sources: set[str] = frozenset()) -> list[str]:
    """The page of every tuning store under ``results/tuning/``, or, when there is none, the committed pages
    of the tunings in ``sources`` (:func:`committed_pages`); index lines. A store that is not valid is a
    warning line, never the end of the report."""
    from ilcforce.report.figures import report_style
    from ilcforce.store.tuning import TuningStoreError, is_tuning_store

    folder = results_dir / "tuning"
    lines: list[str] = []
    for path in sorted(folder.iterdir()) if folder.is_dir() else []:
        if not is_tuning_store(path):
            continue
        try:
            with report_style():
                files, index_lines = write_tuning_report(path, out_dir / "tuning", formats)
        except (TuningStoreError, ValueError, KeyError) as error:
            warnings.append(f"{path}: tuning page not written: {' '.join(str(error).split())}")
            continue
        written += files
        lines += index_lines
    return lines or committed_pages(out_dir, written, set(sources))


def commit_pages(results_dir: Path, out_dir: Path, names: list[str], seconds: dict[str, float]) -> list[Path]:
    """``make tune``'s committed pages: :func:`write_tuning_report` of each named store into ``out_dir``
    (docs/tuning/), each headed by when, at which commit, and in how long it ran."""
    import subprocess
    from datetime import date

    from ilcforce.report.figure_files import write_text_whole
    from ilcforce.report.figures import report_style

    try:
        commit = subprocess.run(["git", "rev-parse", "--short=12", "HEAD"], capture_output=True, text=True,
                                check=True, cwd=COMMITTED.parent.parent).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        commit = "unknown"
    written: list[Path] = []
    for name in names:
        with report_style():
            files, _lines = write_tuning_report(Path(results_dir) / "tuning" / name, out_dir, ("png",))
        index = Path(out_dir) / name / "index.md"
        title, rest = index.read_text(encoding="utf-8").split("\n", 1)
        took = f", {seconds[name] / 60:.0f} min on 2 cores" if name in seconds else ""
        written += files
        written.append(write_text_whole(index, f"{title}\n\nGenerated by `make tune` on {date.today().isoformat()} "
                                              f"at commit {commit}{took}.\n{rest}"))
    return written


def main(argv: list[str] | None = None) -> int:
    import argparse

    parser = argparse.ArgumentParser(prog="python -m ilcforce.report.tuning",
                                     description="write the committed pages of make tune's tunings")
    parser.add_argument("--results", type=Path, default=Path("results"))
    parser.add_argument("--out", type=Path, default=COMMITTED)
    parser.add_argument("names", nargs="+", help="tuning names, each NAME or NAME=SECONDS (its wall time)")
    args = parser.parse_args(argv)
    names, seconds = [], {}
    for item in args.names:
        name, _, took = item.partition("=")
        names.append(name)
        if took:
            seconds[name] = float(took)
    from ilcforce.store.tuning import TuningStoreError

    try:
        written = commit_pages(args.results, args.out, names, seconds)
    except (TuningStoreError, OSError) as error:
        print(f"error: {error}", file=__import__("sys").stderr)
        return 2
    print(f"wrote {len(written)} files under {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
