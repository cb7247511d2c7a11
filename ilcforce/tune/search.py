"""One method's search: an Optuna study with two objectives (error, chattering) and the stability
constraint, its stored trials replayed into it, and when it is done (:meth:`MethodSearch.target`).

The trial asked as number n depends only on the method's trials 0 .. n - 1 and on ``(sampler_seed,
method, n)`` (a fresh seeded sampler per ask), and how many trials a search runs only on its stored
trials, so a resumed tuning asks exactly what an uninterrupted one would have.
"""

from __future__ import annotations

import hashlib
import math

from ilcforce.store.tuning import COMPLETE
from ilcforce.tune import front as fronts
from ilcforce.tune.objectives import HV_REFERENCE
from ilcforce.tune.spec import Tuning


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


def sampler_seed(tuning: Tuning, method: str, number: int) -> int:
    digest = hashlib.sha256(f"{tuning.sampler_seed}/{method}/{number}".encode()).digest()
    return int.from_bytes(digest[:4], "little")


#: The name of the one constraint: 0 when the trial is feasible (stable on its check seeds), 1 when not
#: (Optuna counts a trial with a constraint value above 0 as infeasible).
CONSTRAINT = "stability"


def point(record: dict) -> tuple[float, float] | None:
    """A stored trial's (error, chattering), or None when it failed or is infeasible."""
    if record["state"] != COMPLETE or not record["feasible"]:
        return None
    return record["value"], record["chattering"]


def extent(records: dict[int, dict], first: int, most: int, stop_gain: float) -> dict:
    """How far a search with the stored trials ``records`` (number -> record) goes, from them alone: its
    ``first`` budget, then one more trial at a time while its front still improves
    (:func:`ilcforce.tune.front.converged`), up to ``most``. Returns ``trials`` (the budget now),
    ``done`` (all of them stored), ``converged``, ``gain`` (the front's relative hypervolume gain over the
    last quarter; NaN while not done), ``front`` (its feasible non-dominated trials), ``first``, ``most``."""
    def history(n):
        return [point(records[k]) for k in range(n)]

    n = first
    while n < most and all(k in records for k in range(n)):
        if fronts.converged(history(n), HV_REFERENCE, stop_gain)[0]:
            break
        n += 1
    done = all(k in records for k in range(n))
    ok, gain = fronts.converged(history(n), HV_REFERENCE, stop_gain) if done else (False, math.nan)
    points = [p for p in history(n) if p is not None] if done else []
    return {"trials": n, "first": first, "most": most, "converged": ok, "gain": gain, "done": done,
            "front": len(fronts.pareto_indices(points))}


def outcome(state: dict, *, gain: bool = False) -> str:
    """A search's outcome in words: "no feasible trial" when its front is empty (the stopping rule counts an
    empty front as not improving, so such a search stops at its first budget: it did not converge to
    anything), else "converged" (with the front's gain over the last quarter when ``gain``) or "NOT converged"."""
    if state.get("done", True) and state.get("front", 1) == 0:
        return "no feasible trial"
    if not state.get("converged"):
        return "NOT converged"
    value = state.get("gain", math.nan)
    return f"converged (front grew {value:.1%} over the last quarter)" if gain and math.isfinite(value) else "converged"


class MethodSearch:
    """One method's Optuna study, with the stored trials replayed into it."""

    def __init__(self, tuning: Tuning, method: str, stored: dict[int, dict]) -> None:
        import optuna

        self.tuning, self.method = tuning, method
        self.distributions = _distributions(tuning, method)
        self.study = optuna.create_study(directions=["minimize", "minimize"])
        self.records = dict(stored)
        for number in sorted(stored):
            if stored[number]["in_sampler"]:
                self._replay(stored[number])
        self.asked: set[int] = set()

    def _replay(self, record: dict) -> None:
        import optuna

        complete = record["state"] == COMPLETE
        trial = optuna.trial.create_trial(
            state=optuna.trial.TrialState.COMPLETE if complete else optuna.trial.TrialState.FAIL,
            values=[record["value"], record["chattering"]] if complete else None,
            params=record["params"] or self.tuning.default_params(self.method), distributions=self.distributions)
        trial.set_constraint(CONSTRAINT, 0.0 if record["feasible"] else 1.0)
        self.study.add_trial(trial)

    def target(self) -> int:
        """How many trials this search runs (:func:`extent`)."""
        return self.state()["trials"]

    def state(self) -> dict:
        """:func:`extent` of this search's stored trials."""
        return extent(self.records, self.tuning.first_budget(self.method), self.tuning.most_trials(self.method),
                      self.tuning.budget.stop_gain)

    def next_number(self) -> int | None:
        missing = [k for k in range(self.target()) if k not in self.records and k not in self.asked]
        return missing[0] if missing else None

    def ask(self, number: int) -> tuple[dict, object]:
        """(params, Optuna trial or None): trial 0 is the experiment's gains."""
        import optuna

        self.asked.add(number)
        if number == 0:
            return {}, None
        self.study.sampler = optuna.samplers.TPESampler(seed=sampler_seed(self.tuning, self.method, number))
        trial = self.study.ask(self.distributions)
        return dict(trial.params), trial

    def tell(self, trial, record: dict) -> bool:
        """Tell the sampler; returns whether it learned from this trial."""
        import optuna

        self.asked.discard(record["number"])
        if trial is not None:
            if record["state"] != COMPLETE:
                self.study.tell(trial, state=optuna.trial.TrialState.FAIL)
            else:
                trial.set_constraint(CONSTRAINT, 0.0 if record["feasible"] else 1.0)
                self.study.tell(trial, [record["value"], record["chattering"]])
            return True
        if not self.tuning.defaults_in_space(self.method):
            return False
        self._replay(record)
        return True




    def front_size(self) -> int:
        """Feasible non-dominated trials stored so far."""
        points = [point(r) for r in self.records.values()]
        return len(fronts.pareto_indices([p for p in points if p is not None]))
