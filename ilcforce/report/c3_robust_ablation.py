"""C3-robust taken apart: the table of ``experiments/long/c3-robust-ablation.toml`` (docs/model.md#long-run).

C3-robust changes the paper's C3 (eq. 14) in four ways: a learning window, a Q filter, a bound on the
switching gain alpha_hat, and the desired acceleration in the regressor Psi. The study runs each change alone
(on top of plain C3), each left out (the other three on), all four and none, and the bound replaced by a
leak of alpha_hat; this module turns its store into one row per setting:

* **divergence**: how many seeds diverged within the study's iterations, the median (and range) of the first
  iteration that did not complete, and the median time into that iteration at which the watchdog stopped it;
* **errors**: e_P and e_F (the error 2-norms of Table 2, as docs/model.md's long-run table gives them), the
  mean over j = 15..19 of each seed, median over the seeds that completed those iterations ("through j = 19"),
  and the same over the last five iterations of the seeds that ran every iteration;
* **settled H**: H_x and H_y over t >= 20 ms (the report's settled chattering), median over seeds, at j = 19
  and at the last iteration of the seeds that ran every iteration;
* **alpha_hat against its bound**: alpha_hat(t) is a function of time; the study keeps its RMS over the
  settled window (t >= 20 ms, ``memory_settled_alpha_hat``), here at the last complete iteration of each seed
  (median over seeds), beside the setting's alpha_max; "at the bound" counts the seeds whose settled RMS is
  within 0.1% of alpha_max (the law caps alpha_hat sample by sample, so an RMS that close means alpha_hat
  sits at the cap over the whole settled window), and "reached at j" is the median first iteration of that;
  its rise per iteration over the last 50 iterations (median over the seeds that ran them all) tells a gain
  that has settled from one still climbing;
* **Theta_hat at t = 0** (``memory_start_theta_hat``, its norm at the first sample): at j = 19 and at the last
  iteration of the seeds that ran all, the drift the start mismatch drives (docs/model.md#long-run).

The study keeps alpha_hat's RMS, not alpha_hat(t) itself (a run store of 300 iterations holds about 0.6 GB).
Whether alpha_hat(t) is still a function of time or a constant at the cap is read off the last iteration's
alpha_hat(t) by :func:`alpha_profiles`, which reruns chosen cells of the study file in this process (the same
code and configuration as the study's cells) and keeps only that array: over the settled window, its
minimum, median and maximum, the coefficient of variation over t, and the share of samples within 0.1% of
alpha_max.

``python -m ilcforce.report.c3_robust_ablation --results results --out docs/long-run`` writes
``c3-robust-ablation.md`` and the table as ``c3_robust_ablation.csv``/``.md`` (``make long`` writes them through
:func:`ilcforce.report.long_run.write_page`); nothing else in the folder is touched. With ``--profile SEED``
it also reruns every setting of the study file that ran all its iterations in the stored study, for that seed,
and writes ``c3_robust_alpha_profile.csv``/``.md`` (not part of ``make long``: a few minutes a setting).
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np
import pandas as pd

#: the study's name (experiments/long/c3-robust-ablation.toml)
STUDY = "c3-robust-ablation"
#: the 1,000-iteration check of the leak of alpha_hat (experiments/long/c3-robust-leak-1000.toml), read with
#: ``ilcforce export`` and cited in docs/model.md#c3-robust-ablation; a ``make long`` study like this one
LEAK_CHECK = "c3-robust-leak-1000"
#: the page and the table stem it writes
PAGE = "c3-robust-ablation.md"
TABLE = "c3_robust_ablation"
#: the iterations the errors are averaged over (the paper's last five)
ERROR_WINDOW = (15, 19)
#: alpha_hat's rise per iteration is taken over this many last iterations
RISE_OVER = 50
#: alpha_hat's settled RMS within this fraction of alpha_max counts as at the bound
AT_BOUND = 1e-3
#: an alpha_max at or above this is no bound (the configuration's largest float, 1e12, stands for none)
NO_BOUND = 1e11
#: the profile table's stem (``--profile``)
PROFILE = "c3_robust_alpha_profile"
#: the study file the profile reruns cells of
STUDY_FILE = Path(__file__).resolve().parents[2] / "experiments" / "long" / f"{STUDY}.toml"
#: the four changes, as (config key, name, whether a value turns it on): a setting says which are on
CHANGES = (("learn_from", "window", lambda v: float(v) > 0), ("q_cutoff", "Q", lambda v: float(v) > 0),
           ("alpha_max", "bound", lambda v: float(v) < NO_BOUND),
           ("psi_acceleration", "desired acc.", lambda v: v == "desired"))


def _median(values) -> float:
    values = [float(v) for v in values if v is not None and math.isfinite(float(v))]
    return float(np.median(values)) if values else math.nan


def _range(values, fmt: str) -> str:
    values = [float(v) for v in values if math.isfinite(float(v))]
    if not values:
        return "-"
    low, high = min(values), max(values)
    return format(low, fmt) if low == high else f"{format(low, fmt)}-{format(high, fmt)}"


def ablation_table(results) -> pd.DataFrame:
    """One row per setting of the ablation study (see the module doc for each column)."""
    from ilcforce.report.growth_validation import setting_config, study_settings
    from ilcforce.stability import diverged_at

    rows = []
    for k, label, _p in study_settings(results):
        config = setting_config(results, k)
        gains = config.get("c3-robust", {})
        on = [name for key, name, is_on in CHANGES if is_on(gains.get(key))]
        alpha_max = float(gains.get("alpha_max", math.nan))
        bounded = alpha_max < NO_BOUND
        metrics = results.setting_metrics(k)
        iterations = int(config.get("experiment", {}).get("iterations", 0))
        diverged_j, diverged_t, errors_p, errors_f, hx19, hy19, hx_end, hy_end = ([] for _ in range(8))
        late_p, late_f, rise, start19, start_end = [], [], [], [], []
        alpha_end, reached, at_bound = [], [], 0
        seeds = sorted(int(s) for s in metrics["seed"].unique())
        for _seed, frame in metrics.groupby("seed", sort=True):
            frame = frame.sort_values("iteration")
            complete = frame[frame["status"] == "complete"]
            j = diverged_at(frame)
            if math.isfinite(j):
                diverged_j.append(j)
                diverged_t.append(float(frame.loc[frame["iteration"] == j, "diverged_time"].iloc[0]))
            window = complete[complete["iteration"].between(*ERROR_WINDOW)]
            if len(window) == ERROR_WINDOW[1] - ERROR_WINDOW[0] + 1:
                errors_p.append(float(window["position_error_2norm"].mean()))
                errors_f.append(float(window["force_error_2norm"].mean()))
                at19 = window[window["iteration"] == ERROR_WINDOW[1]].iloc[0]
                hx19.append(float(at19["chattering_task_x_settled"]))
                hy19.append(float(at19["chattering_task_y_settled"]))
                start19.append(float(at19["memory_start_theta_hat"]))
            if len(complete) == iterations:
                hx_end.append(float(complete["chattering_task_x_settled"].iloc[-1]))
                hy_end.append(float(complete["chattering_task_y_settled"].iloc[-1]))
                late_p.append(float(complete["position_error_2norm"].iloc[-5:].mean()))
                late_f.append(float(complete["force_error_2norm"].iloc[-5:].mean()))
                settled_alpha = complete["memory_settled_alpha_hat"].to_numpy(dtype=float)
                if len(settled_alpha) > RISE_OVER:
                    rise.append((settled_alpha[-1] - settled_alpha[-1 - RISE_OVER]) / RISE_OVER)
                start_end.append(float(complete["memory_start_theta_hat"].iloc[-1]))
            if len(complete):
                alpha = complete["memory_settled_alpha_hat"].to_numpy(dtype=float)
                alpha_end.append(float(alpha[-1]))
                if bounded:
                    hit = np.flatnonzero(alpha >= (1.0 - AT_BOUND) * alpha_max)
                    if abs(alpha[-1] - alpha_max) <= AT_BOUND * alpha_max:
                        at_bound += 1
                    if len(hit):
                        reached.append(float(complete["iteration"].iloc[hit[0]]))
        rows.append({
            "setting": label,
            "changes on": ", ".join(on) or "none",
            "seeds": len(seeds),
            "diverged": f"{len(diverged_j)} of {len(seeds)}",
            "diverged at j (median)": _median(diverged_j),
            "diverged at j (range)": _range(diverged_j, ".0f"),
            "at t in the iteration (ms, median)": _median(diverged_t) * 1e3 if diverged_t else math.nan,
            "through j=19": len(errors_p),
            "e_P j=15..19 (m)": _median(errors_p),
            "e_F j=15..19 (N)": _median(errors_f),
            "H_x settled j=19 (N)": _median(hx19),
            "H_y settled j=19 (N)": _median(hy19),
            f"H_x settled j={iterations - 1} (N)": _median(hx_end),
            f"H_y settled j={iterations - 1} (N)": _median(hy_end),
            f"ran all {iterations}": len(hy_end),
            f"e_P j={iterations - 5}..{iterations - 1} (m)": _median(late_p),
            f"e_F j={iterations - 5}..{iterations - 1} (N)": _median(late_f),
            "alpha_hat settled RMS, last j (N)": _median(alpha_end),
            "alpha_hat range over seeds (N)": _range(alpha_end, ".4g"),
            "alpha_max (N)": alpha_max if bounded else math.inf,
            "at the bound": f"{at_bound} of {len(seeds)}" if bounded else "no bound",
            "bound reached at j (median)": _median(reached) if bounded else math.nan,
            f"alpha_hat rise per iteration, j={iterations - 1 - RISE_OVER}..{iterations - 1} (N)": _median(rise),
            "Theta_hat at t=0, j=19": _median(start19),
            f"Theta_hat at t=0, j={iterations - 1}": _median(start_end),
        })
    return pd.DataFrame(rows)


def profile_row(alpha: np.ndarray, alpha_max: float, settled_from_sample: int) -> dict:
    """alpha_hat(t) of one iteration over the settled window: its spread, and the share at the bound."""
    settled = np.asarray(alpha, dtype=float).reshape(-1)[settled_from_sample:]
    mean = float(np.mean(settled))
    bounded = alpha_max < NO_BOUND
    return {"alpha_hat min (N)": float(np.min(settled)), "alpha_hat median (N)": float(np.median(settled)),
            "alpha_hat max (N)": float(np.max(settled)),
            "variation over t (std/mean)": float(np.std(settled) / mean) if mean > 0 else math.nan,
            "share of t at the bound": (float(np.mean(np.abs(settled - alpha_max) <= AT_BOUND * alpha_max))
                                        if bounded else math.nan)}


def alpha_profiles(seed: int, labels, study_file: Path = STUDY_FILE) -> pd.DataFrame:
    """Rerun the settings ``labels`` of ``study_file`` for ``seed`` (every iteration, in this process) and
    describe the last complete iteration's alpha_hat(t) (:func:`profile_row`)."""
    from ilcforce import metrics
    from ilcforce.experiment import simulate_iterations
    from ilcforce.study.spec import Cell, load_study

    study = load_study(study_file)
    rows = []
    for setting in study.settings:
        if setting.label() not in labels:
            continue
        config = study.cell_config(Cell(setting.index, int(seed), "c3-robust"))
        gains = config.gains["c3-robust"]
        last, j_last = None, -1
        for record in simulate_iterations(config, "c3-robust"):
            if record.diverged:
                break
            last, j_last = record.memory["alpha_hat"], record.iteration
        if last is None:
            continue
        k0 = metrics.settled_sample(config.simulation.sample_time)
        rows.append({"setting": setting.label(), "seed": int(seed), "j": j_last,
                     "alpha_max (N)": gains.alpha_max if gains.alpha_max < NO_BOUND else math.inf,
                     **profile_row(last, gains.alpha_max, k0)})
    return pd.DataFrame(rows)


def _profile_lines(out_dir: Path) -> list[str]:
    """The alpha_hat(t) profile table ``--profile`` wrote into ``out_dir``, if it did."""
    from ilcforce.report import table_write

    path = out_dir / f"{PROFILE}.csv"
    if not path.is_file():
        return []
    profile = pd.read_csv(path)
    seeds = ", ".join(str(s) for s in sorted(profile["seed"].unique()))
    return ["## alpha_hat(t) at the last iteration", "",
            f"Written by `--profile` (seed {seeds}): every setting that ran all its iterations, rerun in one process "
            "with the study file's configuration, and alpha_hat(t) of its last iteration over the settled window "
            "(t >= 20 ms).", "", table_write.markdown_table(profile), ""]


def write_page(results_dir: Path, out_dir: Path) -> list[Path]:
    """Write the ablation page and table into ``out_dir`` from ``results_dir/studies/c3-robust-ablation.h5``;
    nothing (an empty list) when that store is absent or unreadable."""
    from ilcforce.report import table_write
    from ilcforce.report.study import studies_provenance
    from ilcforce.study import StudyStoreError, read_study

    path = Path(results_dir) / "studies" / f"{STUDY}.h5"
    if not path.is_file():
        return []
    try:
        results = read_study(path)
    except (StudyStoreError, OSError, KeyError, ValueError, TypeError):
        return []
    table = ablation_table(results)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    written = table_write.write_table(table, out_dir, TABLE)
    seeds = sorted(int(s) for s in results.metrics["seed"].unique())
    command = f"ilcforce study experiments/long/{STUDY}.toml --workers 2 --results RESULTS"
    lines = [
        "# C3-robust taken apart", "",
        f"Generated by `python -m ilcforce.report.c3_robust_ablation --results RESULTS --out docs/long-run` "
        f"(also by `make long`) from the study run by `{command}` ({studies_provenance({STUDY: results})}; seeds "
        f"{', '.join(map(str, seeds))}, method c3-robust, the paper's setup otherwise).", "",
        __doc__.split("\n\n", 1)[1].split("``python -m")[0].strip().replace("``", "`"), "",
        str(getattr(results, "description", "")) + ".", "",
        table_write.markdown_table(table), "",
        *_profile_lines(out_dir),
        "A cell's single run is `ilcforce simulate -m c3-robust -n ITERATIONS --seed SEED --set "
        "c3-robust.KEY=VALUE ...` with the setting's four (or six) keys; the study's cells are bit-identical to "
        "it (docs/studies.md).", ""]
    page = out_dir / PAGE
    page.write_text("\n".join(lines), encoding="utf-8")
    written.append(page)
    return written


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m ilcforce.report.c3_robust_ablation",
                                     description=__doc__.split("\n")[0])
    parser.add_argument("--results", type=Path, default=Path("results"))
    parser.add_argument("--out", type=Path, default=Path("docs/long-run"))
    parser.add_argument("--profile", type=int, metavar="SEED", default=None,
                        help="also rerun, for this seed, every setting that ran all its iterations, and write "
                             "alpha_hat(t)'s profile at the last iteration")
    args = parser.parse_args(argv)
    written = write_page(args.results, args.out)
    if not written:
        print(f"error: no readable {STUDY} study in {args.results / 'studies'} (run make long)", file=sys.stderr)
        return 2
    if args.profile is not None:
        from ilcforce.report import table_write

        table = pd.read_csv(args.out / f"{TABLE}.csv")
        survivors = table.loc[table["diverged"].astype(str).str.startswith("0 of"), "setting"].tolist()
        profile = alpha_profiles(args.profile, survivors)
        written = [*table_write.write_table(profile, args.out, PROFILE), *write_page(args.results, args.out)]
    print(f"wrote {written[-1]}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
