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

from benchmarks.cold import median_seconds as _median_time
from ilcforce.config_load import default_config
from ilcforce.controllers import REGISTRY
from ilcforce.config import ConfigError
from ilcforce.controllers.base import MemoryController
from ilcforce.controllers.nd import law_signature
from ilcforce.experiment import make_controller, run_method
from ilcforce.noise import draw_iteration
from ilcforce.plants.fivebar import _accel_terms
from ilcforce.simulate import IterationInputs, run_iteration


@njit(law_signature(), cache=True, error_model="numpy")
def zero_law(k, t, meas, ref, gains, mem_prev, mem_new, write, diag, tau):
    """A trivial controller: no torque (any n)."""
    tau[:] = 0.0
    return 0


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


def _iteration_runner(config, controller, chunk_steps=None):
    """One iteration of ``controller`` on ``config`` (its inputs made once), run by calling the result;
    ``chunk_steps`` as :func:`~ilcforce.simulate.run_iteration` takes it (None: its default)."""
    draws = draw_iteration(config.experiment.seed, 0, config.n_control, config.noise)
    inputs = IterationInputs(0, config.plant.links(), config.plant.links(), config.wall,
                             config.reference_samples(), config.simulation, config.noise, draws,
                             config.surface.selection)

    def run():
        mem_prev, mem_new = controller.begin_iteration(0)
        run_iteration(inputs, controller, mem_prev, mem_new, chunk_steps=chunk_steps)

    return run


def per_step_figures(repeat: int) -> None:
    """us per control step for each plant (ilcforce.plants.MODELS) and each registered method.

    Each robot runs its own experiment file (experiments/<model>.toml, the gains fitted to it; the
    paper's setup for the five-bar; a robot read from a model file, the first experiments/*-model.toml
    that selects it, else the first experiment file that does: arm3.toml for the spatial arm). A run that
    diverges (a zero torque lets the 2R arm fall) is timed over the steps it simulated, and marked. A method
    the robot cannot run (SL-adapt on three axes) is named and skipped.
    """
    from ilcforce.config_load import load_config
    from ilcforce.plants import DEFAULT_MODEL, MODELS
    from ilcforce.study.spec import is_study_file

    experiments = Path(__file__).resolve().parents[1] / "experiments"
    for model in MODELS:
        own = experiments / f"{model}.toml"
        files = [own] if own.is_file() else sorted(experiments.glob("*-model.toml"))
        configs = [c for c in map(load_config, files) if c.plant.model == model][:1]
        if not configs and model != DEFAULT_MODEL:  # a robot no such file selects: the first experiment that does
            others = (load_config(p) for p in sorted(experiments.glob("*.toml")) if not is_study_file(p))
            configs = [c for c in others if c.plant.model == model][:1]
        config = configs[0] if configs else load_config(None, {"plant.model": model})
        print(f"  plant {model}:")
        rows = [("RK4 control step, zero-torque controller", ZeroController(config.n_control))]
        for method in REGISTRY:  # every registered method
            try:
                rows.append((f"full control step, {method} (implicit scheme)", make_controller(config, method)))
            except ConfigError as exc:
                print(f"    {method:<46}: not run ({exc})")
        for label, controller in rows:
            draws = draw_iteration(config.experiment.seed, 0, config.n_control, config.noise, config.dimension)
            inputs = IterationInputs(0, config.plant.links(), config.plant.links(), config.wall,
                                     config.reference_samples(), config.simulation, config.noise, draws,
                                     config.surface.selection)
            records = []

            def run():
                mem_prev, mem_new = controller.begin_iteration(0)
                records.append(run_iteration(inputs, controller, mem_prev, mem_new))

            t0 = time.perf_counter()
            run()
            first = time.perf_counter() - t0
            t = _median_time(run, repeat)
            record = records[-1]
            steps = (config.n_control - 1 if not record.diverged
                     else max(1, round(record.diverged_time / config.simulation.sample_time)))
            note = f", diverged at t = {record.diverged_time:.3f} s" if record.diverged else ""
            print(f"    {label:<46}: {t / steps * 1e6:8.3f} us   (first call {first:.2f} s{note})")


def chunking_figures(repeat: int) -> None:
    """What returning to Python between chunks of the compiled loop costs, and
    how long one chunk takes at substeps = 1000 (the Ctrl-C latency bound)."""
    from ilcforce.config_load import load_config
    from ilcforce.simulate import CHUNK_RK4_STEPS

    config = default_config()
    steps = config.n_control - 1
    chunked = _iteration_runner(config, make_controller(config, "c3"), None)
    whole = _iteration_runner(config, make_controller(config, "c3"), 10 ** 9)
    chunked(), whole()
    times = {"chunked": [], "whole": []}
    for _ in range(repeat):  # alternate, so both see the same machine load; CPU time of this thread
        for name, run in (("chunked", chunked), ("whole", whole)):
            t0 = time.thread_time()
            run()
            times[name].append(time.thread_time() - t0)
    a, b = (statistics.median(times[k]) / steps * 1e6 for k in ("chunked", "whole"))
    print(f"  c3 step (CPU time), chunks of {CHUNK_RK4_STEPS} RK4 steps vs one call : {a:8.3f} vs {b:.3f} us "
          f"(chunking costs {100 * (a / b - 1):+.2f}%)")
    slow = load_config(None, {"simulation.substeps": 1000, "reference.duration": 0.02})
    chunk = max(1, CHUNK_RK4_STEPS // 1000)
    run = _iteration_runner(slow, make_controller(slow, "c3"), chunk)
    run()
    t = _median_time(run, max(3, repeat // 2))
    n_chunks = -(-slow.n_control // chunk)
    print(f"  one chunk at substeps = 1000 ({chunk} control steps), the Ctrl-C latency : "
          f"{t / n_chunks * 1e3:8.2f} ms")


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=7, help="repetitions per figure (median reported)")
    parser.add_argument("--study-repeat", type=int, default=3, help="repetitions of the full paper study")
    parser.add_argument("--mc-seeds", type=int, default=100, help="seeds of the paper's Monte Carlo study (0: skip)")
    parser.add_argument("--speedup-seeds", type=int, default=10, help="seeds of the 1 -> 2 worker study (0: skip)")
    parser.add_argument("--speedup-repeat", type=int, default=5,
                        help="alternated 1- and 2-worker runs of the speed-up study (its 2-worker cell phase, "
                             "about 8 s, varies by about 10%% between runs on this machine)")
    parser.add_argument("--cold-repeat", type=int, default=5, help="cold processes per user command (0: skip)")
    parser.add_argument("--tune-repeat", type=int, default=1,
                        help="alternated tuning/study pairs for the tuning's overhead per trial (0: skip)")
    parser.add_argument("--against", default=None,
                        help="another tree's ilcforce console script: its cold figures beside these, same rounds")
    parser.add_argument("--floor-repeat", type=int, default=3,
                        help="repetitions of each part of compare's least possible wall time (0: skip)")
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

    per_step_figures(args.repeat)
    chunking_figures(args.repeat)

    with tempfile.TemporaryDirectory() as tmp:
        def study():
            for method in ("c1", "c2", "c3"):
                run_method(config, method, Path(tmp) / f"{method}.h5", overwrite=True, command="bench")
        t = _median_time(study, args.study_repeat)
        size = sum(f.stat().st_size for f in Path(tmp).glob("*.h5"))
    print(f"  paper study, c1+c2+c3 x {config.experiment.iterations} iterations with HDF5 : {t:8.2f} s wall "
          f"(median of {args.study_repeat}; stores {size / 1e6:.0f} MB)")
    if args.cold_repeat > 0:  # the user's commands from a cold process (benchmarks.cold)
        from benchmarks import cold as bench_cold

        bench_cold.report(repeat=args.cold_repeat, against=args.against)
    if args.floor_repeat > 0:  # what no implementation of compare can go below here (benchmarks.floor)
        from benchmarks import floor as bench_floor

        bench_floor.main(["--repeat", str(args.floor_repeat)])
    study_figures(args)
    if args.tune_repeat > 0:  # what a tuning trial costs beyond the same cells in a study (benchmarks.tuning)
        from benchmarks import tuning as bench_tuning

        bench_tuning.main(["--repeat", str(args.tune_repeat)])


def study_figures(args) -> None:
    """The studies' speed and scale figures (``benchmarks.study``)."""
    from benchmarks import study as study_bench

    study_bench.main(mc_seeds=args.mc_seeds, speedup_seeds=args.speedup_seeds, repeat=args.speedup_repeat)


if __name__ == "__main__":
    main()
