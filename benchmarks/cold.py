"""Cold-process figures for ``make bench``: the user's own commands, timed as a user runs them.

Each figure is the median wall time over repeated fresh processes of the real ``ilcforce`` entry
point (console script), with numba's on-disk caches warm (one untimed run first):

* ``ilcforce --help``;
* ``ilcforce simulate --method c3 --iters 20`` (the paper's setup, full store written);
* ``ilcforce compare`` for the paper's study (c1, c2, c3 x 20, every store written, fresh results).

Beside them, the compiled loop's own time for the same work (the simulator kernel timed
in-process, warm, once between each round of cold processes: the machine's speed drifts, and the
overhead compares the two), so that overhead = wall - loop shows; and the split of cold ``simulate`` runs
measured inside each process (:func:`cold_timelines`: when the first loop starts, the loops' own
time, the time between them and after the last; medians), which is not affected by the machine
being faster or slower between two measurements. (A cProfile split, printed until the ninth
session, sees only the main thread, and counted the imports inside the store's calls twice once
the store opened beside the running loop; the timeline replaced it.)
"""

from __future__ import annotations

import os
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from pathlib import Path

METHODS = ("c1", "c2", "c3")
ITERATIONS = 20


def median_seconds(work: Callable[[], object], repeat: int, clock: Callable[[], float] = time.perf_counter) -> float:
    """Median over ``repeat`` runs of ``work()`` of the time ``clock`` measures (wall by default;
    ``time.thread_time`` for this thread's CPU)."""
    times = []
    for _ in range(repeat):
        t0 = clock()
        work()
        times.append(clock() - t0)
    return statistics.median(times)


def loops_ideal(loops: dict[str, float], cores: int) -> float:
    """The compiled loops' own time (s) for methods run at once on ``cores``: all of them over the
    cores, but never less than the longest (a method's iterations run one after another)."""
    return max(sum(loops.values()) / cores, max(loops.values()))


def entry_point() -> list[str]:
    """The installed ``ilcforce`` console script beside this interpreter (or ``python -m ilcforce``)."""
    script = Path(sys.executable).parent / "ilcforce"
    return [str(script)] if script.is_file() else [sys.executable, "-m", "ilcforce"]


def _wall(args: Sequence[str], cwd: Path) -> float:
    t0 = time.perf_counter()
    proc = subprocess.run(list(args), cwd=cwd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    elapsed = time.perf_counter() - t0
    if proc.returncode != 0:
        raise RuntimeError(f"{' '.join(args)} failed ({proc.returncode}): {proc.stderr.strip()[-500:]}")
    return elapsed


def cold_walls(repeat: int, extra: Sequence[str] = (), iterations: int = ITERATIONS,
               between: Callable[[], None] | None = None,
               commands: dict[str, list[str]] | None = None) -> dict[str, dict[str, list[float]]]:
    """Wall times (s) of ``repeat`` cold processes per command and per entry point (``commands``:
    label -> entry point; this tree's by default), the commands and the entry points alternated
    within each round, so that a drift of the machine's speed reaches every figure alike;
    ``between()`` after each round (e.g. a measurement to interleave with them)."""
    commands = commands or {"this tree": entry_point()}
    n = ["--iters", str(iterations), *extra]
    walls = {label: {"help": [], "simulate": [], "compare": []} for label in commands}
    with tempfile.TemporaryDirectory() as tmp:
        tmp_path = Path(tmp)
        for label, cmd in commands.items():  # numba caches warm
            _wall([*cmd, "compare", *n, "--results", str(tmp_path / f"warm-{len(label)}-{hash(label)}")], tmp_path)
        for i in range(repeat):
            for k, (label, cmd) in enumerate(commands.items()):
                mine = walls[label]
                mine["help"].append(_wall([*cmd, "--help"], tmp_path))
                mine["simulate"].append(_wall([*cmd, "simulate", "--method", "c3", *n, "--out",
                                               str(tmp_path / f"s{i}-{k}" / "c3.h5")], tmp_path))
                mine["compare"].append(_wall([*cmd, "compare", "--methods", ",".join(METHODS), *n,
                                              "--results", str(tmp_path / f"c{i}-{k}")], tmp_path))
            if between is not None:
                between()
    return walls


def loop_seconds(methods: Sequence[str], repeat: int, iterations: int = ITERATIONS,
                 overrides: dict | None = None) -> dict[str, float]:
    """Median in-process time of the compiled simulation loop alone, per method, for ``iterations``."""
    from ilcforce import loop
    from ilcforce.compiled import aot
    from ilcforce.config_load import load_config
    from ilcforce.experiment import simulate_iterations

    config = load_config(None, {"experiment.iterations": iterations, **(overrides or {})})
    spent = [0.0]

    def timed(kernel):
        def run(*args):
            t0 = time.perf_counter()
            try:
                return kernel(*args)
            finally:
                spent[0] += time.perf_counter() - t0
        return run

    # the loop a command runs: the ahead-of-time compiled one (ilcforce.compiled.aot), or else numba's
    find, pick = aot.simulator, loop.simulator

    def timed_simulator(*args):
        found = find(*args)
        return None if found is None else timed(found)

    aot.simulator, loop.simulator = timed_simulator, lambda n: timed(pick(n))
    try:
        out = {}
        for method in methods:
            runs = []
            for _ in range(repeat):
                spent[0] = 0.0
                for _record in simulate_iterations(config, method):
                    pass
                runs.append(spent[0])
            out[method] = statistics.median(runs)
        return out
    finally:
        aot.simulator, loop.simulator = find, pick


#: Runs the command through the entry point with each compiled-loop call timed; prints, at the
#: process's end, "TIMELINE <first loop start> <loops> <last loop end> <end>" in seconds from the
#: script's start (the interpreter's start is before it: the wall times include it).
_TIMELINE = """\
import os, sys, time
T0 = time.perf_counter()
from ilcforce.compiled import aot
calls = []
find = aot.simulator
def timed_simulator(*args):
    kernel = find(*args)
    if kernel is None:
        return None
    def run(*a):
        t = time.perf_counter()
        try:
            return kernel(*a)
        finally:
            calls.append((t - T0, time.perf_counter() - t))
    return run
aot.simulator = timed_simulator
exit_now = os._exit
def _report_and_exit(code):
    end = time.perf_counter() - T0
    if calls:
        print("TIMELINE", calls[0][0], sum(d for _, d in calls), calls[-1][0] + calls[-1][1], end, file=sys.stderr)
    exit_now(code)
os._exit = _report_and_exit
sys.argv = ["ilcforce", *sys.argv[1:]]
from ilcforce.cli.entry import main
main()
"""


def cold_timelines(repeat: int, extra: Sequence[str] = (), iterations: int = ITERATIONS) -> dict[str, float]:
    """Medians over ``repeat`` cold ``simulate -m c3`` processes of their own timeline (s): the first
    loop's start and the process's end from the script's start, the compiled loops' total, the time
    between loops and after the last one. Needs the ahead-of-time kernels (numba's loop is not timed)."""
    with tempfile.TemporaryDirectory() as tmp:
        script = Path(tmp) / "timeline.py"
        script.write_text(_TIMELINE)
        rows = []
        for i in range(repeat):
            proc = subprocess.run([sys.executable, str(script), "simulate", "--method", "c3", "--iters",
                                   str(iterations), *extra, "--out", str(Path(tmp) / f"t{i}" / "c3.h5")],
                                  cwd=tmp, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
            line = [x for x in proc.stderr.splitlines() if x.startswith("TIMELINE ")]
            if proc.returncode != 0 or not line:
                raise RuntimeError(f"timeline run failed ({proc.returncode}): {proc.stderr.strip()[-500:]}")
            first, loops, last_end, end = (float(v) for v in line[-1].split()[1:])
            rows.append({"first loop": first, "loops": loops, "between loops": last_end - first - loops,
                         "after the last loop": end - last_end, "end": end})
    return {key: statistics.median(row[key] for row in rows) for key in rows[0]}


def report(repeat: int = 5, loop_repeat: int = 1, extra: Sequence[str] = (), iterations: int = ITERATIONS,
           against: str | None = None) -> None:
    """Print the cold-process figures, the loop/overhead split and the timeline inside the runs;
    with ``against`` (another tree's ``ilcforce`` console script), that tree's cold figures beside
    these, measured in the same rounds."""
    cores = os.cpu_count() or 1
    overrides = dict(_parse_set(extra))
    loop_seconds(METHODS, 1, iterations, overrides)  # warm
    rounds: list[dict[str, float]] = []
    # the loop is timed between the rounds of cold processes, not after all of them: this machine's
    # speed drifts by 20% within minutes, and the overhead compares the two
    commands = {"this tree": entry_point(), **({"against": [against]} if against else {})}
    both = cold_walls(repeat, extra, iterations, commands=commands,
                      between=lambda: rounds.append(loop_seconds(METHODS, loop_repeat, iterations, overrides)))
    walls = both["this tree"]
    loops = {method: statistics.median(r[method] for r in rounds) for method in METHODS}
    med = {k: statistics.median(v) for k, v in walls.items()}
    rng = {k: f"{min(v):.2f}-{max(v):.2f}" for k, v in walls.items()}
    from ilcforce.compiled import aot

    print(f"cold processes of {' '.join(entry_point())} (median of {repeat}, range; numba caches warm; "
          f"{cores} cores); kernels: {aot.status()}:")
    print(f"  ilcforce --help                                   : {med['help']:8.2f} s wall   ({rng['help']})")
    sim_loop = loops["c3"]
    print(f"  ilcforce simulate --method c3 --iters {iterations:<3}          : {med['simulate']:8.2f} s wall   "
          f"({rng['simulate']}); compiled loop {sim_loop:.2f} s, overhead "
          f"{100 * (1 - sim_loop / med['simulate']):.0f}%")
    ideal = loops_ideal(loops, cores)
    print(f"  ilcforce compare (c1, c2, c3 x {iterations}, stores written): {med['compare']:8.2f} s wall   "
          f"({rng['compare']}); compiled loop {sum(loops.values()):.2f} s over the methods "
          f"= {ideal:.2f} s on {min(cores, len(METHODS))} cores, overhead {100 * (1 - ideal / med['compare']):.0f}%")
    if against:
        other = {k: statistics.median(v) for k, v in both["against"].items()}
        spans = {k: f"{min(v):.2f}-{max(v):.2f}" for k, v in both["against"].items()}
        print(f"  the same rounds, alternated, through {against}:")
        for key, label in (("help", "ilcforce --help"), ("simulate", f"simulate --method c3 --iters {iterations}"),
                           ("compare", "compare (c1, c2, c3)")):
            print(f"    {label:<40}: {other[key]:6.2f} s there ({spans[key]}), {med[key]:6.2f} s here: "
                  f"{med[key] - other[key]:+.2f} s")
    if aot.module() is not None:
        line = cold_timelines(repeat, extra, iterations)
        print(f"  inside cold simulate runs (median of {repeat}; from the script's start, after the interpreter's): "
              f"first loop at {line['first loop']:.3f} s, compiled loop {line['loops']:.3f} s, between loops "
              f"{line['between loops']:.3f} s, after the last loop {line['after the last loop']:.3f} s, end "
              f"{line['end']:.3f} s: overhead {100 * (1 - line['loops'] / line['end']):.0f}% of the process's "
              "own time (the interpreter's start not counted)")


def _parse_set(extra: Sequence[str]):
    """``--set key=value`` pairs of ``extra`` as config overrides (for the in-process loop timing)."""
    from ilcforce.config_load import parse_override

    items = list(extra)
    for flag, value in zip(items[::2], items[1::2]):
        if flag == "--set":
            yield parse_override(value)


if __name__ == "__main__":
    report()
