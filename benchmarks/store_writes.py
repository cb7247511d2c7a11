"""Store write benchmark: the store's share of ``simulate --method c3 --iters 20``.

    python -m benchmarks.store_writes [--old-tree DIR] [--repeat 5]

Simulates the paper's c3 x 20 run once, then times only the store (StoreWriter: every append
and the finish) writing those records, repeated, for this tree and optionally for another
checkout (``--old-tree``, e.g. ``git worktree add /tmp/store-old 0550c53``), alternating the two so
both see the same machine load; with and without ``HDF5_USE_FILE_LOCKING=FALSE``. Prints medians,
the last commit's time (O(1) per iteration or not), the store's size and the peak of extra disk
used beside it while writing.
"""

from __future__ import annotations

import argparse
import json
import os
import pickle
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

_USE_TREE = ("import sys\n"  # the editable install's finder would import this tree whatever PYTHONPATH says
             "sys.meta_path[:] = [f for f in sys.meta_path if 'editable' not in repr(f).lower()]\n")

_CHILD = _USE_TREE + r"""
import json, os, pickle, sys, threading, time
from pathlib import Path
data = pickle.load(open(sys.argv[1], "rb"))
out = Path(sys.argv[2])
import ilcforce
assert str(Path(ilcforce.__file__).resolve()).startswith(sys.argv[3]), ilcforce.__file__
from ilcforce.store import StoreWriter
peak = [0]
stop = [False]
watching = sys.argv[4] == "1"
def watch():  # extra disk beside the store: every file in the folder but the store itself
    while not stop[0]:
        total = 0
        for p in out.parent.iterdir():
            try:
                total += p.stat().st_size if p.name != out.name else 0
            except OSError:
                pass
        peak[0] = max(peak[0], total)
        time.sleep(0.002)
t = threading.Thread(target=watch, daemon=True)
if watching:
    t.start()
commits = []
start = time.perf_counter()
with StoreWriter(out, experiment="paper", method="c3", config_toml=data["toml"], config_json=data["json"], seed=0,
                 command="bench", n_iterations=len(data["records"]), reference=data["reference"], overwrite=True) as w:
    for record in data["records"]:
        t0 = time.perf_counter(); w.append(record); commits.append(time.perf_counter() - t0)
    w.finish("complete")
total = time.perf_counter() - start
stop[0] = True
if watching:
    t.join()
print(json.dumps({"total": total, "first": commits[1], "last": commits[-1], "size": out.stat().st_size,
                  "extra_disk": peak[0]}))
"""


def _records(path: Path) -> None:
    from ilcforce.config_load import load_config
    from ilcforce.experiment import reference_log, simulate_iterations

    config = load_config(None, {"experiment.iterations": 20})
    records = list(simulate_iterations(config, "c3"))
    plain = [dict(iteration=r.iteration, status=r.status, diverged_time=r.diverged_time,
                  diverged_reason=r.diverged_reason, fallback_count=r.fallback_count, log=r.log,
                  memory=r.memory, memory_units=r.memory_units) for r in records]
    with open(path, "wb") as handle:
        pickle.dump({"plain": plain, "labels": [r.memory_labels for r in records],
                     "reference": reference_log(config), "toml": config.to_toml(), "json": config.to_json()}, handle)


def _one(tree: Path, data: Path, folder: Path, locking: bool, watch: bool = False) -> dict:
    env = {**os.environ, "PYTHONPATH": str(tree)}
    if not locking:
        env["HDF5_USE_FILE_LOCKING"] = "FALSE"
    script = (_USE_TREE + "import pickle, sys\nfrom ilcforce.records import IterationRecord\n"
              "d = pickle.load(open(sys.argv[1], 'rb'))\n"
              "from ilcforce.records import LOG_SIGNALS\n"
              "for r in d['plain']:\n"  # each tree stores the signals it knows
              "    r['log'] = {k: v for k, v in r['log'].items() if k in LOG_SIGNALS}\n"
              "d['records'] = [IterationRecord(**r) for r in d['plain']]\n"
              "pickle.dump(d, open(sys.argv[1] + '.rec', 'wb'))\n")
    subprocess.run([sys.executable, "-c", script, str(data)], check=True, env=env, cwd=folder)
    out = folder / "c3.h5"
    result = subprocess.run([sys.executable, "-c", _CHILD, str(data) + ".rec", str(out), str(tree.resolve()), "1" if watch else "0"],
                            env=env, capture_output=True, text=True, cwd=folder.parent)
    if result.returncode != 0:
        raise SystemExit(f"{tree}: {result.stderr.strip().splitlines()[-1]}")
    for p in folder.iterdir():
        p.unlink()
    return json.loads(result.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--old-tree", type=Path, default=None)
    parser.add_argument("--repeat", type=int, default=5)
    args = parser.parse_args()
    here = Path(__file__).resolve().parents[1]
    trees = {"this tree": here} | ({"old tree": args.old_tree} if args.old_tree else {})
    with tempfile.TemporaryDirectory() as tmp:
        data = Path(tmp) / "records.pkl"
        _records(data)
        results: dict[tuple[str, bool], list[dict]] = {}
        for _ in range(args.repeat):
            for locking in (True, False):
                for name, tree in trees.items():
                    folder = Path(tmp) / f"{name.replace(' ', '-')}-{locking}"
                    folder.mkdir(exist_ok=True)
                    results.setdefault((name, locking), []).append(_one(tree, data, folder, locking))
        # extra disk, in separate runs: the watcher thread polling the folder would slow the timed ones
        disk = {(name, locking): _one(tree, data, Path(tmp) / f"{name.replace(' ', '-')}-{locking}", locking,
                                      watch=True)["extra_disk"]
                for locking in (True, False) for name, tree in trees.items()}
    print(f"store share of c3 x 20 (medians of {args.repeat}, trees alternated)")
    print(f"{'tree':<10} {'HDF5 locking':<13} {'total s':>8} {'commit 1 ms':>12} {'commit 19 ms':>13} "
          f"{'size MB':>8} {'extra disk MB':>14}")
    for (name, locking), runs in results.items():
        med = {k: statistics.median(r[k] for r in runs) for k in runs[0]}
        med["extra_disk"] = disk[(name, locking)]
        print(f"{name:<10} {'on' if locking else 'FALSE':<13} {med['total']:8.3f} {med['first'] * 1e3:12.1f} "
              f"{med['last'] * 1e3:13.1f} {med['size'] / 1e6:8.1f} {med['extra_disk'] / 1e6:14.1f}")


if __name__ == "__main__":
    main()
