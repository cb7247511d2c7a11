"""The lifted check against the simulation (``make lifted``; docs/lifted/): for each learning method, the band
growth :func:`ilcforce.theory.lifted.analyze` predicts from the model alone beside the growth measured from long runs
with the experiment's noise on held-out seeds (:func:`ilcforce.theory.lifted.measured_band_growth`), and the predicted
boundedness beside what docs/long-run/ found over 1,000 iterations.

    python -m ilcforce.theory.validation experiments/paper.toml experiments/serial2r.toml --out docs/lifted
"""

from __future__ import annotations

import argparse
import csv
import datetime
import json
import sys
import time
from pathlib import Path

import numpy as np

from ilcforce.theory import lifted
from ilcforce.config_load import load_config

#: the learning methods checked (every registered method with a memory that learns across iterations)
METHODS = ("c2", "c3", "c3-leak", "pd-ilc", "c2-robust", "c3-robust")
#: the experiment whose long runs docs/long-run/ holds (the paper's setup)
LONG_RUN_EXPERIMENT = "paper"


def _commit() -> str:
    """The checkout's commit as the stores record it (ilcforce.store.provenance), said dirty when it is."""
    from ilcforce.store.provenance import git_state

    commit, dirty = git_state()
    return (commit[:12] + (" with uncommitted changes" if dirty else "")) if commit else "unknown"


def _long_run_truth(path: Path) -> dict[str, str]:
    """method -> 'bounded' / 'unbounded' from docs/long-run/long_run.csv (the five-bar's paper setup)."""
    if not path.is_file():
        return {}
    with path.open(newline="") as handle:
        return {row["method"]: ("unbounded" if int(row["diverged"]) > 0 or row["late verdict"] == "grows"
                                else "bounded") for row in csv.DictReader(handle)}


#: a growing band's prediction agrees with the measurement within this, per iteration
AGREEMENT = 0.01
#: a contracting band's change, re-excited by the noise at every iteration, stays stationary: measured at most this
STATIONARY = 1.005


def agrees(predicted: float, measured: float) -> str:
    """"yes" / "no" / "" (nothing measured): a band predicted to grow agrees when the measured growth is within
    AGREEMENT of it; a band predicted not to grow, when the measured change is stationary (<= STATIONARY)."""
    if not np.isfinite(measured):
        return ""
    if predicted > 1.0 + 1e-3:
        return "yes" if abs(predicted - measured) <= AGREEMENT else "no"
    return "yes" if measured <= STATIONARY else "no"


#: the cutoffs (Hz) the Q design scans, and the contraction it asks of the slowest band (rho <= 1 - margin)
Q_CUTOFFS = (20.0, 50.0, 100.0, 200.0, 400.0, 800.0, 1500.0)
Q_MARGIN = 0.01


def q_design(path: Path, method: str, cutoffs=Q_CUTOFFS, margin: float = Q_MARGIN, at: int = 20) -> tuple[list, float]:
    """(rows, designed cutoff): per cutoff the lifted check's rho and band growth; the designed cutoff is the
    largest whose every band contracts by at least ``margin`` per iteration (rho <= 1 - margin)."""
    rows, designed = [], float("nan")
    for q in cutoffs:
        check = lifted.analyze(load_config(path, {f"{method}.q_cutoff": q}), method, at=at)
        rows.append({"method": method, "q_cutoff_hz": q, "rho": check.spectral_radius,
                     "band_growth": " ".join(f"{g:.4f}" for _l, _h, g in check.band_growth),
                     "bounded": check.bounded})
        if check.bounded and check.spectral_radius <= 1 - margin:
            designed = q
    return rows, designed


def long_compare(path: Path, method: str, cutoffs, seeds, iterations: int) -> list[dict]:
    """Each cutoff over ``iterations`` iterations with the experiment's noise on ``seeds``: where it diverged,
    e_P and e_F (2-norms) over j = 15..19 and over the last 5 iterations, settled H (x, y) at the last."""
    import dataclasses

    from ilcforce.experiment import simulate_iterations
    from ilcforce.metrics import iteration_metrics

    rows = []
    for q in cutoffs:
        for seed in seeds:
            cfg = load_config(path, {f"{method}.q_cutoff": q, "experiment.seed": seed})
            cfg = dataclasses.replace(cfg, experiment=dataclasses.replace(cfg.experiment, iterations=iterations))
            metrics = [iteration_metrics(r) for r in simulate_iterations(cfg, method)]
            done = [m for m in metrics if m["status"] == "complete"]

            def mean(key, js):
                values = [done[j][key] for j in js if j < len(done)]
                return float(np.mean(values)) if values else float("nan")

            last = range(max(0, len(done) - 5), len(done))
            rows.append({"method": method, "q_cutoff_hz": q, "seed": seed,
                         "diverged_at": len(done) if len(done) < iterations else "",
                         "e_P j=15..19": mean("position_error_2norm", range(15, 20)),
                         "e_F j=15..19": mean("force_error_2norm", range(15, 20)),
                         "e_P last 5": mean("position_error_2norm", last),
                         "e_F last 5": mean("force_error_2norm", last),
                         "H_x settled last": done[-1]["chattering_task_x_settled"] if done else float("nan"),
                         "H_y settled last": done[-1]["chattering_task_y_settled"] if done else float("nan")})
            print(f"{method} q = {q:g} Hz seed {seed}: {len(done)} complete", file=sys.stderr, flush=True)
    return rows


def q_main(args) -> int:
    began = time.perf_counter()
    seeds = [int(s) for s in args.seeds.split(",")]
    lines = ["# The robust variants' Q cutoff, designed from the lifted check", "",
             f"Generated on {datetime.date.today().isoformat()} at commit {_commit()} by `python -m "
             f"ilcforce.theory.validation {args.experiments[0]} --q-design {args.q_design} --seeds {args.seeds} "
             f"--iterations {args.iterations}`.", "",
             f"Rule: the largest cutoff of {', '.join(f'{q:g}' for q in Q_CUTOFFS)} Hz at which every band's "
             f"memory change contracts by at least {Q_MARGIN:.0%} per iteration (rho <= {1 - Q_MARGIN:g}; "
             "`ilcforce analyze -m METHOD --set METHOD.q_cutoff=Q`, noise off, linearised at j = 20). Then the "
             f"designed cutoff against the shipped 50 Hz over {args.iterations} iterations with the experiment's "
             f"noise on held-out seeds {args.seeds}.", ""]
    all_long = []
    for method in args.q_design.split(","):
        rows, designed = q_design(args.experiments[0], method)
        lines += [f"## {method}", "", "| Q cutoff (Hz) | rho | band growth (bands of `analyze`) | predicted |",
                  "|---|---|---|---|"]
        lines += [f"| {r['q_cutoff_hz']:g} | {r['rho']:.4f} | {r['band_growth']} | "
                  f"{'bounded' if r['bounded'] else 'unbounded'} |" for r in rows]
        lines += ["", f"Designed cutoff: **{designed:g} Hz**.", ""]
        compared = sorted({50.0, designed} - {float('nan')})
        long_rows = long_compare(args.experiments[0], method, compared, seeds, args.iterations)
        all_long += long_rows
        keys = list(long_rows[0])
        lines += ["| " + " | ".join(keys) + " |", "|" + "---|" * len(keys)]
        lines += ["| " + " | ".join(f"{v:.4g}" if isinstance(v, float) else str(v) for v in r.values()) + " |"
                  for r in long_rows]
        lines.append("")
    lines.append(f"({(time.perf_counter() - began) / 60:.0f} minutes on this machine's 2 cores.)")
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "q-design.md").write_text("\n".join(lines) + "\n")
    with (args.out / "q-design.csv").open("w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=list(all_long[0]))
        writer.writeheader()
        writer.writerows(all_long)
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("experiments", nargs="+", type=Path, help="experiment files")
    parser.add_argument("--out", type=Path, default=Path("docs/lifted"))
    parser.add_argument("--iterations", type=int, default=220)
    parser.add_argument("--first", type=int, default=60, help="first iteration of the measured fit")
    parser.add_argument("--seeds", default="141,142")
    parser.add_argument("--at", type=int, default=20)
    parser.add_argument("--step", default="auto", help="finite-difference step: 'auto', 'noise' or a relative float")
    parser.add_argument("--q-design", default="", help="comma-separated robust methods: design their Q cutoff instead")
    args = parser.parse_args(argv)
    if args.step not in ("auto", "noise"):
        args.step = float(args.step)
    if args.q_design:
        return q_main(args)
    began = time.perf_counter()
    seeds = [int(s) for s in args.seeds.split(",")]
    truth = _long_run_truth(Path("docs/long-run/long_run.csv"))
    rows = []
    for path in args.experiments:
        label = load_config(path).experiment.name
        for method in METHODS:
            base = load_config(path)
            check = lifted.analyze(base, method, at=args.at, step=args.step)
            measured = []
            for seed in seeds:
                cfg = load_config(path, {"experiment.seed": seed})
                try:
                    measured.append(lifted.measured_band_growth(cfg, method, iterations=args.iterations,
                                                                first=args.first, last=args.iterations - 1))
                except lifted.AnalysisError as exc:
                    print(f"{label} {method} seed {seed}: {exc}", file=sys.stderr)
            for b, (low, high, predicted) in enumerate(check.band_growth):
                values = [m[b][2] for m in measured]
                rows.append({
                    "robot": label, "method": method, "band_low_hz": low, "band_high_hz": high,
                    "predicted": predicted, "measured_median": float(np.median(values)) if values else float("nan"),
                    "measured_seeds": " ".join(f"{v:.4f}" for v in values),
                    "rho": check.spectral_radius, "sigma_max": check.max_singular_value,
                    "agrees": agrees(predicted, float(np.median(values)) if values else float("nan")),
                    "predicted_bounded": check.bounded,
                    "long_run": truth.get(method, "") if label == LONG_RUN_EXPERIMENT else "",
                    "seconds": check.seconds,
                })
            print(f"{label} {method}: {check.seconds:.1f} s", file=sys.stderr, flush=True)
    args.out.mkdir(parents=True, exist_ok=True)
    with (args.out / "validation.csv").open("w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    _page(args, rows, seeds, time.perf_counter() - began)
    _figure(args.out, rows)
    return 0


def _page(args, rows: list[dict], seeds: list[int], seconds: float) -> None:
    today = datetime.date.today().isoformat()
    lines = [
        "# The lifted check against the simulation",
        "",
        f"Generated by `make lifted` on {today} at commit {_commit()} "
        f"(`python -m ilcforce.theory.validation {' '.join(map(str, args.experiments))} --iterations {args.iterations} --first {args.first} "
        f"--seeds {args.seeds} --at {args.at} --step {args.step}`; {seconds / 60:.0f} minutes on this machine's "
        "2 cores, shared with other work).",
        "",
        f"Predicted: `ilcforce analyze` linearised at j = {args.at}, noise off (matrix-free on these grids). "
        f"Measured: the growth per iteration of each band's energy in the settled memory change m_(j+1) - m_j, "
        f"fitted over j = {args.first}..{args.iterations - 2} of runs with the experiment's noise on seeds "
        f"{', '.join(map(str, seeds))} (median; each seed listed). Long run: docs/long-run/ (1,000 iterations, "
        "10 seeds, the five-bar's paper setup). A run that diverged is measured up to its last complete iteration; "
        "one that diverged before enough iterations has no measured value.",
        "",
        f"Agreement: a band predicted to grow (> 1.001) agrees when the measured growth is within {AGREEMENT} per "
        f"iteration; a band predicted to contract agrees when the measured change is stationary (<= {STATIONARY}): "
        "the noise re-excites a contracting band at every iteration, so its change neither grows nor decays.",
        "",
        "| experiment | method | band (Hz) | predicted | measured (median) | per seed | agrees | rho | "
        "sigma_max | predicted | long run |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r['robot']} | {r['method']} | {r['band_low_hz']:g}-{r['band_high_hz']:g} | {r['predicted']:.4f} | "
            f"{r['measured_median']:.4f} | {r['measured_seeds']} | {r['agrees']} | {r['rho']:.4f} | {r['sigma_max']:.3f} | "
            f"{'bounded' if r['predicted_bounded'] else 'unbounded'} | {r['long_run']} |")
    judged = [r for r in rows if r["agrees"]]
    lines += ["", f"{sum(r['agrees'] == 'yes' for r in judged)} of {len(judged)} measured bands agree; predicted "
              "boundedness against the long runs: " + ", ".join(
                  f"{m} {'agrees' if b == t else 'DISAGREES'}" for m, b, t in dict.fromkeys(
                      (r["method"], "bounded" if r["predicted_bounded"] else "unbounded", r["long_run"])
                      for r in rows if r["long_run"])) + ".",
              "", "![predicted against measured band growth](validation.png)", ""]
    (args.out / "validation.md").write_text("\n".join(lines))
    (args.out / "summary.json").write_text(json.dumps({"rows": len(rows)}, indent=1))


def _figure(out: Path, rows: list[dict]) -> None:
    """Predicted against measured growth per band, in % per iteration, of the bands predicted near or above 1
    (a contracting band's measured change is stationary, ~0%: the table shows those); one colour per method."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    colours = {m: f"C{i}" for i, m in enumerate(METHODS)}
    robots = list(dict.fromkeys(r["robot"] for r in rows))
    fig, axes = plt.subplots(1, len(robots), figsize=(5.2 * len(robots), 4.6), constrained_layout=True, squeeze=False)
    for ax, robot in zip(axes[0], robots):
        near = [r for r in rows if r["robot"] == robot and np.isfinite(r["measured_median"]) and r["predicted"] >= 0.97]
        left_out = sum(1 for r in rows if r["robot"] == robot and r["predicted"] < 0.97)
        for method in METHODS:
            pts = [(100 * (r["predicted"] - 1), 100 * (r["measured_median"] - 1)) for r in near if r["method"] == method]
            if pts:
                ax.plot(*zip(*pts), "o", color=colours[method], label=method)
        values = [v for r in near for v in (100 * (r["predicted"] - 1), 100 * (r["measured_median"] - 1))]
        if values:
            lo, hi = min(values + [-1.0]), max(values + [1.0])
            ax.plot([lo, hi], [lo, hi], "k-", lw=0.8, label="measured = predicted")
            ax.fill_between([lo, hi], [lo - 100 * AGREEMENT, hi - 100 * AGREEMENT],
                            [lo + 100 * AGREEMENT, hi + 100 * AGREEMENT], color="0.85", label=f"within {AGREEMENT:g}")
        ax.axhline(0, color="0.5", lw=0.5)
        ax.axvline(0, color="0.5", lw=0.5)
        ax.set_title(f"{robot} ({left_out} contracting bands, predicted < 0.97, in the table only)", fontsize=9)
        ax.set_xlabel("predicted growth of a band, % per iteration")
        ax.set_ylabel("measured growth, % per iteration")
        ax.legend(fontsize=8, loc="upper left")
    fig.savefig(out / "validation.png", dpi=110)


if __name__ == "__main__":
    raise SystemExit(main())
