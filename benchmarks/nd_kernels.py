"""The n-joint kernels' cost per call (``ilcforce.plants.nd``): ``python -m benchmarks.nd_kernels``.

Each plant's ``nd_dyn`` is called through a first-class function pointer of the interface's type (as
an n-joint loop calls it) 1e5 times inside one compiled loop, at each level, with q moving from call
to call; the best of five such loops, per call. Not part of ``make bench``: a figure for the kernels'
docstrings and for choosing what to compile, rough on a loaded machine.
"""

from __future__ import annotations

import time

import numpy as np

CALLS = 100_000
REPEATS = 5


def timing_loop():
    """A compiled ``loop(kernel, address, q, dq, level, out, calls) -> sum of oks`` (made on first call)."""
    from ilcforce.compiled import jit
    from ilcforce.plants import nd

    nb = jit.numba()

    @nb.njit(cache=False)
    def loop(kernel, address, q, dq, level, out, calls):
        total = 0.0
        for c in range(calls):
            q[0] += 1e-9  # a new state each call: nothing to hoist out of the loop
            total += kernel(address, q, dq, level, out)
        return total

    loop.compile((nd.nd_type(), nb.types.intp, *[nb.types.Array(nb.types.float64, 1, "C")] * 2, nb.types.int64,
                  nb.types.Array(nb.types.float64, 1, "C"), nb.types.int64))
    return loop


def per_call(kernel, address: int, n: int, out_width: int, level: int, loop=None) -> float:
    """Seconds per ``kernel`` call at ``level`` (the best of :data:`REPEATS` loops of :data:`CALLS` calls)."""
    loop = loop or timing_loop()
    rng = np.random.default_rng(0)
    q = rng.uniform(0.2, 1.2, n)
    dq = rng.uniform(-2.0, 2.0, n)
    out = np.zeros(out_width)
    loop(kernel, address, q, dq, level, out, 10)
    best = float("inf")
    for _ in range(REPEATS):
        start = time.perf_counter()
        loop(kernel, address, q, dq, level, out, CALLS)
        best = min(best, (time.perf_counter() - start) / CALLS)
    return best


def plants():
    """(name, kernel, address, n, width, keep-alive) of every plant with an n-joint kernel."""
    from ilcforce.config_load import load_config
    from ilcforce.plants import chain_nd, load_model, make_plant

    found = []
    arm = load_model("arm3.xml", "tool")
    found.append(("arm3.xml (chain, n = 3)", arm.nd_kernel(), arm.address, arm.n, arm.nd_width, arm))
    # a 2-joint chain (its task is still 3-D: the chain kernel's layout with task = 3, not the interface's)
    two = load_model("serial2r.xml", "tool")
    found.append(("serial2r.xml (chain, n = 2, task 3)", chain_nd.kernel(), two.address, two.n, chain_nd.width(2), two))
    for name in ("paper.toml", "serial2r.toml", "serial2r-model.toml"):
        plant = make_plant(load_config(f"experiments/{name}").plant.nominal())
        found.append((f"{name} ({type(plant).__name__}, n = 2)", plant.nd_kernel(), plant.address, 2,
                      plant.nd_width, plant))
    return found


def main() -> None:
    loop = timing_loop()
    print(f"ns per nd_dyn call through a function pointer, best of {REPEATS} x {CALLS} calls (levels 0 / 1 / 2)")
    for name, kernel, address, n, width, _alive in plants():
        times = [per_call(kernel, address, n, width, level, loop) * 1e9 for level in (0, 1, 2)]
        print(f"  {name:40s} " + " / ".join(f"{t:7.0f}" for t in times))


if __name__ == "__main__":
    main()
