"""The tuning driver: Optuna's ask-and-tell over each method's gains, every trial's cells on the
same Dask engine as studies (:mod:`ilcforce.study.dask_run`), every finished trial stored at once.

Why Optuna: its ask-and-tell interface leaves the loop, the cluster and the store to us (a trial is
asked, its cells run wherever studies run, its value told back), its TPE sampler handles log and
linear ranges and tens of parameters, and a finished trial is replayed into a new study with
``add_trial`` — which is how a rerun resumes after ``kill -9`` without repeating a trial.

One Optuna study per method, each with the same budget (``tune.trials``). Trials go in rounds: a
round asks the next trial of every method not yet done, runs all their cells (seeds) together on
the cluster, scores and tells each trial as its last cell comes back, and stores it. The trial
asked as number n of a method depends only on that method's trials 0 .. n - 1 and on
``(sampler_seed, method, n)`` (a fresh seeded sampler per ask), so a resumed tuning asks exactly
what an uninterrupted one would have.

Trial 0 of every method is the experiment's own gains (the paper's, or a method's published
defaults), so the chosen gains can only be as good or better on the objective. It is told to the
sampler only when it lies in the search space (:meth:`Tuning.defaults_in_space`).
"""

from __future__ import annotations

import contextlib
import hashlib
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
from ilcforce.tune.output import check_output, tuned_experiment, write_output
from ilcforce.tune.spec import GainRange, SearchedGain, Tuning, TuneError, seed_score
from ilcforce.store.records import RecordError
from ilcforce.store.tuning import COMPLETE, FAILED, SCHEMA_NAME, SCHEMA_VERSION, TuningStore, TuningStoreError


@dataclass(frozen=True)
class TrialCell:
    """One cell of a trial: every iteration of ``method`` on ``seed`` with trial ``number``'s gains."""

    method: str
    number: int
    seed: int

    @property
    def key(self) -> str:
        return f"{self.method}-{self.number}-{self.seed}"


@dataclass(frozen=True)
class TuneProgress:
    """What the driver reports after each stored trial."""

    method: str
    number: int
    trials: int  # the budget per method
    state: str  # "complete" or "failed"
    value: float | None
    best_value: float | None  # the method's best so far
    best_number: int | None
    message: str


@dataclass(frozen=True)
class TuneSummary:
    path: Path
    ran: int  # trials run now
    skipped: int  # trials already stored
    best: dict  # method -> (number, value) or None
    stored: dict  # method -> trials stored (this run's and earlier runs', whatever their budget)
    tuned: Path | None  # the experiment file with the best gains (None: no method could be tuned)
    wall_time: float
    workers: int
    scheduler: str
    quarantined: tuple = ()  # one line per refused record moved aside


def _header(tuning: Tuning) -> dict:
    return {"schema": SCHEMA_NAME, "schema_version": SCHEMA_VERSION, "name": tuning.name,
            "description": tuning.description, "tuning_toml": tuning.source,
            "definition_json": json.dumps(tuning.definition(), sort_keys=True), "fingerprint": fingerprint(),
            "created": datetime.now(timezone.utc).isoformat(timespec="seconds")}


def trial_check(definition: dict) -> Callable[[dict], None]:
    """The search's own check of a stored trial (:func:`ilcforce.store.tuning.check_record` runs it),
    from the search's stored ``definition`` (:meth:`Tuning.definition`) alone: its params are a
    point of the search space, its gains are computed from them (trial 0: the experiment's own), and
    each seed's value is the score (:func:`seed_score`) of its stored error norms."""
    from types import SimpleNamespace

    gains = {m: [SearchedGain(g["field"], tuple(GainRange(**e) if isinstance(e, dict) else e for e in g["elements"]),
                              g["vector"], g["integer"]) for g in gs] for m, gs in definition["gains"].items()}
    names = {m: dict(p for g in gs for p in g.parameter_names()) for m, gs in gains.items()}
    integer = {m: {n for g in gs if g.integer for n, _ in g.parameter_names()} for m, gs in gains.items()}
    experiment = json.loads(definition["experiment"])
    scoring = SimpleNamespace(**{k: definition[k] for k in ("iterations", "score_iterations", "score_last",
                                                              "objective")})

    def check(record: dict) -> None:
        try:
            fits(record)
        except (TypeError, KeyError, ValueError, AttributeError, IndexError) as error:  # a field of the wrong kind
            raise RecordError(f"does not fit its search ({type(error).__name__}: {str(error)[:60]})") from None

    def fits(record: dict) -> None:
        method, params = record["method"], record["params"]
        if params and set(params) != set(names[method]):
            raise RecordError(f"its params are not {method}'s searched gains {sorted(names[method])[:6]}")
        for name, value in params.items():
            if not names[method][name].contains(value) or (name in integer[method] and value != int(value)):
                raise RecordError(f"param {name} = {value:.6g} is outside its range or not an integer")
        ran = ({f"{method}.{g.field}": g.value(params) for g in gains[method]} if params else
               {f"{method}.{g.field}": experiment[method][g.field] for g in gains[method]})
        if json.loads(json.dumps(ran)) != record["gains"]:
            raise RecordError("its gains are not the ones its params give")
        for entry in record["seeds"]:
            if "message" in entry:
                continue
            n, diverged = entry["iterations_run"], entry["diverged_iteration"]
            if not _is_count(n) or diverged is not None and not _is_count(diverged):
                raise RecordError(f"seed {entry['seed']}: iterations_run or diverged_iteration is no iteration count")
            rows = [{"status": "complete" if diverged is None or j < diverged else "diverged",
                     "position_error_rms": p, "force_error_rms": f}
                    for j, (p, f) in enumerate(zip(entry["position_error_rms"], entry["force_error_rms"]))]
            if len(rows) != n or any(not isinstance(r[k], (int, float)) for r in rows if r["status"] == "complete"
                                     for k in ("position_error_rms", "force_error_rms")):
                raise RecordError(f"seed {entry['seed']}: its error norms do not cover its {n} iterations")
            if seed_score(rows, scoring) != entry["value"]:
                raise RecordError(f"seed {entry['seed']}: value {entry['value']} is not the score of its error norms")

    return check


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


def _is_count(value) -> bool:
    return isinstance(value, int) and not isinstance(value, bool) and value >= 0


def tuning_dir(results_dir: Path | str, name: str) -> Path:
    """Where the tuning ``name`` is stored: ``<results>/tuning/<name>/``."""
    return Path(results_dir) / "tuning" / name


def _distributions(tuning: Tuning, method: str) -> dict:
    from optuna.distributions import FloatDistribution, IntDistribution

    out = {}
    integer = {name: g.integer for g in tuning.gains[method] for name, _ in g.parameter_names()}
    for name, r in tuning.parameters(method):
        if integer[name]:
            out[name] = IntDistribution(int(r.low), int(r.high), log=r.log)
        else:
            out[name] = FloatDistribution(r.low, r.high, log=r.log)
    return out


def _sampler_seed(tuning: Tuning, method: str, number: int) -> int:
    digest = hashlib.sha256(f"{tuning.sampler_seed}/{method}/{number}".encode()).digest()
    return int.from_bytes(digest[:4], "little")


class _MethodSearch:
    """One method's Optuna study, with the stored trials replayed into it."""

    def __init__(self, tuning: Tuning, method: str, stored: dict[int, dict]) -> None:
        import optuna

        self.tuning, self.method = tuning, method
        self.distributions = _distributions(tuning, method)
        self.study = optuna.create_study(direction="minimize")
        self.records = dict(stored)
        for number in sorted(stored):
            record = stored[number]
            if record["in_sampler"]:
                self._replay(record)
        # the trials still to run: every number below the budget not stored (a gap left by a record
        # moved aside or lost is run again; a stored trial is never run, so never overwritten)
        self.missing = [n for n in range(tuning.trials) if n not in stored]

    def _replay(self, record: dict) -> None:
        import optuna

        state = optuna.trial.TrialState.COMPLETE if record["state"] == COMPLETE else optuna.trial.TrialState.FAIL
        self.study.add_trial(optuna.trial.create_trial(
            state=state, value=record["value"] if state == optuna.trial.TrialState.COMPLETE else None,
            params=record["params"] or self.tuning.default_params(self.method), distributions=self.distributions))

    def ask(self) -> tuple[int, dict, object]:
        """(number, params, Optuna trial or None): trial 0 is the experiment's gains."""
        import optuna

        number = self.missing.pop(0)
        if number == 0:
            return 0, {}, None
        self.study.sampler = optuna.samplers.TPESampler(seed=_sampler_seed(self.tuning, self.method, number))
        trial = self.study.ask(self.distributions)
        return number, dict(trial.params), trial

    def tell(self, trial, number: int, params: dict, value: float | None) -> bool:
        """Tell the sampler; returns whether it learned from this trial."""
        import optuna

        if trial is not None:
            if value is None:
                self.study.tell(trial, state=optuna.trial.TrialState.FAIL)
            else:
                self.study.tell(trial, value)
            return True
        if not self.tuning.defaults_in_space(self.method):
            return False
        self._replay({"state": COMPLETE if value is not None else FAILED, "value": value, "params": {}})
        return True

    def best(self) -> tuple[int, float] | None:
        done = [(r["value"], n) for n, r in self.records.items() if r["state"] == COMPLETE]
        if not done:
            return None
        value, number = min(done)
        return number, value


def _gains_of(tuning: Tuning, method: str, params: dict) -> dict:
    """The trial's gains as dotted keys (trial 0: the experiment's own)."""
    gains = tuning.base.gains[method]
    return {f"{method}.{g.field}": (list(getattr(gains, g.field)) if g.vector else getattr(gains, g.field))
            if not params else g.value(params) for g in tuning.gains[method]}


def _seed_entry(tuning: Tuning, seed: int, result: dict | None, message: str | None) -> dict:
    rows = result["rows"] if result is not None else []
    diverged = next((r["iteration"] for r in rows if r["status"] != "complete"), None)
    return {"seed": seed, "value": seed_score(rows, tuning) if result is not None else None,
            "iterations_run": len(rows), "diverged_iteration": diverged,
            "position_error_rms": [_json_float(r["position_error_rms"]) for r in rows],
            "force_error_rms": [_json_float(r["force_error_rms"]) for r in rows],
            **({"message": message} if message else {})}


def _json_float(value) -> float | None:
    value = float(value)
    return value if value == value and abs(value) != float("inf") else None


def _trial_value(entries: list[dict]) -> tuple[float | None, str]:
    """The median over seeds of the seed scores, or None with the reason."""
    import statistics

    for entry in entries:
        if entry.get("message"):
            return None, f"seed {entry['seed']}: {entry['message']}"
        if entry["diverged_iteration"] is not None:
            return None, f"seed {entry['seed']} diverged at iteration {entry['diverged_iteration']}"
        if entry["value"] is None:
            return None, f"seed {entry['seed']} has no finite score"
    return statistics.median(e["value"] for e in entries), ""


def run_tuning(tuning: Tuning, results_dir: Path | str = "results", *, workers: int | None = None,
               scheduler: str | None = None, overwrite: bool = False, timeout: float = CONNECT_TIMEOUT,
               command: str = "", output: Path | None = None,
               progress: Callable[[TuneProgress], None] | None = None,
               cell_function: Callable = run_cell) -> TuneSummary:
    """Run every trial of ``tuning`` not yet in ``results/tuning/<name>/`` and store it; write the
    best gains as an experiment file (``tuned.toml`` in the store, and ``output`` if given).

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
    session = {"started": datetime.now(timezone.utc).isoformat(timespec="seconds"), "command": command,
               "host": platform.node(), "scheduler": where, "workers": workers, "trials": tuning.trials}
    store = TuningStore(tuning_dir(results_dir, tuning.name), _header(tuning), session, overwrite=overwrite,
                        check=trial_check(tuning.definition()))
    ran = 0
    try:
        skipped = sum(len(v) for v in store.trials.values())
        searches = {m: _MethodSearch(tuning, m, store.trials.get(m, {})) for m in tuning.methods}
        if any(s.missing for s in searches.values()):
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
                while True:
                    batch = _ask_round(tuning, searches)
                    if not batch:
                        break
                    ran += _run_round(tuning, searches, batch, execute, store, progress)
        best = {m: s.best() for m, s in searches.items()}
        stored = {m: len(store.trials.get(m, {})) for m in tuning.methods}
        tuned = None
        if any(b is not None for b in best.values()):
            # named after the output file when there is one: an experiments/<stem>.toml must be named <stem>
            name = Path(output).stem if output is not None else f"{tuning.name}-tuned"
            text = tuned_experiment(tuning, {m: store.trials[m][b[0]] for m, b in best.items() if b is not None},
                                    {m: store.trials[m][0] for m in tuning.methods if 0 in store.trials.get(m, {})},
                                    name=name, stored=stored)
            tuned = store.write_tuned(text)
            if output is not None:
                tuned = write_output(Path(output), text, replace=overwrite)
        else:  # nothing could be tuned: no tuned file, and none left from an earlier run to be taken for one
            (store.path / "tuned.toml").unlink(missing_ok=True)
        return TuneSummary(store.path, ran, skipped, best, stored, tuned, time.perf_counter() - start,
                           workers or 0, where, tuple(store.quarantined))
    except BaseException:
        store.discard_if_unused()  # e.g. an unreachable scheduler: no empty store left behind
        raise
    finally:
        store.close()


def _warm_up(run, tuning: Tuning) -> None:
    from ilcforce.experiment import preload_kernels

    with contextlib.suppress(Exception):
        run(preload_kernels, tuning.trial_config(tuning.methods[0], {}, tuning.seeds[0]), list(tuning.methods))


def _ask_round(tuning: Tuning, searches: dict) -> list[tuple[str, int, dict, object, dict, str]]:
    """The next trial of every method not done: (method, number, params, optuna trial, seed -> config,
    error message if the gains are not a valid configuration)."""
    batch = []
    for method, search in searches.items():
        if not search.missing:
            continue
        number, params, trial = search.ask()
        configs, message = {}, ""
        try:
            configs = {seed: tuning.trial_config(method, params, seed) for seed in tuning.seeds}
            from ilcforce.experiment import make_controller

            make_controller(configs[tuning.seeds[0]], method)  # gains valid alone but not with this setting
        except ConfigError as exc:
            configs, message = {}, f"invalid gains: {exc}"
        batch.append((method, number, params, trial, configs, message))
    return batch


def _run_round(tuning, searches, batch, execute, store, progress) -> int:
    pending = {}  # (method, number) -> {seed: entry}
    meta = {}
    jobs = []
    for method, number, params, trial, configs, message in batch:
        meta[(method, number)] = (params, trial, message)
        pending[(method, number)] = {}
        for seed, config in configs.items():
            jobs.append((TrialCell(method, number, seed), (config, method, None)))
    finished = 0

    def finish(method, number) -> None:
        nonlocal finished
        params, trial, message = meta[(method, number)]
        entries = [pending[(method, number)][s] for s in sorted(pending[(method, number)])]
        if message:
            value = None
        else:
            value, message = _trial_value(entries)
        elapsed = sum(e.pop("_elapsed", 0.0) for e in entries)
        search = searches[method]
        learned = search.tell(trial, number, params, value)
        record = {"method": method, "number": number, "params": params, "gains": _gains_of(tuning, method, params),
                  "state": COMPLETE if value is not None else FAILED, "value": value, "seeds": entries,
                  "message": message, "elapsed": elapsed,
                  "in_sampler": learned}
        store.commit(record)
        search.records[number] = store.trials[method][number]
        finished += 1
        if progress is not None:
            best = search.best()
            progress(TuneProgress(method, number, tuning.trials, record["state"], value,
                                  best[1] if best else None, best[0] if best else None, message))

    for key, (_params, _trial, message) in meta.items():
        if message:  # no cells: the gains were refused before running
            finish(*key)
    for cell, _attempt, result, failure in execute(iter(jobs)):
        entry = _seed_entry(tuning, cell.seed, result, failure)
        entry["_elapsed"] = float(result["elapsed"]) if result is not None else 0.0
        pending[(cell.method, cell.number)][cell.seed] = entry
        if len(pending[(cell.method, cell.number)]) == len(tuning.seeds):
            finish(cell.method, cell.number)
    return finished
