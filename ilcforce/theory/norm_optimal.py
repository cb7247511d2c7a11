"""The lifted model a norm-optimal ILC learns on (``no-ilc``, docs/methods.md#no-ilc): G, the map from the
coefficients of the learned feed-forward on its basis to the measured tracking error of the nominal closed loop.

G is made as :mod:`ilcforce.theory.lifted` makes its lifted matrices: not derived by hand but by finite
differences of the very iteration the simulator runs (the sampled-data loop, the wall, the acceleration
scheme, the law's feedback part), here on the *nominal* plant (the controller's model; the true plant's
parameter change is what the learning must survive) with the noise off, linearised about the feed-forward
u = 0 (the feedback alone tracking the reference). One simulated iteration per basis function and task axis,
plus the one at u = 0: for the paper's setup (n = 2, 100 knots) 201 iterations of the 2 s horizon.

G depends only on the nominal closed loop and the basis, so it is kept per process (:data:`_CACHE`, keyed
by everything it depends on): the runs of a study's seeds, a resume, the lifted check's controllers make
it once. Nothing here imports ``ilcforce.experiment`` (which hands :func:`lifted_model` to the controller).
"""

from __future__ import annotations

import dataclasses
import threading
import time

import numpy as np

from ilcforce.config import Config
from ilcforce.noise import draw_iteration
from ilcforce.records import STATUS_COMPLETE
from ilcforce.simulate import IterationInputs, prepare_setup, run_iteration

#: the finite-difference step on one basis coefficient, N (the noise-free loop is deterministic, so a small
#: step loses nothing to noise; it is small against the feed-forward of a few N the runs learn)
STEP = 1e-3
#: the most lifted models kept per process (each (n n_log, n M) doubles: 6.4 MB for the paper's)
CACHE_SIZE = 4

_CACHE: dict[str, tuple[np.ndarray, float]] = {}
_LOCK = threading.Lock()


class LiftedModelError(RuntimeError):
    """The nominal closed loop could not be simulated to make G (one line: where and why)."""


def _key(config: Config, controller) -> str:
    """Everything G depends on: the nominal plant, wall, reference, simulation settings, surface, the
    controller's packed gains (feedback and basis) and its memory layout."""
    parts = (config.plant.nominal(), config.wall, config.reference, config.simulation, config.surface,
             controller.gains().tobytes(), controller.n_control, sorted(controller.memory_layout.items()))
    return repr(parts)


@dataclasses.dataclass(frozen=True)
class LiftedModel:
    """A callable a ``no-ilc`` controller asks for its G: ``model(controller)`` -> G (n n_log, n M), the map
    from its basis coefficients (axis-major) to its measured error on the log grid (sample-major), with the
    sign of an output: e_{j+1} = e_j - G dc to first order. ``seconds`` of the last build are kept in
    :attr:`timings` (for the report of its cost)."""

    config: Config

    def __call__(self, controller) -> np.ndarray:
        key = _key(self.config, controller)
        with _LOCK:
            if key in _CACHE:
                return _CACHE[key][0]
        model, seconds = build(self.config, controller)
        with _LOCK:
            while len(_CACHE) >= CACHE_SIZE:
                _CACHE.pop(next(iter(_CACHE)))
            _CACHE[key] = (model, seconds)
        return model


def build_seconds(config: Config, controller) -> float | None:
    """How long the cached G of this setting took to build (s), or None if it is not built in this process."""
    found = _CACHE.get(_key(config, controller))
    return None if found is None else found[1]


def build(config: Config, controller) -> tuple[np.ndarray, float]:
    """(G, seconds): G by forward differences, one noise-free iteration of the nominal plant per coefficient."""
    start = time.perf_counter()
    quiet = dataclasses.replace(config.noise, scale=0.0)
    inputs = IterationInputs(
        iteration=0, true_plant=config.plant.nominal(), nominal_plant=config.plant.nominal(), wall=config.wall,
        reference=config.reference_samples(), settings=config.simulation, noise=quiet,
        draws=draw_iteration(config.experiment.seed, 0, config.n_control, quiet, config.dimension),
        selection=config.surface.selection)
    inputs = prepare_setup(inputs, controller)
    n, width = controller.n, max(stop for _a, stop, _u in controller.memory_layout.values())
    knots = controller.knots

    def error(coefficients: np.ndarray) -> np.ndarray:
        mem_prev = np.zeros((controller.n_control, width))
        mem_prev[:, :n] = controller.feedforward(coefficients)
        mem_new = np.full_like(mem_prev, np.nan)
        record = run_iteration(inputs, controller, mem_prev, mem_new)
        if record.status != STATUS_COMPLETE:
            raise LiftedModelError(f"{controller.name}: the nominal closed loop diverges ({record.diverged_reason}) "
                                   "while its lifted model is made: the feedback gains do not hold the nominal plant")
        return controller.error_vector(mem_new)

    coefficients = np.zeros(n * knots)
    base = error(coefficients)
    model = np.empty((base.size, coefficients.size))
    for c in range(coefficients.size):
        coefficients[c] = STEP
        model[:, c] = (base - error(coefficients)) / STEP  # output sign: more feed-forward, less error
        coefficients[c] = 0.0
    return model, time.perf_counter() - start
