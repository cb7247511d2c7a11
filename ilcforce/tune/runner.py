"""The tuning driver: Optuna's ask-and-tell over each method's gains with two objectives (error and
chattering) and stability as a constraint, every trial's cells on the same Dask engine as studies
(:mod:`ilcforce.study.dask_run`), every finished trial stored at once; then the front re-evaluated on
held-out seeds (:mod:`ilcforce.tune.heldout`) and the tuned experiment file written.

Why Optuna: its ask-and-tell interface leaves the loop, the cluster and the store to us (a trial is
asked, its cells run wherever studies run, its values told back), its TPE sampler handles log and
linear ranges, tens of parameters, several objectives and constraints (a trial's constraint value
above 0 makes it infeasible: the sampler then prefers feasible regions), and a finished trial is
replayed into a new study with ``add_trial``, which is how a rerun resumes after ``kill -9`` without
repeating a trial.

One Optuna study per method. The cap's reference method runs its trial 0 (the experiment's gains) first:
its settled H on the scoring seeds is the unit of every trial's chattering objective. Then trials go in
rounds: a round asks the next trial of every method not yet done, runs their scoring cells and check cells
together on the cluster, and tells and stores each trial as its last cell comes back. The trial asked as
number n of a method depends only on that method's trials 0 .. n - 1 and on ``(sampler_seed, method,
n)``, and whether a method is done only on its stored trials (:meth:`MethodSearch.target`), so a resumed
tuning asks exactly what an uninterrupted one would have.

Trial 0 of every method is the experiment's own gains; it is told to the sampler only when it lies in
the search space (:meth:`Tuning.defaults_in_space`).
"""

from __future__ import annotations

import contextlib
import json
import os
import platform
import time
from collections.abc import Callable
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path

from ilcforce.config import ConfigError
from ilcforce.study.cell import run_cell
from ilcforce.study.dask_run import CONNECT_TIMEOUT, IN_FLIGHT_PER_THREAD, dask_client, run_on_dask
from ilcforce.study.runner import _ADDRESS, _run_in_process, fingerprint, max_local_workers
from ilcforce.tune import check as stability_check
from ilcforce.tune import heldout
from ilcforce.tune.output import check_output, tuned_experiment, write_output
from ilcforce.tune.search import MethodSearch
from ilcforce.tune.spec import Tuning, TuneError
from ilcforce.tune.trial import TrialCell, check_entry, reference_cap, score_entry, trial_check, trial_record
from ilcforce.store.tuning import SCHEMA_NAME, SCHEMA_VERSION, TuningStore, TuningStoreError


@dataclass(frozen=True)
class TuneProgress:
    """What the driver reports after each stored trial."""

    method: str
    number: int
    trials: int  # the method's budget now (its first budget, or more while its front still improves)
    state: str  # "complete" or "failed"
    value: float | None  # the error objective
    chattering: float | None  # the chattering objective
    feasible: bool
    front: int  # feasible non-dominated trials so far
    message: str


@dataclass(frozen=True)
class TuneSummary:
    path: Path
    ran: int  # trials run now
    skipped: int  # trials already stored
    searches: dict  # method -> {"trials", "first", "most", "converged", "gain", "front"}
    chosen: dict  # method -> held-out summary of its shipped point, or None (no stable gains under the cap)
    cap: tuple | None  # the held-out cap, one per task axis (H_x, H_y; or H_u, H_v, H_n), N
    tuned: Path | None  # the experiment file with the chosen gains (None: no method ships gains)
    wall_time: float
    workers: int
    scheduler: str
    quarantined: tuple = ()  # one line per refused record moved aside
    pruned: tuple = (0, 0)  # (check iterations run, check iterations planned) over this run's trials


def _header(tuning: Tuning) -> dict:
    return {"schema": SCHEMA_NAME, "schema_version": SCHEMA_VERSION, "name": tuning.name,
            "description": tuning.description, "tuning_toml": tuning.source,
            "definition_json": json.dumps(tuning.definition(), sort_keys=True), "fingerprint": fingerprint(),
            "created": datetime.now(timezone.utc).isoformat(timespec="seconds")}


def stored_check(path: Path | str) -> Callable[[dict], None]:
    """:func:`trial_check` of the search the tuning store ``path`` holds (from its checked header)."""
    from ilcforce.store.tuning import read_header

    try:
        return trial_check(json.loads(read_header(path)["definition_json"]))
    except (KeyError, TypeError, ValueError, AttributeError) as exc:
        raise TuningStoreError(f"{path}: its search definition cannot be read ({exc})") from None


def validate_tuning(path: Path | str) -> dict:
    """Check a tuning store, every trial against its search too (:func:`ilcforce.store.tuning.validate_tuning`)."""
    from ilcforce.store import tuning

    return tuning.validate_tuning(path, stored_check(path))


def read_trials(path: Path | str) -> dict[str, dict[int, dict]]:
    """Every trial of the tuning store ``path`` that passes every check: method -> {number: record}."""
    from ilcforce.store import tuning

    return tuning.read_trials(path, stored_check(path))


def tuning_dir(results_dir: Path | str, name: str) -> Path:
    """Where the tuning ``name`` is stored: ``<results>/tuning/<name>/``."""
    return Path(results_dir) / "tuning" / name


def run_tuning(tuning: Tuning, results_dir: Path | str = "results", *, workers: int | None = None,
               scheduler: str | None = None, overwrite: bool = False, timeout: float = CONNECT_TIMEOUT,
               command: str = "", output: Path | None = None,
               progress: Callable[[TuneProgress], None] | None = None,
               cell_function: Callable = run_cell) -> TuneSummary:
    """Run every trial of ``tuning`` not yet in ``results/tuning/<name>/`` and store it, re-evaluate each
    method's front on the held-out seeds, and write the chosen gains as an experiment file
    (``tuned.toml`` in the store, and ``output`` if given).

    ``workers``: local Dask workers (default: one per usable core; 1 runs in this process);
    ``scheduler``: an existing Dask scheduler's address instead. Raises TuneError (bad request),
    TuningStoreError (store cannot be used), StudyRunError (no scheduler / workers);
    KeyboardInterrupt after storing every finished trial.
    """
    import optuna

    if scheduler and workers is not None:
        raise TuneError("--workers does not apply with --scheduler (the cluster has its own workers)")
    if scheduler is not None and not _ADDRESS.fullmatch(scheduler):
        raise TuneError(f"--scheduler expects an address like tcp://HOST:PORT, got {scheduler!r}")
    if workers is not None and not 1 <= workers <= max_local_workers():
        raise TuneError(f"--workers must be 1 .. {max_local_workers()}, got {workers}")
    if not 0 < timeout < 3600:
        raise TuneError(f"--timeout must be more than 0 s and less than 3600 s, got {timeout:g}")
    if workers is None and not scheduler:
        workers = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    start = time.perf_counter()
    if output is not None:
        check_output(Path(output), tuning, overwrite=overwrite)
    where = scheduler or ("in-process" if workers == 1 else "LocalCluster")
    most = max(tuning.most_trials(m) for m in tuning.methods)
    session = {"started": datetime.now(timezone.utc).isoformat(timespec="seconds"), "command": command,
               "host": platform.node(), "scheduler": where, "workers": workers, "trials": most}
    store = TuningStore(tuning_dir(results_dir, tuning.name), _header(tuning), session, overwrite=overwrite,
                        check=trial_check(tuning.definition()))
    ran, pruned = 0, [0, 0]
    try:
        skipped = sum(len(v) for v in store.trials.values())
        searches = {m: MethodSearch(tuning, m, store.trials.get(m, {})) for m in tuning.methods}
        todo = heldout.missing(tuning, store)
        if any(s.next_number() is not None for s in searches.values()) or todo is None or todo:
            with contextlib.ExitStack() as stack:
                if scheduler or workers > 1:
                    client = stack.enter_context(dask_client(workers or 0, scheduler, timeout))
                    threads = max(1, sum(client.nthreads().values()))
                    if cell_function is run_cell:
                        _warm_up(lambda *a: client.run(*a), tuning)

                    def execute(jobs):
                        return run_on_dask(client, jobs, cell_function, IN_FLIGHT_PER_THREAD * threads)
                else:
                    if cell_function is run_cell:
                        _warm_up(lambda f, *a: f(*a), tuning)

                    def execute(jobs):
                        return _run_in_process(jobs, cell_function)
                reference = searches[tuning.cap_reference]
                if 0 not in reference.records:  # the cap first: every chattering value is relative to it
                    ran += _run_round(tuning, searches, _ask_round(tuning, {tuning.cap_reference: reference}),
                                      execute, store, progress, None, pruned)
                cap = reference_cap(reference.records[0], tuning.axes)
                if cap is None:
                    raise TuneError(f"the cap's reference {tuning.cap_reference} did not complete its scored "
                                    f"iterations with the experiment's gains ({reference.records[0]['message']}); "
                                    "there is no chattering cap to tune against")
                while True:
                    batch = _ask_round(tuning, searches)
                    if not batch:
                        break
                    ran += _run_round(tuning, searches, batch, execute, store, progress, cap, pruned)
                heldout.run(tuning, store, searches, execute)
        states = {m: s.state() for m, s in searches.items()}
        chosen, cap = heldout.choose(tuning, store)
        tuned = None
        if any(c is not None for c in chosen.values()):
            # named after the output file when there is one: an experiments/<stem>.toml must be named <stem>
            name = Path(output).stem if output is not None else f"{tuning.name}-tuned"
            text = tuned_experiment(tuning, chosen, states, cap, name=name)
            if store.tuned_text() != text or output is not None:
                tuned = store.write_tuned(text) if store.tuned_text() != text else store.path / "tuned.toml"
            else:
                tuned = store.path / "tuned.toml"
            if output is not None:  # its model-file paths relative to where it is written
                text = tuned_experiment(tuning, chosen, states, cap, name=name, folder=Path(output).parent)
                tuned = write_output(Path(output), text, replace=overwrite)
        else:  # no method ships gains: no tuned file, and none left from an earlier run to be taken for one
            (store.path / "tuned.toml").unlink(missing_ok=True)
        return TuneSummary(store.path, ran, skipped, states, chosen, cap, tuned, time.perf_counter() - start,
                           workers or 0, where, tuple(store.quarantined), tuple(pruned))
    except BaseException:
        store.discard_if_unused()  # e.g. an unreachable scheduler: no empty store left behind
        raise
    finally:
        store.close()


def _warm_up(run, tuning: Tuning) -> None:
    from ilcforce.experiment import preload_kernels

    with contextlib.suppress(Exception):
        run(preload_kernels, tuning.trial_config(tuning.methods[0], {}, tuning.seeds[0]), list(tuning.methods))


def _ask_round(tuning: Tuning, searches: dict) -> list[tuple]:
    """The next trial of every method not done: (method, number, params, optuna trial, [(cell, args)],
    error message if the gains are not a valid configuration)."""
    batch = []
    for method, search in searches.items():
        number = search.next_number()
        if number is None:
            continue
        params, trial = search.ask(number)
        jobs, message = [], ""
        try:
            from ilcforce.experiment import make_controller

            for seed in tuning.seeds:
                config = tuning.trial_config(method, params, seed)
                jobs.append((TrialCell(method, number, seed), (config, method, None, None)))
            make_controller(jobs[0][1][0], method)  # gains valid alone but not with this setting
            p = tuning.base.plant.perturbation.from_iteration
            for seed in tuning.check_seeds:
                config = tuning.trial_config(method, params, seed, tuning.check_iterations)
                stop = stability_check.stopper(method, p, config.to_dict(), tuning.check_iterations)
                jobs.append((TrialCell(method, number, seed, "check"), (config, method, None, stop)))
        except ConfigError as exc:
            jobs, message = [], f"invalid gains: {exc}"
        batch.append((method, number, params, trial, jobs, message))
    return batch


def _run_round(tuning, searches, batch, execute, store, progress, cap, pruned) -> int:
    pending: dict = {}  # (method, number) -> {cell: entry}
    meta, expected = {}, {}
    jobs = []
    for method, number, params, trial, cells, message in batch:
        meta[(method, number)] = (params, trial, message, {c: a[0].to_dict() for c, a in cells})
        pending[(method, number)] = {}
        expected[(method, number)] = len(cells)
        jobs.extend(cells)
    finished = 0

    def finish(method, number) -> None:
        nonlocal finished
        params, trial, message, _configs = meta[(method, number)]
        cells = pending[(method, number)]
        scores = [cells[c] for c in sorted(cells, key=lambda c: c.seed) if c.role == "score"]
        checks = [cells[c] for c in sorted(cells, key=lambda c: c.seed) if c.role == "check"]
        record = trial_record(tuning, method, number, params, scores, checks, message, cap)
        search = searches[method]
        record["in_sampler"] = search.tell(trial, record)
        store.commit(record)
        search.records[number] = store.trials[method][number]
        pruned[0] += sum(c["iterations_run"] for c in checks)
        pruned[1] += tuning.check_iterations * len(checks)
        finished += 1
        if progress is not None:
            state = search.state()
            progress(TuneProgress(method, number, state["trials"], record["state"], record["value"],
                                  record["chattering"], record["feasible"], search.front_size(), record["message"]))

    for key, (_params, _trial, message, _configs) in meta.items():
        if message:  # no cells: the gains were refused before running
            finish(*key)
    for cell, _attempt, result, failure in execute(iter(jobs)):
        configs = meta[(cell.method, cell.number)][3]
        if cell.role == "score":
            entry = score_entry(tuning, cell.seed, result, failure, cap)
        else:
            entry = check_entry(tuning, cell.method, cell.seed, result, failure, configs[cell])
        entry["_elapsed"] = float(result["elapsed"]) if result is not None else 0.0
        pending[(cell.method, cell.number)][cell] = entry
        if len(pending[(cell.method, cell.number)]) == expected[(cell.method, cell.number)]:
            finish(cell.method, cell.number)
    return finished
