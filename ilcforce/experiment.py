"""The iteration (learning) loop: one method, all iterations, straight into the store.

``run_method`` is the library entry point the CLI calls. Per iteration j it

1. picks the true plant (perturbed from ``plant.perturbation.from_iteration`` on) while the
   controller keeps the nominal model;
2. draws the disturbance and noise from (seed, j): the same for every method;
3. simulates the iteration (``ilcforce.simulate``), the learning updates happening inside at each
   sample (current-iteration ILC, docs/model.md#c3);
4. attaches tau_d and the learned memory and commits the iteration to the HDF5 store.

A diverged iteration is stored and ends the method's run. ``resume=True`` continues a stored run
from its last complete iteration, restoring the learned memory; because every random draw
depends on (seed, j) only, the result is bit-identical to an uninterrupted run.
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import os
import threading
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ilcforce import pipeline, samerun
from ilcforce.config import Config, ConfigError
from ilcforce.controllers import REGISTRY, MethodNameError, canonical_method
from ilcforce.controllers.nd import check_widths
from ilcforce.noise import draw_iteration
from ilcforce.records import REFERENCE_SIGNALS, STATUS_COMPLETE, STATUS_DIVERGED, IterationRecord
from ilcforce.simulate import (IterationInputs, complete_record, desired_inputs, prepare_first_chunk, prepare_setup,
                               run_iteration)
from ilcforce.task import REF_ACCELERATION, REF_FORCE, REF_POSITION, REF_VELOCITY, reference_block



class UnknownMethodError(ValueError):
    """A method name that is not in the controller registry."""


@dataclass(frozen=True)
class RunSummary:
    """What ``run_method`` did. ``rows`` holds one metrics dict per iteration run in this call."""

    path: Path
    method: str
    first_iteration: int  # first iteration simulated in this call
    rows: tuple[dict, ...]
    status: str  # "complete" or "diverged"; "complete" also when nothing was left to run

    @property
    def diverged(self) -> bool:
        return self.status == STATUS_DIVERGED


def canonical(method: str) -> str:
    """The registry's name of ``method`` (any case); UnknownMethodError, one line, for no method."""
    try:
        return canonical_method(method)
    except MethodNameError as exc:
        raise UnknownMethodError(str(exc)) from None


def make_controller(config: Config, method: str):
    """Instantiate the registered controller ``method`` (any case) with the experiment's gains."""
    method = canonical(method)
    refusal = config.tuning.refusal(method)
    if refusal:
        raise ConfigError(refusal)
    cls = REGISTRY[method].controller_class
    try:  # a table the experiment does not give keeps the planar task's defaults: refused on a task of other axes
        check_widths(method, config.gains[method], config.dimension)
    except ValueError as exc:
        raise ConfigError(str(exc)) from None
    try:
        # a law with the plant's own regressor (sl-adapt) also takes the nominal plant's parameters
        extra = ({"nominal": config.plant.nominal(), "frame": config.wall.frame(config.dimension)}
                 if getattr(cls, "needs_nominal_plant", False) else {})
        if getattr(cls, "needs_lifted_model", False):  # a law learning on the nominal closed loop's lifted map (no-ilc)
            from ilcforce.theory.norm_optimal import LiftedModel

            extra.update(lifted_model=LiftedModel(config), log_every=config.simulation.log_every)
        return cls(config.n_control, config.surface, config.wall.sign, config.gains[method],
                   gravity=config.plant.has_gravity, sample_time=config.simulation.sample_time, **extra)
    except ValueError as exc:  # gains valid alone but not with this setting (e.g. a Q cutoff above Nyquist)
        raise ConfigError(str(exc)) from None


def reference_log(config: Config) -> dict[str, np.ndarray]:
    """The /reference datasets of the store (records.REFERENCE_SIGNALS) on the log grid."""
    ref = config.reference_samples()[:: config.simulation.log_every]
    n = config.dimension
    out = {
        "time": config.control_times()[:: config.simulation.log_every],
        "position_desired": reference_block(ref, REF_POSITION, n),
        "velocity_desired": reference_block(ref, REF_VELOCITY, n),
        "acceleration_desired": reference_block(ref, REF_ACCELERATION, n),
        "force_desired": reference_block(ref, REF_FORCE, n),
    }
    assert set(out) == set(REFERENCE_SIGNALS)
    return {k: np.ascontiguousarray(v) for k, v in out.items()}


def memory_labels(controller) -> dict[str, tuple[str, ...]]:
    """Column labels of each learned-memory matrix (from the controller's memory layout)."""
    labels = getattr(controller, "learned_labels", None)
    return dict(labels()) if callable(labels) else {}


def iteration_inputs(config: Config, j: int, reference: np.ndarray, chunk_steps: int | None = None, *,
                     ahead: bool = False) -> IterationInputs:
    """What iteration ``j`` simulates apart from the controller: the true plant (perturbed from
    ``plant.perturbation.from_iteration`` on), the disturbance and noise drawn from (seed, j), the
    settings and ``reference`` (``config.reference_samples()``, made once per run). ``ahead=True``
    also makes its first chunk's disturbance now (:func:`~ilcforce.simulate.prepare_first_chunk`;
    same numbers)."""
    inputs = IterationInputs(
        iteration=j, true_plant=config.plant.true_plant(j), nominal_plant=config.plant.links(), wall=config.wall,
        reference=reference, settings=config.simulation, noise=config.noise,
        draws=draw_iteration(config.experiment.seed, j, config.n_control, config.noise, config.dimension),
        selection=config.surface.selection,
    )
    return prepare_first_chunk(inputs, chunk_steps) if ahead else inputs


def simulate_iterations(config: Config, method: str, first: int = 0, memory: dict | None = None,
                        stop_requested: Callable[[], bool] | None = None, chunk_steps: int | None = None,
                        desired_cache: dict | None = None, *, prefetch: bool = False,
                        turns: pipeline.Turns | None = None):
    """Yield the :class:`IterationRecord` of iterations ``first .. iterations - 1`` in order.

    Stops after a diverged iteration. ``memory`` (a stored learned state) seeds iteration ``first``.
    ``stop_requested()`` is looked at before each iteration (KeyboardInterrupt when true); it and
    ``chunk_steps`` go to :func:`~ilcforce.simulate.run_iteration` (an iteration in flight is
    abandoned with KeyboardInterrupt within one chunk of the request).
    ``desired_cache`` (true plant -> tau_d arrays) may be shared by callers that run many cells of
    the same wall, reference and grids (a study's worker); it must only ever hold entries computed
    for that same (wall, reference, sample_time, log_every).
    ``prefetch=True`` makes each iteration's inputs (noise, disturbance, tau_d of a new true plant)
    in a background thread while the one before simulates (for a machine with a core to spare; the
    numbers are the same). ``turns`` (:class:`ilcforce.pipeline.Turns`) is told when the compiled
    loop runs, and that background thread makes what is not needed at once while it does; it is
    over when this ends.
    """
    controller = make_controller(config, canonical(method))
    for unfinished in _unfinished_iterations(config, controller, first, memory, stop_requested, chunk_steps,
                                             desired_cache, prefetch, turns):
        yield unfinished.complete()


def _unfinished_iterations(config: Config, controller, first: int, memory: dict | None,
                           stop_requested: Callable[[], bool] | None, chunk_steps: int | None,
                           desired_cache: dict | None, prefetch: bool, turns: pipeline.Turns | None):
    """:func:`simulate_iterations`' records, each still to be completed (:class:`_Unfinished`)."""
    turns = turns if turns is not None else pipeline.Turns()
    try:
        yield from _iterations(config, controller, first, memory, stop_requested, chunk_steps, desired_cache,
                               prefetch, turns)
    finally:
        turns.over()  # also when the run fails before its first iteration


@dataclass(frozen=True)
class _Unfinished:
    """A simulated iteration whose record is completed (tau_d and the learned memory attached) by
    whoever takes it: :class:`StartedRun` hands these over, so that the simulation thread starts
    the next iteration at once, even while tau_d is still being made (cold, iteration 0's took
    about 30 ms, longer than its loop)."""

    record: IterationRecord
    desired: Callable[[], tuple[np.ndarray, np.ndarray]]
    memory: dict
    units: dict
    labels: dict

    def complete(self) -> IterationRecord:
        completed = complete_record(self.record, self.desired(), self.memory, self.units)
        return dataclasses.replace(completed, memory_labels=self.labels)


def _iterations(config: Config, controller, first: int, memory: dict | None,
                stop_requested: Callable[[], bool] | None, chunk_steps: int | None, desired_cache: dict | None,
                prefetch: bool, turns: pipeline.Turns):
    """:func:`simulate_iterations`' records, not yet completed (:class:`_Unfinished`), run by
    ``controller`` (a fresh one, made for this run: it learns from these iterations)."""
    if memory:
        controller.restore(memory)
    reference = config.reference_samples()
    ref_log = reference[:: config.simulation.log_every]
    if desired_cache is None:
        desired_cache = {}
    making: dict = {}  # true plant -> Event, while the inputs thread makes its tau_d
    finished = [first - 1]  # the last iteration whose compiled loop has returned

    def desired(true_plant, *, wait: bool = True):
        """tau_d along the reference on ``true_plant``: the cache's, or made now and kept (after the
        inputs thread, if it is making it: once is enough)."""
        event = making.get(true_plant)  # (the inputs thread removes it once made)
        if wait and event is not None:
            event.wait()
        if true_plant not in desired_cache:
            desired_cache[true_plant] = desired_inputs(true_plant, config.wall, ref_log)
        return desired_cache[true_plant]

    def prepared():
        """Each iteration's inputs; with ``prefetch``, in the background thread, which then also
        makes the tau_d of a new true plant while that iteration simulates, after the next
        iteration's inputs (the simulation needs those first; tau_d only the record's taker)."""
        later: list = []  # (iteration, new true plant) whose tau_d is still to be made
        last = config.experiment.iterations - 1
        try:
            for j in range(first, last + 1):
                if prefetch and finished[0] < j - 1:  # not awaited yet: made while iteration j - 1's loop runs
                    turns.wait()
                inputs = iteration_inputs(config, j, reference, chunk_steps, ahead=prefetch)
                if prefetch:  # the iteration then starts as soon as the one before ends
                    inputs = prepare_setup(inputs, controller)
                plant = inputs.true_plant
                if prefetch and plant not in desired_cache and plant not in making:
                    making[plant] = threading.Event()
                    later.append((j, plant))
                yield inputs
                for since, made in [(i, p) for i, p in later if i < j or j == last]:
                    turns.wait()
                    desired(made, wait=False)
                    later.remove((since, made))
                    making.pop(made).set()
                if j == first + 1:  # the tau_d of iteration `first` is made: all its end needs
                    turns.ready()
        finally:
            for _since, plant in later:  # stopped: whoever waits for one makes it
                making.pop(plant).set()
            turns.ready()  # (a run of one iteration: nothing more to make)

    with contextlib.ExitStack() as stack:
        if prefetch:
            inputs_of = iter(stack.enter_context(pipeline.Ahead(lambda stopping: prepared(), depth=2,
                                                                name="ilcforce-inputs", join=False)))
        else:
            inputs_of = prepared()
        for inputs in inputs_of:
            if stop_requested is not None and stop_requested():  # also between iterations: an iteration
                raise KeyboardInterrupt  # may be one chunk, so run_iteration might never look
            mem_prev, mem_new = controller.begin_iteration(inputs.iteration)
            record = run_iteration(inputs, controller, mem_prev, mem_new, stop_requested, chunk_steps, turns)
            finished[0] = inputs.iteration
            controller.end_iteration(record)  # between-iteration learning sees the finished iteration
            # a diverged iteration stores the memory it was writing (NaN where it never got)
            memory_now = (controller.learned_state() if record.status == STATUS_COMPLETE
                          else controller.unfinished_state())
            if record.status == STATUS_DIVERGED or inputs.iteration == config.experiment.iterations - 1:
                turns.over()  # the loop will not run again: the consumer need not wait for it
            yield _Unfinished(record, functools.partial(desired, inputs.true_plant), memory_now,
                              controller.learned_units(), memory_labels(controller))
            if record.status == STATUS_DIVERGED:
                return


#: The command line's words in a store's refusal, and what a Python caller passes instead.
_PYTHON_WORDS = (("--overwrite", "overwrite=True"), ("--resume", "resume=True"), ("--out", "out"))


def api_run_method(config: Config, method: str, out: Path, **options) -> RunSummary:
    """:func:`run_method` as ``ilcforce.run_method``: the same run, with a refusal that names the
    keyword arguments a Python caller passes (``overwrite=True replaces it or resume=True continues
    it``) instead of the command line's flags. Same exceptions, same classes."""
    from ilcforce.store import StoreError

    try:
        return run_method(config, method, out, **options)
    except StoreError as error:
        text = str(error)
        for flag, keyword in _PYTHON_WORDS:
            text = text.replace(flag, keyword)
        if text == str(error):
            raise
        raise type(error)(text) from None


def run_method(config: Config, method: str, out: Path, *, overwrite: bool = False, resume: bool = False,
               command: str = "", progress: Callable[[IterationRecord, dict], None] | None = None,
               stop_requested: Callable[[], bool] | None = None, chunk_steps: int | None = None,
               desired_cache: dict | None = None) -> RunSummary:
    """Run ``method`` over the experiment's iterations and store every iteration in ``out``.

    ``progress(record, metrics_row)`` is called after each stored iteration. If
    ``stop_requested()`` turns true (e.g. Ctrl-C), the run stops within one chunk of the compiled
    loop (a fraction of a second), abandoning the iteration in flight, by raising KeyboardInterrupt;
    every finished iteration is stored and the store is left "partial", ready for ``resume``.
    Raises ``ilcforce.store.StoreError`` for store problems (existing result, concurrent writer, ...).
    """
    method = canonical(method)  # the store says the registry's name, whatever the spelling asked
    controller = make_controller(config, method)  # fails on a bad method before any file is touched
    rows = []

    def iterations(first: int, memory: dict | None) -> StartedRun:
        return StartedRun(config, controller, first, memory, stop_requested, chunk_steps, desired_cache)

    # Iteration j + 1 simulates (compiled loop, GIL released) while j is stored. A run into a new
    # file starts simulating at once, while this thread sets up the store (an existing file is
    # checked first: a refusal must not wait for the simulation to stop; a resumed run needs the
    # store's memory). A stop request ends the simulation within one chunk (KeyboardInterrupt,
    # raised here after every finished iteration is stored); a store error stops it the same way.
    with contextlib.ExitStack() as stack:
        ahead = None
        if not resume and not os.path.lexists(out):
            ahead = stack.enter_context(iterations(0, None))
            # h5py's import holds the GIL in long calls: let iteration 0 start first
            ahead.turns.wait_ready(_START_WAIT)
        from ilcforce.store import StoreWriter  # h5py and the writer: imported while iteration 0 simulates

        writer = stack.enter_context(StoreWriter(
            out, experiment=config.experiment.name, method=method, config_toml=config.to_toml(),
            config_json=config.to_json(), seed=config.experiment.seed, command=command,
            n_iterations=config.experiment.iterations, reference=reference_log(config),
            control_time=config.control_times(), overwrite=overwrite, resume=resume,
            same_run=samerun.same_run_check(config.to_dict(), method),
        ))
        first = writer.last_complete_iteration + 1
        if resume and writer.stored_status() == STATUS_DIVERGED:
            writer.finish(STATUS_DIVERGED)
            return RunSummary(Path(out), method, first, (), STATUS_DIVERGED)
        if ahead is None:
            ahead = stack.enter_context(iterations(first, writer.resume_memory() if first > 0 else None))
        elif first != 0:  # a new store always starts at iteration 0
            raise RuntimeError(f"{out}: a new store starts at iteration {first}, not 0")
        status = STATUS_COMPLETE
        last = config.experiment.iterations - 1
        for record in ahead.records():
            if record.status == STATUS_DIVERGED:
                status = STATUS_DIVERGED
            # the last iteration's commit also marks the run finished: one commit less at the end
            ends = status == STATUS_DIVERGED or record.iteration == last
            if not ahead.queued():  # commit while the loop runs, not while the next iteration waits to start
                ahead.turns.wait()  # (unless the store is behind: the simulation may be waiting for it)
            row = writer.append(record, finish=status if ends else None)  # the store computes the metrics row
            rows.append(row)
            if progress is not None:
                progress(record, row)
        if not writer.finished:  # nothing was left to run
            writer.finish(status)
    return RunSummary(Path(out), method, first, tuple(rows), status)


class StartedRun:
    """Iterations of one run simulating in a background thread, up to :func:`records_ahead`
    finished records ahead of their consumer (:func:`run_method`, which stores them): the next
    iteration simulates while the last one is stored, and a new store opens while iteration 0
    runs. A context manager: leaving it stops the simulation within one chunk of the compiled loop
    and joins its thread."""

    def __init__(self, config: Config, controller, first: int = 0, memory: dict | None = None,
                 stop_requested: Callable[[], bool] | None = None, chunk_steps: int | None = None,
                 desired_cache: dict | None = None) -> None:
        self.first = first
        self.turns = pipeline.Turns()  # the compiled loop runs (iteration `first` has begun), or it is over

        def make(consumer_gone):
            def stopping() -> bool:
                return consumer_gone() or (stop_requested is not None and stop_requested())

            return _unfinished_iterations(config, controller, first, memory, stopping, chunk_steps, desired_cache,
                                          True, self.turns)

        self._ahead = pipeline.Ahead(make, depth=records_ahead(config))

    def records(self):
        """The :class:`IterationRecord` of each iteration, in order (iterate once); each completed
        here, in the taker's thread."""
        return (unfinished.complete() for unfinished in self._ahead)

    def queued(self) -> int:
        """How many finished records wait to be taken."""
        return self._ahead.queued()

    def close(self) -> None:
        self._ahead.close()

    def __enter__(self) -> StartedRun:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def start_iterations(config: Config, method: str, first: int = 0, memory: dict | None = None,
                     stop_requested: Callable[[], bool] | None = None, chunk_steps: int | None = None,
                     desired_cache: dict | None = None) -> StartedRun:
    """The iterations of :func:`simulate_iterations` (with ``prefetch``), started in a background
    thread at once; the taker completes each record (:meth:`StartedRun.records`)."""
    return StartedRun(config, make_controller(config, method), first, memory, stop_requested, chunk_steps,
                      desired_cache)


#: Bytes of finished records the simulation may run ahead of the store by (see :func:`records_ahead`).
RECORDS_AHEAD_BYTES = 64 * 1024**2
#: At most this many finished iterations wait for the store.
MAX_RECORDS_AHEAD = 8


def records_ahead(config: Config) -> int:
    """How many finished iterations may wait for the store (1 to :data:`MAX_RECORDS_AHEAD`): enough
    that the simulation does not wait while the store opens, within :data:`RECORDS_AHEAD_BYTES` of
    records (a record holds at most about 56 float64 per control sample:
    :func:`ilcforce.config_load.run_footprint`). A cold ``simulate`` opens its store (typer's and
    h5py's imports, the file's first commit) about 0.2 s after iteration 0 starts: with four
    records, the paper's run (7 allowed) waited 20-50 ms at its fifth iteration."""
    record_bytes = 56 * 8 * config.n_control
    return max(1, min(MAX_RECORDS_AHEAD, RECORDS_AHEAD_BYTES // max(1, record_bytes)))


def preload_kernels(config, methods: Sequence[str]) -> None:
    """Import and load in the parent what every worker would otherwise load for itself.

    Forked workers inherit the imported modules (the store's h5py among them) and the loaded
    kernels (ahead-of-time compiled, or numba's: the simulation loop, the plant's kernels, each
    method's law), so each pays for none of them again.
    """
    from ilcforce.compiled import aot
    from ilcforce.plants import make_plant
    from ilcforce.simulate import desired_inputs
    from ilcforce.store import StoreWriter  # noqa: F401  (h5py and the writer, imported once for all workers)

    robot = make_plant(config.plant.links())
    calls = getattr(robot, "calls", None)
    if calls is not None:  # the kernels of a planar plant's Python API (ahead-of-time or numba's)
        calls()
    for method in methods:
        controller = make_controller(config, method)
        if aot.simulator(controller, type(robot), type(robot)) is None:  # numba's loop, law and kernel
            from ilcforce import loop

            loop.simulator(robot.dimension)
            robot.nd_kernel()
            controller.law  # noqa: B018
    desired_inputs(config.plant.links(), config.wall, config.reference_samples()[:1])  # its kernels


#: At most this long (s) a new run's store waits to open until iteration 0 has started to simulate.
_START_WAIT = 0.5

@dataclass(frozen=True)
class StoredRun:
    """What is stored at a run's path, for the run a configuration and a method ask for.

    ``state`` is "absent", "other method" (``detail`` names it), "different run" (``detail`` names
    the keys that differ, both values), "partial" (the same run, to be continued) or "finished"
    (the same run, complete over the experiment's iterations, or diverged)."""

    state: str
    detail: str = ""


def stored_run(config: Config, method: str, path: Path) -> StoredRun:
    """Is the store at ``path`` the run of ``method`` with ``config``? The one decision, by the
    same-run policy (:mod:`ilcforce.samerun`), that ``compare`` and the report's matching use."""
    from ilcforce import store

    if not os.path.lexists(path):
        return StoredRun("absent")
    provenance = store.read_provenance(path)
    if str(provenance.get("method", method)) != method:  # e.g. another method's store copied here
        return StoredRun("other method", f"a {provenance.get('method')} run, not {method}")
    stored = samerun.stored_config(provenance)
    keys = samerun.differences(stored, config.to_dict(), method)
    if keys:
        return StoredRun("different run", samerun.describe(stored, config.to_dict(), keys))
    finished = provenance.get("run_state") == "diverged" or (
        provenance.get("run_state") == "complete" and len(store.iterations(path)) >= config.experiment.iterations)
    return StoredRun("finished" if finished else "partial")


def default_store_path(results_dir: Path, config: Config, method: str,
                       overrides: dict[str, object] | None = None) -> Path:
    """``results/<experiment>/<method>.h5``; with ``--set`` overrides, the variant's own folder
    (:func:`ilcforce.samerun.variant_folder`)."""
    folder = samerun.variant_folder(config.experiment.name, overrides or {})
    return Path(results_dir) / folder / f"{method}.h5"

