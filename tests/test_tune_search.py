"""A method's search as Optuna sees it (ilcforce/tune/search.py), and the stability check's early stop
(ilcforce/tune/check.py): the stability constraint reaches the sampler, for stored trials replayed on
resume as for trials told as they finish; a check run stops at 40 (or 50) iterations when the growth
test already flags it, and not otherwise."""

from __future__ import annotations

import pytest

from ilcforce.config_load import load_config
from ilcforce.store.tuning import COMPLETE, FAILED
from ilcforce.tune import build_tuning
from ilcforce.tune import check
from ilcforce.tune.search import CONSTRAINT, MethodSearch, extent
from tunekit import EXPERIMENTS, tiny_table


def record(number: int, value: float | None, chattering: float | None, feasible: bool, params: dict) -> dict:
    """The fields of a stored trial the search reads."""
    return {"method": "c1", "number": number, "params": params, "state": COMPLETE if value is not None else FAILED,
            "value": value, "chattering": chattering, "feasible": feasible, "in_sampler": True}


def infeasible_score(trial) -> float:
    """How infeasible the TPE sampler takes ``trial`` to be (0: feasible): Optuna's own function."""
    from optuna.samplers._tpe.sampler import _get_infeasible_trial_score

    return _get_infeasible_trial_score(trial)


def test_a_stored_infeasible_trial_replayed_is_infeasible_to_the_sampler():
    tuning = build_tuning(tiny_table())
    stored = {0: record(0, -2.0, 0.0, True, {}),
              1: record(1, -5.0, -1.0, False, {"k[0]": 50.0, "k[1]": 50.0}),  # better in both, but unstable
              2: record(2, -1.0, 0.5, True, {"k[0]": 3.0, "k[1]": 3.0}),
              3: record(3, None, None, False, {"k[0]": 900.0, "k[1]": 900.0})}  # failed
    search = MethodSearch(tuning, "c1", stored)
    trials = search.study.get_trials(deepcopy=False)
    assert len(trials) == 4
    assert [t.constraints for t in trials] == [{CONSTRAINT: 0.0}, {CONSTRAINT: 1.0}, {CONSTRAINT: 0.0},
                                               {CONSTRAINT: 1.0}]
    assert [infeasible_score(t) > 0 for t in trials[:3]] == [False, True, False]
    assert trials[0].params == tuning.default_params("c1")  # trial 0: the experiment's gains
    assert trials[1].values == [-5.0, -1.0] and trials[3].values is None
    # the sampler's split: the feasible trials are its good ones, the infeasible one is not, though its
    # objectives are the best of all
    from optuna.samplers._tpe.sampler import _split_trials

    from optuna.trial import TrialState

    complete = search.study.get_trials(deepcopy=False, states=(TrialState.COMPLETE,))
    below, above = _split_trials(search.study, complete, 2)
    assert {t.number for t in below} == {0, 2} and {t.number for t in above} == {1}


def test_a_trial_told_as_it_finishes_carries_the_constraint():
    tuning = build_tuning(tiny_table())
    search = MethodSearch(tuning, "c1", {0: record(0, -2.0, 0.0, True, {})})
    for number, feasible in ((1, False), (2, True)):
        params, trial = search.ask(number)
        assert set(params) == {"k[0]", "k[1]"} and trial is not None
        assert search.tell(trial, record(number, -3.0, 0.1, feasible, params))
    constraints = [t.constraints for t in search.study.get_trials(deepcopy=False)]
    assert constraints == [{CONSTRAINT: 0.0}, {CONSTRAINT: 1.0}, {CONSTRAINT: 0.0}]
    # a failed trial is a failed one to Optuna
    params, trial = search.ask(3)
    search.tell(trial, record(3, None, None, False, params))
    assert search.study.get_trials(deepcopy=False)[-1].state.name == "FAIL"


def test_trial_0_outside_the_space_is_not_told():
    tuning = build_tuning(tiny_table(gains={"c1": {"k": {"low": 100.0, "high": 1000.0}}, "c3": {"eta": {"low": 0.0,
                                                                                                     "high": 1.0}}}))
    assert not tuning.defaults_in_space("c1")  # the paper's k = (10, 100)
    search = MethodSearch(tuning, "c1", {})
    params, trial = search.ask(0)
    assert params == {} and trial is None
    assert not search.tell(None, record(0, -2.0, 0.0, True, {}))
    assert search.study.get_trials(deepcopy=False) == []


def test_extent_follows_the_stored_trials_alone():
    def rec(n, point):
        return record(n, *(point if point else (None, None)), point is not None, {} if n == 0 else {"k[0]": 1.0})

    # every trial improves: the search runs past its first budget, up to the most
    improving = {n: rec(n, (-float(n), -float(n))) for n in range(12)}
    state = extent(improving, 4, 12, 0.01)
    assert (state["trials"], state["first"], state["most"], state["converged"], state["done"], state["front"]) == \
        (12, 4, 12, False, True, 1) and state["gain"] > 0.01
    # nothing after trial 0 improves: it stops at its first budget, converged
    flat = {n: rec(n, (0.0, 0.0) if n == 0 else (0.5, 0.5)) for n in range(4)}
    state = extent(flat, 4, 12, 0.01)
    assert (state["trials"], state["converged"], state["done"], state["gain"]) == (4, True, True, 0.0)
    # a trial missing: not done, the budget is the first one
    state = extent({n: r for n, r in flat.items() if n != 2}, 4, 12, 0.01)
    assert state["trials"] == 4 and not state["done"] and state["gain"] != state["gain"]  # NaN


# ------------------------------------------------------------------------------------------------
# the check's early stop


def growing_rows(n: int, rate: float = 1.1) -> list[dict]:
    return [{"iteration": j, "status": "complete", "chattering_task_x_settled": 0.01 * rate ** j,
             "chattering_task_y_settled": 0.05, "position_error_rms": 1e-3, "force_error_rms": 0.1} for j in range(n)]


@pytest.fixture(scope="module")
def paper():
    config = load_config(EXPERIMENTS / "paper.toml")
    return config.to_dict(), config.plant.perturbation.from_iteration


def test_a_check_run_whose_learning_grows_stops_at_40(paper):
    config, p = paper
    stop = check.stopper("c1", p, config, 60)
    assert stop(growing_rows(40)) and stop(growing_rows(50))  # the prune points
    assert not any(stop(growing_rows(n)) for n in (20, 30, 39, 41, 49, 51, 59))  # judged only there
    assert check.PRUNE_AT == (40, 50)


def test_a_bounded_check_run_is_not_stopped(paper):
    config, p = paper
    stop = check.stopper("c1", p, config, 60)
    assert not stop(growing_rows(40, rate=1.0)) and not stop(growing_rows(50, rate=1.0))


def test_a_check_run_is_not_stopped_at_its_horizon(paper):
    """At the horizon the run ends anyway, and its verdict is taken on all of it."""
    config, p = paper
    assert not check.stopper("c1", p, config, 40)(growing_rows(40))
    assert not check.stopper("c1", p, config, 50)(growing_rows(50))
    assert check.stopper("c1", p, config, 50)(growing_rows(40))  # 40 is before a horizon of 50
    assert check.judge(growing_rows(40), "c1", p, config)[0] == "flagged"  # what the whole run is judged


def test_the_stopper_is_picklable_for_dask(paper):
    import pickle

    config, p = paper
    stop = pickle.loads(pickle.dumps(check.stopper("c1", p, config, 60)))
    assert stop(growing_rows(40)) and not stop(growing_rows(40, rate=1.0))


def test_run_cell_honours_the_stop(paper):
    """A real check cell stops where its stop says so (here: after 2 of 9 iterations)."""
    from ilcforce.study.cell import run_cell

    config = load_config(EXPERIMENTS / "paper.toml", {"reference.duration": 0.2, "experiment.iterations": 9})
    result = run_cell(config, "c1", None, lambda rows: len(rows) == 2)
    assert len(result["rows"]) == 2


def test_a_search_without_a_feasible_trial_is_never_called_converged():
    from ilcforce.tune.search import outcome

    empty = {"trials": 8, "done": True, "converged": True, "gain": 0.0, "front": 0}  # as extent() says it
    assert outcome(empty) == outcome(empty, gain=True) == "no feasible trial"
    grown = {**empty, "front": 3, "gain": 0.004}
    assert outcome(grown) == "converged"
    assert outcome(grown, gain=True) == "converged (front grew 0.4% over the last quarter)"
    assert outcome({**grown, "converged": False}) == "NOT converged"
    assert outcome({}) == "NOT converged"  # a search with nothing stored yet
