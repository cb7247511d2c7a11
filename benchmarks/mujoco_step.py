"""MuJoCo's own step of a model file's arm, the plant alone (no controller, no contact), for scale beside ilcforce's
control step (docs/speed.md):

    .venv/bin/python -m benchmarks.mujoco_step experiments/models/serial2r.xml

RK4 at a 0.1 ms timestep (the paper's sample time, as the MuJoCo cross-check runs it); the median over seven
rounds of 20,000 ``mj_step`` calls, in us.
"""

from __future__ import annotations

import statistics
import sys
import time


def main(path: str, steps: int = 20000, rounds: int = 7) -> None:
    import mujoco

    model = mujoco.MjModel.from_xml_path(path)
    model.opt.integrator = mujoco.mjtIntegrator.mjINT_RK4
    model.opt.timestep = 1e-4
    data = mujoco.MjData(model)
    times = []
    for _ in range(rounds):
        mujoco.mj_resetData(model, data)
        t0 = time.perf_counter()
        for _ in range(steps):
            mujoco.mj_step(model, data)
        times.append((time.perf_counter() - t0) / steps * 1e6)
    print(f"{path}: mj_step (RK4, 0.1 ms) {statistics.median(times):.2f} us, {model.nv} dof")


if __name__ == "__main__":
    main(sys.argv[1])
