"""Control-step time of one robot's methods, for the tree ``PYTHONPATH`` selects (run as a script, so that two trees
can be timed one after the other with the same script):

    PYTHONPATH=<tree> .venv/bin/python benchmarks/steps.py fivebar c3,c1,c2
    PYTHONPATH=<tree> .venv/bin/python benchmarks/steps.py serial2r c3,c2      (experiments/serial2r.toml)

Prints, per method, the median over seven runs (after one that loads the kernels) of iteration 0's wall time
divided by its control steps, in us. The robot is the paper's five-bar, or an experiment file of that name.
"""

from __future__ import annotations

import statistics
import sys
import time
from pathlib import Path


def main(model: str, methods: list[str], repeat: int = 8) -> None:
    import ilcforce
    from ilcforce.config_load import load_config
    from ilcforce.experiment import make_controller
    from ilcforce.noise import draw_iteration
    from ilcforce.simulate import IterationInputs, run_iteration

    root = Path(__file__).resolve().parents[1]
    config = (load_config(None, {"plant.model": model}) if model == "fivebar"
              else load_config(root / "experiments" / f"{model}.toml"))
    out = []
    for method in methods:
        controller = make_controller(config, method)
        draws = draw_iteration(config.experiment.seed, 0, config.n_control, config.noise, config.dimension)
        inputs = IterationInputs(0, config.plant.links(), config.plant.links(), config.wall,
                                 config.reference_samples(), config.simulation, config.noise, draws,
                                 config.surface.selection)
        times = []
        for rep in range(repeat):
            mem_prev, mem_new = controller.begin_iteration(0)
            t0 = time.perf_counter()
            run_iteration(inputs, controller, mem_prev, mem_new)
            if rep:
                times.append((time.perf_counter() - t0) / (config.n_control - 1) * 1e6)
        out.append(f"{method} {statistics.median(times):.3f}")
    print(Path(ilcforce.__file__).parents[1].name, model, " ".join(out), "(us a control step)")


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2].split(","))
