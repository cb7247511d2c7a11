"""Where a cold ``ilcforce compare`` spends its CPU, by kind of thread (Linux ``perf`` sampling).

    python -m benchmarks.cpu [--repeat 3] [--frequency 2000] [-- extra compare options]

``compare`` is CPU-bound on a 2-core machine (its wall time is at least its CPU time over the
cores), so its overhead is the CPU that is not the compiled loop. Each run is sampled by
``perf record`` over all of the command's processes and threads; every thread is then counted as
one of: the parent (imports before the workers fork, the progress display), a worker's
simulation thread (the compiled loop: most of its samples in the ahead-of-time kernels), a
worker's main thread (its store), a worker's inputs thread (noise draws, tau_d, the set-up made
ahead), or other (git, ``uname -p`` run by h5py's import, anything under 0.2% of the samples).
Needs ``perf`` and permission to sample (``kernel.perf_event_paranoid`` <= 2 for one's own
processes); it is not part of ``make bench``.
"""

from __future__ import annotations

import argparse
import collections
import shutil
import statistics
import subprocess
import sys
import tempfile
from collections.abc import Iterable
from pathlib import Path

KINDS = ("simulation threads (compiled loop)", "worker main threads (store)", "parent (imports, display)",
         "inputs threads (draws, tau_d, set-up)", "other (git, uname -p, short-lived)")
_KERNELS = "_kernels_aot"
_TOOLS = ("git", "uname")


def split(lines: Iterable[str]) -> tuple[dict[str, float], int]:
    """(share (%) of the samples per kind, number of samples) from ``perf script -F pid,tid,ip,dso``
    lines."""
    threads: dict[tuple[int, int], collections.Counter] = collections.defaultdict(collections.Counter)
    for line in lines:
        fields = line.split()
        if len(fields) < 3 or "/" not in fields[0]:
            continue
        pid, tid = (int(x) for x in fields[0].split("/"))
        threads[(pid, tid)][fields[-1].strip("()").rsplit("/", 1)[-1]] += 1
    total = sum(sum(c.values()) for c in threads.values())
    shares = dict.fromkeys(KINDS, 0.0)
    if not total:
        return shares, 0
    parent = min(pid for pid, _ in threads)  # the command's own process starts first
    for (pid, tid), dsos in threads.items():
        n = sum(dsos.values())
        if any(d in _TOOLS for d in dsos) or (pid != parent and n < 0.002 * total):
            kind = KINDS[4]
        elif pid == parent:
            kind = KINDS[2]
        elif dsos.most_common(1)[0][0].startswith(_KERNELS):
            kind = KINDS[0]
        elif pid == tid:
            kind = KINDS[1]
        else:
            kind = KINDS[3]
        shares[kind] += 100.0 * n / total
    return shares, total


def _sample(folder: Path, run: int, frequency: int, extra: list[str]) -> tuple[dict[str, float], float]:
    """(shares, CPU seconds sampled) of one perf-sampled cold ``compare``."""
    data = folder / f"perf{run}.data"
    record = subprocess.run(["perf", "record", "-q", "-F", str(frequency), "-o", str(data), "--",
                             sys.executable, "-m", "ilcforce", "compare", "--results", str(folder / f"r{run}"),
                             *extra], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    if record.returncode != 0:
        raise SystemExit(f"bench_cpu: perf record failed ({record.returncode}): "
                         f"{(record.stderr.strip().splitlines() or ['no message'])[-1]}")
    script = subprocess.run(["perf", "script", "-i", str(data), "-F", "pid,tid,ip,dso"],
                            capture_output=True, text=True)
    if script.returncode != 0:
        raise SystemExit(f"bench_cpu: perf script failed: {(script.stderr.strip().splitlines() or [''])[-1]}")
    shares, samples = split(script.stdout.splitlines())
    return shares, samples / frequency


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--frequency", type=int, default=2000, help="samples per second and thread")
    parser.add_argument("extra", nargs="*", help="options passed on to compare (after --)")
    args = parser.parse_args(argv)
    if shutil.which("perf") is None:
        raise SystemExit("bench_cpu: needs Linux perf on PATH (not found)")
    with tempfile.TemporaryDirectory() as tmp:
        sampled = [_sample(Path(tmp), i, args.frequency, args.extra) for i in range(args.repeat)]
    runs = [shares for shares, _ in sampled]
    seconds = statistics.median(cpu for _, cpu in sampled)
    print(f"CPU of cold `ilcforce compare` by thread (median of {args.repeat} perf-sampled runs, range; "
          f"about {seconds:.2f} s of CPU sampled per run):")
    for kind in KINDS:
        values = [r[kind] for r in runs]
        print(f"  {statistics.median(values):5.1f}%  ({min(values):.1f}-{max(values):.1f})  {kind}")


if __name__ == "__main__":
    main()
