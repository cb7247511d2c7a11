"""The cost of tuning over studying, for ``make bench``: the same cells run as trials of ``ilcforce
tune`` (scoring cells, check cells over 3x the horizon, the held-out re-evaluation) and as studies (one
per role: the trials' gains as listed settings on the scoring seeds, on the check seeds, and the held-out
points on the held-out seeds), on the same local cluster size, alternated; the difference per trial is the
tuning's own overhead (asking the sampler, a round of cells per trial, judging growth, storing records),
less what pruning saves (none here: c3 with these gains is not flagged within 15 iterations).

    python -m benchmarks.tuning [--trials 3] [--seeds 3] [--repeat 3]
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


CHECK_SEEDS, HELDOUT_SEEDS = [100, 101], [200, 201]


def tuning_file(trials: int, seeds: int, iterations: int) -> dict:
    return {"tune": {"name": "bench-tune", "experiment": str(ROOT / "experiments" / "paper.toml"),
                     "methods": ["c3"], "seeds": f"0-{seeds - 1}", "iterations": iterations,
                     "check_seeds": CHECK_SEEDS, "check_iterations": 3 * iterations,
                     "heldout_seeds": HELDOUT_SEEDS, "heldout_iterations": 3 * iterations,
                     "budget": {"base": trials, "per_dimension": 0, "extend": 1}, "cap": {"reference": "c3"},
                     "sampler_seed": 0, "gains": {"c3": {"eta": {"low": 1.0, "high": 10.0, "log": True}}}}}


def once(trials: int, seeds: int, iterations: int, workers: int) -> tuple[float, float]:
    """(tuning wall, study wall) in s for the same cells: the study runs each trial's gains as a setting."""
    from ilcforce.store.tuning import read_heldout
    from ilcforce.study import run_study
    from ilcforce.study.spec import build_study
    from ilcforce.tune import build_tuning, run_tuning
    from ilcforce.tune.runner import read_trials, stored_check, tuning_dir

    with tempfile.TemporaryDirectory() as tmp:
        tuning = build_tuning(tuning_file(trials, seeds, iterations))
        t0 = time.perf_counter()
        run_tuning(tuning, Path(tmp) / "t", workers=workers)
        tuned = time.perf_counter() - t0
        store = tuning_dir(Path(tmp) / "t", tuning.name)
        records = read_trials(store)["c3"]
        heldout = read_heldout(store, stored_check(store))

        def settings(numbers):
            return [{"label": f"trial {n}", "c3.eta": float(records[n]["gains"]["c3.eta"])} for n in sorted(numbers)]
        studies = [(list(range(seeds)), iterations, settings(records)),
                   (CHECK_SEEDS, 3 * iterations, settings(records)),
                   (HELDOUT_SEEDS, 3 * iterations, settings(n for _m, n in heldout))]
        t0 = time.perf_counter()
        for k, (seed_list, horizon, listed) in enumerate(studies):
            study = build_study({"study": {"name": f"bench-study-{k}", "methods": ["c3"], "seeds": seed_list,
                                           "experiment": str(ROOT / "experiments" / "paper.toml"),
                                           "set": {"experiment.iterations": horizon}, "settings": listed}})
            run_study(study, Path(tmp) / "s", workers=workers)
        return tuned, time.perf_counter() - t0


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=3)
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--iterations", type=int, default=5)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args(argv)
    pairs = [once(args.trials, args.seeds, args.iterations, args.workers) for _ in range(args.repeat)]
    tuned = statistics.median(p[0] for p in pairs)
    studied = statistics.median(p[1] for p in pairs)
    print(f"  tuning against studies of the same cells (c3, {args.trials} trials x ({args.seeds} seeds x "
          f"{args.iterations} iterations + {len(CHECK_SEEDS)} check seeds x {3 * args.iterations}) and the held-out "
          f"points x {len(HELDOUT_SEEDS)} seeds x {3 * args.iterations}, {args.workers} workers, median of "
          f"{args.repeat}): tune {tuned:.1f} s, studies {studied:.1f} s: {(tuned - studied) / args.trials:+.2f} s "
          "per trial")


if __name__ == "__main__":
    main()
