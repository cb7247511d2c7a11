"""Each method's front re-evaluated on held-out seeds over a long horizon, the cap, and the gains shipped.

When a method's search has finished, its feasible front (:func:`ilcforce.tune.front.pareto_indices` of
(error, chattering)) is thinned to at most :data:`FRONT_POINTS` points spread along it
(:func:`ilcforce.tune.front.spread`), and each, with the method's trial 0 (its published gains, for
comparison), runs ``heldout_iterations`` on every held-out seed: seeds no trial was scored or checked on.
Each seed gives the mean RMS errors over the last ``score_last`` iterations, the settled H of the last
iteration per task axis, and the growth test's verdict on the whole run.

The **cap** is the reference method's trial 0 (the experiment's gains) on the same held-out seeds:
``factor`` x the median over seeds of its settled H at the last iteration, per task axis (x, y; or u, v,
n). A point is **shippable** when no held-out seed diverged, the growth test flags none, and the median
settled H at the last iteration is within the cap on every task axis; of those, the one with the lowest
error objective (of the medians) is shipped. A method with none ships no gains.
"""

from __future__ import annotations

import statistics

from ilcforce.store.tuning import record_axes
from ilcforce.tune import check
from ilcforce.tune.front import pareto_indices, spread
from ilcforce.tune.search import MethodSearch, point
from ilcforce.tune.objectives import error_value, settled_column
from ilcforce.tune.spec import Tuning
from ilcforce.tune.trial import TrialCell, diverged_at, json_float

#: Front points re-evaluated per method (the front's ends always among them).
FRONT_POINTS = 6
#: What the tuned tables say of a method that ships no gains.
NONE_UNDER_CAP = "no stable gains found under the cap"


def candidates(tuning: Tuning, trials: dict[int, dict]) -> list[int]:
    """The trial numbers of one method re-evaluated on the held-out seeds: trial 0 and its front's spread."""
    numbers = sorted(trials)
    points = [point(trials[n]) for n in numbers]
    feasible = [n for n, p in zip(numbers, points) if p is not None]
    front = [feasible[i] for i in pareto_indices([point(trials[n]) for n in feasible])]
    return sorted({*([0] if 0 in trials else []), *spread(front, FRONT_POINTS)})


def missing(tuning: Tuning, store) -> list | None:
    """(method, number) pairs still to evaluate on the held-out seeds; None while a search is unfinished
    (its front is not known yet)."""
    todo = []
    for method in tuning.methods:
        search = MethodSearch(tuning, method, store.trials.get(method, {}))
        if search.next_number() is not None:
            return None
        todo += [(method, n) for n in candidates(tuning, search.records) if (method, n) not in store.heldout]
    return todo


def run(tuning: Tuning, store, searches: dict, execute) -> int:
    """Evaluate every candidate not yet stored on the held-out seeds; store each as it finishes."""
    todo = missing(tuning, store) or []
    jobs, configs = [], {}
    for method, number in todo:
        record = searches[method].records[number]
        for seed in tuning.heldout_seeds:
            config = tuning.trial_config(method, record["params"], seed, tuning.heldout_iterations)
            cell = TrialCell(method, number, seed, "heldout")
            configs[cell] = config.to_dict()
            jobs.append((cell, (config, method, None, None)))
    pending: dict = {}
    p = tuning.base.plant.perturbation.from_iteration
    for cell, _attempt, result, failure in execute(iter(jobs)):
        rows = result["rows"] if result is not None else []
        complete = [r for r in rows if r["status"] == "complete"]
        last = complete[-tuning.score_last:] if len(complete) == len(rows) and rows else []

        def mean(column):
            return json_float(statistics.mean(float(r[column]) for r in last)) if last else None

        verdict, text = check.judge(rows, cell.method, p, configs[cell]) if rows else ("", failure or "")
        entry = {"seed": cell.seed, "iterations_run": len(rows), "diverged_iteration": diverged_at(rows),
                 "e_p": mean("position_error_rms"), "e_f": mean("force_error_rms"),
                 **{f"h_{a}": json_float(rows[-1][settled_column(a)]) if last else None for a in tuning.axes},
                 "verdict": verdict, "text": text, **({"message": failure} if failure else {})}
        key = (cell.method, cell.number)
        pending.setdefault(key, {})[cell.seed] = entry
        if len(pending[key]) == len(tuning.heldout_seeds):
            trial = searches[cell.method].records[cell.number]
            store.commit_heldout({"method": cell.method, "number": cell.number, "gains": trial["gains"],
                                  "seeds": [pending[key][s] for s in tuning.heldout_seeds]})
    return len(todo)


def summary(tuning: Tuning, record: dict) -> dict:
    """One held-out evaluation in numbers: medians over seeds (None where a seed did not complete) of
    ``e_p``, ``e_f`` and the settled H per task axis (``h_x``, ``h_y`` or ``h_u``, ``h_v``, ``h_n``; ``axes``
    names them), whether it stayed stable (no divergence, nothing flagged), its error objective."""
    from ilcforce.stability import FLAGGED

    seeds = record["seeds"]
    axes = record_axes(record)
    stable = all(e["diverged_iteration"] is None and e["verdict"] != FLAGGED and "message" not in e for e in seeds)

    def median(key):
        values = [e[key] for e in seeds]
        return statistics.median(values) if None not in values else None

    out = {"method": record["method"], "trial": record["number"], "gains": record["gains"], "stable": stable,
           "diverged": min((e["diverged_iteration"] for e in seeds if e["diverged_iteration"] is not None),
                           default=None),
           "flagged": sum(e["verdict"] == FLAGGED for e in seeds), "seeds": len(seeds),
           "axes": axes, **{k: median(k) for k in ("e_p", "e_f", *(f"h_{a}" for a in axes))}}
    out["error"] = error_value(out["e_p"], out["e_f"], tuning.objective) if stable and out["e_p"] is not None else None
    return out


def choose(tuning: Tuning, store) -> tuple[dict, tuple | None]:
    """(method -> the summary of its shipped point or None, the held-out cap (one per task axis: H_x, H_y,
    or H_u, H_v, H_n) or None before the reference's trial 0 was evaluated)."""
    reference = store.heldout.get((tuning.cap_reference, 0))
    cap = None
    if reference is not None:
        ref = summary(tuning, reference)
        if ref[f"h_{ref['axes'][0]}"] is not None:
            cap = tuple(tuning.cap_factor * ref[f"h_{a}"] for a in ref["axes"])
    chosen = {}
    for method in tuning.methods:
        options = [summary(tuning, r) for (m, _n), r in sorted(store.heldout.items()) if m == method]
        under = [o for o in options if cap is not None and o["error"] is not None
                 and all(o[f"h_{a}"] <= c for a, c in zip(o["axes"], cap, strict=True))]
        chosen[method] = min(under, key=lambda o: (o["error"], o["trial"])) if under else None
    return chosen, cap
