"""The choice of the shipped gains on held-out records made by hand (ilcforce/tune/heldout.py): the
lowest-error point that stayed stable within the cap is shipped; a point over the cap, flagged or
diverged is not; a method with none ships nothing, is listed under [tuning] withheld, and no command
runs it with the tuned file."""

from __future__ import annotations

from types import SimpleNamespace

import pytest
from typer.testing import CliRunner

from ilcforce.cli.main import app
from ilcforce.config_load import load_config
from ilcforce.tune import build_tuning
from ilcforce.tune.heldout import candidates, choose, summary
from ilcforce.tune.output import tuned_experiment
from tunekit import tiny_table

C1_GAINS = {"c1.k": [10.0, 100.0]}


def seed(number, e_p=1e-4, e_f=0.1, h_x=0.1, h_y=0.2, verdict="not flagged", diverged=None):
    return {"seed": number, "iterations_run": 9 if diverged is None else diverged + 1, "diverged_iteration": diverged,
            "e_p": None if diverged is not None else e_p, "e_f": None if diverged is not None else e_f,
            "h_x": None if diverged is not None else h_x, "h_y": None if diverged is not None else h_y,
            "verdict": "flagged" if diverged is not None else verdict,
            "text": f"diverged at j = {diverged}" if diverged is not None else verdict}


def evaluation(method, number, gains, seeds):
    return {"method": method, "number": number, "gains": gains, "seeds": seeds}


def c3_gains(k: float) -> dict:
    return {"c3.k": [k, 100.0], "c3.eta": 5.0}


@pytest.fixture
def tuning():
    return build_tuning(tiny_table(methods=["c1", "c3", "c2"], gains={
        "c1": {"k": {"low": 1.0, "high": 1e3, "log": True}},
        "c3": {"k": [{"low": 1.0, "high": 100.0, "log": True}, 100.0]},
        "c2": {"k": {"low": 1.0, "high": 1e4, "log": True}}}))


def store(*records):
    return SimpleNamespace(heldout={(r["method"], r["number"]): r for r in records})


def test_the_lowest_error_stable_point_under_the_cap_is_chosen(tuning):
    held = store(
        # the cap: C1's trial 0, median per axis over the held-out seeds: H_x 0.1 N, H_y 0.2 N
        evaluation("c1", 0, C1_GAINS, [seed(90, h_x=0.08, h_y=0.25), seed(91, h_x=0.12, h_y=0.15)]),
        evaluation("c3", 0, c3_gains(10.0), [seed(90, e_p=1e-4), seed(91, e_p=1e-4)]),          # stable, in
        evaluation("c3", 1, c3_gains(20.0), [seed(90, e_p=1e-7, h_y=0.3), seed(91, e_p=1e-7, h_y=0.3)]),  # over H_y
        evaluation("c3", 2, c3_gains(30.0), [seed(90, e_p=1e-7), seed(91, e_p=1e-7, verdict="flagged")]),  # flagged
        evaluation("c3", 3, c3_gains(40.0), [seed(90, e_p=1e-7), seed(91, diverged=6)]),         # diverged
        evaluation("c3", 4, c3_gains(50.0), [seed(90, e_p=1e-5), seed(91, e_p=1e-5)]),          # stable, in: best
        evaluation("c3", 5, c3_gains(60.0), [seed(90, e_p=1e-6, h_x=0.11), seed(91, e_p=1e-6, h_x=0.11)]),  # over H_x
        # C2: every point over the cap, flagged or diverged
        evaluation("c2", 0, {"c2.k": [400.0, 400.0]}, [seed(90, h_x=0.5), seed(91, h_x=0.5)]),
        evaluation("c2", 1, {"c2.k": [4.0, 4.0]}, [seed(90), seed(91, diverged=3)]),
        evaluation("c2", 2, {"c2.k": [40.0, 40.0]}, [seed(90, verdict="flagged"), seed(91, verdict="flagged")]),
    )
    chosen, cap = choose(tuning, held)
    assert cap == pytest.approx((0.1, 0.2))
    assert chosen["c3"]["trial"] == 4 and chosen["c3"]["gains"] == c3_gains(50.0)
    assert chosen["c3"]["error"] == pytest.approx(-2.0 - 1.0)  # log10(1e-5 m / 1 mm) + log10(0.1 N / 1 N)
    assert chosen["c1"]["trial"] == 0  # the reference is within its own cap
    assert chosen["c2"] is None
    # what each refused point is, in the summary
    by_trial = {n: summary(tuning, r) for (m, n), r in held.heldout.items() if m == "c3"}
    assert by_trial[2]["stable"] is False and by_trial[2]["flagged"] == 1 and by_trial[2]["error"] is None
    assert by_trial[3]["stable"] is False and by_trial[3]["diverged"] == 6 and by_trial[3]["e_p"] is None
    assert by_trial[1]["stable"] and by_trial[1]["h_y"] > cap[1]
    # a looser cap (factor 2) lets the lowest-error point over the cap in: trial 1
    loose = build_tuning({**tiny_table(methods=list(tuning.methods), gains=tiny_table()["tune"]["gains"] | {
        "c2": {"k": {"low": 1.0, "high": 1e4, "log": True}}}, cap={"reference": "c1", "factor": 2.0})})
    assert choose(loose, held)[0]["c3"]["trial"] == 1


def test_ties_go_to_the_lower_trial_and_no_reference_means_no_cap(tuning):
    held = store(evaluation("c1", 0, C1_GAINS, [seed(90), seed(91)]),
                 evaluation("c1", 3, {"c1.k": [5.0, 5.0]}, [seed(90), seed(91)]),
                 evaluation("c1", 1, {"c1.k": [2.0, 2.0]}, [seed(90), seed(91)]))
    assert choose(tuning, held)[0]["c1"]["trial"] == 0
    # without the reference's trial 0 evaluated there is no cap, and nothing ships
    chosen, cap = choose(tuning, store(evaluation("c3", 0, c3_gains(10.0), [seed(90), seed(91)])))
    assert cap is None and chosen == {"c1": None, "c3": None, "c2": None}
    # the reference diverged on a held-out seed: no cap either
    chosen, cap = choose(tuning, store(evaluation("c1", 0, C1_GAINS, [seed(90), seed(91, diverged=4)])))
    assert cap is None and chosen["c1"] is None


def test_a_withheld_method_is_listed_and_refused_by_simulate(tuning, tmp_path):
    held = store(evaluation("c1", 0, C1_GAINS, [seed(90), seed(91)]),
                 evaluation("c3", 4, c3_gains(50.0), [seed(90, e_p=1e-5), seed(91, e_p=1e-5)]),
                 evaluation("c2", 0, {"c2.k": [400.0, 400.0]}, [seed(90, h_x=0.5), seed(91, h_x=0.5)]))
    chosen, cap = choose(tuning, held)
    path = tmp_path / "tiny-tuned.toml"
    path.write_text(tuned_experiment(tuning, chosen, {}, cap))
    config = load_config(path)
    assert list(config.tuning.withheld) == ["c2"] and config.tuning.source == "tiny"
    assert list(config.c3.k) == [50.0, 100.0]
    assert "c2: ? trials (NOT converged, front 0); no stable gains found under the cap: withheld" in path.read_text()
    result = CliRunner().invoke(app, ["simulate", "-c", str(path), "-m", "c2", "-n", "1", "--out",
                                      str(tmp_path / "c2.h5")])
    assert result.exit_code == 2, result.output
    lines = result.output.strip().splitlines()
    assert len(lines) == 1 and "c2 has no gains in this tuned experiment" in lines[0] and "withheld" in lines[0], \
        result.output
    assert not (tmp_path / "c2.h5").exists()


def test_the_candidates_are_trial_0_and_the_spread_of_the_feasible_front(tuning):
    def rec(point, feasible=True):
        return {"state": "complete" if point else "failed", "value": point[0] if point else None,
                "chattering": point[1] if point else None, "feasible": feasible and bool(point)}

    trials = {0: rec((0.0, 0.0)), 1: rec((-1.0, 1.0)), 2: rec((-2.0, 2.0), feasible=False), 3: rec(None),
              4: rec((1.0, -1.0)), 5: rec((2.0, 2.0))}
    # trial 0 always; the front of the feasible trials (1, 0, 4); never the infeasible 2 or the failed 3
    assert candidates(tuning, trials) == [0, 1, 4]
    many = {n: rec((float(n), -float(n))) for n in range(20)}  # all on the front
    picked = candidates(tuning, many)
    assert len(picked) == 6 and picked[0] == 0 and picked[-1] == 19
