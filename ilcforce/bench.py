"""Speed figures for ``make bench`` (medians over repeated runs; never a timed test).

Prints microseconds per plant evaluation, per RK4 control step with a trivial (zero-torque)
controller, per full control step with C1 and C3 (implicit scheme: four law evaluations, one
plant linearisation and RK4), and the wall time of the paper's whole study (c1, c2, c3 x 20
iterations at Ts = 0.1 ms, writing HDF5). Compiled kernels come from numba's on-disk cache; the
first-call time (cache load or compilation) is printed separately.
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np
from numba import njit

from ilcforce.config import default_config
from ilcforce.controllers import REGISTRY
from ilcforce.controllers.base import LAW_SIGNATURE, MemoryController
from ilcforce.experiment import make_controller, run_method
from ilcforce.noise import draw_iteration
from ilcforce.plant import _accel_terms
from ilcforce.simulate import IterationInputs, run_iteration


@njit(LAW_SIGNATURE, cache=True, error_model="numpy")
def zero_law(k, t, meas, ref, gains, mem_prev, mem_new, write, diag):
    """A trivial controller: no torque."""
    return 0.0, 0.0


class ZeroController(MemoryController):
    name = "zero"
    law = staticmethod(zero_law)
    uses_nominal_dynamics = False
    memory_layout = {}

    def gains(self) -> np.ndarray:
        return np.zeros(9)


@njit(cache=True, error_model="numpy")
def _plant_loop(p, n):
    acc = 0.0
    for i in range(n):
        out = _accel_terms(p, 1.3 + 1e-7 * i, 0.6, 0.1, -0.2)
        acc += out[9] + out[11]
    return acc


def _median_time(fn, repeat: int) -> float:
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def _iteration_runner(config, controller):
    draws = draw_iteration(config.experiment.seed, 0, config.n_control, config.noise)
    inputs = IterationInputs(0, config.plant.links(), config.plant.links(), config.wall,
                             config.reference_samples(), config.simulation, config.noise, draws,
                             config.surface.selection)

    def run():
        mem_prev, mem_new = controller.begin_iteration(0)
        run_iteration(inputs, controller, mem_prev, mem_new)

    return run


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=7, help="repetitions per figure (median reported)")
    parser.add_argument("--study-repeat", type=int, default=3, help="repetitions of the full paper study")
    parser.add_argument("--cold-repeat", type=int, default=5, help="cold processes per user command (0: skip)")
    args = parser.parse_args(argv)
    config = default_config()
    steps = config.n_control - 1
    print(f"ilcforce bench: medians over {args.repeat} runs; {steps} control steps per iteration, Ts = "
          f"{config.simulation.sample_time:g} s, RK4 substeps = {config.simulation.substeps}")

    p = config.plant.links().as_array()
    t0 = time.perf_counter()
    _plant_loop(p, 10)
    first = time.perf_counter() - t0
    n = 1_000_000
    t = _median_time(lambda: _plant_loop(p, n), args.repeat)
    print(f"  plant evaluation (Dq^-1, Cq dtheta, J, dJ dtheta) : {t / n * 1e6:8.3f} us   (first call {first:.2f} s)")

    rows = [("RK4 control step, zero-torque controller", ZeroController(config.n_control))]
    for method in REGISTRY:  # every registered method
        rows.append((f"full control step, {method} (implicit scheme)", make_controller(config, method)))
    for label, controller in rows:
        run = _iteration_runner(config, controller)
        t0 = time.perf_counter()
        run()
        first = time.perf_counter() - t0
        t = _median_time(run, args.repeat)
        print(f"  {label:<48}: {t / steps * 1e6:8.3f} us   (first call {first:.2f} s)")

    with tempfile.TemporaryDirectory() as tmp:
        def study():
            for method in ("c1", "c2", "c3"):
                run_method(config, method, Path(tmp) / f"{method}.h5", overwrite=True, command="bench")
        t = _median_time(study, args.study_repeat)
        size = sum(f.stat().st_size for f in Path(tmp).glob("*.h5"))
    print(f"  paper study, c1+c2+c3 x {config.experiment.iterations} iterations with HDF5 : {t:8.2f} s wall "
          f"(median of {args.study_repeat}; stores {size / 1e6:.0f} MB)")
    if args.cold_repeat > 0:  # the user's commands from a cold process (ilcforce.bench_cold)
        from ilcforce import bench_cold

        bench_cold.report(repeat=args.cold_repeat)


if __name__ == "__main__":
    main()
