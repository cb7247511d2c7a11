"""The least wall time any implementation of a cold ``ilcforce compare`` could take on this machine.

    python -m benchmarks.floor [--repeat 3] [--iters 20]

The target was that everything that is not the compiled loop stay under 30% of a command's wall time.
For ``compare`` (c1, c2, c3 x 20, every iteration stored) this module measures the parts that no
design can leave out, each as cheaply as it can be done, and adds them up on the machine's cores:

* **S**, the start: a cold ``python -c "import numpy"`` (wall; nothing of the run can begin before it);
* **L**, each method's compiled loops (:func:`benchmarks.cold.loop_seconds`, as ``make bench``);
* **I**, each method's inputs: every iteration's noise draws, disturbance and set-up, and tau_d of
  each true plant, by ilcforce's own functions (the same numbers the run needs);
* **W**, writing each method's iterations, three ways: today's layout through plain h5py (one
  dataset per signal with its ``units`` attribute, the file kept open: no journal, no commit per
  iteration, no metrics or provenance), one dataset per iteration (the signals stacked beforehand,
  so stacking is not counted), and the bare bytes with ``os.write`` (no format at all).

I and W are the CPU time of one thread in a warm process (median of ``repeat``): less than the same
work costs in a cold command. On C cores the command then takes at least
``S + max((sum L + sum I + sum W) / C, max L)`` (inputs and writes may overlap a method's loops on
other cores, but a core does one thing at a time), and its overhead is ``1 - ideal / that``, where
``ideal = max(sum L / C, max L)`` is the loops' own time, as in ``make bench``
(:func:`benchmarks.cold.report`). If even the bare bytes give an overhead over the target, no
store format can meet it on this machine. For contrast, the same bound for ``simulate --method c3``.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path

from benchmarks.cold import METHODS, ITERATIONS, loop_seconds, loops_ideal, median_seconds
from benchmarks.floor_writes import stack, write_bare, write_one_per_iteration, write_per_signal

LAYOUTS = ("per signal", "one per iteration", "bare bytes")


def least_wall(start: float, loops: Mapping[str, float], rest: Mapping[str, float], cores: int) -> float:
    """The least wall time (s) of running every method's ``loops`` and ``rest`` (CPU s) on ``cores``
    after a serial ``start``: neither less than all the work over the cores, nor than one method's
    loops (each runs its iterations one after another; its rest may run beside them)."""
    total = sum(loops.values()) + sum(rest.values())
    return start + max(total / cores, max(loops.values()))


def _cpu(work: Callable[[], object], repeat: int) -> float:
    """Median CPU time (s) of this thread running ``work()``."""
    return median_seconds(work, repeat, time.thread_time)


def cold_numpy(repeat: int) -> float:
    """Median wall time (s) of a cold ``python -c "import numpy"`` (one OpenBLAS thread, as the CLI)."""
    env = dict(os.environ, OPENBLAS_NUM_THREADS=os.environ.get("OPENBLAS_NUM_THREADS") or "1")
    return median_seconds(lambda: subprocess.run([sys.executable, "-c", "import numpy"], check=True, env=env), repeat)


def _inputs_cpu(config, method: str, repeat: int) -> float:
    """CPU (s) of making every iteration's inputs and each true plant's tau_d, as the inputs thread does."""
    from ilcforce.experiment import iteration_inputs, make_controller
    from ilcforce.simulate import desired_inputs, prepare_setup

    controller = make_controller(config, method)
    reference = config.reference_samples()
    ref_log = reference[:: config.simulation.log_every]

    def work():
        plants = set()
        for j in range(config.experiment.iterations):
            inputs = prepare_setup(iteration_inputs(config, j, reference, ahead=True), controller)
            plants.add(inputs.true_plant)
        for plant in plants:
            desired_inputs(plant, config.wall, ref_log)

    return _cpu(work, repeat)


def measure(methods: Sequence[str] = METHODS, iterations: int = ITERATIONS, repeat: int = 3) -> dict:
    """Every part, per method: {"start": S, "loop": {m: L}, "inputs": {m: I}, "write": {layout: {m: W}}}."""
    from ilcforce.config_load import load_config
    from ilcforce.experiment import simulate_iterations

    config = load_config(None, {"experiment.iterations": iterations})
    parts: dict = {"start": cold_numpy(max(repeat, 5)), "loop": loop_seconds(methods, repeat, iterations),
                   "inputs": {}, "write": {layout: {} for layout in LAYOUTS}}
    with tempfile.TemporaryDirectory() as tmp:
        for method in methods:
            records = list(simulate_iterations(config, method))
            parts["inputs"][method] = _inputs_cpu(config, method, repeat)
            stacked = stack(records)
            path = Path(tmp) / f"{method}.out"
            for layout, write in zip(LAYOUTS, (lambda: write_per_signal(path, records),
                                               lambda: write_one_per_iteration(path, stacked),
                                               lambda: write_bare(path, records))):
                parts["write"][layout][method] = _cpu(write, repeat)
                path.unlink()
    return parts


def report(parts: dict, cores: int, target: float = 0.30) -> list[str]:
    """The lines ``main`` prints: the parts, then the least wall time and overhead per layout."""
    loops, inputs = parts["loop"], parts["inputs"]
    ideal = loops_ideal(loops, cores)
    lines = [f"  start (cold python + numpy, wall): {parts['start']:.3f} s",
             "  method   loop (s)  inputs (s)  writes (s): " + " / ".join(LAYOUTS)]
    for m in loops:
        writes = " / ".join(f"{parts['write'][layout][m]:.3f}" for layout in LAYOUTS)
        lines.append(f"  {m:<8} {loops[m]:8.3f}  {inputs[m]:10.3f}  {writes}")
    lines.append(f"  the loops alone on {cores} cores: {ideal:.3f} s; under {100 * target:.0f}% overhead "
                 f"needs a wall time under {ideal / (1 - target):.3f} s")
    for layout in LAYOUTS:
        rest = {m: inputs[m] + parts["write"][layout][m] for m in loops}
        wall = least_wall(parts["start"], loops, rest, cores)
        overhead = 1 - ideal / wall
        lines.append(f"  least wall, writes {layout + ':':<19} {wall:.3f} s, overhead at least "
                     f"{100 * overhead:.0f}% ({'over' if overhead > target else 'within'} the target)")
    c3 = "c3" if "c3" in loops else next(iter(loops))
    wall = least_wall(parts["start"], {c3: loops[c3]}, {c3: inputs[c3] + parts["write"][LAYOUTS[0]][c3]}, cores)
    lines.append(f"  for contrast, simulate --method {c3}: least wall {wall:.3f} s, overhead at least "
                 f"{100 * (1 - loops[c3] / wall):.0f}%")
    return lines


def _positive(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        value = 0
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected a whole number of at least 1, got {text!r}")
    return value


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=_positive, default=3, help="repetitions per part (median)")
    parser.add_argument("--iters", type=_positive, default=ITERATIONS, help="iterations per method")
    parser.add_argument("--cores", type=_positive, default=os.cpu_count() or 1, help="cores to spread the work on")
    args = parser.parse_args(argv)
    parts = measure(METHODS, args.iters, args.repeat)
    print(f"floor of a cold `ilcforce compare` ({', '.join(METHODS)} x {args.iters}, every iteration written) "
          f"on {args.cores} cores, from measured parts (warm, one thread's CPU; median of {args.repeat}):")
    print("\n".join(report(parts, args.cores)))


if __name__ == "__main__":
    main()
