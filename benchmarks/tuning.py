"""The cost of tuning over studying, for ``make bench``: the same cells run as trials of ``ilcforce
tune`` and as one study, on the same local cluster size, alternated; the difference per trial is
the tuning's own overhead (asking the sampler, a round of cells per trial, storing the record).

    python -m benchmarks.tuning [--trials 3] [--seeds 5] [--repeat 3]
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def tuning_file(trials: int, seeds: int, iterations: int) -> dict:
    return {"tune": {"name": "bench-tune", "experiment": str(ROOT / "experiments" / "paper.toml"),
                     "methods": ["c3"], "seeds": f"0-{seeds - 1}", "iterations": iterations,
                     "trials": trials, "sampler_seed": 0,
                     "gains": {"c3": {"eta": {"low": 1.0, "high": 10.0, "log": True}}}}}


def once(trials: int, seeds: int, iterations: int, workers: int) -> tuple[float, float]:
    """(tuning wall, study wall) in s for the same cells: the study runs each trial's gains as a setting."""
    from ilcforce.study import run_study
    from ilcforce.study.spec import build_study
    from ilcforce.tune import build_tuning, run_tuning
    from ilcforce.tune.runner import read_trials, tuning_dir

    with tempfile.TemporaryDirectory() as tmp:
        tuning = build_tuning(tuning_file(trials, seeds, iterations))
        t0 = time.perf_counter()
        run_tuning(tuning, Path(tmp) / "t", workers=workers)
        tuned = time.perf_counter() - t0
        records = read_trials(tuning_dir(Path(tmp) / "t", tuning.name))["c3"]
        settings = [{"label": f"trial {n}", "c3.eta": float(r["gains"]["c3.eta"])} for n, r in sorted(records.items())]
        study = build_study({"study": {"name": "bench-study", "experiment": str(ROOT / "experiments" / "paper.toml"),
                                       "methods": ["c3"], "seeds": f"0-{seeds - 1}",
                                       "set": {"experiment.iterations": iterations}, "settings": settings}})
        t0 = time.perf_counter()
        run_study(study, Path(tmp) / "s", workers=workers)
        return tuned, time.perf_counter() - t0


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=3)
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--iterations", type=int, default=20)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args(argv)
    pairs = [once(args.trials, args.seeds, args.iterations, args.workers) for _ in range(args.repeat)]
    tuned = statistics.median(p[0] for p in pairs)
    studied = statistics.median(p[1] for p in pairs)
    print(f"  tuning against a study of the same cells (c3, {args.trials} trials x {args.seeds} seeds x "
          f"{args.iterations} iterations, {args.workers} workers, median of {args.repeat}): tune {tuned:.1f} s, "
          f"study {studied:.1f} s: {(tuned - studied) / args.trials:+.2f} s per trial")


if __name__ == "__main__":
    main()
