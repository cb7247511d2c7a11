"""One trial's cells and record: the scoring and check cells it runs, what each seed's cell gives (its
objectives from the scored iterations, the growth test's verdict on a check run), the trial's record
with its objectives, feasibility and cap, and the search's own check of a stored record.
"""

from __future__ import annotations

import json
import math
import statistics
from collections.abc import Callable
from dataclasses import dataclass

from ilcforce.store.records import RecordError
from ilcforce.store.tuning import COMPLETE, FAILED, record_axes
from ilcforce.tune import check as stability_check
from ilcforce.tune.objectives import chattering_over, error_value, scored_means, settled_column
from ilcforce.tune.spec import GainRange, SearchedGain, Tuning, definition_axes


@dataclass(frozen=True)
class TrialCell:
    """One cell of a trial: ``method`` on ``seed`` with trial ``number``'s gains; ``role`` "score" (the
    scored horizon), "check" (the stability check) or "heldout" (the front re-evaluated)."""

    method: str
    number: int
    seed: int
    role: str = "score"

    @property
    def key(self) -> str:
        return f"{self.method}-{self.number}-{self.role}-{self.seed}"


def _searched(definition: dict) -> dict:
    return {m: [SearchedGain(g["field"], tuple(GainRange(**e) if isinstance(e, dict) else e for e in g["elements"]),
                             g["vector"], g["integer"]) for g in gs] for m, gs in definition["gains"].items()}


def trial_check(definition: dict) -> Callable[[dict], None]:
    """The search's own check of a stored trial (:func:`ilcforce.store.tuning.check_record` runs it),
    from the search's stored ``definition`` (:meth:`Tuning.definition`) alone: its params are a point of
    the search space, its gains are computed from them (trial 0: the experiment's own), each scoring
    seed's error and chattering are those of its stored norms and the record's cap (a seed whose cell
    failed, with a message, ran nothing and has none), the trial is complete exactly when every seed
    scored, and its feasibility is what its check runs say."""
    from types import SimpleNamespace

    gains = _searched(definition)
    names = {m: dict(p for g in gs for p in g.parameter_names()) for m, gs in gains.items()}
    integer = {m: {n for g in gs if g.integer for n, _ in g.parameter_names()} for m, gs in gains.items()}
    experiment = json.loads(definition["experiment"])
    axes = definition_axes(definition)
    scoring = SimpleNamespace(iterations=definition["iterations"], score_last=definition["score_last"], axes=axes)

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
        cap = record["cap"]
        held = record_axes(record)
        if held not in (None, axes) or cap is not None and len(cap) != len(axes):
            raise RecordError(f"its seeds or its cap are not of the task axes {', '.join(axes)} of its experiment")
        seeds = record["seeds"]
        for entry in seeds:  # a seed whose cell failed (its "message") ran nothing: no norms, no values
            if "message" in entry and not (isinstance(entry["message"], str) and entry["message"]
                                           and entry["iterations_run"] == 0):
                raise RecordError(f"seed {entry['seed']}: a failed cell (its message) that ran iterations, or an "
                                  "empty message")
            means = scored_means(stored_rows(entry, axes), scoring)
            values = ((None, None) if means is None or cap is None else
                      (error_value(means["e_p"], means["e_f"], definition["objective"]),
                       chattering_over([means[f"h_{a}"] for a in axes], cap)))
            if values != (entry["value"], entry["chattering"]):
                raise RecordError(f"seed {entry['seed']}: its values are not the scores of its norms")
        scored = bool(seeds) and all("message" not in e and e["diverged_iteration"] is None and
                                     e["value"] is not None and e["chattering"] is not None for e in seeds)
        if scored != (record["state"] == COMPLETE):
            raise RecordError(f"its state is {str(record['state'])[:20]!r} but its seeds "
                              + ("all scored" if scored else "did not all score (a failure, a divergence or no score)"))
        checks = record["checks"]
        feasible = (record["state"] == COMPLETE and len(checks) == len(definition["check_seeds"]) and
                    all(check_passed(c, definition["check_iterations"]) for c in checks))
        if feasible != record["feasible"]:
            raise RecordError(f"feasible is {record['feasible']}, its check runs say {feasible}")

    return check


def check_passed(entry: dict, horizon: int) -> bool:
    """Whether a check run passed: it ran the whole ``horizon`` (a run stops early only when it diverged or
    the growth test flagged it) without divergence, a flag or a failure."""
    from ilcforce.stability import FLAGGED

    return (entry["diverged_iteration"] is None and entry["verdict"] != FLAGGED and "message" not in entry
            and entry["planned"] == horizon and entry["iterations_run"] == horizon)


def score_columns(axes: tuple[str, ...]) -> tuple[str, ...]:
    """The metrics columns a scoring seed stores per iteration: the RMS error norms and the settled H per
    task axis."""
    return ("position_error_rms", "force_error_rms", *(settled_column(a) for a in axes))


def stored_rows(entry: dict, axes: tuple[str, ...]) -> list[dict]:
    """A stored scoring seed's rows (on a task of ``axes``) as :func:`scored_means` reads them."""
    diverged = entry["diverged_iteration"]
    columns = score_columns(axes)
    n = entry["iterations_run"]
    if not (isinstance(n, int) and all(len(entry[c]) == n for c in columns)):
        raise RecordError(f"seed {entry['seed']}: its norms do not cover its {n} iterations")
    return [{"status": "complete" if diverged is None or j < diverged else "diverged",
             **{c: (entry[c][j] if entry[c][j] is not None else math.nan) for c in columns}} for j in range(n)]


def gains_of(tuning: Tuning, method: str, params: dict) -> dict:
    """The trial's gains as dotted keys (trial 0: the experiment's own)."""
    gains = tuning.base.gains[method]
    return {f"{method}.{g.field}": (list(getattr(gains, g.field)) if g.vector else getattr(gains, g.field))
            if not params else g.value(params) for g in tuning.gains[method]}


def json_float(value) -> float | None:
    value = float(value)
    return value if value == value and abs(value) != float("inf") else None


def diverged_at(rows: list[dict]) -> int | None:
    return next((int(r["iteration"]) for r in rows if r["status"] != "complete"), None)


def score_entry(tuning: Tuning, seed: int, result: dict | None, message: str | None, cap) -> dict:
    rows = result["rows"] if result is not None else []
    means = scored_means(rows, tuning) if result is not None else None
    values = ((None, None) if means is None or cap is None else
              (error_value(means["e_p"], means["e_f"], tuning.objective),
               chattering_over([means[f"h_{a}"] for a in tuning.axes], cap)))
    return {"seed": seed, "value": values[0], "chattering": values[1], "iterations_run": len(rows),
            "diverged_iteration": diverged_at(rows),
            **{c: [json_float(r[c]) for r in rows] for c in score_columns(tuning.axes)},
            **({"message": message} if message else {})}


def check_entry(tuning: Tuning, method: str, seed: int, result: dict | None, message: str | None,
                 config: dict) -> dict:
    rows = result["rows"] if result is not None else []
    if result is None:
        verdict, text = "", ""
    else:
        verdict, text = stability_check.judge(rows, method, tuning.base.plant.perturbation.from_iteration, config)
    return {"seed": seed, "iterations_run": len(rows), "planned": tuning.check_iterations,
            "diverged_iteration": diverged_at(rows), "verdict": verdict, "text": text,
            **{f"h_{a}_last": json_float(rows[-1][settled_column(a)]) if rows else None for a in tuning.axes},
            **({"message": message} if message else {})}


def reference_cap(record: dict, axes: tuple[str, ...]) -> tuple[float, ...] | None:
    """The search's cap (N per task axis, in the order of the axes): the median over scoring seeds of the
    reference trial 0's mean settled H over the scored iterations (before the cap factor: the chattering
    objective is relative to the reference itself); None when it did not complete."""
    if record["state"] != COMPLETE:
        return None
    scoring = _Scoring(record, axes)
    means = [scored_means(stored_rows(e, axes), scoring) for e in record["seeds"]]
    return tuple(statistics.median(m[f"h_{a}"] for m in means) for a in axes)


@dataclass(frozen=True)
class _Scoring:  # the scored horizon of a stored record (what scored_means reads)
    record: dict
    axes: tuple[str, ...]  # the task's axes

    @property
    def iterations(self) -> int:
        return self.record["scored"][0]

    @property
    def score_last(self) -> int:
        return self.record["scored"][1]


def trial_record(tuning: Tuning, method: str, number: int, params: dict, scores: list, checks: list, message: str,
            cap) -> dict:
    """A finished trial's record: its objectives (medians over scoring seeds), feasibility, every cell."""
    elapsed = sum(e.pop("_elapsed", 0.0) for e in scores + checks)
    if cap is None and not message:  # the reference's trial 0: it is its own cap
        probe = {"seeds": scores, "state": COMPLETE, "scored": [tuning.iterations, tuning.score_last]}
        ok = all(e.get("message") is None and e["diverged_iteration"] is None and
                 e["iterations_run"] >= tuning.iterations for e in scores)
        cap = reference_cap(probe, tuning.axes) if ok else None
        if cap is not None:
            for e in scores:
                means = scored_means(stored_rows(e, tuning.axes), tuning)
                e["value"] = error_value(means["e_p"], means["e_f"], tuning.objective)
                e["chattering"] = chattering_over([means[f"h_{a}"] for a in tuning.axes], cap)
    value = chattering = None
    if not message:
        for entry in scores:
            if entry.get("message"):
                message = f"seed {entry['seed']}: {entry['message']}"
            elif entry["diverged_iteration"] is not None:
                message = f"seed {entry['seed']} diverged at iteration {entry['diverged_iteration']}"
            elif entry["value"] is None or entry["chattering"] is None:
                message = f"seed {entry['seed']} has no finite score"
            if message:
                break
        else:
            value = statistics.median(e["value"] for e in scores)
            chattering = statistics.median(e["chattering"] for e in scores)
    state = COMPLETE if value is not None else FAILED
    feasible = (state == COMPLETE and len(checks) == len(tuning.check_seeds) and
                all(check_passed(c, tuning.check_iterations) for c in checks))
    if state == COMPLETE and not feasible:
        bad = next(c for c in checks if not check_passed(c, tuning.check_iterations))
        message = (f"check seed {bad['seed']}: " + (bad.get("message") or
                   (f"diverged at iteration {bad['diverged_iteration']}" if bad["diverged_iteration"] is not None
                    else f"{bad['text']} (stopped at {bad['iterations_run']} of {bad['planned']})")))
    return {"method": method, "number": number, "params": params, "gains": gains_of(tuning, method, params),
            "state": state, "value": value, "chattering": chattering, "feasible": feasible,
            "cap": list(cap) if cap is not None else None, "scored": [tuning.iterations, tuning.score_last],
            "seeds": scores, "checks": checks, "message": message, "elapsed": elapsed}
